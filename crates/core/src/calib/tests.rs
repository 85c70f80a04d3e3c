use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Point3};

use super::*;
use crate::chain::chain;
use crate::geometry::{Distortion, Intrinsics};
use crate::test_support::damage_each;

fn fixture(relative: &str) -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("tests/fixtures")
        .join(relative)
}

fn load_fixture(relative: &str) -> Calibration {
    let path = fixture(relative);
    load(&path).unwrap_or_else(|e| panic!("{relative} should load: {e}"))
}

/// Loads fixture `relative`, whose two cameras must be `size` pixels.
#[track_caller]
fn load_sized(relative: &str, size: (u32, u32)) -> Calibration {
    let calib = load_fixture(relative);
    for cam in [&calib.rig.left, &calib.rig.right] {
        assert_eq!((cam.width(), cam.height()), size, "{relative}");
    }
    calib
}

/// Loads `tests/fixtures/calib/<file>`, which must fail with a message that names the file and
/// contains each of `expected` (include the field name there).
#[track_caller]
fn check_err(file: &str, expected: &[&str]) {
    let err = match load(&fixture("calib").join(file)) {
        Ok(_) => panic!("{file}: loaded, but it is broken"),
        Err(err) => err,
    };
    let message = crate::chain::chain(&err);
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
    let calib = load_sized("middlebury-motorcycle/calib.txt", (741, 500));
    let (left, right) = (&calib.rig.left, &calib.rig.right);
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

/// A minimal OpenCV stereo file: 640x480 cameras, no distortion, the given R and T and extra keys.
fn opencv_text(header_keys: &str, r: &Matrix3<f64>, t: [f64; 3]) -> String {
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:e}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let r_rows: Vec<f64> = (0..3)
        .flat_map(|i| (0..3).map(move |j| r[(i, j)]))
        .collect();
    format!(
        "%YAML:1.0\n---\n{header_keys}\
         K1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n\
         D1: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   data: [ 0., 0., 0., 0. ]\n\
         K2: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 510., 0., 330., 0., 505., 235., 0., 0., 1. ]\n\
         D2: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ -0.1, 0.01, 0., 0., 0. ]\n\
         R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {} ]\n\
         T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ {} ]\n",
        list(&r_rows),
        list(&t)
    )
}

#[test]
fn opencv_stereo_loads_with_default_placement() {
    let calib = load_sized("calib/opencv_stereo.yml", (1280, 720));
    let (left, right) = (&calib.rig.left, &calib.rig.right);
    assert_close(left.intrinsics().fx, 1_052.823_145_791_044, 1e-9, "K1 fx");
    assert_close(left.intrinsics().cy, 359.871_622_809_353_8, 1e-9, "K1 cy");
    assert_close(right.intrinsics().cx, 636.4891207735019, 1e-9, "K2 cx");
    assert_close(left.distortion().k1, -0.17451208235371, 1e-12, "D1 k1");
    assert_close(left.distortion().k3, 0.0090471139002081, 1e-12, "D1 k3");
    assert_close(right.distortion().p2, 0.00051183317761934, 1e-12, "D2 p2");
    // Default import: metres, left camera 1.2 m above the road, level, straight ahead.
    assert_eq!(left.centre(), Point3::new(0.0, 1.2, 0.0));
    assert_eq!(left.rotation().matrix(), &Matrix3::identity());
    let t_norm = (0.11984315f64.powi(2) + 0.0004127f64.powi(2) + 0.00119812f64.powi(2)).sqrt();
    assert_close(calib.rig.baseline(), t_norm, 1e-12, "baseline = |T|");
    // T's x is negative: the right camera is to the right of the left one.
    assert!(right.centre().x > 0.119);
    assert!(calib.has_road);
    assert_eq!(calib.depth_range, None);
}

#[test]
fn opencv_pose_follows_the_stereo_calibrate_convention() {
    // Whatever the mounting, p_right_cam = R * p_left_cam + T must hold for every point.
    let r = *nalgebra::Rotation3::from_euler_angles(0.01, -0.035, 0.02).matrix();
    let t = [-0.12, 0.004, 0.01];
    let text = opencv_text("image_width: 640\nimage_height: 480\n", &r, t);
    let opts = OpenCvImport {
        left_position: Point3::new(-0.3, 1.4, 1.0),
        pitch_deg: 5.0,
        yaw_deg: -3.0,
        roll_deg: 1.0,
        ..OpenCvImport::default()
    };
    let calib = parse_opencv_yaml(&text, Path::new("inline.yml"), &opts).expect("valid");
    let (left, right) = (&calib.rig.left, &calib.rig.right);
    assert_eq!(left.centre(), opts.left_position);
    assert_eq!(right.intrinsics().fy, 505.0);
    assert_eq!(right.distortion().k1, -0.1);
    for p_left in [
        Point3::new(0.0, 0.0, 10.0),
        Point3::new(1.5, -0.7, 4.0),
        Point3::new(-2.0, 0.4, 25.0),
    ] {
        let p_vehicle = left.vehicle_from_camera(&p_left);
        let expected = r * p_left.coords + nalgebra::Vector3::from(t);
        let actual = right.camera_from_vehicle(&p_vehicle);
        assert!(
            (actual.coords - expected).norm() < 1e-12,
            "{actual} vs {expected}"
        );
    }
}

#[test]
fn opencv_rational_model_with_zero_terms_in_millimetres() {
    // Old OpenCV 2 header (no '---'), 8 coefficients with k4..k6 = 0, T in mm, no image size.
    let path = fixture("calib/opencv_rational_mm.yml");
    let text = std::fs::read_to_string(&path).expect("fixture");
    let opts = OpenCvImport {
        translation_unit: Unit::Millimetre,
        image_size: Some((640, 480)),
        ..OpenCvImport::default()
    };
    let calib = parse_opencv_yaml(&text, &path, &opts).expect("valid");
    let t_mm = (62.8411902f64.powi(2) + 0.2204137f64.powi(2) + 0.8312054f64.powi(2)).sqrt();
    assert_close(calib.rig.baseline(), t_mm / 1000.0, 1e-12, "baseline");
    assert_close(
        calib.rig.left.distortion().k3,
        -0.0310487322,
        1e-12,
        "D1 k3",
    );
    assert_eq!(calib.rig.right.width(), 640);
    // Without the options, the size is missing; with metres, T is 63 m.
    let err = parse_opencv_yaml(&text, &path, &OpenCvImport::default()).expect_err("no size");
    assert!(err.to_string().contains("'image_width'"), "{err}");
    let metres = OpenCvImport {
        image_size: Some((640, 480)),
        ..OpenCvImport::default()
    };
    let err = parse_opencv_yaml(&text, &path, &metres).expect_err("mm as m");
    assert!(crate::chain::chain(&err).contains("millimetres"), "{err}");
}

#[test]
fn opencv_image_size_spellings() {
    let r = Matrix3::identity();
    let t = [-0.1, 0.0, 0.0];
    let size_of = |keys: &str, given: Option<(u32, u32)>| {
        let opts = OpenCvImport {
            image_size: given,
            ..OpenCvImport::default()
        };
        parse_opencv_yaml(&opencv_text(keys, &r, t), Path::new("size.yml"), &opts)
            .map(|c| (c.rig.left.width(), c.rig.right.height()))
            .map_err(|e| crate::chain::chain(&e))
    };
    assert_eq!(size_of("imageSize: [ 640, 480 ]\n", None), Ok((640, 480)));
    assert_eq!(size_of("image_size: [ 800, 600 ]\n", None), Ok((800, 600)));
    let matrix =
        "imageSize: !!opencv-matrix\n   rows: 1\n   cols: 2\n   dt: d\n   data: [ 1024., 768. ]\n";
    assert_eq!(size_of(matrix, None), Ok((1024, 768)));
    assert_eq!(size_of("", Some((640, 480))), Ok((640, 480)));
    assert_eq!(
        size_of("imageSize: [ 640, 480 ]\n", Some((640, 480))),
        Ok((640, 480))
    );
    let mismatch = size_of("imageSize: [ 640, 480 ]\n", Some((1280, 960))).expect_err("differ");
    assert!(
        mismatch.contains("'imageSize'") && mismatch.contains("1280x960"),
        "{mismatch}"
    );
    let half = size_of("image_width: 640\n", None).expect_err("no height");
    assert!(half.contains("'image_height'"), "{half}");
    let fraction = size_of("imageSize: [ 640.5, 480 ]\n", None).expect_err("fraction");
    assert!(fraction.contains("'imageSize'"), "{fraction}");
}

#[test]
fn broken_opencv_files() {
    check_err("broken/yml_missing_T.yml", &["field 'T': missing"]);
    check_err(
        "broken/yml_K1_8_numbers.yml",
        &["field 'K1': expected 9 numbers (3x3 matrix), got 8"],
    );
    check_err("broken/yml_D1_7_coefficients.yml", &["'D1'", "1x7"]);
    check_err("broken/yml_nan_K2.yml", &["'K2'", ".nan", "finite"]);
    check_err(
        "broken/yml_negative_focal.yml",
        &["'K1 (left camera)'", "fx must be positive"],
    );
    check_err("broken/yml_rational_nonzero.yml", &["'D2'", "k4 = 0.0021"]);
    check_err(
        "broken/yml_baseline_mm.yml",
        &["'T'", "millimetres", "translation_unit = \"mm\""],
    );
    check_err("broken/yml_not_a_rotation.yml", &["'R'", "rotation"]);
    check_err(
        "broken/yml_no_image_size.yml",
        &["'image_width'", "image size"],
    );
    check_err(
        "broken/yml_non_overlapping.yml",
        &["'R, T'", "degrees away from the vehicle's forward axis"],
    );
    check_err("broken/yml_syntax_error.yml", &["'D2'", "invalid YAML"]);
}

#[test]
fn rig_toml_with_explicit_cameras_loads() {
    // The right section gives no size: it takes the left one's.
    let calib = load_sized("calib/rig_explicit.toml", (640, 480));
    let (left, right) = (&calib.rig.left, &calib.rig.right);
    assert_eq!(
        *left.intrinsics(),
        Intrinsics {
            fx: 520.0,
            fy: 521.5,
            cx: 319.5,
            cy: 239.5
        }
    );
    assert_eq!(right.intrinsics().cx, 322.1);
    assert_eq!(
        *left.distortion(),
        Distortion {
            k1: -0.05,
            k2: 0.01,
            p1: 0.0005,
            p2: -0.0002,
            k3: 0.0
        }
    );
    assert_eq!(right.distortion().k2, 0.009);
    assert_eq!(left.centre(), Point3::new(-0.15, 1.3, 0.0));
    assert_eq!(right.centre(), Point3::new(0.15, 1.3, 0.0));
    // The right camera's explicit matrix and the left camera's angles describe the same pitch.
    let pitched = crate::geometry::rotation_from_angles(5.0, 0.0, 0.0);
    assert!((left.rotation().matrix() - pitched).abs().max() < 1e-12);
    assert!((right.rotation().matrix() - pitched).abs().max() < 1e-12);
    assert_close(calib.rig.baseline(), 0.3, 1e-12, "baseline");
    assert_eq!(calib.depth_range, Some((1.0, 25.0)));
    assert!(calib.has_road);
}

#[test]
fn rig_toml_imports_and_mounts_an_opencv_file() {
    let calib = load_fixture("calib/rig_opencv.toml");
    let yaml = fixture("calib/opencv_stereo.yml");
    let text = std::fs::read_to_string(&yaml).expect("fixture");
    let opts = OpenCvImport {
        left_position: Point3::new(-0.06, 1.25, 1.8),
        pitch_deg: 3.0,
        ..OpenCvImport::default()
    };
    let direct = parse_opencv_yaml(&text, &yaml, &opts).expect("valid");
    assert_eq!(calib.rig, direct.rig);
    assert_eq!(calib.rig.left.centre(), Point3::new(-0.06, 1.25, 1.8));
    assert_eq!(calib.depth_range, Some((2.0, 40.0)));
    assert!(calib.has_road);

    let mm = load_fixture("calib/rig_opencv_mm.toml");
    let t_mm = (62.8411902f64.powi(2) + 0.2204137f64.powi(2) + 0.8312054f64.powi(2)).sqrt();
    assert_close(mm.rig.baseline(), t_mm / 1000.0, 1e-12, "baseline");
    assert_eq!((mm.rig.left.width(), mm.rig.left.height()), (640, 480));
    assert_eq!(mm.rig.left.centre(), Point3::new(0.0, 1.2, 0.0));
    assert_eq!(mm.depth_range, None);
    assert!(!mm.has_road);
}

#[test]
fn broken_rig_files() {
    check_err(
        "broken/toml_unknown_key.toml",
        &["'left.focal'", "unknown field"],
    );
    check_err(
        "broken/toml_wrong_type.toml",
        &["'left.fx'", "invalid type"],
    );
    check_err("broken/toml_missing_field.toml", &["'right.cy'", "missing"]);
    check_err(
        "broken/toml_negative_focal.toml",
        &["'right.fy'", "must be positive"],
    );
    check_err(
        "broken/toml_nan_position.toml",
        &["'left.position'", "finite"],
    );
    check_err(
        "broken/toml_depth_order.toml",
        &["'search.min_depth'", "max_depth"],
    );
    check_err(
        "broken/toml_rotation_and_angles.toml",
        &["'left.rotation'", "not both"],
    );
    check_err("broken/toml_negative_width.toml", &["'left.width'", "-640"]);
    check_err(
        "broken/toml_baseline_too_long.toml",
        &["'right.position'", "baseline"],
    );
    check_err(
        "broken/toml_distortion_count.toml",
        &["'right.distortion'", "got 3"],
    );
    check_err(
        "broken/toml_road_not_bool.toml",
        &["'search.road'", "boolean"],
    );
    check_err(
        "broken/toml_syntax_error.toml",
        &["'line 4'", "unclosed table"],
    );
    check_err(
        "broken/toml_non_overlapping.toml",
        &["'right'", "degrees away from the vehicle's forward axis"],
    );
    check_err("broken/toml_both_sources.toml", &["'opencv'", "not both"]);
    check_err("broken/toml_mount_without_opencv.toml", &["'mount'"]);
    check_err(
        "broken/toml_unit_mm_as_m.toml",
        &[
            "'opencv.file'",
            "opencv_rational_mm.yml",
            "'T'",
            "millimetres",
        ],
    );
    check_err(
        "broken/toml_bad_unit.toml",
        &["'opencv.translation_unit'", "km"],
    );
    check_err(
        "broken/toml_missing_yaml.toml",
        &["'opencv.file'", "no_such_calibration.yml"],
    );
    check_err(
        "broken/toml_size_mismatch.toml",
        &[
            "'opencv.file'",
            "opencv_stereo.yml",
            "'image_width'",
            "640x360",
        ],
    );
    check_err(
        "broken/toml_mount_nan.toml",
        &["'mount.pitch_deg'", "finite"],
    );
    check_err(
        "broken/toml_search_half.toml",
        &["'search.max_depth'", "missing"],
    );
    check_err("broken/unknown_format.txt", &["unrecognised format"]);
}

#[test]
fn toml_errors_inside_multi_line_arrays_name_the_key() {
    let text = "[left]\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
                position = [0.0, 1.2, 0.0]\nrotation = [\n  [1.0, 0.0, 0.0],\n  [0.0, 1.0, 0.0],\n  \
                [0.0, \"x\", 1.0],\n]\n";
    let err = parse_rig_toml(text, Path::new("inline.toml")).expect_err("bad element");
    assert_eq!(err.field(), Some("left.rotation"), "{err}");
}

/// Cutting a good file anywhere must give an error or a valid rig, never a panic.
#[test]
fn truncated_files_never_panic() {
    for relative in [
        "middlebury-motorcycle/calib.txt",
        "calib/middlebury_vmin_vmax.txt",
        "calib/opencv_stereo.yml",
        "calib/opencv_rational_mm.yml",
        "calib/rig_explicit.toml",
        "calib/rig_opencv.toml",
    ] {
        let path = fixture(relative);
        let text = std::fs::read_to_string(&path).expect("fixture");
        let opts = OpenCvImport {
            translation_unit: Unit::Millimetre,
            image_size: Some((640, 480)),
            ..OpenCvImport::default()
        };
        for end in (0..text.len())
            .step_by(5)
            .filter(|&i| text.is_char_boundary(i))
        {
            let cut = &text[..end];
            let results = [
                parse_middlebury(cut, &path),
                parse_opencv_yaml(cut, &path, &opts),
                parse_rig_toml(cut, &path),
            ];
            // Errors are fine; whatever loads went through the same checks as a whole file.
            for calib in results.into_iter().flatten() {
                assert!(calib.rig.baseline().is_finite(), "{relative}[..{end}]");
            }
        }
    }
}

#[test]
fn rig_toml_right_camera_may_state_its_own_size() {
    // A right camera of another resolution is fine as long as the file says so: flies are
    // projected into each image independently.
    let text = "[left]\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
                position = [-0.1, 1.2, 0.0]\n\
                [right]\nwidth = 1280\nheight = 960\nfx = 1000.0\nfy = 1000.0\ncx = 640.0\n\
                cy = 480.0\nposition = [0.1, 1.2, 0.0]\n";
    let calib = parse_rig_toml(text, Path::new("inline.toml")).expect("valid");
    assert_eq!(
        (calib.rig.left.width(), calib.rig.right.width()),
        (640, 1280)
    );
    assert_eq!(calib.depth_range, None);
    assert!(calib.has_road);
}

#[test]
fn rig_toml_rectification_gives_the_right_images_row_correction() {
    let rig = "[left]\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nwidth = 640\nheight = 480\n\
               position = [-0.1, 1.2, 0.0]\n\
               [right]\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
               position = [0.1, 1.2, 0.0]\n";
    let parse = |extra: &str| parse_rig_toml(&format!("{rig}{extra}"), Path::new("inline.toml"));
    assert_eq!(parse("").expect("valid").right_row_offset_px, 0.0);
    let c = parse("[rectification]\nright_row_offset_px = -0.37\n").expect("valid");
    assert_eq!(c.right_row_offset_px, -0.37);
    for bad in ["2.5", "-3.0", "nan", "inf"] {
        let e = parse(&format!("[rectification]\nright_row_offset_px = {bad}\n"))
            .expect_err(bad)
            .to_string();
        assert!(
            e.contains("rectification.right_row_offset_px"),
            "{bad}: {e}"
        );
    }
    let e = parse("[rectification]\nrow = 1\n").expect_err("unknown key");
    assert!(e.to_string().contains("inline.toml"), "{e}");
}

/// Whatever a damaged file parses into is usable: every camera parameter finite, a depth range
/// (if any) finite and ordered, and a point ahead projecting to a finite pixel or to none.
fn check_usable(cal: &Calibration, what: &str) {
    for cam in [&cal.rig.left, &cal.rig.right] {
        let (k, d, c) = (cam.intrinsics(), cam.distortion(), cam.centre());
        let values = [
            k.fx, k.fy, k.cx, k.cy, d.k1, d.k2, d.p1, d.p2, d.k3, c.x, c.y, c.z,
        ];
        assert!(
            values.iter().all(|v| v.is_finite()),
            "{what}: non-finite camera parameter {values:?}"
        );
        assert!(
            cam.rotation().matrix().iter().all(|v| v.is_finite()),
            "{what}: rotation"
        );
        assert!(cam.width() > 0 && cam.height() > 0, "{what}: empty image");
        let ahead = cal
            .rig
            .left
            .vehicle_from_camera(&Point3::new(0.1, 0.1, 5.0));
        if let Some(px) = cam.pixel_from_vehicle(&ahead) {
            assert!(px.x.is_finite() && px.y.is_finite(), "{what}: NaN pixel");
        }
    }
    if let Some((near, far)) = cal.depth_range {
        assert!(
            near.is_finite() && far.is_finite() && 0.0 < near && near < far,
            "{what}: depth range {near}..{far}"
        );
    }
}

#[test]
fn damaged_calibration_files_are_errors_or_usable_never_a_panic() {
    let middlebury = std::fs::read_to_string(fixture("middlebury-motorcycle/calib.txt"))
        .expect("Middlebury fixture");
    let yaml = std::fs::read_to_string(fixture("calib/opencv_stereo.yml")).expect("YAML fixture");
    let toml = std::fs::read_to_string(fixture("calib/rig_explicit.toml")).expect("rig fixture");
    let origin = Path::new("damaged");
    let (mut loaded, mut refused) = (0, 0);
    let usable = |cal: &Calibration, label: &str| check_usable(cal, label);
    for (name, counts) in [
        (
            "calib.txt",
            damage_each(
                &middlebury,
                0..2_000,
                "damaged",
                |t| parse_middlebury(t, origin),
                usable,
            ),
        ),
        (
            "opencv_stereo.yml",
            damage_each(
                &yaml,
                0..2_000,
                "damaged",
                |t| parse_opencv_yaml(t, origin, &OpenCvImport::default()),
                usable,
            ),
        ),
        (
            "rig_explicit.toml",
            damage_each(
                &toml,
                0..2_000,
                "damaged",
                |t| parse_rig_toml(t, origin),
                usable,
            ),
        ),
    ] {
        println!("{name}: {} usable, {} refused", counts.0, counts.1);
        loaded += counts.0;
        refused += counts.1;
    }
    // Both outcomes occur: damage that leaves a valid file (a comment, a digit of a value) and
    // damage that breaks it.
    println!("damaged calibrations: {loaded} loaded and usable, {refused} refused");
    assert!(
        loaded > 200 && refused > 2000,
        "{loaded} loaded, {refused} refused"
    );
}

/// KITTI's raw `calib_cam_to_cam.txt` layout (2011-09-26 values for cameras 0, 2 and 3; the
/// unrectified parts rounded).
const KITTI_CAM_TO_CAM: &str = "\
calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
S_rect_00: 1.242000e+03 3.750000e+02
P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_02: 1.392000e+03 5.120000e+02
K_02: 9.597910e+02 0.000000e+00 6.960217e+02 0.000000e+00 9.569251e+02 2.241806e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_02: -3.691481e-01 1.968681e-01 1.353473e-03 5.677587e-04 -6.770705e-02
R_02: 9.999758e-01 -5.267463e-03 -4.552439e-03 5.251945e-03 9.999804e-01 -3.413835e-03 4.570332e-03 3.389843e-03 9.999838e-01
T_02: 5.956621e-02 2.900141e-04 2.577209e-03
S_rect_02: 1.242000e+03 3.750000e+02
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
S_03: 1.392000e+03 5.120000e+02
K_03: 9.037596e+02 0.000000e+00 6.957519e+02 0.000000e+00 9.019653e+02 2.242509e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_03: -3.639558e-01 1.788651e-01 6.029694e-04 -3.922424e-04 -5.382460e-02
R_03: 9.995599e-01 1.699522e-02 -2.431313e-02 -1.704422e-02 9.998531e-01 -1.809756e-03 2.427880e-02 2.223358e-03 9.997028e-01
T_03: -4.731050e-01 5.551470e-03 -5.250882e-03
S_rect_03: 1.242000e+03 3.750000e+02
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
";

#[test]
fn kitti_cam_to_cam_rectified_pair_at_kittis_mount() {
    let cal = parse_kitti(
        KITTI_CAM_TO_CAM,
        Path::new("c2c.txt"),
        &KittiImport::default(),
    )
    .expect("valid");
    let (left, right) = (&cal.rig.left, &cal.rig.right);
    assert_eq!((left.width(), left.height()), (1242, 375));
    assert_eq!(left.intrinsics().fx, 721.5377);
    assert!(left.distortion().is_zero());
    // P = K [I | t], t = K^-1 P[:, 3]: camera 2 is 6 cm left of camera 0, camera 3 47 cm right.
    let tx = |p03: f64, tz: f64| (p03 - 609.5593 * tz) / 721.5377;
    assert_close(left.centre().x, -tx(44.85728, 2.745884e-3), 1e-12, "left x");
    assert_close(
        right.centre().x,
        -tx(-339.5242, 2.729905e-3),
        1e-12,
        "right x",
    );
    assert_close(left.centre().y, KITTI_CAMERA_HEIGHT, 1e-3, "left height");
    assert_close(cal.rig.baseline(), 0.5327, 1e-3, "baseline");
    assert!(cal.has_road);
    // A road point 10 m ahead projects below the principal point, as a level rig 1.65 m up sees.
    let px = left
        .pixel_from_vehicle(&Point3::new(0.0, 0.0, 10.0))
        .expect("visible");
    assert_close(px.y, 172.854 + 721.5377 * 1.65 / 10.0, 0.5, "road row");
}

#[test]
fn kitti_unrectified_cameras_keep_their_distortion_and_rotation() {
    let opts = KittiImport {
        rectified: false,
        ..KittiImport::default()
    };
    let cal = parse_kitti(KITTI_CAM_TO_CAM, Path::new("c2c.txt"), &opts).expect("valid");
    let (left, right) = (&cal.rig.left, &cal.rig.right);
    assert_eq!((left.width(), left.height()), (1392, 512));
    assert_eq!(left.distortion().k1, -3.691481e-01);
    assert_eq!(right.intrinsics().fx, 9.037596e+02);
    assert_close(cal.rig.baseline(), 0.5327, 2e-3, "baseline from T_02, T_03");
    assert!(right.rotation().angle() > 0.01, "R_03 is not the identity");
}

#[test]
fn kitti_odometry_file_needs_and_takes_the_image_size() {
    let text = "P0: 7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0\n\
                P1: 7.188560e+02 0 6.071928e+02 -3.861448e+02 0 7.188560e+02 1.852157e+02 0 0 0 1 0\n\
                P2: 7.188560e+02 0 6.071928e+02 4.538225e+01 0 7.188560e+02 1.852157e+02 -1.130887e-01 0 0 1 3.779761e-03\n\
                P3: 7.188560e+02 0 6.071928e+02 -3.372877e+02 0 7.188560e+02 1.852157e+02 2.369057e+00 0 0 1 4.915215e-03\n\
                Tr: 4.276802e-04 -9.999672e-01 -8.084491e-03 -1.198459e-02 -7.210626e-03 8.081198e-03 -9.999413e-01 -5.403984e-02 9.999738e-01 4.859485e-04 -7.206933e-03 -2.921968e-01\n";
    let origin = Path::new("calib.txt");
    let err = parse_kitti(text, origin, &KittiImport::default()).unwrap_err();
    assert_eq!(err.field(), Some("image size"), "{err}");
    let opts = KittiImport {
        image_size: Some((1241, 376)),
        ..KittiImport::default()
    };
    let cal = parse_kitti(text, origin, &opts).expect("valid");
    assert_close(cal.rig.baseline(), 0.53233, 1e-3, "colour baseline");
    let grey = KittiImport {
        cameras: (0, 1),
        ..opts
    };
    let cal = parse_kitti(text, origin, &grey).expect("valid");
    assert_close(
        cal.rig.baseline(),
        386.1448 / 718.856,
        1e-9,
        "grey baseline",
    );
    assert_eq!(
        cal.rig.left.centre(),
        Point3::new(0.0, KITTI_CAMERA_HEIGHT, 0.0)
    );
}

#[test]
fn kitti_files_with_missing_or_broken_matrices_name_the_key() {
    let origin = Path::new("c2c.txt");
    let without = |key: &str| {
        KITTI_CAM_TO_CAM
            .lines()
            .filter(|l| !l.starts_with(key))
            .collect::<Vec<_>>()
            .join("\n")
    };
    let err = parse_kitti(&without("P_rect_03"), origin, &KittiImport::default()).unwrap_err();
    assert_eq!(err.field(), Some("P_rect_03"), "{err}");
    let broken = KITTI_CAM_TO_CAM.replace("P_rect_02: 7.215377e+02", "P_rect_02: x");
    let err = parse_kitti(&broken, origin, &KittiImport::default()).unwrap_err();
    assert_eq!(err.field(), Some("P_rect_02"), "{err}");
    let bad = KittiImport {
        cameras: (2, 2),
        ..KittiImport::default()
    };
    assert_eq!(
        parse_kitti(KITTI_CAM_TO_CAM, origin, &bad)
            .unwrap_err()
            .field(),
        Some("cameras")
    );
    let sized = KittiImport {
        image_size: Some((640, 480)),
        ..KittiImport::default()
    };
    let err = parse_kitti(KITTI_CAM_TO_CAM, origin, &sized).unwrap_err();
    assert!(chain(&err).contains("1242x375"), "{err}");
}

#[test]
fn kitti_fixtures_load_placed_on_the_vehicle() {
    // KITTI's P matrices through a rig TOML's [import] (the file records no size).
    let seq = load_sized("kitti/kitti_raw_2011_09_26_seq12/rig.toml", (1242, 375));
    assert_close(seq.rig.baseline(), 0.5327, 1e-3, "baseline");
    assert_close(seq.rig.left.centre().y, KITTI_CAMERA_HEIGHT, 1e-3, "height");
    assert!(seq.has_road);
    // A pair's Middlebury calib.txt placed by [mount].
    let pair = load_sized("kitti/kitti2015_train_000000/rig.toml", (1242, 375));
    assert_eq!(pair.rig.left.centre(), Point3::new(-0.06, 1.65, 0.0));
    assert_close(pair.rig.right.centre().x, -0.06 + 0.532725, 1e-9, "right x");
    assert!(pair.has_road && pair.depth_range.is_none());
    // Detected when loaded directly, sized by the caller.
    let direct = super::load_sized(
        &fixture("kitti/kitti_raw_2011_09_26_seq12/calib_kitti_P_rect.txt"),
        (1242, 375),
    )
    .expect("loads");
    assert_eq!(direct.rig, seq.rig);
}

#[test]
fn an_import_checks_what_it_is_given() {
    let dir = tempfile::tempdir().expect("tempdir");
    let write = |name: &str, text: &str| std::fs::write(dir.path().join(name), text).unwrap();
    write("c2c.txt", KITTI_CAM_TO_CAM);
    let check = |toml: &str, field: &str| {
        write("rig.toml", toml);
        let err = super::load(&dir.path().join("rig.toml")).unwrap_err();
        assert_eq!(err.field(), Some(field), "{}", chain(&err));
    };
    check(
        "[import]\nfile = \"c2c.txt\"\ntranslation_unit = \"mm\"\n",
        "import.translation_unit",
    );
    check("[import]\nfile = \"missing.txt\"\n", "import.file");
    check(
        "[import]\nfile = \"c2c.txt\"\nwidth = 1242\n",
        "import.height",
    );
    let middlebury = std::fs::read_to_string(fixture("middlebury-motorcycle/calib.txt")).unwrap();
    write("calib.txt", &middlebury);
    check("[import]\nfile = \"calib.txt\"\n", "mount.position");
    write(
        "rig.toml",
        "[import]\nfile = \"c2c.txt\"\n[mount]\npitch_deg = 2.0\n",
    );
    let tilted = super::load(&dir.path().join("rig.toml")).expect("loads");
    let level = parse_kitti(KITTI_CAM_TO_CAM, Path::new("c"), &KittiImport::default()).unwrap();
    assert_eq!(tilted.rig.left.centre(), level.rig.left.centre());
    assert_close(
        tilted.rig.baseline(),
        level.rig.baseline(),
        1e-12,
        "baseline",
    );
}

/// A simple rig TOML: both cameras 1.2 m up, 0.2 m apart; `right` replaces the right camera's
/// pose lines.
fn rig_with_right(right_pose: &str) -> String {
    format!(
        "[left]\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
         position = [-0.1, 1.2, 0.0]\n[right]\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
         {right_pose}\n"
    )
}

/// A right camera turned round by a rotation matrix (180 degrees about the vertical axis, as
/// OpenCV's R = diag(-1, 1, -1)) was accepted and modelled as unrotated; it is modelled as it
/// is, and refused like yaw_deg = 180.
#[test]
fn a_camera_turned_round_by_its_rotation_matrix_is_refused() {
    let turned = "position = [0.1, 1.2, 0.0]\nrotation = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]";
    let by_angle = "position = [0.1, 1.2, 0.0]\nyaw_deg = 180.0";
    for pose in [turned, by_angle] {
        let e = parse_rig_toml(&rig_with_right(pose), Path::new("inline.toml"))
            .expect_err(pose)
            .to_string();
        assert!(e.contains("inline.toml"), "{e}");
        assert!(e.contains("looks 180 degrees away"), "{pose}: {e}");
    }
    // The rotation is kept as given (the camera model, not only the check).
    let r = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, 1.0, -1.0));
    let cam = crate::geometry::Camera::new(
        64,
        48,
        crate::geometry::Intrinsics {
            fx: 50.0,
            fy: 50.0,
            cx: 32.0,
            cy: 24.0,
        },
        crate::geometry::Distortion::default(),
        r,
        nalgebra::Point3::new(0.0, 1.0, 0.0),
    )
    .expect("a proper rotation");
    assert!((cam.rotation().matrix() - r).abs().max() < 1e-12);
    // A camera looking 10 degrees aside is still a camera ahead.
    let aside = "position = [0.1, 1.2, 0.0]\nyaw_deg = 10.0";
    assert!(parse_rig_toml(&rig_with_right(aside), Path::new("inline.toml")).is_ok());
}

/// A rig placed 20 m (or 1e6 m) beside the vehicle origin was accepted (CLEAR with a
/// pedestrian ahead); a camera must be on the vehicle.
#[test]
fn a_rig_far_from_the_vehicle_origin_is_refused() {
    for (left, right) in [(20.0, 20.2), (1e6, 1e6 + 0.2)] {
        let text = rig_with_right(&format!("position = [{right:?}, 1.2, 0.0]")).replace(
            "position = [-0.1, 1.2, 0.0]",
            &format!("position = [{left:?}, 1.2, 0.0]"),
        );
        let e = parse_rig_toml(&text, Path::new("inline.toml"))
            .expect_err("far away")
            .to_string();
        assert!(e.contains("within 2 m of its axis"), "{left}: {e}");
    }
}
