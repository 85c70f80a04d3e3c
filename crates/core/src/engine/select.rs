//! Elitist, deterministic selection in O(N): which flies are the `keep` fittest, and the
//! compaction that moves them to the front ([`Survival`]).
//!
//! A sort costs O(N log N) and a comparison-based selection chases an index array through the
//! fitness array. Non-negative f32 compare like their bit patterns as integers, so a radix pass
//! finds the histogram bin that holds the boundary; only the flies of that one bin need an exact
//! selection. Ties at the boundary go to the lower index, so the result depends only on the
//! fitness values, never on an earlier permutation.

use super::Population;
use super::lists::gather_flags;
use crate::isa::{Isa, dispatch};

/// Bins of the radix pass: the top 15 bits below the sign (exponent and 7 mantissa bits, so a
/// bin spans under 1 % of fitness). The finer the bins, the fewer flies share the boundary bin,
/// whose flies are searched for chunk by chunk and then selected exactly: with 2048 bins it held
/// hundreds of flies. Only the band of bins between the smallest and the largest
/// nonzero key (and bin 0) is cleared and counted each generation: a few thousand of them.
const BINS: usize = 1 << (31 - SHIFT);
const SHIFT: u32 = 16;

/// Keys tested at once for the boundary bin.
const CHUNK: usize = 32;

/// Survival: the `keep` fittest flies (by shared fitness) move to the front of the population,
/// in place. Owns the selection and the compaction's lists.
#[derive(Debug, Clone)]
pub(super) struct Survival {
    selector: Selector,
    /// Survivor flags of the current selection.
    chosen: Vec<bool>,
    /// Non-survivor slots below `keep`, survivors above it.
    holes: Vec<u32>,
    movers: Vec<u32>,
}

impl Survival {
    pub(super) fn new(flies: usize) -> Self {
        Self {
            selector: Selector::new(flies),
            chosen: vec![false; flies],
            holes: vec![0; flies],
            movers: vec![0; flies],
        }
    }

    /// Selects the `keep` fittest flies of `pop` and compacts them into `0..keep`.
    pub(super) fn run(&mut self, isa: Isa, pop: &mut Population, keep: usize) {
        let n = pop.len();
        let t = super::phase::start(super::phase::Phase::Select);
        self.selector
            .select_on(isa, &pop.fitness, keep, &mut self.chosen);
        t.stop();
        let _t = super::phase::start(super::phase::Phase::Compact);
        // Each non-survivor slot below `keep` takes a survivor from above it, the k-th hole
        // the k-th such survivor. There are exactly as many of one as of the other. Survivors
        // already below `keep` (the usual case for long-lived flies) do not move. The two
        // lists are built without branches (a survivor flag is a coin toss to a predictor).
        let holes = gather_flags(isa, &self.chosen[..keep], false, 0, &mut self.holes);
        let movers = gather_flags(isa, &self.chosen[keep..n], true, keep, &mut self.movers);
        for k in 0..holes.min(movers) {
            pop.move_fly(self.holes[k] as usize, self.movers[k] as usize);
        }
    }
}

#[derive(Debug, Clone)]
pub(crate) struct Selector {
    hist: Vec<u32>,
    boundary: Vec<u64>,
    /// Radix key of every fly, computed once (a vectorised pass).
    keys: Vec<u32>,
}

/// Radix key of a fitness: NaN and non-positive values rank as zero.
#[inline]
fn key(f: f32) -> u32 {
    if f > 0.0 { f.to_bits() } else { 0 }
}

impl Selector {
    pub(crate) fn new(flies: usize) -> Self {
        Self {
            hist: vec![0; BINS],
            boundary: Vec::with_capacity(flies),
            keys: vec![0; flies],
        }
    }

    dispatch! {
        /// [`Selector::select`] compiled for instruction set `isa` (the same flies on each).
        pub(crate) fn select_on(self: &mut Selector, fitness: &[f32], keep: usize, chosen: &mut [bool]);
        up to Avx512 => Selector::select
    }

    /// Sets `chosen[i]` for exactly `keep` flies: the fittest, ties to the lower index.
    #[inline(always)]
    pub(crate) fn select(&mut self, _: Isa, fitness: &[f32], keep: usize, chosen: &mut [bool]) {
        let n = fitness.len().min(chosen.len()).min(self.keys.len());
        let keep = keep.min(n);
        let keys = &mut self.keys[..n];
        // Keys, and the smallest nonzero and the largest one (vectorised min / max).
        let (mut low, mut top) = (u32::MAX, 0);
        for (k, &f) in keys.iter_mut().zip(&fitness[..n]) {
            *k = key(f);
            low = low.min(if *k == 0 { u32::MAX } else { *k });
            top = top.max(*k);
        }
        // Every key lies in bin 0 or in `low_bin..=top_bin`: only those bins are cleared and
        // read (the others keep stale counts).
        let top_bin = (top >> SHIFT) as usize;
        let low_bin = ((low >> SHIFT) as usize).min(top_bin);
        // (Bin 0 is the last one read, so its count never matters; cleared all the same, so it
        // cannot overflow over a long run.)
        self.hist[0] = 0;
        self.hist[low_bin..=top_bin].fill(0);
        for &k in keys.iter() {
            // Keys are below 2^31 (non-negative f32): the mask only drops the bounds check.
            self.hist[(k >> SHIFT) as usize & (BINS - 1)] += 1;
        }
        // The bin holding the keep-th best, and how many flies rank strictly above it.
        let (mut bin, mut above) = (top_bin, 0usize);
        loop {
            let c = self.hist[bin] as usize;
            if above + c >= keep || bin == 0 {
                break;
            }
            above += c;
            // Below the band only bin 0 holds keys.
            bin = if bin <= low_bin { 0 } else { bin - 1 };
        }
        self.boundary.clear();
        // Compared in u32, as the keys are: the flag pass vectorises.
        let bin32 = bin as u32;
        for (c, &k) in chosen[..n].iter_mut().zip(keys.iter()) {
            *c = (k >> SHIFT) > bin32;
        }
        // The boundary bin holds a few flies: a vectorised test finds the chunks that hold one,
        // and only those are searched (a branch per fly cost more than the rest together).
        for (c, chunk) in keys.chunks(CHUNK).enumerate() {
            if !chunk
                .iter()
                .fold(false, |any, &k| any | ((k >> SHIFT) == bin32))
            {
                continue;
            }
            for (j, &k) in chunk.iter().enumerate() {
                if (k >> SHIFT) == bin32 {
                    let i = c * CHUNK + j;
                    // Larger key = better: fitness first, then the lower index.
                    self.boundary
                        .push(((k as u64) << 32) | (!(i as u32)) as u64);
                }
            }
        }
        let need = keep - above;
        let m = self.boundary.len();
        if need < m {
            if need > 0 {
                self.boundary.select_nth_unstable(m - need);
            }
            for &k in &self.boundary[m - need..] {
                chosen[!(k as u32) as usize] = true;
            }
        } else {
            for &k in &self.boundary {
                chosen[!(k as u32) as usize] = true;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference: a full sort, ties to the lower index.
    fn reference(fitness: &[f32], keep: usize) -> Vec<bool> {
        let mut idx: Vec<usize> = (0..fitness.len()).collect();
        idx.sort_by(|&a, &b| key(fitness[b]).cmp(&key(fitness[a])).then(a.cmp(&b)));
        let mut chosen = vec![false; fitness.len()];
        for &i in &idx[..keep] {
            chosen[i] = true;
        }
        chosen
    }

    fn check(fitness: &[f32], keep: usize) {
        // Every instruction set this CPU has (the SIMD ones print no SKIP: the baseline alone is
        // the whole of the selection's code, the others are the same code compiled wider).
        for &isa in Isa::available() {
            let mut chosen = vec![false; fitness.len()];
            Selector::new(fitness.len()).select_on(isa, fitness, keep, &mut chosen);
            assert_eq!(
                chosen,
                reference(fitness, keep),
                "{isa:?} {fitness:?} keep {keep}"
            );
            assert_eq!(chosen.iter().filter(|&&c| c).count(), keep);
        }
    }

    #[test]
    fn a_reused_selector_ignores_the_bins_of_earlier_generations() {
        // Each call clears only the bins its keys fall in: fitness ranges that move up and
        // down between calls must not read the stale counts of the others.
        let mut s = Selector::new(64);
        for (round, scale) in [1e3f32, 1e-3, 1.0, 1e6, 1e-6, 0.0, 10.0]
            .into_iter()
            .enumerate()
        {
            let fitness: Vec<f32> = (0..64)
                .map(|i| match (i * 7 + round) % 5 {
                    0 => 0.0,
                    r => scale * (1.0 + (i % 9) as f32 * 0.37) * r as f32,
                })
                .collect();
            for keep in [0, 1, 13, 40, 64] {
                let mut chosen = vec![false; 64];
                s.select(Isa::BASELINE, &fitness, keep, &mut chosen);
                assert_eq!(
                    chosen,
                    reference(&fitness, keep),
                    "scale {scale} keep {keep}"
                );
            }
        }
    }

    #[test]
    fn matches_a_full_sort() {
        check(&[3.0, 1.0, 2.0, 5.0, 4.0], 2);
        check(&[0.0, 0.0, 0.0, 1.0], 2); // ties at zero go to the lower index
        check(&[1.0, 1.0, 1.0, 1.0], 3);
        check(&[f32::NAN, -1.0, 2.0, 0.5], 2); // NaN and negatives rank as zero
        check(&[7.0; 10], 0);
        check(&[7.0; 10], 10);
        // Values sharing a radix bin (same exponent, close mantissas).
        check(&[1.0, 1.0001, 1.0002, 1.00005, 0.999, 1.0003], 3);
        let mut next = crate::test_support::xorshift32(0x1234_5678);
        let many: Vec<f32> = (0..5000)
            .map(|_| {
                let x = next();
                if x.is_multiple_of(7) {
                    0.0
                } else {
                    (x % 100_000) as f32 * 1e-3
                }
            })
            .collect();
        check(&many, 2000);
    }
}
