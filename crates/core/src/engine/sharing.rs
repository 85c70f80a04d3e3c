//! Sharing (fitness sharing over a grid of the left image), O(N).
//!
//! The paper lowers the fitness of flies packed together so the population spreads over every
//! object instead of piling onto the single best match. Classic sharing compares every pair of
//! individuals (O(N^2)); here the niche of a fly is the square cell of `cell_px` x `cell_px`
//! pixels its left projection falls in, and
//!
//! `F_shared = F_raw / n^alpha`, n = number of flies in that cell, alpha = `sharing_exponent`.
//!
//! With alpha = 1 a cell's flies share its fitness: a cell holding ten copies of one match is
//! worth as much as one fly there, so selection favours covering new cells; the default, 1.5,
//! pushes harder (false matches on an empty road bred into clusters at 1). Cells are
//! counted in the image, not in 3-D: flies on one left pixel at different depths compete, which
//! is right for opaque surfaces (one depth per pixel is true).
//!
//! Two passes over the flies plus clearing the counts: no allocation.

use super::Population;
use super::trunc::trunc;
use crate::isa::{Isa, Level, dispatch};

#[derive(Debug, Clone)]
pub(crate) struct Grid {
    cell_px: f32,
    cols: u32,
    counts: Vec<u32>,
    /// `1 / n^alpha` for n = 0..=flies (n = 0 unused).
    factor: Vec<f32>,
}

impl Grid {
    pub(crate) fn new(width: u32, height: u32, cell_px: u32, alpha: f64, flies: usize) -> Self {
        let cols = width.div_ceil(cell_px);
        let rows = height.div_ceil(cell_px);
        let factor = (0..=flies)
            .map(|n| {
                if n == 0 {
                    1.0
                } else {
                    (1.0 / (n as f64).powf(alpha)) as f32
                }
            })
            .collect();
        Self {
            cell_px: cell_px as f32,
            cols,
            counts: vec![0; (cols * rows) as usize],
            factor,
        }
    }

    /// Sharing cell of a left-image position (inside the image).
    #[inline(always)]
    pub(crate) fn cell(&self, u: f32, v: f32) -> u32 {
        // u, v >= -0.5: shift to pixel-edge coordinates before binning. `trunc` of values
        // clamped at 0 (NaN too): a saturating `as u32` kept the evaluation's cell pass scalar.
        let inv = 1.0 / self.cell_px;
        let cx = trunc(((u + 0.5) * inv).max(0.0)) as u32;
        let cy = trunc(((v + 0.5) * inv).max(0.0)) as u32;
        (cy * self.cols + cx).min(self.counts.len() as u32 - 1)
    }

    dispatch! {
        /// [`Grid::apply`] compiled for instruction set `isa` (the same fitness on each).
        pub(crate) fn apply_on(self: &mut Grid, pop: &mut Population);
        up to Avx512 => Grid::apply
    }

    /// Sets `fitness` from `raw_fitness` and the cells the evaluation assigned (`u32::MAX` for a
    /// fly outside an image: fitness 0).
    #[inline(always)]
    pub(crate) fn apply(&mut self, _: Isa, pop: &mut Population) {
        self.counts.fill(0);
        for &cell in &pop.cell {
            if let Some(c) = self.counts.get_mut(cell as usize) {
                *c += 1;
            }
        }
        let last = self.factor.len() - 1;
        for ((f, &raw), &cell) in pop.fitness.iter_mut().zip(&pop.raw_fitness).zip(&pop.cell) {
            let factor = match self.counts.get(cell as usize) {
                Some(&n) => self.factor[(n as usize).min(last)],
                None => 0.0,
            };
            *f = raw * factor;
        }
    }
}

/// Survivors grouped by sharing cell, for mating restriction: a crossover between two flies on
/// the same few pixels interpolates along one surface (or along one line of sight, a search in
/// depth), where a crossover with a random mate lands between unrelated objects. This is what
/// lets a newly found obstacle fill with flies in a few generations. Counting sort: O(survivors
/// + cells), no allocation.
#[derive(Debug, Clone)]
pub(crate) struct Mates {
    /// `start[c + 1]..start[c + 2]` indexes `members` for cell c (the offset by one lets the
    /// counting sort fill it in place, see [`Mates::index`]).
    start: Vec<u32>,
    members: Vec<u32>,
}

impl Mates {
    pub(crate) fn new(width: u32, height: u32, cell_px: u32, flies: usize) -> Self {
        let cells = (width.div_ceil(cell_px) * height.div_ceil(cell_px)) as usize;
        Self {
            start: vec![0; cells + 2],
            members: vec![0; flies],
        }
    }

    dispatch! {
        /// [`Mates::index`] compiled for instruction set `isa` (the same groups on each; with
        /// AVX-512, the prefix sum 16 cells a vector).
        pub(crate) fn index_on(self: &mut Mates, cells: &[u32]);
        up to Avx512 => Mates::index
    }

    /// Groups flies `0..cells.len()` by their cell (`u32::MAX`: no cell, left out).
    #[inline(always)]
    pub(crate) fn index(&mut self, isa: Isa, cells: &[u32]) {
        match isa.level() {
            // SAFETY: the level is AVX-512 only in `index_on`'s AVX-512 function.
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => self.index_with(cells, |v| unsafe { prefix_sum_avx512(v) }),
            _ => self.index_with(cells, prefix_sum),
        }
    }

    /// [`Mates::index`] with the running sum done by `scan` (an inclusive prefix sum).
    #[inline(always)]
    fn index_with(&mut self, cells: &[u32], scan: impl FnOnce(&mut [u32])) {
        // Counts at `start[c + 1]`; a running sum turns them into ends, `start[c + 1]` = the end
        // of cell c (the sum in a register: no store-to-load chain through the array).
        let n_cells = self.start.len() - 2;
        self.start.fill(0);
        for &c in cells {
            if (c as usize) < n_cells {
                self.start[c as usize + 1] += 1;
            }
        }
        scan(&mut self.start);
        // Backwards, each fly takes the last free place of its cell and moves the cell's end
        // down: when done, `start[c + 1]` has come down to the start of cell c, while
        // `start[c + 2]` is the start of cell c + 1 = the end of cell c. Members in fly order.
        for (i, &c) in cells.iter().enumerate().rev() {
            if (c as usize) < n_cells {
                let at = &mut self.start[c as usize + 1];
                *at -= 1;
                if let Some(m) = self.members.get_mut(*at as usize) {
                    *m = i as u32;
                }
            }
        }
    }

    /// A member of `cell` chosen with 32 random bits, or `None` if the cell is empty.
    #[cfg(test)]
    pub(crate) fn pick(&self, cell: u32, bits: u32) -> Option<usize> {
        self.picker().pick(cell, bits)
    }

    /// The index as two slices, for a loop that picks many mates (the slices stay in
    /// registers, where the fields of `&self` are reloaded after every store).
    pub(crate) fn picker(&self) -> Picker<'_> {
        Picker {
            start: &self.start,
            members: &self.members,
        }
    }
}

/// Inclusive prefix sum of `v` in place, four at a time: their partial sums do not wait for
/// the running total, which then advances by one addition every four values instead of every
/// value (the chain set this loop's pace). Sums of counts of flies: no overflow.
#[inline(always)]
fn prefix_sum(v: &mut [u32]) {
    let mut end = 0u32;
    let mut quads = v.chunks_exact_mut(4);
    for q in &mut quads {
        let (a, b, c, d) = (q[0], q[1], q[2], q[3]);
        let (ab, abc) = (a.wrapping_add(b), a.wrapping_add(b).wrapping_add(c));
        (q[0], q[1], q[2], q[3]) = (
            end.wrapping_add(a),
            end.wrapping_add(ab),
            end.wrapping_add(abc),
            end.wrapping_add(abc).wrapping_add(d),
        );
        end = end.wrapping_add(abc).wrapping_add(d);
    }
    for s in quads.into_remainder() {
        end = end.wrapping_add(*s);
        *s = end;
    }
}

/// [`prefix_sum`] with AVX-512, 16 values a vector: a scan within the vector in four
/// shift-and-add steps, then the running total added and carried on (~0.5 us over the mate
/// index's ~8,560 cells, against 2.5 us four at a time).
///
/// # Safety
/// The CPU must support AVX-512 F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
unsafe fn prefix_sum_avx512(v: &mut [u32]) {
    use std::arch::x86_64::*;
    let full = v.len() / 16 * 16;
    let mut end = 0u32;
    // SAFETY: every load and store touches 16 values at `j < full <= v.len() - 16`.
    unsafe {
        let zero = _mm512_setzero_si512();
        let last = _mm512_set1_epi32(15);
        let mut carry = zero;
        for j in (0..full).step_by(16) {
            let p = v.as_mut_ptr().add(j);
            let mut x = _mm512_loadu_si512(p.cast());
            // Lane i += lane i - k, for k = 1, 2, 4, 8 (lanes below k take zeros).
            x = _mm512_add_epi32(x, _mm512_alignr_epi32::<15>(x, zero));
            x = _mm512_add_epi32(x, _mm512_alignr_epi32::<14>(x, zero));
            x = _mm512_add_epi32(x, _mm512_alignr_epi32::<12>(x, zero));
            x = _mm512_add_epi32(x, _mm512_alignr_epi32::<8>(x, zero));
            x = _mm512_add_epi32(x, carry);
            _mm512_storeu_si512(p.cast(), x);
            carry = _mm512_permutexvar_epi32(last, x);
        }
        if full > 0 {
            end = v[full - 1];
        }
    }
    for s in &mut v[full..] {
        end = end.wrapping_add(*s);
        *s = end;
    }
}

/// [`Mates`] borrowed for picking.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Picker<'a> {
    start: &'a [u32],
    members: &'a [u32],
}

impl Picker<'_> {
    /// See [`Mates::pick`].
    #[inline(always)]
    pub(crate) fn pick(&self, cell: u32, bits: u32) -> Option<usize> {
        let c = cell as usize;
        if c + 2 >= self.start.len() {
            return None;
        }
        let (lo, hi) = (self.start[c + 1], self.start[c + 2]);
        if hi <= lo {
            return None;
        }
        let k = lo + (((hi - lo) as u64 * bits as u64) >> 32) as u32;
        self.members.get(k as usize).map(|&m| m as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::isa::Isa;

    #[test]
    fn prefix_sums_are_the_same_on_every_instruction_set() {
        let mut next = crate::test_support::xorshift32(0x0bad_f00d);
        for n in [0, 1, 15, 16, 17, 31, 32, 33, 8562] {
            let v: Vec<u32> = (0..n).map(|_| next() % 5).collect();
            let mut want = v.clone();
            let mut end = 0;
            for w in &mut want {
                end += *w;
                *w = end;
            }
            let mut got = v.clone();
            prefix_sum(&mut got);
            assert_eq!(got, want, "n {n}");
            #[cfg(target_arch = "x86_64")]
            if Isa::detect().level() == Level::Avx512 {
                let mut got = v.clone();
                // SAFETY: the detected `Isa` proves AVX-512 F/BW/VL.
                unsafe { prefix_sum_avx512(&mut got) };
                assert_eq!(got, want, "avx512 n {n}");
            } else if n == 0 {
                println!("SKIP the AVX-512 prefix sum: this CPU has no AVX-512");
            }
        }
    }

    fn pop(points: &[(f32, f32, f32)]) -> Population {
        let mut p = Population::with_len(points.len());
        for (i, &(u, v, f)) in points.iter().enumerate() {
            p.u_left[i] = u;
            p.v_left[i] = v;
            p.raw_fitness[i] = f;
        }
        p
    }

    fn apply(g: &mut Grid, p: &mut Population) {
        for i in 0..p.len() {
            p.cell[i] = if p.u_left[i].is_nan() {
                u32::MAX
            } else {
                g.cell(p.u_left[i], p.v_left[i])
            };
        }
        g.apply(Isa::BASELINE, p);
    }

    #[test]
    fn packed_flies_share_their_cell() {
        // Three flies in cell (0,0), one alone in cell (1,0), one outside the image.
        let mut p = pop(&[
            (1.0, 1.0, 9.0),
            (2.0, 3.0, 9.0),
            (7.0, 7.0, 9.0),
            (8.0, 0.0, 9.0),
            (f32::NAN, f32::NAN, 9.0),
        ]);
        let mut g = Grid::new(64, 64, 8, 1.0, 5);
        apply(&mut g, &mut p);
        assert_eq!(p.fitness, vec![3.0, 3.0, 3.0, 9.0, 0.0]);
        assert_eq!(p.cell[..4], [0, 0, 0, 1]);
    }

    #[test]
    fn exponent_zero_disables_sharing() {
        let mut p = pop(&[(1.0, 1.0, 2.0), (1.0, 1.0, 5.0)]);
        apply(&mut Grid::new(64, 64, 8, 0.0, 2), &mut p);
        assert_eq!(p.fitness, vec![2.0, 5.0]);
    }

    #[test]
    fn half_exponent() {
        let mut p = pop(&[(1.0, 1.0, 8.0); 4]);
        apply(&mut Grid::new(64, 64, 8, 0.5, 4), &mut p);
        assert_eq!(p.fitness, vec![4.0; 4]);
    }

    #[test]
    fn mates_come_from_the_same_cell() {
        let mut m = Mates::new(32, 16, 8, 6); // 4 x 2 cells
        m.index(Isa::BASELINE, &[5, 0, 5, u32::MAX, 7, 5]);
        let pick = |cell, k: u32| m.pick(cell, k.wrapping_mul(0x4000_0000));
        let in5: std::collections::BTreeSet<usize> = (0..4).filter_map(|k| pick(5, k)).collect();
        assert_eq!(in5, [0, 2, 5].into_iter().collect());
        assert_eq!(pick(0, 3), Some(1));
        assert_eq!(pick(7, 0), Some(4));
        assert_eq!(pick(3, 0), None);
        assert_eq!(pick(u32::MAX, 0), None);
    }

    #[test]
    fn border_pixels_stay_in_the_grid() {
        // 60 px wide with 8 px cells: 8 columns, the last one partial.
        let mut p = pop(&[(59.4, 59.4, 1.0), (-0.5, -0.5, 1.0)]);
        let mut g = Grid::new(60, 60, 8, 1.0, 2);
        apply(&mut g, &mut p);
        assert_eq!(p.cell[..2], [7 * 8 + 7, 0]);
    }
}
