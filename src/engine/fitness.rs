//! The fitness of the paper (section 3.1), evaluated in bulk:
//!
//! `F = |grad(M_L)| * |grad(M_R)| / (sum_colours sum_(i,j in N) (L(xL+i, yL+j) - R(xR+i, yR+j))^2 / |N| + floor)`
//!
//! The sum of squared differences is divided by the number of compared samples |N| (pixels x
//! channels): the same ranking as the paper's formula, but a fitness (and so a warning) that
//! does not change scale with the neighbourhood size or the channel count. With frames
//! photometrically normalised ([`crate::frame`]) it does not change with contrast or camera
//! gain either, which is what makes warning thresholds portable across scenes and cameras.
//! Units: gradients are Sobel norms / 4 of the normalised luma, differences grey levels.
//!
//! - Projections are rounded to the nearest pixel; a fly outside either image (or behind a
//!   camera) gets the worst fitness, 0.
//! - The gradient norms are the quantised Sobel norms stored in the prepared frames (computed once
//!   per frame, not per fly).
//! - The neighbourhood spans `(2r+1) x (2r+1)` pixels; every `row_step`-th row of it is compared
//!   (rows -3, 0, +3 for the default r = 3, step 3: a 7-pixel-wide window along the epipolar
//!   lines that costs 3 rows instead of 7, measured as accurate on Middlebury). Each row is compared with one fixed-width
//!   load of 16 or 32 bytes (4 bytes per pixel, [`crate::frame`]) under a byte mask that drops the
//!   gradient byte, unused channels and the bytes past the window. Fixed widths let the compiler
//!   turn each row into a handful of SIMD instructions on any x86-64 (SSE2 baseline), with no
//!   `unsafe` and no runtime dispatch.
//! - `floor = ssd_floor` (grey levels squared per sample) guards the division.
//! - The road region of interest is applied here too (a multiplier on F).

use super::Population;
use super::params::{EngineParams, RoadRoi};
use super::projector::Projector;
use super::sharing::Grid;
use crate::frame::{BPP, NORMALISED_STD, PreparedImage, StereoFrame};
pub(crate) use crate::isa::Isa;
use std::ops::Range;

/// Constant factor of every fitness. It changes no ranking; it puts the global warning on the
/// scale of the paper's figures (hw-mock: 0.05-0.2 on an empty road, ~6-7 with a pedestrian 4 m
/// ahead), which also keeps it inside the CAN signal's range (0.001 resolution, up to 65.5).
pub const FITNESS_SCALE: f32 = 0.01;

pub(crate) struct Kernel<'a> {
    left: &'a PreparedImage,
    right: &'a PreparedImage,
    radius: usize,
    floor: f32,
    /// `FITNESS_SCALE * |N|`, |N| being the samples compared per fly.
    scale: f32,
    /// Rows of the neighbourhood compared: every `row_step`-th, from the top one.
    row_step: usize,
    roi: Option<RoadRoi>,
    channels: usize,
    /// SSD (summed over the compared samples) under which a fly's windows match.
    match_ssd: f32,
    /// Instruction set of the evaluation, detected at run time.
    isa: Isa,
}

/// Byte mask of one neighbourhood row loaded as `W` bytes: the window's colour channels.
/// A compile-time constant in the kernel, so masking costs one vector AND.
const fn mask<const W: usize>(radius: usize, channels: usize) -> [u8; W] {
    let mut m = [0u8; W];
    let mut k = 0;
    while k < W {
        if k < (2 * radius + 1) * BPP && k % BPP < channels {
            m[k] = 0xff;
        }
        k += 1;
    }
    m
}

/// [`mask`] widened to 16-bit lanes (what the AVX2 kernel compares in).
const fn mask16<const W: usize>(radius: usize, channels: usize) -> [i16; W] {
    let bytes = mask::<W>(radius, channels);
    let mut m = [0i16; W];
    let mut k = 0;
    while k < W {
        m[k] = if bytes[k] != 0 { -1 } else { 0 };
        k += 1;
    }
    m
}

impl<'a> Kernel<'a> {
    /// The kernel for `frame` on instruction set `isa` (the engine's, detected once).
    pub(crate) fn new(frame: &'a StereoFrame, params: &EngineParams, isa: Isa) -> Self {
        let radius = params.neighbourhood_radius as usize;
        // Channels present in *both* images (a grey camera paired with a colour one compares grey).
        let channels = frame.left.channels().min(frame.right.channels()) as usize;
        let row_step = params.neighbourhood_row_step as usize;
        let samples = (2 * radius + 1) * (2 * radius + 1).div_ceil(row_step) * channels;
        Self {
            left: &frame.left,
            right: &frame.right,
            radius,
            floor: (params.ssd_floor * samples as f64) as f32,
            scale: FITNESS_SCALE * samples as f32,
            row_step,
            roi: params.roi,
            channels,
            match_ssd: (MATCH_SSD_PER_SAMPLE * samples as f64) as f32,
            isa,
        }
    }

    /// Gradient byte of the left image at the pixel nearest to `(u, v)` (0 outside it).
    #[inline]
    pub(crate) fn left_gradient(&self, u: f32, v: f32) -> u8 {
        let (w, h) = (self.left.width() as f32, self.left.height() as f32);
        if u >= -0.5 && u < w - 0.5 && v >= -0.5 && v < h - 0.5 {
            self.left.gradient((u + 0.5) as u32, (v + 0.5) as u32)
        } else {
            0
        }
    }

    /// Evaluates flies `range` of `pop`: projections, sharing cells (of `grid`) and `raw_fitness`.
    /// Returns how many of them both cameras see, and how many of those match (see [`Matches`]).
    pub(crate) fn evaluate(
        &self,
        left: &Projector,
        right: &Projector,
        pop: &mut Population,
        range: Range<usize>,
        grid: &Grid,
        scratch: &mut Scratch,
    ) -> Matches {
        match self.isa {
            Isa::Baseline => self.evaluate_on::<false>(left, right, pop, range, grid, scratch),
            // SAFETY: `Isa::Avx2` is only ever set after `is_x86_feature_detected!("avx2")`.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { self.evaluate_avx2(left, right, pop, range, grid, scratch) },
        }
    }

    /// The evaluation compiled with AVX2 enabled (projection, scalar code and SSD alike).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn evaluate_avx2(
        &self,
        left: &Projector,
        right: &Projector,
        pop: &mut Population,
        range: Range<usize>,
        grid: &Grid,
        scratch: &mut Scratch,
    ) -> Matches {
        self.evaluate_on::<true>(left, right, pop, range, grid, scratch)
    }

    #[inline(always)]
    fn evaluate_on<const AVX2: bool>(
        &self,
        left: &Projector,
        right: &Projector,
        pop: &mut Population,
        range: Range<usize>,
        grid: &Grid,
        scratch: &mut Scratch,
    ) -> Matches {
        // One instantiation per (radius, channels): the row width and mask become constants.
        match (self.radius, self.channels) {
            (1, 1) => self.evaluate_with::<16, 1, 1, AVX2>(left, right, pop, range, grid, scratch),
            (1, _) => self.evaluate_with::<16, 1, 3, AVX2>(left, right, pop, range, grid, scratch),
            (2, 1) => self.evaluate_with::<32, 2, 1, AVX2>(left, right, pop, range, grid, scratch),
            (2, _) => self.evaluate_with::<32, 2, 3, AVX2>(left, right, pop, range, grid, scratch),
            (_, 1) => self.evaluate_with::<32, 3, 1, AVX2>(left, right, pop, range, grid, scratch),
            (_, _) => self.evaluate_with::<32, 3, 3, AVX2>(left, right, pop, range, grid, scratch),
        }
    }

    #[inline(always)]
    fn evaluate_with<const W: usize, const R: usize, const C: usize, const AVX2: bool>(
        &self,
        left: &Projector,
        right: &Projector,
        pop: &mut Population,
        range: Range<usize>,
        grid: &Grid,
        scratch: &mut Scratch,
    ) -> Matches {
        let mask = &const { mask::<W>(R, C) };
        let mask16 = &const { mask16::<W>(R, C) };
        let (ld, rd) = (self.left.data(), self.right.data());
        let (ls, rs) = (self.left.stride(), self.right.stride());
        let rows = 2 * R + 1;
        let row_step = self.row_step;
        pop.project(left, right, range.clone());
        let roi = self.roi.map(|roi| {
            (
                roi.min_height as f32,
                roi.max_height as f32,
                roi.max_ahead as f32,
                roi.penalty as f32,
            )
        });
        // Offset from a window's first byte to its centre pixel's gradient byte.
        let (gl_at, gr_at) = (ls * R + BPP * R + 3, rs * R + BPP * R + 3);
        let roi = roi.unwrap_or((f32::MIN, f32::MAX, f32::MAX, 1.0));
        let (min_h, max_h, max_z, penalty) = roi;
        // Re-sliced to one length so the compiler drops the bounds checks in the loops.
        // The engine sizes the scratch for its largest evaluation.
        debug_assert!(range.len() <= scratch.len(), "evaluation scratch too small");
        let (from, len) = (range.start, range.len().min(scratch.len()));
        let (ul, vl) = (&pop.u_left[from..][..len], &pop.v_left[from..][..len]);
        let (ur, vr) = (&pop.u_right[from..][..len], &pop.v_right[from..][..len]);
        let (ys, zs) = (&pop.y[from..][..len], &pop.z[from..][..len]);
        let fitness = &mut pop.raw_fitness[from..][..len];
        let cells = &mut pop.cell[from..][..len];
        let (lo, ro) = (&mut scratch.lo[..len], &mut scratch.ro[..len]);
        let (ts, grads) = (&mut scratch.t[..len], &mut scratch.grads[..len]);
        let ssds = &mut scratch.ssd[..len];

        // 1. Window offsets, sub-pixel weights and sharing cells: straight-line arithmetic over
        //    the projections, which the compiler vectorises.
        for i in 0..len {
            // NaN marks a fly outside an image (project_batch); such a fly gets cell MAX and,
            // below, fitness 0. Its offsets are computed from harmless stand-ins.
            let outside = ul[i].is_nan() | ur[i].is_nan();
            let (ul, vl) = if outside { (0.0, 0.0) } else { (ul[i], vl[i]) };
            let (ur, vr) = if outside { (0.0, 0.0) } else { (ur[i], vr[i]) };
            // Projections lie in [-0.5, size - 0.5): every value below is a small integer.
            let (uli, vli) = (trunc(ul + 0.5), trunc(vl + 0.5));
            // The left window sits on the rounded left pixel, i.e. `fl = ul - round(ul)` away from
            // the projection; the right window is taken at `ur - fl`, interpolated horizontally,
            // so the compared windows show the same scene point and the fitness resolves
            // disparity below the pixel (what the disparity accuracy rests on).
            let fl = ul - uli as f32;
            let ur_shift = ur - fl;
            let uri = ur_shift.floor();
            ts[i] = trunc((ur_shift - uri) * 128.0 + 0.5) as u16;
            let (uri, vri) = (trunc(uri), trunc(vr + 0.5));
            lo[i] = self.left.offset32(uli - R as i32, vli - R as i32);
            ro[i] = self.right.offset32(uri - R as i32, vri - R as i32);
            cells[i] = if outside { u32::MAX } else { grid.cell(ul, vl) };
        }

        // 2. The windows: gradients and SSD, one fly at a time. The windows are scattered over
        //    two images larger than L2: the rows of the fly a few places ahead are fetched
        //    while this one is compared.
        let n_rows = rows.div_ceil(row_step);
        let (lstep, rstep) = (ls * row_step, rs * row_step);
        for i in 0..len {
            if let (Some(&a), Some(&b)) = (lo.get(i + PREFETCH_AHEAD), ro.get(i + PREFETCH_AHEAD)) {
                for j in 0..n_rows {
                    prefetch::<W>(ld, a as usize + j * lstep);
                    prefetch::<W>(rd, b as usize + j * rstep);
                }
            }
            let (l, r) = (lo[i] as usize, ro[i] as usize);
            // -1 = not compared: outside an image (or, defensively, a window off the buffer).
            ssds[i] = -1.0;
            if cells[i] == u32::MAX {
                continue;
            }
            let (Some(&gl), Some(&gr)) = (ld.get(l + gl_at), rd.get(r + gr_at)) else {
                continue;
            };
            let t = ts[i];
            let ssd = match () {
                // SAFETY: AVX2 is true only inside `evaluate_avx2`, entered after detection.
                #[cfg(target_arch = "x86_64")]
                () if AVX2 => unsafe {
                    avx2::ssd::<W>(ld, l, lstep, rd, r, rstep, n_rows, mask16, t)
                },
                () => ssd::<W>(ld, l, lstep, rd, r, rstep, n_rows, mask, t),
            };
            grads[i] = gl as f32 * gr as f32;
            ssds[i] = ssd as f32;
        }

        // 3. Fitness, region of interest and match counts: straight-line again.
        let mut m = Matches::default();
        for i in 0..len {
            let compared = ssds[i] >= 0.0;
            let (g, ssd) = if compared {
                (grads[i], ssds[i])
            } else {
                (0.0, 0.0)
            };
            m.visible += u32::from(compared);
            m.matched += u32::from(compared & (ssd <= self.match_ssd));
            // FITNESS_SCALE gl gr / (ssd / |N| + ssd_floor), written with one division.
            let f = g * self.scale / (ssd + self.floor);
            let out = (ys[i] > max_h) | (ys[i] < min_h) | (zs[i] > max_z);
            let f = if out { f * penalty } else { f };
            fitness[i] = if compared { f } else { 0.0 };
        }
        m
    }
}

/// Per-fly intermediate values of an evaluation, sized once (no allocation per generation).
#[derive(Debug, Clone)]
pub(crate) struct Scratch {
    /// Byte offsets of each fly's left and right windows.
    lo: Vec<u32>,
    ro: Vec<u32>,
    /// Sub-pixel weight of the right window, /128.
    t: Vec<u16>,
    /// `gl * gr` of the compared flies.
    grads: Vec<f32>,
    /// SSD of the compared flies, -1 for the others.
    ssd: Vec<f32>,
}

impl Scratch {
    /// Room for evaluating `flies` flies at once.
    pub(crate) fn new(flies: usize) -> Self {
        Self {
            lo: vec![0; flies],
            ro: vec![0; flies],
            t: vec![0; flies],
            grads: vec![0.0; flies],
            ssd: vec![0.0; flies],
        }
    }

    fn len(&self) -> usize {
        self.lo.len()
    }
}

/// `x as i32` for the small coordinates of the evaluation. Clamped first (NaN to a bound too),
/// so the unchecked conversion is always defined; values within +-2^24 are unchanged. Unlike a
/// saturating `as`, this vectorises.
#[inline(always)]
pub(super) fn trunc(x: f32) -> i32 {
    const BOUND: f32 = 16_777_216.0;
    // Not `clamp`: it keeps NaN, which must not reach the conversion.
    #[allow(clippy::manual_clamp)]
    let x = x.max(-BOUND).min(BOUND);
    // SAFETY: x is finite and within +-2^24 (the line above; `max` maps NaN to -2^24).
    unsafe { x.to_int_unchecked::<i32>() }
}

/// How many flies ahead the evaluation prefetches windows. The two images (2.5 MB at 640x480)
/// mostly sit in L2/L3: a short distance only starts the loads a little earlier, and a long
/// one evicted lines before use (`flyd bench`, interleaved: 2 or 3 ahead 147-148 us, 8 ahead
/// 151, 16 ahead 153, none 155).
const PREFETCH_AHEAD: usize = 2;

/// Hints the cache lines of a `W + BPP`-byte window row starting at `data[at]` (a hint only:
/// an address outside `data` is never dereferenced).
#[inline(always)]
fn prefetch<const W: usize>(data: &[u8], at: usize) {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse"))]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = data.as_ptr().wrapping_add(at).cast::<i8>();
        // SAFETY: a prefetch is a hint that never dereferences its address (it cannot fault),
        // and SSE is part of the x86-64 baseline (checked by the cfg above).
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(p);
            _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(W + BPP - 1));
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse")))]
    let _ = (data, at);
}

/// Per-sample SSD under which two windows count as matching: a quarter of what two unrelated
/// windows of normalised images give on average (2 x NORMALISED_STD^2). Frames are normalised
/// to that standard deviation, so the level holds for any camera and scene.
const MATCH_SSD_PER_SAMPLE: f64 = 0.25 * 2.0 * NORMALISED_STD * NORMALISED_STD;

/// What one evaluation saw: flies inside both images, and those whose windows match.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Matches {
    pub(crate) visible: u32,
    pub(crate) matched: u32,
}

/// Sum of squared differences of `rows` rows of `W` bytes under `mask`, the right row being
/// interpolated between its pixel and the next one with weight `t / 128`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn ssd<const W: usize>(
    l: &[u8],
    lo: usize,
    ls: usize,
    r: &[u8],
    ro: usize,
    rs: usize,
    rows: usize,
    mask: &[u8; W],
    t: u16,
) -> u32 {
    let mut acc = 0u32;
    for j in 0..rows {
        let (Some(a), Some(b0), Some(b1)) = (
            l.get(lo + j * ls..).and_then(|s| s.first_chunk::<W>()),
            r.get(ro + j * rs..).and_then(|s| s.first_chunk::<W>()),
            r.get(ro + j * rs + BPP..)
                .and_then(|s| s.first_chunk::<W>()),
        ) else {
            // Unreachable with the padded layout; fail as a mismatch rather than panic.
            return u32::MAX / 2;
        };
        acc += row_ssd(a, b0, b1, t, mask);
    }
    acc
}

/// Squared differences of one row, SSE2 (baseline on every x86-64): per 16 bytes, the right
/// bytes are blended `(b0 (128 - t) + b1 t + 64) >> 7` in 16 bits, the mask zeroes what is not
/// compared, and one `pmaddwd` per half squares and sums.
#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
#[inline(always)]
fn row_ssd<const W: usize>(a: &[u8; W], b0: &[u8; W], b1: &[u8; W], t: u16, mask: &[u8; W]) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is enabled for this build (checked by the cfg above; it is part of the x86-64
    // baseline), and every load reads 16 bytes through a pointer taken from a `&[u8; 16]`.
    unsafe {
        let zero = _mm_setzero_si128();
        let w1 = _mm_set1_epi16(t as i16);
        let w0 = _mm_set1_epi16(128 - t as i16);
        let half = _mm_set1_epi16(64);
        let chunk = |a: &[u8; 16], b0: &[u8; 16], b1: &[u8; 16], m: &[u8; 16]| {
            let vm = _mm_loadu_si128(m.as_ptr().cast());
            let va = _mm_and_si128(_mm_loadu_si128(a.as_ptr().cast()), vm);
            let v0 = _mm_loadu_si128(b0.as_ptr().cast());
            let v1 = _mm_loadu_si128(b1.as_ptr().cast());
            let blend = |x0: __m128i, x1: __m128i| {
                let s = _mm_add_epi16(_mm_mullo_epi16(x0, w0), _mm_mullo_epi16(x1, w1));
                _mm_srli_epi16(_mm_add_epi16(s, half), 7)
            };
            let blo = blend(_mm_unpacklo_epi8(v0, zero), _mm_unpacklo_epi8(v1, zero));
            let bhi = blend(_mm_unpackhi_epi8(v0, zero), _mm_unpackhi_epi8(v1, zero));
            let vb = _mm_and_si128(_mm_packus_epi16(blo, bhi), vm);
            let lo = _mm_sub_epi16(_mm_unpacklo_epi8(va, zero), _mm_unpacklo_epi8(vb, zero));
            let hi = _mm_sub_epi16(_mm_unpackhi_epi8(va, zero), _mm_unpackhi_epi8(vb, zero));
            _mm_add_epi32(_mm_madd_epi16(lo, lo), _mm_madd_epi16(hi, hi))
        };
        // W is 16 or 32 (a compile-time constant): one or two chunks, no loop.
        let (Some(a0), Some(b00), Some(b10), Some(m0)) = (
            a.first_chunk::<16>(),
            b0.first_chunk::<16>(),
            b1.first_chunk::<16>(),
            mask.first_chunk::<16>(),
        ) else {
            return 0;
        };
        let mut sum = chunk(a0, b00, b10, m0);
        if W == 32 {
            if let (Some(a1), Some(b01), Some(b11), Some(m1)) = (
                a.last_chunk::<16>(),
                b0.last_chunk::<16>(),
                b1.last_chunk::<16>(),
                mask.last_chunk::<16>(),
            ) {
                sum = _mm_add_epi32(sum, chunk(a1, b01, b11, m1));
            }
        }
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32(sum, 0b01_00_11_10));
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32(sum, 0b10_11_00_01));
        _mm_cvtsi128_si32(sum) as u32
    }
}

/// The SSD with AVX2: each 16 bytes of a row widened to 16-bit lanes in one load, the right
/// row interpolated as `b0 + (((b1 - b0) t + 64) >> 7)` with one `vpmulhrsw` (the same integer
/// as the SSE2 blend `(b0 (128 - t) + b1 t + 64) >> 7`), masked, squared and summed by
/// `vpmaddwd`.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::BPP;
    use std::arch::x86_64::*;

    /// Same contract and result as [`super::ssd`]; `mask` is the byte mask widened to lanes.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn ssd<const W: usize>(
        l: &[u8],
        lo: usize,
        ls: usize,
        r: &[u8],
        ro: usize,
        rs: usize,
        rows: usize,
        mask: &[i16; W],
        t: u16,
    ) -> u32 {
        // t = 128 is all of the next pixel: the same bytes as t = 0 one pixel on, and keeps
        // t << 8 inside an i16.
        let (ro, t) = if t >= 128 { (ro + BPP, 0) } else { (ro, t) };
        let last = rows.saturating_sub(1);
        // One bounds check for the whole window instead of one per load.
        if rows == 0
            || lo + last * ls + W > l.len()
            || ro + last * rs + W + BPP > r.len()
            || !(W == 16 || W == 32)
        {
            return u32::MAX / 2;
        }
        let (lp, rp) = (l.as_ptr(), r.as_ptr());
        // SAFETY: every load below reads 16 bytes at an offset checked above to lie inside
        // `l` or `r`; AVX2 is enabled for this function.
        unsafe {
            let tw = _mm256_set1_epi16((t << 8) as i16);
            let m0 = _mm256_loadu_si256(mask.as_ptr().cast());
            let m1 = _mm256_loadu_si256(mask.as_ptr().add(W - 16).cast());
            let widen = |p: *const u8| _mm256_cvtepu8_epi16(_mm_loadu_si128(p.cast()));
            let half = |a: *const u8, b: *const u8, m: __m256i| {
                let (va, b0, b1) = (widen(a), widen(b), widen(b.add(BPP)));
                let vb = _mm256_add_epi16(b0, _mm256_mulhrs_epi16(_mm256_sub_epi16(b1, b0), tw));
                let d = _mm256_and_si256(_mm256_sub_epi16(va, vb), m);
                _mm256_madd_epi16(d, d)
            };
            let mut acc = _mm256_setzero_si256();
            for j in 0..rows {
                let (a, b) = (lp.add(lo + j * ls), rp.add(ro + j * rs));
                acc = _mm256_add_epi32(acc, half(a, b, m0));
                if W == 32 {
                    acc = _mm256_add_epi32(acc, half(a.add(16), b.add(16), m1));
                }
            }
            let s = _mm_add_epi32(
                _mm256_castsi256_si128(acc),
                _mm256_extracti128_si256::<1>(acc),
            );
            let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
            let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
            _mm_cvtsi128_si32(s) as u32
        }
    }
}

/// Portable version of the row kernel (the reference the SSE2 one is tested against).
#[cfg_attr(all(target_arch = "x86_64", target_feature = "sse2"), allow(dead_code))]
#[inline(always)]
fn row_ssd_portable<const W: usize>(
    a: &[u8; W],
    b0: &[u8; W],
    b1: &[u8; W],
    t: u16,
    mask: &[u8; W],
) -> u32 {
    let mut s = 0u32;
    for k in 0..W {
        let b = ((b0[k] as u16 * (128 - t) + b1[k] as u16 * t + 64) >> 7) as u8;
        let d = (a[k] & mask[k]) as i32 - (b & mask[k]) as i32;
        s += (d * d) as u32;
    }
    s
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
use row_ssd_portable as row_ssd;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masks_cover_the_window_and_skip_the_gradient() {
        let m: [u8; 16] = mask(1, 3);
        assert_eq!(
            m,
            [
                255, 255, 255, 0, 255, 255, 255, 0, 255, 255, 255, 0, 0, 0, 0, 0
            ]
        );
        let m: [u8; 32] = mask(3, 1);
        let on: Vec<usize> = (0..32).filter(|&k| m[k] != 0).collect();
        assert_eq!(on, vec![0, 4, 8, 12, 16, 20, 24]);
    }

    #[test]
    fn ssd_counts_only_masked_bytes() {
        let l = vec![10u8; 64];
        let mut r = vec![10u8; 64];
        r[3] = 200; // gradient byte: ignored
        r[13] = 200; // beyond the 3-pixel window: ignored
        r[5] = 13; // counted: 3^2
        r[16] = 8; // second row, first byte: 2^2
        let m: [u8; 16] = mask(1, 3);
        // t = 0: no interpolation.
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 2, &m, 0), 13);
    }

    #[test]
    fn interpolation_halfway_between_pixels() {
        let l = vec![30u8; 64];
        // Right row: pixel values 20, 40, 20, 40, ... halfway blends are 30 = the left row.
        let r: Vec<u8> = (0..64)
            .map(|k| if (k / 4) % 2 == 0 { 20 } else { 40 })
            .collect();
        let m: [u8; 16] = mask(1, 3);
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 1, &m, 64), 0);
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 1, &m, 0), 9 * 100);
    }

    #[test]
    fn avx2_ssd_matches_the_baseline_one() {
        if Isa::detect() == Isa::Baseline {
            println!("SKIP avx2_ssd_matches_the_baseline_one: this CPU has no AVX2");
            return;
        }
        let mut x = 0x2545_f491u32;
        let mut byte = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        };
        let (l, r): (Vec<u8>, Vec<u8>) = (0..4096).map(|_| (byte(), byte())).unzip();
        for t in 0..=128u16 {
            for (lo, ro) in [(0, 0), (5, 17), (300, 1200), (1000, 3)] {
                let (m, m16) = (mask::<32>(3, 3), mask16::<32>(3, 3));
                let want = ssd::<32>(&l, lo, 640, &r, ro, 640, 3, &m, t);
                // SAFETY: AVX2 detected above.
                let got = unsafe { avx2::ssd::<32>(&l, lo, 640, &r, ro, 640, 3, &m16, t) };
                assert_eq!(got, want, "t {t} lo {lo} ro {ro}");
                let (m, m16) = (mask::<16>(1, 1), mask16::<16>(1, 1));
                let want = ssd::<16>(&l, lo, 64, &r, ro, 64, 3, &m, t);
                // SAFETY: AVX2 detected above.
                let got = unsafe { avx2::ssd::<16>(&l, lo, 64, &r, ro, 64, 3, &m16, t) };
                assert_eq!(got, want, "t {t} lo {lo} ro {ro}");
            }
        }
        // A window that would read past the buffer fails as a mismatch.
        let m16 = mask16::<32>(3, 3);
        // SAFETY: AVX2 detected above.
        let past = unsafe { avx2::ssd::<32>(&l, 4090, 640, &r, 0, 640, 3, &m16, 0) };
        assert_eq!(past, u32::MAX / 2);
    }

    #[test]
    fn simd_row_kernel_matches_the_portable_one() {
        let mut x = 0x9e37_79b9u32;
        let mut byte = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        };
        for t in [0u16, 1, 37, 64, 127, 128] {
            let (mut a, mut b0, mut b1) = ([0u8; 32], [0u8; 32], [0u8; 32]);
            for k in 0..32 {
                (a[k], b0[k], b1[k]) = (byte(), byte(), byte());
            }
            let m: [u8; 32] = mask(3, 3);
            assert_eq!(
                row_ssd(&a, &b0, &b1, t, &m),
                row_ssd_portable(&a, &b0, &b1, t, &m)
            );
            let m: [u8; 32] = mask(2, 1);
            assert_eq!(
                row_ssd(&a, &b0, &b1, t, &m),
                row_ssd_portable(&a, &b0, &b1, t, &m)
            );
        }
    }
}
