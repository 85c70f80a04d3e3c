use std::path::{Path, PathBuf};

use nalgebra::Point3;

use super::*;

fn fixture(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(relative)
}

fn load_fixture(relative: &str) -> Calibration {
    let path = fixture(relative);
    load(&path).unwrap_or_else(|e| panic!("{relative} should load: {e}"))
}

/// Loads `tests/fixtures/calib/<file>`, which must fail with a message that names the file and
/// contains each of `expected` (include the field name there).
#[track_caller]
fn check_err(file: &str, expected: &[&str]) {
    let err = match load(&fixture("calib").join(file)) {
        Ok(_) => panic!("{file}: loaded, but it is broken"),
        Err(err) => err,
    };
    let message = err.to_string();
    let name = file.rsplit('/').next().unwrap_or(file);
    assert!(
        message.contains(name),
        "{file}: message does not name the file: {message}"
    );
    for part in expected {
        assert!(
            message.contains(part),
            "{file}: message lacks {part:?}: {message}"
        );
    }
}

/// Horizontal disparity u_left - u_right of the point `depth` metres ahead on the left camera's
/// optical axis, by projecting it through both cameras.
fn axis_disparity(rig: &StereoRig, depth: f64) -> f64 {
    let k = rig.left.intrinsics();
    let p = rig
        .left
        .vehicle_from_pixel_depth(k.cx, k.cy, depth)
        .expect("the principal point back-projects");
    let right = rig.right.pixel_from_vehicle(&p).expect("in front");
    k.cx - right.x
}

fn assert_close(actual: f64, expected: f64, tolerance: f64, what: &str) {
    assert!(
        (actual - expected).abs() <= tolerance,
        "{what}: {actual} is not within {tolerance} of {expected}"
    );
}

#[test]
fn middlebury_motorcycle_loads() {
    let calib = load_fixture("middlebury-motorcycle/calib.txt");
    let (left, right) = (&calib.rig.left, &calib.rig.right);
    assert_eq!((left.width(), left.height()), (741, 500));
    assert_eq!((right.width(), right.height()), (741, 500));
    assert_eq!(left.intrinsics().fx, 994.978);
    assert_eq!(left.intrinsics().fy, 994.978);
    assert_eq!(left.intrinsics().cx, 311.193);
    assert_eq!(right.intrinsics().cx, 342.279);
    assert!(left.distortion().is_zero() && right.distortion().is_zero());
    assert_eq!(left.centre(), Point3::origin());
    assert_close(calib.rig.baseline(), 0.193001, 1e-12, "baseline");
    assert_close(right.centre().x, 0.193001, 1e-12, "right camera x");
    assert!(!calib.has_road);

    // ndisp = 68: the range ends are where the disparity is 68 (near) and 0 (far).
    let (near, far) = calib.depth_range.expect("Middlebury implies a depth range");
    assert_close(near, 0.193001 * 994.978 / (68.0 + 31.086), 1e-9, "near");
    assert_close(far, 0.193001 * 994.978 / 31.086, 1e-9, "far");
    assert_close(
        axis_disparity(&calib.rig, near),
        68.0,
        1e-6,
        "near disparity",
    );
    assert_close(axis_disparity(&calib.rig, far), 0.0, 1e-6, "far disparity");
}

#[test]
fn middlebury_projection_gives_the_documented_disparity() {
    // d = u_left - u_right = baseline * f / Z - doffs, on the same row, anywhere in the image.
    let calib = load_fixture("middlebury-motorcycle/calib.txt");
    let (b, f, doffs) = (0.193001, 994.978, 31.086);
    for p in [
        Point3::new(0.0, 0.0, 2.0),
        Point3::new(-0.4, 0.3, 2.5),
        Point3::new(0.6, -0.5, 4.0),
        Point3::new(1.1, 0.2, 6.0),
    ] {
        let l = calib.rig.left.pixel_from_vehicle(&p).expect("in front");
        let r = calib.rig.right.pixel_from_vehicle(&p).expect("in front");
        assert!(calib.rig.left.contains(&l) && calib.rig.right.contains(&r));
        assert_close(l.x - r.x, b * f / p.z - doffs, 1e-9, "disparity");
        assert_close(l.y, r.y, 1e-9, "rectified rows");
    }
}

#[test]
fn middlebury_vmin_vmax_bound_the_depth_range() {
    // vmin = 23, vmax = 245, widened by 2 px on each side.
    let calib = load_fixture("calib/middlebury_vmin_vmax.txt");
    let (near, far) = calib.depth_range.expect("depth range");
    assert_close(axis_disparity(&calib.rig, near), 247.0, 1e-6, "near");
    assert_close(axis_disparity(&calib.rig, far), 21.0, 1e-6, "far");
    assert_eq!(calib.rig.left.intrinsics().fx, 3979.911);
}

#[test]
fn middlebury_far_end_stays_finite_without_doffs() {
    // doffs = 0 and no vmin: disparity 0 is infinitely far, so the range stops at 1 px.
    let text = "cam0=[500 0 100; 0 500 80; 0 0 1]\r\ncam1=[500 0 100; 0 500 80; 0 0 1]\r\n\
                doffs=0\r\nbaseline=100\r\nwidth=200\r\nheight=160\r\nndisp=50\r\n";
    let calib = parse_middlebury(text, Path::new("inline.txt")).expect("valid");
    let (near, far) = calib.depth_range.expect("depth range");
    assert_close(near, 0.1 * 500.0 / 50.0, 1e-12, "near");
    assert_close(far, 0.1 * 500.0, 1e-12, "far");
}

#[test]
fn broken_middlebury_files() {
    check_err("broken/mb_missing_baseline.txt", &["'baseline'", "missing"]);
    check_err(
        "broken/mb_cam0_8_numbers.txt",
        &["field 'cam0': expected 9 numbers, got 8"],
    );
    check_err("broken/mb_nan_doffs.txt", &["'doffs'", "finite", "nan"]);
    check_err(
        "broken/mb_negative_focal.txt",
        &["'cam1 (right camera)'", "fx must be positive"],
    );
    check_err("broken/mb_doffs_mismatch.txt", &["'doffs'", "31.08"]);
    check_err("broken/mb_not_rectified.txt", &["'cam1'", "rectified"]);
    check_err("broken/mb_width_not_whole.txt", &["'width'", "741.5"]);
    check_err("broken/mb_vmin_above_vmax.txt", &["'vmin'", "vmax"]);
    check_err(
        "broken/mb_line_without_equals.txt",
        &["'line 6'", "key=value"],
    );
    check_err("broken/mb_duplicate_key.txt", &["'baseline'", "twice"]);
}

#[test]
fn io_errors_name_the_file() {
    let err = load(&fixture("calib/does_not_exist.txt")).expect_err("no such file");
    assert!(err.to_string().contains("does_not_exist.txt"), "{err}");
    assert!(err.field().is_none());
}
