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
//!   `unsafe`; the AVX2 and AVX-512 kernels, chosen at run time ([`Isa`]), give the same
//!   integers with fewer instructions (AVX-512: a whole 32-byte row in one vector) and trust
//!   their caller's single bounds check a window.
//! - `floor = ssd_floor` (grey levels squared per sample) guards the division.
//! - The road region of interest is applied here too (a multiplier on F).

use super::Population;
use super::params::{EngineParams, RoadRoi};
use super::projector::Projector;
use super::sharing::Grid;
use super::trunc::trunc;
use super::windows::{Windows, mask, mask_bits, mask16};
use crate::frame::{BPP, NORMALISED_STD, PreparedImage, StereoFrame};
use crate::isa::{Isa, dispatch};
use crate::road_plane::RoadPlane;
use std::ops::Range;

/// Constant factor of every fitness. It changes no ranking; it puts the global warning on the
/// scale of the paper's figures (hw-mock: 0.05-0.2 on an empty road, ~6-7 with a pedestrian 4 m
/// ahead), which also keeps it inside the CAN signal's range (0.001 resolution, up to 65.5).
pub const FITNESS_SCALE: f32 = 0.01;

/// An evaluation's arguments besides the kernel: the cameras, the flies and which of them, the
/// sharing grid (for the flies' cells), the scratch.
type Args<'a> = (
    &'a Projector,
    &'a Projector,
    &'a mut Population,
    Range<usize>,
    &'a Grid,
    &'a mut Scratch,
);

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
    /// The road the region of interest's heights are measured from (`RoadPlane::coefficients`).
    road: [f32; 3],
    channels: usize,
    /// SSD (summed over the compared samples) under which a fly's windows match.
    match_ssd: f32,
}

impl<'a> Kernel<'a> {
    /// The kernel for `frame`, heights measured from `road`.
    pub(crate) fn new(frame: &'a StereoFrame, params: &EngineParams, road: &RoadPlane) -> Self {
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
            road: road.coefficients(),
            channels,
            match_ssd: (MATCH_SSD_PER_SAMPLE * samples as f64) as f32,
        }
    }

    /// The same kernel without the region of interest (every fly judged on its match alone).
    pub(crate) fn without_roi(self) -> Self {
        Self { roi: None, ..self }
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

    dispatch! {
        #[allow(clippy::too_many_arguments)]
        /// Evaluates flies `range` of `pop`: projections, sharing cells (of `grid`) and
        /// `raw_fitness`. Returns how many of them both cameras see, and how many of those
        /// match (see [`Matches`]).
        pub(crate) fn evaluate['a](
            self: &Kernel<'a>,
            left: &Projector,
            right: &Projector,
            pop: &mut Population,
            range: Range<usize>,
            grid: &Grid,
            scratch: &mut Scratch,
        ) -> Matches;
        up to Avx512 => Kernel::evaluate_at
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn evaluate_at(
        &self,
        isa: Isa,
        left: &Projector,
        right: &Projector,
        pop: &mut Population,
        range: Range<usize>,
        grid: &Grid,
        scratch: &mut Scratch,
    ) -> Matches {
        let args = (left, right, pop, range, grid, scratch);
        // One instantiation per (radius, channels): the row width and mask become constants.
        match (self.radius, self.channels) {
            (1, 1) => self.evaluate_with::<16, 1, 1>(isa, args),
            (1, _) => self.evaluate_with::<16, 1, 3>(isa, args),
            (2, 1) => self.evaluate_with::<32, 2, 1>(isa, args),
            (2, _) => self.evaluate_with::<32, 2, 3>(isa, args),
            (_, 1) => self.evaluate_with::<32, 3, 1>(isa, args),
            (_, _) => self.evaluate_with::<32, 3, 3>(isa, args),
        }
    }

    #[inline(always)]
    fn evaluate_with<const W: usize, const R: usize, const C: usize>(
        &self,
        isa: Isa,
        (left, right, pop, range, grid, scratch): Args<'_>,
    ) -> Matches {
        let mask = &const { mask::<W>(R, C) };
        let mask16 = &const { mask16::<W>(R, C) };
        let mask_bits = const { mask_bits::<W>(R, C) };
        let (ld, rd) = (self.left.data(), self.right.data());
        let (ls, rs) = (self.left.stride(), self.right.stride());
        let rows = 2 * R + 1;
        let row_step = self.row_step;
        pop.project(isa, left, right, range.clone());
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
        let (xs, ys, zs) = (
            &pop.x[from..][..len],
            &pop.y[from..][..len],
            &pop.z[from..][..len],
        );
        let [r0, rz, rx] = self.road;
        let fitness = &mut pop.raw_fitness[from..][..len];
        let cells = &mut pop.cell[from..][..len];
        let matched = &mut pop.matched[from..][..len];
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
            // A fly outside an image is marked by an offset past every buffer (pass 2).
            lo[i] = if outside {
                u32::MAX
            } else {
                self.left.offset32(uli - R as i32, vli - R as i32)
            };
            ro[i] = self.right.offset32(uri - R as i32, vri - R as i32);
            cells[i] = if outside { u32::MAX } else { grid.cell(ul, vl) };
        }

        // 2. The windows: gradients and SSD, one fly at a time.
        let windows = Windows {
            left: (ld, ls * row_step, gl_at),
            right: (rd, rs * row_step, gr_at),
            n_rows: rows.div_ceil(row_step),
            mask,
            mask16,
            mask_bits,
        };
        windows.compare(isa, lo, ro, ts, grads, ssds);

        // 3. Fitness, region of interest and match counts: straight-line again.
        let mut m = Matches::default();
        for i in 0..len {
            let compared = ssds[i] >= 0;
            let (g, ssd) = if compared {
                (grads[i] as f32, ssds[i] as f32)
            } else {
                (0.0, 0.0)
            };
            m.visible += u32::from(compared);
            matched[i] = compared & (ssd <= self.match_ssd);
            // A match counts only on texture: uniform windows (a black or saturated image)
            // have a zero SSD everywhere and would otherwise "match" at every depth.
            m.matched += u32::from(compared & (ssd <= self.match_ssd) & (g >= MATCH_MIN_GRADIENT));
            // FITNESS_SCALE gl gr / (ssd / |N| + ssd_floor), written with one division.
            let f = g * self.scale / (ssd + self.floor);
            let h = ys[i] - (r0 + rz * zs[i] + rx * xs[i]);
            let out = (h > max_h) | (h < min_h) | (zs[i] > max_z);
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
    grads: Vec<i32>,
    /// SSD of the compared flies, -1 for the others.
    ssd: Vec<i32>,
}

impl Scratch {
    /// Room for evaluating `flies` flies at once.
    pub(crate) fn new(flies: usize) -> Self {
        let n = flies;
        Self {
            lo: vec![0; n],
            ro: vec![0; n],
            t: vec![0; n],
            grads: vec![0; n],
            ssd: vec![0; n],
        }
    }

    fn len(&self) -> usize {
        self.lo.len()
    }
}

/// Per-sample SSD under which two windows count as matching: a quarter of what two unrelated
/// windows of normalised images give on average (2 x NORMALISED_STD^2). Frames are normalised
/// to that standard deviation, so the level holds for any camera and scene.
const MATCH_SSD_PER_SAMPLE: f64 = 0.25 * 2.0 * NORMALISED_STD * NORMALISED_STD;

/// `gl * gr` (the windows' centre gradient bytes, normalised Sobel magnitude / 4) from which
/// a match counts as one on texture: both centres at a normalised gradient of about 16, a
/// third of a typical edge's after normalisation. Uniform windows have 0.
const MATCH_MIN_GRADIENT: f32 = 16.0;

/// What one evaluation saw: flies inside both images, and those whose windows match (on
/// texture).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Matches {
    pub(crate) visible: u32,
    pub(crate) matched: u32,
}
