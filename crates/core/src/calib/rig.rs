//! The flyd rig TOML: the project's own calibration format.
//!
//! Either two explicit cameras:
//!
//! ```toml
//! [left]
//! width = 640                 # pixels; [right] defaults to the left size
//! height = 480
//! fx = 520.0                  # pixels
//! fy = 520.0
//! cx = 319.5                  # pixel centres, origin at the centre of the top-left pixel
//! cy = 239.5
//! distortion = [-0.05, 0.01, 0.0, 0.0, 0.0]  # k1 k2 p1 p2 [k3], optional
//! position = [-0.15, 1.3, 0.0]                # optical centre, vehicle frame, metres
//! pitch_deg = 5.0             # optional, see geometry::rotation_from_angles; or
//! yaw_deg = 0.0               # rotation = [[...], [...], [...]] (rows; forward frame -> camera)
//! roll_deg = 0.0
//! [right]
//! ...
//! ```
//!
//! or an OpenCV file placed on the vehicle:
//!
//! ```toml
//! [opencv]
//! file = "stereo.yml"         # relative to this TOML
//! translation_unit = "mm"     # unit of T: "m" (default), "cm" or "mm"
//! width = 640                 # optional if the YAML records the size
//! height = 480
//! [mount]                     # optional: where the left camera is (default 1.2 m up, level)
//! position = [-0.15, 1.3, 0.0]
//! pitch_deg = 5.0
//! ```
//!
//! or any other calibration file flyd reads (OpenCV YAML, Middlebury `calib.txt`, KITTI
//! `calib_cam_to_cam.txt` or odometry `calib.txt`), placed on the vehicle:
//!
//! ```toml
//! [import]
//! file = "calib_cam_to_cam.txt"  # relative to this TOML; the format is detected
//! width = 1242                # when the file records no size (KITTI odometry)
//! height = 375
//! cameras = [2, 3]            # KITTI: which cameras (default the colour pair)
//! rectified = true            # KITTI: P_rect (default) or the raw K/D/R/T
//! translation_unit = "mm"     # OpenCV: unit of T
//! [mount]                     # where the left camera is (default: where the format puts it;
//! position = [-0.06, 1.65, 0.0]   # a Middlebury file needs one)
//! pitch_deg = 0.0
//! roll_deg = 0.0
//! ```
//!
//! and in all cases an optional search section (an import's own depth range, a Middlebury
//! file's disparity range, is not used: it describes that dataset, not the road):
//!
//! ```toml
//! [search]
//! min_depth = 1.0             # metres along the left camera axis; both or neither
//! max_depth = 25.0
//! road = true                 # default true
//! ```
//!
//! and an optional row correction of a rectified pair (what `flyd replay` measures as
//! `row_offset.residual_px`; [`crate::rectification`]):
//!
//! ```toml
//! [rectification]
//! right_row_offset_px = -0.5  # row y of the right image is read at y - 0.5; |x| <= 2
//! measure = true              # flyd measures what is left and corrects it (a rectified rig)
//! ```

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Point3};
use serde::Deserialize;

use super::{
    CalibError, Calibration, KittiImport, OpenCvImport, Part, RigFields, Side, Unit, build_camera,
    check_depth_range, check_rig, field_error, kitti, opencv,
};
use crate::geometry::{Camera, Distortion, Intrinsics, StereoRig, rotation_from_angles};

mod import;
use import::{import_any, imported_rig};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    left: Option<CameraToml>,
    right: Option<CameraToml>,
    opencv: Option<OpenCvToml>,
    import: Option<ImportToml>,
    mount: Option<MountToml>,
    search: Option<SearchToml>,
    rectification: Option<RectificationToml>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RectificationToml {
    right_row_offset_px: Option<f64>,
    measure: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImportToml {
    file: PathBuf,
    width: Option<u32>,
    height: Option<u32>,
    cameras: Option<[u8; 2]>,
    rectified: Option<bool>,
    translation_unit: Option<Unit>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraToml {
    width: Option<u32>,
    height: Option<u32>,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: Option<Vec<f64>>,
    position: [f64; 3],
    pitch_deg: Option<f64>,
    yaw_deg: Option<f64>,
    roll_deg: Option<f64>,
    rotation: Option<[[f64; 3]; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct OpenCvToml {
    file: PathBuf,
    translation_unit: Option<Unit>,
    width: Option<u32>,
    height: Option<u32>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MountToml {
    position: Option<[f64; 3]>,
    pitch_deg: Option<f64>,
    yaw_deg: Option<f64>,
    roll_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SearchToml {
    min_depth: Option<f64>,
    max_depth: Option<f64>,
    road: Option<bool>,
}

/// Parses a flyd rig TOML. `origin` names the file in errors and is where an `[opencv]` file is
/// looked up relative to.
/// Two keys that go together, `(value, key)` each: both values, or neither.
fn paired<T>(
    file: &Path,
    (a, a_key): (Option<T>, &str),
    (b, b_key): (Option<T>, &str),
) -> Result<Option<(T, T)>, CalibError> {
    match (a, b) {
        (Some(a), Some(b)) => Ok(Some((a, b))),
        (None, None) => Ok(None),
        (Some(_), None) => Err(field_error(
            file,
            b_key,
            format!("missing ({a_key} is given)"),
        )),
        (None, Some(_)) => Err(field_error(
            file,
            a_key,
            format!("missing ({b_key} is given)"),
        )),
    }
}

pub fn parse_rig_toml(text: &str, origin: &Path) -> Result<Calibration, CalibError> {
    let file: RigFile = toml::from_str(text).map_err(|e| toml_error(origin, text, &e))?;
    let search = file.search.unwrap_or_default();
    let (min, max) = ("search.min_depth", "search.max_depth");
    let depth_range = paired(origin, (search.min_depth, min), (search.max_depth, max))?;
    if let Some(range) = depth_range {
        check_depth_range(origin, range, min, max)?;
    }
    let rectification = file.rectification.unwrap_or_default();
    let right_row_offset_px = rectification.right_row_offset_px.unwrap_or(0.0);
    let measure_rows = rectification.measure.unwrap_or(true);
    if !(right_row_offset_px.is_finite() && right_row_offset_px.abs() <= MAX_RIGHT_ROW_OFFSET) {
        return Err(field_error(
            origin,
            "rectification.right_row_offset_px",
            format!(
                "{right_row_offset_px} px: a rectified pair more than {MAX_RIGHT_ROW_OFFSET} px \
                 off vertically needs rectifying again, not a row shift"
            ),
        ));
    }
    if let Some(import) = &file.import {
        if file.left.is_some() || file.right.is_some() || file.opencv.is_some() {
            return Err(field_error(
                origin,
                "import",
                "give one of [left] and [right], [opencv] or [import]",
            ));
        }
        let (rig, mount_assumed) = import_any(origin, import, file.mount, depth_range)?;
        return Ok(Calibration {
            rig,
            depth_range,
            has_road: search.road.unwrap_or(true),
            right_row_offset_px,
            measure_rows,
            mount_assumed,
        });
    }
    // Explicit cameras give their own positions; an [opencv] section without one, the
    // import's default.
    let mount_assumed = (file.opencv.is_some()
        && file.mount.as_ref().is_none_or(|m| m.position.is_none()))
    .then_some(crate::calib::OPENCV_MOUNT);
    let rig = match (file.left, file.right, file.opencv) {
        (Some(_), _, Some(_)) | (_, Some(_), Some(_)) => {
            return Err(field_error(
                origin,
                "opencv",
                "give either [left] and [right] or [opencv], not both",
            ));
        }
        (None, None, None) => {
            return Err(field_error(
                origin,
                "left",
                "missing: a rig needs [left] and [right] cameras, or an [opencv] import",
            ));
        }
        (Some(_), None, None) => return Err(field_error(origin, "right", "missing")),
        (None, Some(_), None) => return Err(field_error(origin, "left", "missing")),
        (Some(left), Some(right), None) => {
            if file.mount.is_some() {
                return Err(field_error(
                    origin,
                    "mount",
                    "only used with [opencv]; explicit cameras give their own position and angles",
                ));
            }
            explicit_rig(origin, &left, &right, depth_range)?
        }
        (None, None, Some(import)) => {
            imported_rig(origin, &import, file.mount.unwrap_or_default(), depth_range)?
        }
    };
    Ok(Calibration {
        rig,
        depth_range,
        has_road: search.road.unwrap_or(true),
        right_row_offset_px,
        measure_rows,
        mount_assumed,
    })
}

/// The largest `rectification.right_row_offset_px` a rig file may give, pixels.
pub const MAX_RIGHT_ROW_OFFSET: f64 = 2.0;

fn explicit_rig(
    file: &Path,
    left: &CameraToml,
    right: &CameraToml,
    depth_range: Option<(f64, f64)>,
) -> Result<StereoRig, CalibError> {
    let left = camera(file, Side::Left, left, None)?;
    let right = camera(
        file,
        Side::Right,
        right,
        Some((left.width(), left.height())),
    )?;
    let rig = StereoRig { left, right };
    check_rig(
        file,
        &rig,
        depth_range,
        RigFields {
            baseline: "right.position",
            overlap: "right",
            position: ["left.position", "right.position"],
        },
    )?;
    Ok(rig)
}

/// One explicit camera; `default_size` is the size used when the section gives none.
fn camera(
    file: &Path,
    side: Side,
    spec: &CameraToml,
    default_size: Option<(u32, u32)>,
) -> Result<Camera, CalibError> {
    let key = |name: &str| format!("{side}.{name}");
    let width = spec
        .width
        .or(default_size.map(|s| s.0))
        .ok_or_else(|| field_error(file, key("width"), "missing"))?;
    let height = spec
        .height
        .or(default_size.map(|s| s.1))
        .ok_or_else(|| field_error(file, key("height"), "missing"))?;
    let distortion = match spec.distortion.as_deref() {
        None => Distortion::default(),
        Some(&[k1, k2, p1, p2]) => Distortion {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        },
        Some(&[k1, k2, p1, p2, k3]) => Distortion { k1, k2, p1, p2, k3 },
        Some(other) => {
            return Err(field_error(
                file,
                key("distortion"),
                format!(
                    "expected 4 or 5 coefficients (k1 k2 p1 p2 [k3]), got {}",
                    other.len()
                ),
            ));
        }
    };
    let angles = [
        ("pitch_deg", spec.pitch_deg),
        ("yaw_deg", spec.yaw_deg),
        ("roll_deg", spec.roll_deg),
    ];
    let rotation = match spec.rotation {
        Some(rows) => {
            if angles.iter().any(|(_, a)| a.is_some()) {
                return Err(field_error(
                    file,
                    key("rotation"),
                    "give either rotation or pitch_deg/yaw_deg/roll_deg, not both",
                ));
            }
            Matrix3::from_row_slice(rows.as_flattened())
        }
        None => {
            let [pitch, yaw, roll] = finite_angles(file, &key, angles)?;
            rotation_from_angles(pitch, yaw, roll)
        }
    };
    let intrinsics = Intrinsics {
        fx: spec.fx,
        fy: spec.fy,
        cx: spec.cx,
        cy: spec.cy,
    };
    let centre = Point3::from(spec.position);
    let camera = Camera::new(width, height, intrinsics, distortion, rotation, centre);
    build_camera(file, side, camera, |side, part| {
        let name = match part {
            Part::Width => "width",
            Part::Height => "height",
            Part::Intrinsics(name) => name,
            Part::Distortion => "distortion",
            Part::Rotation => "rotation",
            Part::Position => "position",
        };
        format!("{side}.{name}")
    })
}

/// The angles (degrees, 0 when absent), which must be finite.
fn finite_angles(
    file: &Path,
    key: &impl Fn(&str) -> String,
    angles: [(&str, Option<f64>); 3],
) -> Result<[f64; 3], CalibError> {
    let mut out = [0.0; 3];
    for (slot, (name, value)) in out.iter_mut().zip(angles) {
        let value = value.unwrap_or(0.0);
        if !value.is_finite() {
            return Err(field_error(
                file,
                key(name),
                format!("must be a finite number of degrees (got {value})"),
            ));
        }
        *slot = value;
    }
    Ok(out)
}

/// A TOML or schema error, blaming the dotted key at the error's position.
fn toml_error(file: &Path, text: &str, error: &toml::de::Error) -> CalibError {
    let message = error.message().trim();
    let offset = error.span().map(|span| span.start);
    let mut field = offset
        .map(|offset| crate::toml_key::key_at(text, offset))
        .unwrap_or_default();
    // For missing (and some unknown) fields the position is the enclosing table; serde names the
    // key in backquotes.
    let named = ["missing field `", "unknown field `"]
        .iter()
        .find_map(|prefix| message.strip_prefix(prefix))
        .and_then(|rest| rest.split('`').next());
    if let Some(name) = named
        && field.rsplit('.').next() != Some(name)
    {
        if !field.is_empty() {
            field.push('.');
        }
        field.push_str(name);
    }
    if field.is_empty() {
        // Before any key (a broken first header, say): the line is the best name there is.
        field = match offset {
            Some(offset) => {
                let line = text.get(..offset).map_or(0, |t| t.matches('\n').count()) + 1;
                format!("line {line}")
            }
            None => "(document)".to_string(),
        };
    }
    field_error(file, field, message)
}
