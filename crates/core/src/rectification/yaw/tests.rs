use super::*;
use crate::frame::PixelFormat;
use crate::geometry::{Camera, Distortion, Intrinsics, rotation_from_angles};

const W: u32 = 400;
const H: u32 = 240;
const F: f64 = 350.0;

/// A rectified rig 0.4 m wide, 1.4 m up, level; its right camera turned right by `yaw_deg`.
fn rig(yaw_deg: f64) -> StereoRig {
    let k = Intrinsics {
        fx: F,
        fy: F,
        cx: 0.5 * f64::from(W - 1),
        cy: 0.5 * f64::from(H - 1) - 30.0,
    };
    let camera = |x: f64, yaw: f64| {
        Camera::new(
            W,
            H,
            k,
            Distortion::default(),
            rotation_from_angles(0.0, yaw, 0.0),
            Point3::new(x, 1.4, 0.0),
        )
        .expect("camera")
    };
    StereoRig {
        left: camera(-0.2, 0.0),
        right: camera(0.2, yaw_deg),
    }
}

/// Value noise: a hash of the lattice cell, bilinear between the corners, two octaves.
fn texture(a: f64, b: f64, cell: f64) -> f64 {
    let lattice = |i: i64, j: i64| {
        let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        z ^= z >> 29;
        z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z ^= z >> 32;
        (z % 1000) as f64 / 1000.0
    };
    let octave = |cell: f64| {
        let (x, y) = (a / cell, b / cell);
        let (x0, y0) = (x.floor(), y.floor());
        let (s, t) = (x - x0, y - y0);
        let (i, j) = (x0 as i64, y0 as i64);
        (1.0 - s) * (1.0 - t) * lattice(i, j)
            + s * (1.0 - t) * lattice(i + 1, j)
            + (1.0 - s) * t * lattice(i, j + 1)
            + s * t * lattice(i + 1, j + 1)
    };
    0.65 * octave(cell) + 0.35 * octave(cell * 0.37)
}

/// What `camera` sees after the vehicle drove `driven` metres straight on: a textured road, a
/// wall 45 m ahead and two boxes' fronts (9 m to the left, 17 m to the right), each pixel the
/// mean of 2 x 2 rays.
fn view(camera: &Camera, driven: f64) -> PreparedImage {
    let mut pixels = Vec::with_capacity((W * H) as usize);
    for v in 0..H {
        for u in 0..W {
            let mut sum = 0.0;
            for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let (o, d) = camera
                    .ray_from_pixel(f64::from(u) + du, f64::from(v) + dv)
                    .expect("ray");
                let oz = o.z + driven;
                let mut best = (f64::INFINITY, 0.3);
                if d.y < 0.0 {
                    let t = -o.y / d.y;
                    let (x, z) = (o.x + t * d.x, oz + t * d.z);
                    best = (t, texture(x, z, 0.12));
                }
                for (z0, x0, x1, y1, cell) in [
                    (9.0, -4.0, -1.6, 2.0, 0.05),
                    (17.0, 1.8, 5.0, 2.5, 0.08),
                    (45.0, -60.0, 60.0, 12.0, 0.25),
                ] {
                    if d.z > 0.0 {
                        let t = (z0 - oz) / d.z;
                        let (x, y) = (o.x + t * d.x, o.y + t * d.y);
                        if t > 0.0 && t < best.0 && x >= x0 && x <= x1 && y >= 0.0 && y <= y1 {
                            best = (t, texture(x + 100.0, y, cell));
                        }
                    }
                }
                sum += best.1;
            }
            pixels.push((sum / 4.0 * 255.0).round().clamp(0.0, 255.0) as u8);
        }
    }
    PreparedImage::from_pixels(W, H, PixelFormat::Grey8, &pixels).expect("image")
}

/// The check over five pairs 1 m apart, the images seen through `truth`, judged on `declared`.
fn checked(truth: &StereoRig, declared: &StereoRig, step: f64) -> ColumnReport {
    let mut check = ColumnCheck::new();
    let moved = EgoTransform::new(step, 0.0);
    for i in 0..5 {
        let at = f64::from(i) * step;
        let before = StereoFrame::new(view(&truth.left, at), view(&truth.right, at), 1);
        let after = view(&truth.left, at + step);
        check.observe(&before, &after, declared, &moved, step);
    }
    check.report(declared)
}

#[test]
fn a_right_camera_as_calibrated_agrees_with_the_motion() {
    let r = checked(&rig(0.0), &rig(0.0), 1.0);
    assert_eq!(r.verdict, ColumnVerdict::Agrees, "{r:?}");
    assert!(r.offset_px.abs() < 0.15, "{r:?}");
    assert!(r.speed_share.abs() < 0.01, "{r:?}");
}

#[test]
fn a_right_camera_turned_is_measured_and_said_beyond_the_tolerance() {
    // At 350 px a tenth of a degree is 0.61 px, at the tolerance: measured all the same.
    let r = checked(&rig(0.1), &rig(0.0), 1.0);
    assert!((r.right_yaw_deg - 0.1).abs() < 0.02, "{r:?}");
    assert!((r.offset_px + 0.61).abs() < 0.12, "{r:?}");
    for yaw in [-0.15, 0.2] {
        let r = checked(&rig(yaw), &rig(0.0), 1.0);
        assert_eq!(r.verdict, ColumnVerdict::Disagrees, "{yaw}: {r:?}");
        assert!((r.right_yaw_deg - yaw).abs() < 0.03, "{yaw}: {r:?}");
        // And the calibration corrected by what it said agrees.
        let corrected = checked(&rig(yaw), &rig(r.right_yaw_deg), 1.0);
        assert_eq!(
            corrected.verdict,
            ColumnVerdict::Agrees,
            "{yaw}: {corrected:?}"
        );
    }
}

#[test]
fn a_vehicle_standing_still_measures_nothing() {
    let truth = rig(0.2);
    let frame = StereoFrame::new(view(&truth.left, 0.0), view(&truth.right, 0.0), 1);
    let mut check = ColumnCheck::new();
    let measured = check.observe(
        &frame,
        &frame.left,
        &rig(0.0),
        &EgoTransform::new(0.0, 0.0),
        0.0,
    );
    assert!(!measured);
    let r = check.report(&rig(0.0));
    assert_eq!(r.verdict, ColumnVerdict::Unmeasured, "{r:?}");
    assert!(r.offset_px.is_nan());
}

#[test]
fn a_speed_that_reads_high_is_a_scale_not_a_yaw() {
    // The motion says 1.03 m where the vehicle drove 1 m: every motion depth 3 % far.
    let truth = rig(0.0);
    let mut check = ColumnCheck::new();
    for i in 0..5 {
        let at = f64::from(i);
        let before = StereoFrame::new(view(&truth.left, at), view(&truth.right, at), 1);
        let after = view(&truth.left, at + 1.0);
        check.observe(&before, &after, &truth, &EgoTransform::new(1.03, 0.0), 1.03);
    }
    let r = check.report(&truth);
    assert_eq!(r.verdict, ColumnVerdict::Agrees, "{r:?}");
    assert!((r.speed_share - 0.03).abs() < 0.012, "{r:?}");
}
