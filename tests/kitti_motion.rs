//! Flies that travel, on real images: two consecutive KITTI odometry frames (sequence 00, the
//! car driving down a street; tests/fixtures/kitti/kitti_odom_00_color_2frames).
//!
//! The population converges on frame 0. The vehicle's motion between the frames is derived
//! from the scene alone: the forward travel and yaw that make the 250 fittest flies, moved as
//! `Engine::predict` moves them, fittest on frame 1 (a grid search). KITTI's own pose of
//! frame 1 (poses/00.txt, not shipped: 0.859 m forward, 0.047 m to the left, 0.12 degrees of
//! yaw) is the reference it must agree with. Then each predicted fly is re-evaluated along
//! its left camera ray on frame 1 (+-3 px of disparity, every 0.05 px): the predicted and the
//! fittest disparity should agree within 1 px (the target; measured here: 58 %, against
//! 76 % for the same flies on their own frame). The scene holds a motorbike that drives on,
//! which no ego-motion predicts.

use std::path::{Path, PathBuf};

use flyd_core::engine::{Engine, EngineParams};
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::geometry::StereoRig;
use flyd_core::kinematics::EgoTransform;
use nalgebra::Point3;

fn fixture(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/kitti/kitti_odom_00_color_2frames")
        .join(path)
}

fn frame(rig: &StereoRig, index: u32) -> StereoFrame {
    let load = |side: &str| {
        let img = image::open(fixture(&format!("{side}/{index:06}.png")))
            .expect("fixture image")
            .to_rgb8();
        PreparedImage::from_pixels(img.width(), img.height(), PixelFormat::Rgb8, img.as_raw())
            .expect("prepared")
    };
    let f = StereoFrame::new(load("left"), load("right"), u64::from(index));
    assert_eq!(f.left.width(), rig.left.width());
    f
}

/// Sum of fitness on `frame` of `points` moved by (`travelled`, `turned`).
fn fitness_after(
    e: &mut Engine,
    frame: &StereoFrame,
    points: &[[f32; 3]],
    travelled: f64,
    turned: f64,
) -> f64 {
    let t = EgoTransform::new(travelled, turned);
    let moved: Vec<[f32; 3]> = points
        .iter()
        .map(|p| {
            let (x, z) = t.apply(p[0], p[2]);
            [x, p[1], z]
        })
        .collect();
    let mut out = vec![0.0; moved.len()];
    e.evaluate_points(frame, &moved, &mut out)
        .expect("evaluates");
    out.iter().map(|&f| f64::from(f)).sum()
}

#[test]
fn flies_predicted_with_the_scenes_motion_land_within_a_pixel_on_the_next_frame() {
    let cal = flyd_core::calib::load(&fixture("calib.txt")).expect("calibration");
    let rig = cal.rig.clone();
    let mut params = EngineParams {
        flies: 5000,
        seed: 1,
        ..EngineParams::default()
    };
    cal.apply_to(&mut params);
    let (f0, f1) = (frame(&rig, 0), frame(&rig, 1));
    let mut e = Engine::new(&rig, params).expect("engine");
    for _ in 0..60 {
        e.step(&f0).expect("step");
    }
    let p = e.population();
    let best: Vec<[f32; 3]> = p
        .best(250)
        .iter()
        .map(|&i| [p.x[i], p.y[i], p.z[i]])
        .collect();
    // Frame 1 becomes the engine's frame (one generation) before points are evaluated on it.
    let mut probe = Engine::new(&rig, e.params().clone()).expect("engine");
    probe.step(&f1).expect("step");

    // The motion from the scene: forward 0..1.6 m every 2 cm, yaw +-0.01 rad every 0.001.
    let mut found = (0.0, 0.0, f64::MIN);
    for k in 0..=80 {
        for j in -10..=10 {
            let (d, yaw) = (0.02 * f64::from(k), 0.001 * f64::from(j));
            let f = fitness_after(&mut probe, &f1, &best, d, yaw);
            if f > found.2 {
                found = (d, yaw, f);
            }
        }
    }
    let (d, yaw, _) = found;
    let still = fitness_after(&mut probe, &f1, &best, 0.0, 0.0);
    println!(
        "motion from the scene: {d:.2} m forward, {:.3} deg of yaw (KITTI pose: 0.859 m, 0.118 \
         deg); fitness of the 250 flies on frame 1 {:.3e} predicted, {still:.3e} not",
        yaw.to_degrees(),
        found.2
    );
    // Measured: 0.76 m, 0.17 degrees; the predicted flies 1.6x as fit on frame 1 as unmoved.
    assert!(
        (d - 0.859).abs() <= 0.15,
        "forward travel {d} m, KITTI says 0.859 m"
    );
    assert!(
        found.2 > 1.4 * still,
        "prediction hardly helps: {} vs {still}",
        found.2
    );
    assert!(yaw.abs() <= 0.005, "yaw {yaw} rad");

    let errors_scene = refit(&mut probe, &rig, &f1, &best, d, yaw, 0.0);
    // KITTI's pose: 0.859 m forward, 0.047 m left, 0.118 degrees of yaw.
    let errors_pose = refit(&mut probe, &rig, &f1, &best, 0.859, 0.00207, -0.047);
    // The control: the same flies re-evaluated on their own frame 0 (how well they had
    // converged).
    let mut own = Engine::new(&rig, e.params().clone()).expect("engine");
    own.step(&f0).expect("step");
    let errors_own = refit(&mut own, &rig, &f0, &best, 0.0, 0.0, 0.0);
    let mut errors = errors_scene;
    errors.sort_by(f64::total_cmp);
    let share_of =
        |e: &[f64]| e.iter().filter(|&&x| x <= 1.0).count() as f64 / e.len().max(1) as f64;
    let (within, counted, share) = (
        errors.iter().filter(|&&x| x <= 1.0).count(),
        errors.len(),
        share_of(&errors),
    );
    println!(
        "within 1 px: scene's motion {:.0} %, KITTI pose {:.0} % ({} flies), the flies on \
         their own frame 0 {:.0} % ({} flies)",
        100.0 * share,
        100.0 * share_of(&errors_pose),
        errors_pose.len(),
        100.0 * share_of(&errors_own),
        errors_own.len()
    );
    println!(
        "{within} of {counted} predicted flies within 1 px of disparity of their best match on \
         frame 1 ({:.0} %), median error {:.2} px",
        100.0 * share,
        errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN)
    );
    // Measured: 58 % (scene's motion), 54 % (KITTI's pose), against 76 % for the same flies on
    // their own frame: the "within 1 px" for the static scene is not met (the flies'
    // own convergence on frame 0 is the first limit). A guard against losing what there is.
    assert!(counted >= 150, "{counted} flies re-evaluated");
    assert!(share >= 0.5, "{:.0} % within 1 px", 100.0 * share);
}

/// For each point of `best` moved by (`travelled`, `turned`, then `lateral` metres to the
/// right), the disparity error of its prediction: how far along its left ray (+-3 px every
/// 0.05 px) it is fittest on `frame`. Points with no fitness anywhere are left out.
fn refit(
    e: &mut Engine,
    rig: &StereoRig,
    frame: &StereoFrame,
    best: &[[f32; 3]],
    travelled: f64,
    turned: f64,
    lateral: f64,
) -> Vec<f64> {
    let fb = rig.right.intrinsics().fx * rig.baseline();
    let centre = rig.left.centre();
    let t = EgoTransform::new(travelled, turned);
    let shifts: Vec<f64> = (-60..=60).map(|k| 0.05 * f64::from(k)).collect();
    let mut errors = Vec::new();
    for p in best {
        let (x, z) = t.apply(p[0], p[2]);
        let q = Point3::new(f64::from(x) - lateral, f64::from(p[1]), f64::from(z));
        let depth = rig.left.camera_from_vehicle(&q).z;
        if depth <= 1.0 {
            continue;
        }
        let disparity = fb / depth;
        let points: Vec<[f32; 3]> = shifts
            .iter()
            .map(|s| {
                let r = centre + (q - centre) * (disparity / (disparity + s));
                [r.x as f32, r.y as f32, r.z as f32]
            })
            .collect();
        let mut fit = vec![0.0; points.len()];
        e.evaluate_points(frame, &points, &mut fit)
            .expect("evaluates");
        let (k, &f) = fit
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("points");
        if f > 0.0 {
            errors.push(shifts[k].abs());
        }
    }
    errors
}
