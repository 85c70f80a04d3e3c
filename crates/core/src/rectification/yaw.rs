//! The right camera's yaw relative to the left one, checked against the vehicle's motion.
//!
//! A rectified pair whose right camera is turned about its vertical axis by a small angle `a`
//! relative to what the calibration says shows every scene point `f tan(a)` pixels further
//! along its row: a constant disparity offset (0.1 degree is 1.2 px at KITTI's 707 px, 0.9 px
//! at hw-mock's 520 px). Every depth is biased by it, by `z^2 offset / (f B)`: on KITTI's rig
//! 1.3 m at 20 m for 0.1 degree. One pair cannot show it: a pair whose right camera is turned
//! is the same images as a scene whose every point lies at the biased depth. The rows of the
//! pair are measured from the images ([`super::residual_row_offset`]); the columns need a
//! second measure of depth, and a moving vehicle has one: motion parallax in the left camera
//! alone. Driving `s` metres, a static point at depth `z` moves in the left image along a line
//! (the motion's epipolar line) by an amount that depends on `z` only, not on the right
//! camera: a point 300 px from the focus of expansion at 10 m moves 41 px for KITTI's 1.2 m a
//! frame. (Monocular depth from known motion against stereo depth: the consistency check of
//! stereo visual odometry, whose scale the baseline fixes; here the motion is known and the
//! right camera is in question.)
//!
//! [`pair_flows`] takes two frames of the left camera `s` metres apart (the [`EgoTransform`]
//! between them, from the vehicle's measured speed and yaw rate) and the right image of the
//! first. The left image's corners (Shi-Tomasi, as the rows' measure) are matched along the
//! calibration's epipolar curve in the right image (continued past its infinity: a turned camera
//! shows far points beyond it; a unique best, refined by a parabola), and along their motion
//! curve in the later left image between the depths [`NEAREST`] and [`FARTHEST`], every half
//! pixel, the window magnified by the depth ratio (its square down the image: the road). A pitch
//! that changes between the frames (the car's bounce: a uniform vertical shift of the later
//! image) is found first as the shift whose matches cost least over all corners, as the rows
//! are; each match is then refined +-3 px both ways. The travel's direction is not the mount's:
//! the focus of expansion and the pitch shift are measured on the pair's flows (Gauss-Newton on
//! each flow's distance from its line through the focus, Huber).
//!
//! Each corner's growth away from the focus gives its depth, and the calibration's right
//! camera says where it should show that point: the difference from where it does, pixels, is
//! the sample. On a correct rig the samples scatter around 0; a turn of the right camera moves a
//! point `x` focal lengths from its centre by `1 + x^2` focal lengths a radian; a speed that
//! reads 1 % high scales every motion depth by 1 % and shifts each sample by 1 % of its
//! disparity. [`ColumnCheck`] keeps the flows of many pairs; its report fits each pair's
//! samples on their own, `sample = turn (1 + x^2) f + scale disparity`, weighted by how much a
//! quarter pixel of flow moves each prediction (a corner near the focus says little), robust
//! (Huber), and takes the median of the pairs' turns (a pair whose motion or matches went wrong
//! is an outlier; moving objects are outliers within a pair). Offline code (it allocates; 0.15 s
//! of CPU a pair at 1226x370): `flyd replay` runs it on a feed that comes with its
//! motion. It assumes a pair rectified but for the turn, as the rows' measure.

use serde::Serialize;

use super::{R, UNIQUENESS, corners, scaled_ssd, ssd};
use crate::frame::{PreparedImage, StereoFrame};
use crate::geometry::StereoRig;
use crate::kinematics::EgoTransform;
use nalgebra::Point3;

/// Corners tried a pair at most (the strongest of the grid's cells).
const CORNERS: usize = 160;
/// The motion line's depths, metres: the nearest and the farthest a corner may lie at.
pub const NEAREST: f64 = 2.0;
pub const FARTHEST: f64 = 200.0;
/// Spacing of the samples along the motion line, pixels.
const SPACING: f64 = 0.5;
/// Samples along one motion line at most (256 px).
const MAX_SAMPLES: usize = 513;
/// Fewest pixels a motion line spans between [`NEAREST`] and [`FARTHEST`]: one shorter (a
/// corner at the focus of expansion, or a vehicle barely moving) measures no depth.
const MIN_SPAN: f64 = 3.0;
/// The fewest metres driven between two frames [`pair_flows`] compares.
pub const MIN_TRAVEL: f64 = 0.5;
/// A quarter pixel: the motion match's and the stereo match's uncertainties, pixels.
const MOTION_SIGMA: f64 = 0.25;
const STEREO_SIGMA: f64 = 0.15;
/// Fewest samples a pair is fitted from, and fewest pairs fitted a report is made from.
const MIN_PAIR_SAMPLES: usize = 20;
pub const MIN_PAIRS: usize = 5;
/// The right camera disagrees with the images when the offset is beyond this, pixels, and
/// beyond three of its standard errors. On the real drive of KITTI odometry 06 with its
/// calibration as published the check measures +0.47 px (hw-mock's scenarios, whose rig is
/// the truth: -0.08..+0.19 px); 0.1 degree of yaw is 1.23 px there (0.91 px on hw-mock's rig):
/// docs/perception.md, "The right camera's yaw checked against the motion".
pub const TOLERANCE_PX: f64 = 0.6;
/// No verdict of agreement when the offset's standard error is beyond this, pixels.
const MAX_SIGMA_PX: f64 = 0.2;

/// One corner's evidence: the disparity the pair shows and how far the right image shows it
/// from where the calibration puts the depth the motion measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColumnSample {
    /// The pair's disparity at the corner, pixels.
    pub disparity: f64,
    /// Where the right image shows the corner, less where the calibration's right camera
    /// shows the point at the motion's depth, pixels (positive: further right).
    pub residual: f64,
    /// How far the right camera's image moves there for a radian of its yaw, pixels.
    pub yaw_gain: f64,
    /// Inverse variance of `residual`, 1/px^2.
    pub weight: f64,
}

/// What a pair of frames showed: each corner's stereo match and flow, and the focus of
/// expansion they point away from.
#[derive(Debug, Clone)]
pub struct PairFlows {
    flows: Vec<Flow>,
    /// The focus measured on this pair, ideal pixels.
    focus: (f64, f64),
    /// Metres driven between the frames.
    travelled: f64,
}

/// The flows of the pair `before` and the later left image `after`, taken after the vehicle
/// moved by `moved` (how a static point moves in the vehicle frame from the first to the
/// second), on the calibration `rig`; none when the vehicle moved less than [`MIN_TRAVEL`]
/// (`travelled`, metres), the images are too small or too little matched.
pub fn pair_flows(
    before: &StereoFrame,
    after: &PreparedImage,
    rig: &StereoRig,
    moved: &EgoTransform,
    travelled: f64,
) -> Option<PairFlows> {
    let left = &before.left;
    // The magnified window reaches 4 R from its centre (m = 2 down the image), +-4 px away.
    let margin = (4 * R + 6) as usize;
    let (w, h) = (left.width() as usize, left.height() as usize);
    if travelled.abs() < MIN_TRAVEL
        || w < 2 * margin + 2
        || h < 2 * margin + 2
        || after.width() != left.width()
        || after.height() != left.height()
        || before.right.width() != left.width()
        || before.right.height() != left.height()
    {
        return None;
    }
    let inside = |(x, y): (f64, f64)| {
        x >= margin as f64
            && y >= margin as f64
            && x <= (w - margin - 2) as f64
            && y <= (h - margin - 2) as f64
    };
    // Where the later left image and the right image show the corner (x, y) at inverse depth q.
    let later = |x: f64, y: f64, q: f64| -> Option<(f64, f64)> {
        let p = rig.left.vehicle_from_pixel_depth(x, y, 1.0 / q)?;
        let (mx, mz) = moved.apply(p.x as f32, p.z as f32);
        let px = rig
            .left
            .pixel_from_vehicle(&Point3::new(f64::from(mx), p.y, f64::from(mz)))?;
        Some((px.x, px.y))
    };
    // How much larger the later image shows the corner's surroundings: its depth then over
    // now (a surface facing the camera; the road's, seen at a grazing angle, grows by the
    // square of it down the image).
    let magnification = |x: f64, y: f64, q: f64| -> f64 {
        let Some(p) = rig.left.vehicle_from_pixel_depth(x, y, 1.0 / q) else {
            return 1.0;
        };
        let (mx, mz) = moved.apply(p.x as f32, p.z as f32);
        let then = rig
            .left
            .camera_from_vehicle(&Point3::new(f64::from(mx), p.y, f64::from(mz)))
            .z;
        let m = 1.0 / (q * then);
        if m.is_finite() {
            m.clamp(0.5, 2.0)
        } else {
            1.0
        }
    };
    // The cost of a place along the motion curve, the window magnified as a surface facing
    // the camera would be.
    let moving_cost = |x: usize, y: usize, p: &Place, dv: f64| -> f64 {
        let m = magnification(x as f64, y as f64, p.q) as f32;
        let v = (p.v + dv) as f32;
        scaled_ssd(left, x as i32, y as i32, after, p.u as f32, v, m, m)
    };
    let beside = |x: f64, y: f64, q: f64| -> Option<(f64, f64)> {
        let p = rig.left.vehicle_from_pixel_depth(x, y, 1.0 / q)?;
        let px = rig.right.pixel_from_vehicle(&p)?;
        Some((px.x, px.y))
    };
    let q_far = 1.0 / FARTHEST;
    let q_near = 1.0 / NEAREST.max(1.5 * travelled.abs());

    // Each corner with a unique match along its epipolar curve in the right image, and along
    // its motion curve in the later left image (the curve follows the travel's direction as the
    // mount declares it: the match is then refined in both directions, and the focus and the
    // pitch measured on the flows).
    let k = rig.left.intrinsics();
    let ideal = |u: f64, v: f64| {
        rig.left
            .normalised_from_pixel(u, v)
            .map(|(x, y)| (x * k.fx, y * k.fy))
    };
    // The travel's direction (the focus of expansion) and the later image's pitch shift that
    // make every flow point away from it; declared by the mount to start with.
    let declared = {
        let c = rig.left.centre();
        let (tx, tz) = moved.invert(0.0, 0.0);
        let ahead = rig.left.camera_from_vehicle(&Point3::new(
            c.x - f64::from(tx),
            c.y,
            c.z - f64::from(tz),
        ));
        let here = rig.left.camera_from_vehicle(&c);
        let t = ahead - here;
        (k.fx * t.x / t.z, k.fy * t.y / t.z)
    };
    // Each corner's stereo match, once; its motion match twice: along the curve as declared,
    // then shifted by the pitch the first pass measured (the car's bounce moves the whole later
    // image up to 2 px: a corner on the road, whose curve runs down the image, would be
    // matched that far along it).
    let mut stereo = Vec::new();
    let mut places = Vec::new();
    let mut costs = Vec::new();
    let mut found = corners(left, margin);
    found.truncate(CORNERS);
    for (x, y) in found {
        let (xf, yf) = (x as f64, y as f64);
        walk(|q| beside(xf, yf, q), q_far, q_near, &inside, &mut places);
        beyond_infinity(&mut places, &inside);
        costs.clear();
        costs.extend(places.iter().map(|p| {
            ssd(
                left,
                x as i32,
                y as i32,
                &before.right,
                p.u as f32,
                p.v as f32,
            )
        }));
        if let Some(best) = unique_best(&costs, &places) {
            stereo.push((x, y, best.u));
        }
    }
    let mut flows = Vec::new();
    let mut dv = 0.0;
    for pass in 0..2 {
        flows.clear();
        for &(x, y, right_u) in &stereo {
            let (xf, yf) = (x as f64, y as f64);
            walk(|q| later(xf, yf, q), q_far, q_near, &inside, &mut places);
            if places.len() < 3 || span(&places) < MIN_SPAN {
                continue;
            }
            costs.clear();
            costs.extend(places.iter().map(|p| moving_cost(x, y, p, dv)));
            let Some(motion) = unique_best(&costs, &places) else {
                continue;
            };
            let m = magnification(xf, yf, motion.q) as f32;
            let Some((u1, v1)) = refine(left, x, y, after, motion.u, motion.v + dv, m, &inside)
            else {
                continue;
            };
            // Where the later image shows the corner's point at an infinite depth: the turn
            // alone.
            let (Some(turned), Some(found)) = (
                later(xf, yf, 1e-6).and_then(|(u, v)| ideal(u, v)),
                ideal(u1, v1),
            ) else {
                continue;
            };
            flows.push(Flow {
                x: xf,
                y: yf,
                right_u,
                turned,
                found,
            });
        }
        if pass == 0 {
            let Some((_, shift)) = expansion(&flows, declared, true) else {
                break;
            };
            dv = shift.clamp(-3.0, 3.0);
        }
    }
    let (focus, _) = expansion(&flows, declared, true)?;
    Some(PairFlows {
        flows,
        focus,
        travelled: travelled.abs(),
    })
}

/// The samples of `pair` with the focus of expansion at `focus` (ideal pixels), the pair's
/// pitch shift measured again with it, on `rig`: added to `out`.
fn pair_samples(pair: &PairFlows, focus: (f64, f64), rig: &StereoRig, out: &mut Vec<ColumnSample>) {
    let Some((_, shift_v)) = expansion(&pair.flows, focus, false) else {
        return;
    };
    let k = rig.left.intrinsics();
    let along = 1.0 / (1.0 + (focus.0 / k.fx).powi(2) + (focus.1 / k.fy).powi(2)).sqrt();
    let travel_z = pair.travelled * along;
    for flow in &pair.flows {
        let (xf, yf) = (flow.x, flow.y);
        let a = (flow.turned.0 - focus.0, flow.turned.1 - focus.1);
        let b = (flow.found.0 - focus.0, flow.found.1 - focus.1 - shift_v);
        let r2 = a.0 * a.0 + a.1 * a.1;
        if r2 < 1.0 {
            continue;
        }
        // The point's image grows away from the focus by its depth then over now.
        let growth = (b.0 * a.0 + b.1 * a.1) / r2;
        let depth = |growth: f64| travel_z * growth / (growth - 1.0);
        let z = depth(growth);
        if growth <= 1.0 || !(NEAREST..=FARTHEST).contains(&z) {
            continue;
        }
        let predicted = |z: f64| -> Option<f64> {
            let p = rig.left.vehicle_from_pixel_depth(xf, yf, z)?;
            Some(rig.right.pixel_from_vehicle(&p)?.x)
        };
        // How far the prediction moves for a quarter pixel of flow along the radial.
        let dg = MOTION_SIGMA / r2.sqrt();
        let (Some(u), Some(u_lo), Some(u_hi)) = (
            predicted(z),
            predicted(depth(growth + dg)),
            predicted(depth((growth - dg).max(1.0 + 1e-6))),
        ) else {
            continue;
        };
        let variance = (0.5 * (u_hi - u_lo)).powi(2) + STEREO_SIGMA.powi(2);
        let residual = flow.right_u - u;
        // A turn of the right camera moves a point seen at normalised column x by (1 + x^2)
        // focal lengths a radian.
        let kr = rig.right.intrinsics();
        let x_n = (flow.right_u - kr.cx) / kr.fx;
        let yaw_gain = kr.fx * (1.0 + x_n * x_n);
        if residual.is_finite() && variance.is_finite() && variance > 0.0 {
            out.push(ColumnSample {
                disparity: xf - flow.right_u,
                residual,
                yaw_gain,
                weight: 1.0 / variance,
            });
        }
    }
}

/// A corner of the earlier left image: where the right image shows it, and its flow
/// between the frames in ideal pixels (undistorted, from the principal point): where the turn
/// alone puts it, and where it was found.
#[derive(Debug, Clone, Copy)]
struct Flow {
    x: f64,
    y: f64,
    right_u: f64,
    turned: (f64, f64),
    found: (f64, f64),
}

/// The focus of expansion and the later image's vertical shift (pitch between the frames)
/// that make every flow, less the shift, point away from the focus: iteratively reweighted
/// least squares (Huber) on each flow's distance from its line through the focus, one
/// unknown group at a time, from the focus `start` (kept there unless `fit_focus`). `None`
/// with fewer than 8 flows.
fn expansion(flows: &[Flow], start: (f64, f64), fit_focus: bool) -> Option<((f64, f64), f64)> {
    if flows.len() < 8 {
        return None;
    }
    // cross(a - e, b - (0, d) - e) = a x b - ax d + ex (ay - by + d) - ey (ax - bx): zero for
    // each flow; Gauss-Newton on (ex, ey, d), or on d alone, each term over |a - e|.
    let (mut e, mut d) = (start, 0.0f64);
    let mut huber = vec![1.0f64; flows.len()];
    let mut z = vec![0.0f64; flows.len()];
    let n = if fit_focus { 3 } else { 1 };
    for _ in 0..20 {
        let mut normal = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        for ((f, h), zi) in flows.iter().zip(&huber).zip(z.iter_mut()) {
            let (a, b) = (f.turned, f.found);
            let r = ((a.0 - e.0).powi(2) + (a.1 - e.1).powi(2)).max(1.0).sqrt();
            let value = a.0 * b.1 - a.1 * b.0 - a.0 * d + e.0 * (a.1 - b.1 + d) - e.1 * (a.0 - b.0);
            *zi = (value / r).abs();
            let grad = nalgebra::Vector3::new(-a.0 + e.0, a.1 - b.1 + d, -(a.0 - b.0));
            let g = if fit_focus {
                nalgebra::Vector3::new(grad[1], grad[2], grad[0])
            } else {
                nalgebra::Vector3::new(grad[0], 0.0, 0.0)
            };
            let w = h / (r * r);
            normal += w * g * g.transpose();
            rhs -= w * value * g;
        }
        let step = if fit_focus {
            normal.try_inverse().map(|inv| inv * rhs)?
        } else if normal[(0, 0)] > 0.0 {
            nalgebra::Vector3::new(rhs[0] / normal[(0, 0)], 0.0, 0.0)
        } else {
            return None;
        };
        if n == 3 {
            e = (e.0 + step[0], e.1 + step[1]);
            d += step[2];
        } else {
            d += step[0];
        }
        let mut sorted = z.clone();
        let mid = sorted.len() / 2;
        sorted.select_nth_unstable_by(mid, f64::total_cmp);
        let spread = (1.4826 * sorted[mid]).max(0.05);
        for (h, zi) in huber.iter_mut().zip(&z) {
            *h = (1.345 * spread / zi.max(1e-12)).min(1.0);
        }
    }
    (e.0.is_finite() && e.1.is_finite() && d.is_finite()).then_some((e, d))
}

/// The place near `(u, v)` in `after` where the corner `(x, y)` of `left` matches best (its
/// surroundings magnified `m` times, across and down, or `m` across and `m^2` down as the road
/// grows): over +-3 px both ways by a pixel, then +-0.75 px around the best by a quarter,
/// refined by a parabola each way; `None` at the search's edge or outside the image.
#[allow(clippy::too_many_arguments)]
fn refine(
    left: &PreparedImage,
    x: usize,
    y: usize,
    after: &PreparedImage,
    u: f64,
    v: f64,
    m: f32,
    inside: &impl Fn((f64, f64)) -> bool,
) -> Option<(f64, f64)> {
    let cost = |a: f64, b: f64| {
        let (a, b) = (a as f32, b as f32);
        scaled_ssd(left, x as i32, y as i32, after, a, b, m, m).min(scaled_ssd(
            left,
            x as i32,
            y as i32,
            after,
            a,
            b,
            m,
            m * m,
        ))
    };
    // The least of a (2 steps + 1)^2 grid around (u, v), and the grid.
    let grid = |u: f64, v: f64, steps: i32, step: f64| {
        let n = (2 * steps + 1) as usize;
        let mut g = vec![0.0f64; n * n];
        for j in 0..n {
            for i in 0..n {
                g[j * n + i] = cost(
                    u + f64::from(i as i32 - steps) * step,
                    v + f64::from(j as i32 - steps) * step,
                );
            }
        }
        let best = (0..g.len()).min_by(|&a, &b| g[a].total_cmp(&g[b]));
        (g, n, best)
    };
    if !inside((u - 4.0, v - 4.0)) || !inside((u + 4.0, v + 4.0)) {
        return None;
    }
    let (_, n, best) = grid(u, v, 3, 1.0);
    let best = best?;
    let (i, j) = (best % n, best / n);
    if i == 0 || j == 0 || i + 1 == n || j + 1 == n {
        return None;
    }
    let (u, v) = (u + (i as f64 - 3.0), v + (j as f64 - 3.0));
    let (g, n, best) = grid(u, v, 3, 0.25);
    let best = best?;
    let (i, j) = (best % n, best / n);
    if i == 0 || j == 0 || i + 1 == n || j + 1 == n {
        return None;
    }
    let at = |i: usize, j: usize| g[j * n + i];
    let di = parabola(at(i - 1, j), at(i, j), at(i + 1, j));
    let dj = parabola(at(i, j - 1), at(i, j), at(i, j + 1));
    Some((
        u + (i as f64 - 3.0 + di) * 0.25,
        v + (j as f64 - 3.0 + dj) * 0.25,
    ))
}

/// A place along a curve of inverse depths: the inverse depth and its pixel.
#[derive(Debug, Clone, Copy)]
struct Place {
    q: f64,
    u: f64,
    v: f64,
}

/// The places of `curve` from inverse depth `q_far` towards `q_near`, about [`SPACING`] pixels
/// apart, while `inside` the image (at most [`MAX_SAMPLES`]): into `out`.
fn walk(
    curve: impl Fn(f64) -> Option<(f64, f64)>,
    q_far: f64,
    q_near: f64,
    inside: &impl Fn((f64, f64)) -> bool,
    out: &mut Vec<Place>,
) {
    out.clear();
    let Some(first) = curve(q_far).filter(|&p| inside(p)) else {
        return;
    };
    out.push(Place {
        q: q_far,
        u: first.0,
        v: first.1,
    });
    let mut step = (q_near - q_far) / 256.0;
    let mut at = (q_far, first);
    while out.len() < MAX_SAMPLES && at.0 < q_near && step > 1e-12 {
        let q = (at.0 + step).min(q_near);
        let Some(p) = curve(q) else {
            return;
        };
        let apart = (p.0 - at.1.0).hypot(p.1 - at.1.1);
        if apart > 1.5 * SPACING {
            step *= 0.5;
            continue;
        }
        if !inside(p) {
            return;
        }
        out.push(Place { q, u: p.0, v: p.1 });
        at = (q, p);
        if apart < 0.5 * SPACING {
            step *= 1.5;
        }
    }
}

/// Pixels the stereo search reaches past the calibration's infinity: a right camera turned by
/// up to half a degree at 1000 px shows the farthest points that much beyond it.
const PAST_INFINITY: f64 = 9.0;

/// The curve of `places` continued [`PAST_INFINITY`] pixels past its first place (its far
/// end), straight on, while inside: a turned camera shows far points beyond where the
/// calibration puts infinity. The added places' inverse depths continue the first step's.
fn beyond_infinity(places: &mut Vec<Place>, inside: &impl Fn((f64, f64)) -> bool) {
    let (Some(&a), Some(&b)) = (places.first(), places.get(1)) else {
        return;
    };
    let (du, dv, dq) = (a.u - b.u, a.v - b.v, a.q - b.q);
    let step = du.hypot(dv);
    if step.is_nan() || step <= 0.0 {
        return;
    }
    let mut past = Vec::new();
    for k in 1..=(PAST_INFINITY / step).ceil() as usize {
        let t = k as f64;
        let p = Place {
            q: a.q + t * dq,
            u: a.u + t * du,
            v: a.v + t * dv,
        };
        if !inside((p.u, p.v)) {
            break;
        }
        past.push(p);
    }
    past.reverse();
    places.splice(0..0, past);
}

/// The pixels a curve's places span from the first to the last.
fn span(places: &[Place]) -> f64 {
    match (places.first(), places.last()) {
        (Some(a), Some(b)) => (b.u - a.u).hypot(b.v - a.v),
        _ => 0.0,
    }
}

/// The sub-sample offset of a parabola's vertex through three equally spaced costs, within
/// half a sample.
fn parabola(a: f64, b: f64, c: f64) -> f64 {
    let curvature = a - 2.0 * b + c;
    if curvature > 0.0 {
        (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// The best of a curve's matches, refined.
struct Best {
    /// Its inverse depth and pixel, refined by a parabola between the places.
    q: f64,
    u: f64,
    v: f64,
}

/// The least of `costs` (one a place), when it is inside the curve (not at an end) and unique
/// (at most [`UNIQUENESS`] of the least more than 1.5 px away along the curve), refined.
fn unique_best(costs: &[f64], places: &[Place]) -> Option<Best> {
    let k = (0..costs.len()).min_by(|&a, &b| costs[a].total_cmp(&costs[b]))?;
    if k == 0 || k + 1 >= costs.len() || costs.len() != places.len() {
        return None;
    }
    let at = places[k];
    let rival = costs
        .iter()
        .zip(places)
        .filter(|(_, p)| (p.u - at.u).hypot(p.v - at.v) > 1.5)
        .map(|(&c, _)| c)
        .fold(f64::MAX, f64::min);
    if costs[k] > UNIQUENESS * rival {
        return None;
    }
    let t = parabola(costs[k - 1], costs[k], costs[k + 1]);
    let toward = if t >= 0.0 {
        places[k + 1]
    } else {
        places[k - 1]
    };
    let share = t.abs();
    Some(Best {
        q: at.q + share * (toward.q - at.q),
        u: at.u + share * (toward.u - at.u),
        v: at.v + share * (toward.v - at.v),
    })
}

named_enum! {
    /// What the motion says about the right camera's yaw.
    pub enum ColumnVerdict {
        /// Too few samples, or too scattered: the vehicle did not move, or too little was seen.
        Unmeasured = 0 => "UNMEASURED",
        /// Within [`TOLERANCE_PX`] (or within three standard errors).
        Agrees = 1 => "AGREES",
        /// Beyond both.
        Disagrees = 2 => "DISAGREES",
    }
}

impl Serialize for ColumnVerdict {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// The right camera's columns against the motion, over the pairs measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ColumnReport {
    pub verdict: ColumnVerdict,
    /// Pairs of frames compared, those fitted (enough samples), and the samples they gave.
    pub pairs: u32,
    pub fitted: u32,
    pub samples: usize,
    /// The right image shows a point at its centre this many pixels further right than the
    /// calibration puts it (NaN when unmeasured): a disparity offset of minus this (a point
    /// `x` focal lengths beside the centre, `1 + x^2` times this).
    pub offset_px: f64,
    /// Its standard error, pixels: each pair is fitted on its own, and the offset is their
    /// median.
    pub offset_sigma_px: f64,
    /// The yaw to add to the right camera (degrees, the rig's `yaw_deg`) for the calibration to
    /// show what the images do: the offset's angle at the right camera's focal length.
    pub right_yaw_deg: f64,
    /// The share by which the motion's depths are longer than the pair's: a speed that reads
    /// high (or a baseline declared short) by that share (it shifts each sample by minus that
    /// share of its disparity).
    pub speed_share: f64,
}

/// Pairs [`ColumnCheck`] keeps (the newest).
pub const KEPT_PAIRS: usize = 300;

/// The flows of many pairs and what they say ([`ColumnReport`]).
#[derive(Debug, Clone, Default)]
pub struct ColumnCheck {
    pairs: std::collections::VecDeque<PairFlows>,
    measured: u32,
}

impl ColumnCheck {
    pub fn new() -> Self {
        Self::default()
    }

    /// [`pair_flows`] of one pair of frames, kept (the newest [`KEPT_PAIRS`]). Whether it
    /// measured anything.
    pub fn observe(
        &mut self,
        before: &StereoFrame,
        after: &PreparedImage,
        rig: &StereoRig,
        moved: &EgoTransform,
        travelled: f64,
    ) -> bool {
        let Some(pair) = pair_flows(before, after, rig, moved, travelled) else {
            return false;
        };
        self.pairs.push_back(pair);
        self.measured += 1;
        if self.pairs.len() > KEPT_PAIRS {
            self.pairs.pop_front();
        }
        true
    }

    /// What the pairs say about `rig`'s right camera.
    pub fn report(&self, rig: &StereoRig) -> ColumnReport {
        let mut report = ColumnReport {
            verdict: ColumnVerdict::Unmeasured,
            pairs: self.measured,
            fitted: 0,
            samples: 0,
            offset_px: f64::NAN,
            offset_sigma_px: f64::NAN,
            right_yaw_deg: f64::NAN,
            speed_share: f64::NAN,
        };
        // Each pair's own fit: the errors a pair's samples share (the focus and the pitch
        // measured on it, its motion) stay in that pair.
        let mut samples = Vec::new();
        let (mut turns, mut scales) = (Vec::new(), Vec::new());
        for pair in &self.pairs {
            samples.clear();
            pair_samples(pair, pair.focus, rig, &mut samples);
            report.samples += samples.len();
            if samples.len() < MIN_PAIR_SAMPLES {
                continue;
            }
            if let Some(fit) = robust_fit(&samples) {
                turns.push(fit.turn);
                scales.push(fit.scale);
            }
        }
        report.fitted = turns.len() as u32;
        if turns.len() < MIN_PAIRS {
            return report;
        }
        // The median of the pairs' (a pair whose frames the motion or the matches got wrong
        // is an outlier), its standard error from their spread (the MAD's, times 1.25 for a
        // median).
        let turn = median(&mut turns);
        let mut spread: Vec<f64> = turns.iter().map(|t| (t - turn).abs()).collect();
        let sigma = 1.2533 * 1.4826 * median(&mut spread) / (turns.len() as f64).sqrt();
        let focal_px = rig.right.intrinsics().fx;
        let (offset, sigma) = (turn * focal_px, sigma * focal_px);
        // Off when clearly beyond the tolerance; within it only when measured closely.
        report.verdict = if sigma.is_nan() {
            ColumnVerdict::Unmeasured
        } else if offset.abs() > TOLERANCE_PX && offset.abs() > 3.0 * sigma {
            ColumnVerdict::Disagrees
        } else if sigma > MAX_SIGMA_PX {
            ColumnVerdict::Unmeasured
        } else {
            ColumnVerdict::Agrees
        };
        report.offset_px = offset;
        report.offset_sigma_px = sigma;
        // The image shows points further right than the calibration: the right camera looks
        // further left than it says (the rig's yaw_deg turns it right).
        report.right_yaw_deg = -turn.to_degrees();
        report.speed_share = -median(&mut scales);
        report
    }
}

/// The median of `v` (reordered), NaN when empty.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, f64::total_cmp);
    v[mid]
}

/// `residual = turn * yaw_gain + scale * disparity`, weighted and robust.
struct Fit {
    /// Radians.
    turn: f64,
    scale: f64,
}

/// Iteratively reweighted least squares with Huber's weights (k = 1.345 robust standard
/// deviations of the weighted residuals, the MAD's).
fn robust_fit(samples: &[ColumnSample]) -> Option<Fit> {
    let n = samples.len();
    let mut huber = vec![1.0f64; n];
    let mut fit = None;
    let mut z = Vec::with_capacity(n);
    let mut sorted = Vec::with_capacity(n);
    for _ in 0..20 {
        let (mut gg, mut gd, mut dd, mut gr, mut dr) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (s, h) in samples.iter().zip(&huber) {
            let w = s.weight * h;
            gg += w * s.yaw_gain * s.yaw_gain;
            gd += w * s.yaw_gain * s.disparity;
            dd += w * s.disparity * s.disparity;
            gr += w * s.yaw_gain * s.residual;
            dr += w * s.disparity * s.residual;
        }
        let det = gg * dd - gd * gd;
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        let turn = (dd * gr - gd * dr) / det;
        let scale = (gg * dr - gd * gr) / det;
        z.clear();
        z.extend(samples.iter().map(|s| {
            ((s.residual - turn * s.yaw_gain - scale * s.disparity) * s.weight.sqrt()).abs()
        }));
        sorted.clear();
        sorted.extend_from_slice(&z);
        let mid = n / 2;
        sorted.select_nth_unstable_by(mid, f64::total_cmp);
        let spread = (1.4826 * sorted[mid]).max(1e-9);
        for (h, zi) in huber.iter_mut().zip(&z) {
            *h = (1.345 * spread / zi.max(1e-12)).min(1.0);
        }
        fit = Some(Fit { turn, scale });
    }
    fit
}

#[cfg(test)]
mod tests;
