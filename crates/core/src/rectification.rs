//! The residual vertical misalignment of a rectified pair, measured on the images.
//!
//! A rectified pair shows every scene point on the same row of both images. Real ones are off
//! by a fraction of a row (the KITTI pairs of the fixtures: -0.4 to +0.4 px), and on an edge
//! slanted by `du/dv` a vertical error `e` is a disparity error `e du/dv`: on a road marking
//! running 20 degrees from the horizontal, 0.5 px of row error is 1.4 px of disparity, which a
//! stereo matcher, the flies as OpenCV's SGBM, then reports for that edge.
//!
//! [`residual_row_offset`] measures the error as a sparse stereo matcher would: the corners of
//! the left image (the smaller eigenvalue of the structure tensor, Shi-Tomasi; one per cell of
//! a grid, the strongest cells kept) are matched along their row over the disparity range
//! (a unique best, as SGBM's `uniquenessRatio`), then the right image around each match is
//! compared with the corner's window at vertical offsets, each with its best horizontal one;
//! the offset with the least summed cost, refined by a parabola, is the residual. Corners, not
//! the fittest flies: a fly is fittest where the rows as calibrated already match, which biases
//! a measure on flies towards 0. The residual is corrected by giving it to the rig file
//! (`rectification.right_row_offset_px`), which [`crate::frame::PreparedImage::with_row_shift`]
//! applies to every right frame. Offline code (it allocates; ~50 ms at 1242x375): `flyd replay`
//! reports it for the pair it replays. It assumes a rectified pair (epipolar lines along the
//! rows); for a rig that is not, it says nothing useful.

use crate::frame::{BPP, PreparedImage, StereoFrame};
use crate::geometry::StereoRig;

pub mod yaw;

/// Half the window side, pixels (7 x 7 windows, as the fitness's).
const R: i32 = 3;
/// Offsets tried, both ways, pixels: -1.5..=1.5 by 0.25.
const STEP: f32 = 0.25;
const STEPS: i32 = 6;
const N: usize = (2 * STEPS + 1) as usize;
/// Side of the grid's cells, pixels: at most one corner a cell.
const CELL: usize = 24;
/// Corners matched at most.
const CORNERS: usize = 200;
/// A corner's best disparity must cost at most this share of its best more than 1 px away.
const UNIQUENESS: f64 = 0.7;
/// Fewest matched corners a measure is made from.
pub const MIN_MATCHES: usize = 16;

/// A measured residual row offset.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RowOffset {
    /// Where the right image shows a left row, relative to where the calibration (with its
    /// row correction) puts it, pixels: add it to `rectification.right_row_offset_px`.
    pub residual_px: f64,
    /// Corners it was measured on.
    pub corners: usize,
    /// The least cost's edge of the tried range was the best (the residual may be larger).
    pub at_range_edge: bool,
}

/// The right image's row correction to apply: the calibration's (the prior), or the prior plus
/// the residual measured on the images. `flyd replay` decides it on the first frame, the
/// daemon on each measure of its `flyd-rows` worker.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RowCorrection {
    /// The calibration's (`rectification.right_row_offset_px`).
    pub prior_px: f64,
    /// What the first frame's corners measured on top of it, when they did.
    pub measured_px: Option<f64>,
    /// Corners matched for that measure.
    pub corners: usize,
    /// The correction every right frame got.
    pub applied_px: f64,
    /// "measured": the prior plus the measure; "rig": the prior (why: `refused`).
    pub source: &'static str,
    /// Why the measure was not applied: "off" (`rectification.measure = false`), "not
    /// rectified", "too few corners", "beyond the range" (at the edge of the offsets tried,
    /// or the sum beyond `MAX_RIGHT_ROW_OFFSET`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refused: Option<&'static str>,
}

impl RowCorrection {
    /// The correction for a right image calibrated at `prior` px, given what the first frame
    /// measured (`None`: too few corners) and whether measuring is on (`measure`) for this
    /// rig (`rectified`).
    pub fn decide(prior: f64, measure: bool, rectified: bool, measured: Option<RowOffset>) -> Self {
        let rig = |refused, measured: Option<RowOffset>| Self {
            prior_px: prior,
            measured_px: measured.map(|m| m.residual_px),
            corners: measured.map_or(0, |m| m.corners),
            applied_px: prior,
            source: "rig",
            refused: Some(refused),
        };
        if !measure {
            return rig("off", None);
        }
        if !rectified {
            return rig("not rectified", None);
        }
        let Some(m) = measured else {
            return rig("too few corners", None);
        };
        let sum = prior + m.residual_px;
        if m.at_range_edge || !sum.is_finite() || sum.abs() > crate::calib::MAX_RIGHT_ROW_OFFSET {
            return rig("beyond the range", Some(m));
        }
        Self {
            prior_px: prior,
            measured_px: Some(m.residual_px),
            corners: m.corners,
            applied_px: sum,
            source: "measured",
            refused: None,
        }
    }
}

/// The disparity (whole pixels, 1..=512) of the nearest depth `min_depth` searched on `rig`:
/// how far along its row [`residual_row_offset`] matches a corner.
pub fn max_disparity(rig: &StereoRig, min_depth: f64) -> u32 {
    let d = rig.right.intrinsics().fx * rig.baseline() / min_depth.max(0.1);
    d.clamp(1.0, 512.0).ceil() as u32
}

/// The residual of `frame`'s rows (see the module docs), matching corners up to
/// `max_disparity` pixels; `None` with fewer than [`MIN_MATCHES`] matched corners.
pub fn residual_row_offset(frame: &StereoFrame, max_disparity: u32) -> Option<RowOffset> {
    let (left, right) = (&frame.left, &frame.right);
    let margin = (R + 2 + STEPS / 4) as usize;
    let (w, h) = (left.width() as usize, left.height() as usize);
    if w < 2 * margin + 2 || h < 2 * margin + 2 || right.width() != left.width() {
        return None;
    }
    let mut corners = corners(left, margin);
    corners.truncate(CORNERS);
    let mut total = [0f64; N];
    let mut used = 0;
    for (x, y) in corners {
        let Some(d) = disparity(left, right, x, y, max_disparity, margin) else {
            continue;
        };
        let (xr, yr) = (x as f32 - d as f32, y as f32);
        // Cost per vertical offset: the least over the horizontal ones.
        let mut cost = [f64::MAX; N];
        for (j, c) in cost.iter_mut().enumerate() {
            let dy = (j as i32 - STEPS) as f32 * STEP;
            for i in -STEPS..=STEPS {
                let dx = i as f32 * STEP;
                *c = c.min(ssd(left, x as i32, y as i32, right, xr + dx, yr + dy));
            }
        }
        let mean = cost.iter().sum::<f64>() / N as f64;
        if mean.is_nan() || mean <= 0.0 {
            continue;
        }
        for (t, c) in total.iter_mut().zip(cost) {
            *t += c / mean;
        }
        used += 1;
    }
    if used < MIN_MATCHES {
        return None;
    }
    let j = (0..N).min_by(|&a, &b| total[a].total_cmp(&total[b]))?;
    let at_range_edge = j == 0 || j == N - 1;
    let mut at = j as f64 - f64::from(STEPS);
    if !at_range_edge {
        let (a, b, c) = (total[j - 1], total[j], total[j + 1]);
        let curvature = a - 2.0 * b + c;
        if curvature > 0.0 {
            at += 0.5 * (a - c) / curvature;
        }
    }
    Some(RowOffset {
        residual_px: at * f64::from(STEP),
        corners: used,
        at_range_edge,
    })
}

/// The strongest corner of each grid cell (Shi-Tomasi: the structure tensor's smaller
/// eigenvalue over a 7 x 7 window, on the green channel (a grey image's only one) every
/// second pixel), strongest first.
fn corners(img: &PreparedImage, margin: usize) -> Vec<(usize, usize)> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let d = img.data();
    let channel = usize::from(img.channels() == 3);
    let g = |x: usize, y: usize| f64::from(d[img.offset(x as isize, y as isize) + channel]);
    let mut best: Vec<(f64, usize, usize)> = Vec::new();
    let m = margin + 1;
    for cy in (m..h - m).step_by(CELL) {
        for cx in (m..w - m).step_by(CELL) {
            let mut cell = (0.0, 0, 0);
            for y in (cy..(cy + CELL).min(h - m)).step_by(2) {
                for x in (cx..(cx + CELL).min(w - m)).step_by(2) {
                    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
                    for j in y - R as usize..=y + R as usize {
                        for i in x - R as usize..=x + R as usize {
                            let gx = g(i + 1, j) - g(i - 1, j);
                            let gy = g(i, j + 1) - g(i, j - 1);
                            sxx += gx * gx;
                            syy += gy * gy;
                            sxy += gx * gy;
                        }
                    }
                    let tr = 0.5 * (sxx + syy);
                    let min_eig = tr - (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
                    if min_eig > cell.0 {
                        cell = (min_eig, x, y);
                    }
                }
            }
            if cell.0 > 0.0 {
                best.push(cell);
            }
        }
    }
    best.sort_by(|a, b| b.0.total_cmp(&a.0));
    best.into_iter().map(|(_, x, y)| (x, y)).collect()
}

/// The corner's disparity along its row (whole pixels, `0..=max`), when its best is unique.
fn disparity(
    left: &PreparedImage,
    right: &PreparedImage,
    x: usize,
    y: usize,
    max: u32,
    margin: usize,
) -> Option<u32> {
    let reach = (x.saturating_sub(margin + 1) as u32).min(max);
    let costs: Vec<f64> = (0..=reach)
        .map(|d| {
            ssd(
                left,
                x as i32,
                y as i32,
                right,
                (x as u32 - d) as f32,
                y as f32,
            )
        })
        .collect();
    let best = (0..costs.len()).min_by(|&a, &b| costs[a].total_cmp(&costs[b]))?;
    let second = costs
        .iter()
        .enumerate()
        .filter(|&(d, _)| d.abs_diff(best) > 1)
        .map(|(_, &c)| c)
        .fold(f64::MAX, f64::min);
    (costs[best] <= UNIQUENESS * second && best > 0).then_some(best as u32)
}

/// Sum of squared colour differences between the 7 x 7 window of `left` centred on `(x, y)`
/// and that of `right` centred on `(u, v)`, bilinearly interpolated. The caller keeps both
/// windows (and the interpolation's next pixel) inside the images.
fn ssd(left: &PreparedImage, x: i32, y: i32, right: &PreparedImage, u: f32, v: f32) -> f64 {
    scaled_ssd(left, x, y, right, u, v, 1.0, 1.0)
}

/// [`ssd`] with the second window magnified `mx` times across and `my` times down: the sum of
/// squared differences between the 7 x 7 window of `left` at `(x, y)` and `right` read
/// bilinearly at `(u + mx i, v + my j)`. The caller keeps both (and the next pixel) inside the
/// images' padding.
#[allow(clippy::too_many_arguments)]
fn scaled_ssd(
    left: &PreparedImage,
    x: i32,
    y: i32,
    right: &PreparedImage,
    u: f32,
    v: f32,
    mx: f32,
    my: f32,
) -> f64 {
    let (ld, rd) = (left.data(), right.data());
    let channels = usize::from(left.channels().min(right.channels()));
    let rs = right.stride();
    let mut sum = 0f64;
    for j in -R..=R {
        let vv = v + my * j as f32;
        let v0 = vv.floor();
        let b = vv - v0;
        for i in -R..=R {
            let uu = u + mx * i as f32;
            let u0 = uu.floor();
            let a = uu - u0;
            let w = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
            let lo = left.offset((x + i) as isize, (y + j) as isize);
            let ro = right.offset(u0 as isize, v0 as isize);
            for c in 0..channels {
                let r = w[0] * f32::from(rd[ro + c])
                    + w[1] * f32::from(rd[ro + BPP + c])
                    + w[2] * f32::from(rd[ro + rs + c])
                    + w[3] * f32::from(rd[ro + rs + BPP + c]);
                let d = f32::from(ld[lo + c]) - r;
                sum += f64::from(d * d);
            }
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::PixelFormat;

    /// A textured pair 10 px of disparity apart whose right image shows each left row `rows`
    /// rows lower (left row y at right row y + rows), prepared with the row shift `shift`.
    /// The scene is blurred noise (texture at the windows' scale, corners everywhere), read
    /// bilinearly where the right camera sees it.
    fn pair(rows: f64, shift: f64) -> StereoFrame {
        pair_as(PixelFormat::Rgb8, rows, shift)
    }

    /// [`pair`] in `format` (grey: the red channel's values alone).
    fn pair_as(format: PixelFormat, rows: f64, shift: f64) -> StereoFrame {
        let (w, h) = (240usize, 160usize);
        let (sw, sh) = (w + 40, h + 20);
        let noise: Vec<f64> = (0..sw * sh)
            .map(|i| {
                let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
                z ^= z >> 29;
                z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z ^= z >> 32;
                (z % 256) as f64
            })
            .collect();
        // A 3 x 3 binomial blur.
        let k = [0.25, 0.5, 0.25];
        let at = |x: usize, y: usize| noise[y.min(sh - 1) * sw + x.min(sw - 1)];
        let blurred: Vec<f64> = (0..sw * sh)
            .map(|i| {
                let (x, y) = (i % sw, i / sw);
                let mut v = 0.0;
                for (j, kj) in k.iter().enumerate() {
                    for (i, ki) in k.iter().enumerate() {
                        v += kj * ki * at((x + i).saturating_sub(1), (y + j).saturating_sub(1));
                    }
                }
                v
            })
            .collect();
        let scene = |x: f64, y: f64| {
            let (x0, y0) = (x.floor(), y.floor());
            let (a, b) = (x - x0, y - y0);
            let (x0, y0) = (x0 as usize, y0 as usize);
            let p = |dx: usize, dy: usize| blurred[(y0 + dy) * sw + x0 + dx];
            let v = (1.0 - a) * (1.0 - b) * p(0, 0)
                + a * (1.0 - b) * p(1, 0)
                + (1.0 - a) * b * p(0, 1)
                + a * b * p(1, 1);
            v.round().clamp(0.0, 255.0) as u8
        };
        let disparity = 10.0;
        let mut l = Vec::new();
        let mut r = Vec::new();
        for y in 0..h {
            for x in 0..w {
                // Scene coordinates start 5 px in, so that shifted reads stay inside.
                let (xf, yf) = (x as f64 + 5.0, y as f64 + 5.0);
                let a = scene(xf, yf);
                l.extend([a, a / 2, 255 - a]);
                let b = scene(xf + disparity, yf - rows);
                r.extend([b, b / 2, 255 - b]);
            }
        }
        let (w, h) = (w as u32, h as u32);
        if format == PixelFormat::Grey8 {
            l = l.into_iter().step_by(3).collect();
            r = r.into_iter().step_by(3).collect();
        }
        let left = PreparedImage::from_pixels(w, h, format, &l).expect("left");
        let mut right = PreparedImage::new(w, h)
            .expect("right")
            .with_row_shift(shift);
        right.prepare(format, &r).expect("prepare");
        StereoFrame::new(left, right, 1)
    }

    #[test]
    fn a_pair_off_by_a_fraction_of_a_row_is_measured() {
        for rows in [-0.6, -0.3, 0.0, 0.4, 0.75] {
            let m = residual_row_offset(&pair(rows, 0.0), 32).expect("measured");
            assert!(
                (m.residual_px - rows).abs() <= 0.1,
                "{rows} px off: measured {m:?}"
            );
            assert!(!m.at_range_edge && m.corners >= MIN_MATCHES, "{m:?}");
        }
    }

    #[test]
    fn a_grey_pair_is_measured_as_well() {
        let m = residual_row_offset(&pair_as(PixelFormat::Grey8, 0.4, 0.0), 32).expect("measured");
        assert!((m.residual_px - 0.4).abs() <= 0.1, "{m:?}");
    }

    #[test]
    fn the_row_shift_corrects_what_was_measured() {
        let off = residual_row_offset(&pair(0.5, 0.0), 32).expect("measured");
        let corrected = pair(0.5, off.residual_px);
        assert!((corrected.right.row_shift() - off.residual_px).abs() < 1.0 / 256.0);
        let after = residual_row_offset(&corrected, 32).expect("measured");
        assert!(after.residual_px.abs() <= 0.1, "{off:?} then {after:?}");
    }

    #[test]
    fn images_without_corners_measure_nothing() {
        let flat = vec![90u8; 240 * 160 * 3];
        let img = || PreparedImage::from_pixels(240, 160, PixelFormat::Rgb8, &flat).expect("img");
        assert_eq!(
            residual_row_offset(&StereoFrame::new(img(), img(), 1), 32),
            None
        );
        let tiny = || PreparedImage::new(8, 8).expect("img");
        assert_eq!(
            residual_row_offset(&StereoFrame::new(tiny(), tiny(), 1), 32),
            None
        );
    }

    #[test]
    fn a_measure_is_applied_on_top_of_the_prior_unless_it_cannot_be_trusted() {
        let m = |px: f64, corners: usize, at_range_edge: bool| RowOffset {
            residual_px: px,
            corners,
            at_range_edge,
        };
        let c = RowCorrection::decide(0.5, true, true, Some(m(-0.44, 80, false)));
        assert_eq!((c.source, c.refused), ("measured", None));
        assert!((c.applied_px - 0.06).abs() < 1e-9, "{c:?}");
        for (measure, rectified, measured, why) in [
            (false, true, Some(m(-0.44, 80, false)), "off"),
            (true, false, Some(m(-0.44, 80, false)), "not rectified"),
            (true, true, None, "too few corners"),
            (true, true, Some(m(1.5, 80, true)), "beyond the range"),
            (true, true, Some(m(1.6, 80, false)), "beyond the range"),
            (true, true, Some(m(f64::NAN, 80, false)), "beyond the range"),
        ] {
            let c = RowCorrection::decide(0.5, measure, rectified, measured);
            assert_eq!((c.source, c.refused), ("rig", Some(why)), "{c:?}");
            assert_eq!(c.applied_px, 0.5, "the prior stands: {c:?}");
        }
    }
}
