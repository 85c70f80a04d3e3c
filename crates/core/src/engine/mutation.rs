//! Gaussian mutation (the paper's), in two passes so that no coin toss is a branch.
//!
//! Each offspring's coins are drawn by the breeding loop (16 bits a coordinate of one word,
//! [`super::breeding::Breeder::coins`]): coordinate k of fly j moves with probability
//! `threshold / 65536`. One pass over the coins lists, without branches, the flies each
//! coordinate moves ([`super::lists`]' kernels); then only those draw a normal. This room owns
//! the lists.

#[cfg(target_arch = "x86_64")]
use super::lists::{compress16, left_pack8};
use crate::isa::{Isa, Level, dispatch};
use rand::Rng;
use rand::rngs::Xoshiro256PlusPlus;
use rand_distr::{Distribution, StandardNormal};

/// The mutation and its scratch: three lists of up to n flies, one per coordinate.
#[derive(Debug, Clone)]
pub(super) struct Mutation {
    hits: Vec<u32>,
}

impl Mutation {
    /// Room for mutating up to `flies` flies at once.
    pub(super) fn new(flies: usize) -> Self {
        Self {
            hits: vec![0; 3 * flies],
        }
    }

    /// Mutates flies `[x, y, z]` (their coins are `coins`, one word a fly) on instruction set
    /// `isa`: see [`mutate_at`] (the same flies on every set).
    pub(super) fn run(
        &mut self,
        isa: Isa,
        coords: [&mut [f32]; 3],
        coins: &[u64],
        generator: &mut Xoshiro256PlusPlus,
        threshold: u32,
        sigma: f32,
    ) {
        mutate_on(
            isa,
            coords,
            coins,
            &mut self.hits,
            generator,
            threshold,
            sigma,
        );
    }
}

dispatch! {
    /// [`mutate_at`] compiled for instruction set `isa` (the same flies on each: integer and
    /// f32 arithmetic only), the coins' lists made 8 (AVX2) or 16 (AVX-512) coins at a time.
    fn mutate_on(
        coords: [&mut [f32]; 3],
        masks: &[u64],
        hits: &mut [u32],
        generator: &mut Xoshiro256PlusPlus,
        threshold: u32,
        sigma: f32,
    );
    up to Avx512 => mutate_at
}

/// Gaussian mutation of flies `[x, y, z]`: coordinate k of fly j moves with probability
/// `threshold / 65536` (bits 16k..16k+16 of `masks[j]` below it) by rand_distr's
/// `StandardNormal` times `sigma * max(z, 1)`, z before the mutation. A coin toss per coordinate
/// is a branch no predictor guesses, so the mutation is done in two passes: one pass over the
/// coins gathers, without branches, the indices of the flies each coordinate moves (into
/// `hits`, three lists of up to n: `hits` holds 3 per fly), then only those draw a normal,
/// coordinate by coordinate. Flies beyond `masks` or a third of `hits` are left as they are.
#[inline(always)]
pub(super) fn mutate_at(
    isa: Isa,
    coords: [&mut [f32]; 3],
    masks: &[u64],
    hits: &mut [u32],
    generator: &mut Xoshiro256PlusPlus,
    threshold: u32,
    sigma: f32,
) {
    let lists = |m: &[u64], t: u64, l: [&mut [u32]; 3]| match isa.level() {
        // SAFETY: the level is AVX-512 only in `mutate_on`'s AVX-512 function.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { coin_lists_avx512(m, t, l) },
        // SAFETY: as above, for AVX2.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { coin_lists_avx2(m, t, l) },
        _ => coin_lists(m, t, l, 0, [0; 3]),
    };
    mutate_with(coords, masks, hits, generator, threshold, sigma, lists);
}

/// [`mutate_at`], the coins' lists made by `lists` (a [`coin_lists`] from 0).
#[inline(always)]
fn mutate_with<R: Rng + Clone>(
    [x, y, z]: [&mut [f32]; 3],
    masks: &[u64],
    hits: &mut [u32],
    generator: &mut R,
    threshold: u32,
    sigma: f32,
    lists: impl FnOnce(&[u64], u64, [&mut [u32]; 3]) -> [usize; 3],
) {
    // `hits` holds three lists of up to n indices, one per coordinate.
    let n = x
        .len()
        .min(y.len())
        .min(z.len())
        .min(masks.len())
        .min(hits.len() / 3);
    let (hx, rest) = hits.split_at_mut(n);
    let (hy, hz) = rest.split_at_mut(n);
    // One pass over the coins fills the three lists, without branches.
    let t = u64::from(threshold);
    let [cx, cy, cz] = lists(&masks[..n], t, [&mut *hx, &mut *hy, &mut *hz]);
    // z is mutated last: every coordinate's scale is the depth before the mutation. One loop
    // a coordinate, drawing from a local copy of the generator (see `breed`): a loop choosing
    // its coordinate per draw, through the reference, kept its state and half its values on
    // the stack.
    let (x, y, z) = (&mut x[..n], &mut y[..n], &mut z[..n]);
    let mut rng = generator.clone();
    for &j in &hx[..cx.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        x[j] += sigma * z[j].max(1.0) * g;
    }
    for &j in &hy[..cy.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        y[j] += sigma * z[j].max(1.0) * g;
    }
    for &j in &hz[..cz.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        z[j] += sigma * z[j].max(1.0) * g;
    }
    *generator = rng;
}

/// The mutation's three lists (see [`mutate_at`]): into `lists[k]`, from `counts[k]` on, the index
/// (`base` + position) of every coin of `masks` whose chunk k is below `t`; returns the new
/// counts. Each list must have room for `counts[k] + masks.len()` entries (entries past the
/// count are scratch).
#[inline(always)]
pub(super) fn coin_lists(
    masks: &[u64],
    t: u64,
    [hx, hy, hz]: [&mut [u32]; 3],
    base: usize,
    [mut cx, mut cy, mut cz]: [usize; 3],
) -> [usize; 3] {
    for (j, &m) in masks.iter().enumerate() {
        let j32 = (base + j) as u32;
        if let (Some(a), Some(b), Some(c)) = (hx.get_mut(cx), hy.get_mut(cy), hz.get_mut(cz)) {
            (*a, *b, *c) = (j32, j32, j32);
        }
        cx += usize::from(m & 0xffff < t);
        cy += usize::from((m >> 16) & 0xffff < t);
        cz += usize::from((m >> 32) & 0xffff < t);
    }
    [cx, cy, cz]
}

/// How many coins of `masks` the three `lists` have room for (one entry a coin at most).
#[inline(always)]
fn room(masks: &[u64], lists: &[&mut [u32]; 3]) -> usize {
    lists.iter().fold(masks.len(), |n, l| n.min(l.len()))
}

/// [`coin_lists`] from 0 with AVX-512: 16 coins at a time, compared in 64-bit lanes, their
/// indices compressed into each list with one masked store (a branch-free scalar pass cost
/// ~3 us a generation).
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub(super) unsafe fn coin_lists_avx512(
    masks: &[u64],
    t: u64,
    lists: [&mut [u32]; 3],
) -> [usize; 3] {
    use std::arch::x86_64::*;
    let n = room(masks, &lists);
    let full = n / 16 * 16;
    let mut counts = [0usize; 3];
    // SAFETY: the loads read 16 u64 at `j < full <= masks.len() - 16`; list k's store writes
    // the `popcount` lanes of a mask below 2^popcount at `counts[k]`, and counts[k] + popcount
    // <= j + 16 <= n <= the list's length (a list gets at most one entry per coin).
    unsafe {
        let tv = _mm512_set1_epi64(t as i64);
        let chunk = _mm512_set1_epi64(0xffff);
        for j in (0..full).step_by(16) {
            let m0 = _mm512_loadu_si512(masks.as_ptr().add(j).cast());
            let m1 = _mm512_loadu_si512(masks.as_ptr().add(j + 8).cast());
            let below = |a: __m512i, b: __m512i| {
                let lo = _mm512_cmplt_epu64_mask(_mm512_and_si512(a, chunk), tv);
                let hi = _mm512_cmplt_epu64_mask(_mm512_and_si512(b, chunk), tv);
                u16::from(lo) | (u16::from(hi) << 8)
            };
            let flags = [
                below(m0, m1),
                below(_mm512_srli_epi64::<16>(m0), _mm512_srli_epi64::<16>(m1)),
                below(_mm512_srli_epi64::<32>(m0), _mm512_srli_epi64::<32>(m1)),
            ];
            for (k, &f) in flags.iter().enumerate() {
                counts[k] += compress16(f, j, lists[k].as_mut_ptr().add(counts[k]));
            }
        }
    }
    let [hx, hy, hz] = lists;
    coin_lists(&masks[full..n], t, [hx, hy, hz], full, counts)
}

/// [`coin_lists`] from 0 with AVX2: 8 coins at a time, compared in 64-bit lanes (the 16-bit
/// chunks and the threshold are far inside a signed compare), packed with [`left_pack8`].
///
/// # Safety
/// The CPU must support AVX2 (and BMI1/BMI2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
pub(super) unsafe fn coin_lists_avx2(masks: &[u64], t: u64, lists: [&mut [u32]; 3]) -> [usize; 3] {
    use std::arch::x86_64::*;
    let n = room(masks, &lists);
    let full = n / 8 * 8;
    let mut counts = [0usize; 3];
    // SAFETY: the loads read 8 u64 at `j < full <= masks.len() - 8`; list k's store writes 8
    // lanes at `counts[k] <= j`, so up to j + 8 <= n <= the list's length.
    unsafe {
        // Chunks are below 2^16: a threshold clamped to 2^20 compares the same, signed.
        let tv = _mm256_set1_epi64x(t.min(1 << 20) as i64);
        let chunk = _mm256_set1_epi64x(0xffff);
        for j in (0..full).step_by(8) {
            let m0 = _mm256_loadu_si256(masks.as_ptr().add(j).cast());
            let m1 = _mm256_loadu_si256(masks.as_ptr().add(j + 4).cast());
            let below = |a: __m256i, b: __m256i| {
                let lo = _mm256_cmpgt_epi64(tv, _mm256_and_si256(a, chunk));
                let hi = _mm256_cmpgt_epi64(tv, _mm256_and_si256(b, chunk));
                let lo = _mm256_movemask_pd(_mm256_castsi256_pd(lo)) as u32;
                let hi = _mm256_movemask_pd(_mm256_castsi256_pd(hi)) as u32;
                lo | (hi << 4)
            };
            let flags = [
                below(m0, m1),
                below(_mm256_srli_epi64::<16>(m0), _mm256_srli_epi64::<16>(m1)),
                below(_mm256_srli_epi64::<32>(m0), _mm256_srli_epi64::<32>(m1)),
            ];
            for (k, &f) in flags.iter().enumerate() {
                let at = lists[k].as_mut_ptr().add(counts[k]);
                counts[k] += left_pack8(f, j, at);
            }
        }
    }
    let [hx, hy, hz] = lists;
    coin_lists(&masks[full..n], t, [hx, hy, hz], full, counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn mutation_rate_and_scale() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        let threshold = (0.4f64 * 65536.0).round() as u32;
        let n = 20000;
        let (mut x, mut y, mut z) = (vec![0.0; n], vec![0.0; n], vec![5.0; n]);
        let masks: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
        let mut hits = vec![0; 3 * n];
        mutate_at(
            Isa::BASELINE,
            [&mut x, &mut y, &mut z],
            &masks,
            &mut hits,
            &mut rng,
            threshold,
            0.02,
        );
        let (mut moved, mut sq) = (0usize, 0.0f64);
        for (j, m) in masks.iter().enumerate() {
            for (k, d) in [x[j], y[j], z[j] - 5.0].into_iter().enumerate() {
                let hit = (m >> (16 * k)) & 0xffff < u64::from(threshold);
                assert_eq!(
                    d != 0.0,
                    hit,
                    "coordinate {k} of fly {j} moves iff its bits say so"
                );
                if hit {
                    moved += 1;
                    sq += f64::from(d).powi(2);
                }
            }
        }
        let rate = moved as f64 / (3 * n) as f64;
        assert!((rate - 0.4).abs() < 0.01, "mutation rate {rate}");
        let sigma = (sq / moved as f64).sqrt();
        assert!((sigma - 0.1).abs() < 0.005, "sigma {sigma} for 0.02 * 5 m");
        let (mut x, mut y, mut z) = (vec![1.0; 4], vec![2.0; 4], vec![3.0; 4]);
        mutate_at(
            Isa::BASELINE,
            [&mut x, &mut y, &mut z],
            &masks[..4],
            &mut hits,
            &mut rng,
            0,
            0.02,
        );
        assert!(
            x == [1.0; 4] && y == [2.0; 4] && z == [3.0; 4],
            "rate 0 never mutates"
        );
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_simd_coin_lists_are_the_scalar_ones() {
        if Isa::available().len() == 1 {
            println!("SKIP the_simd_coin_lists_are_the_scalar_ones: this CPU has no AVX2");
            return;
        }
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        // Lengths around the 8- and 16-coin blocks; thresholds from never to always.
        for n in [0, 1, 7, 8, 9, 15, 16, 17, 31, 100, 2750] {
            let masks: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
            for t in [0u64, 1, 26214, 32768, 65535, 65536] {
                let mut want = vec![vec![u32::MAX; n]; 3];
                let [a, b, c] = &mut want[..] else {
                    unreachable!()
                };
                let wc = coin_lists(&masks, t, [a, b, c], 0, [0; 3]);
                for &isa in &Isa::available()[1..] {
                    let mut got = vec![vec![u32::MAX; n]; 3];
                    let [a, b, c] = &mut got[..] else {
                        unreachable!()
                    };
                    let gc = match isa.level() {
                        // SAFETY: `isa` (from detection) proves AVX-512 F/BW/VL.
                        Level::Avx512 => unsafe { coin_lists_avx512(&masks, t, [a, b, c]) },
                        // SAFETY: `isa` proves AVX2.
                        Level::Avx2 => unsafe { coin_lists_avx2(&masks, t, [a, b, c]) },
                        Level::Baseline => unreachable!("the loop skips the baseline"),
                    };
                    assert_eq!(wc, gc, "{isa:?} n {n} t {t}");
                    for k in 0..3 {
                        assert_eq!(
                            want[k][..wc[k]],
                            got[k][..gc[k]],
                            "{isa:?} n {n} t {t} list {k}"
                        );
                    }
                }
            }
        }
    }
}
