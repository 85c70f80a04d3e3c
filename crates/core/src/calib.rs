//! Stereo calibration files: loading a [`StereoRig`] placed in the vehicle frame.
//!
//! # Formats
//! - **Middlebury `calib.txt`** ([`parse_middlebury`]): `key=value` lines with `cam0`/`cam1`
//!   intrinsics `[f 0 cx; 0 f cy; 0 0 1]` in pixels, `doffs` (= cx1 - cx0, pixels), `baseline`
//!   (**millimetres**), `width`, `height`, `ndisp` and optionally `vmin`, `vmax` (disparity
//!   bounds, pixels), `isint`, `dyavg`, `dymax`. The images are rectified and undistorted. The left
//!   camera sits at the vehicle origin looking along +z, the right one at x = baseline. The depth
//!   range comes from the disparity range; the scene has no road.
//! - **OpenCV FileStorage YAML** ([`parse_opencv_yaml`]) as saved by `cv::stereoCalibrate` users:
//!   `K1`, `D1`, `K2`, `D2`, `R`, `T` as `!!opencv-matrix` with `p_right_cam = R * p_left_cam + T`,
//!   T in the unit declared in [`OpenCvImport`]. The file says nothing about where the rig is on the
//!   vehicle: [`OpenCvImport`] places the left camera.
//! - **KITTI** ([`parse_kitti`]): the raw dataset's `calib_cam_to_cam.txt` (rectified
//!   `P_rect_0N`, or `K/D/R/T_0N` for unrectified images) and the odometry benchmark's
//!   `calib.txt` (`P0`..`P3`), placed at KITTI's mount (camera 0 on the centre line, 1.65 m up,
//!   level); the scene has a road.
//! - **flyd rig TOML** ([`parse_rig_toml`]), the project's own format: either two explicit cameras
//!   (`[left]`, `[right]`) or an import of any of the formats above (`[import]`, or the older
//!   `[opencv]`) placed on the vehicle by `[mount]`, plus an optional `[search]` depth range and
//!   road flag. Unknown keys are errors.
//!
//! [`load`] picks the format from the extension and content; [`load_sized`] also gives the
//! image size to a file that records none (a KITTI odometry file) and checks it against one
//! that does.
//!
//! # Conventions and units
//! Frames are those of [`crate::geometry`]: vehicle frame x right, y up from the road, z forward;
//! OpenCV camera frame. Positions, baselines and depths are metres, intrinsics pixels, angles
//! degrees. Depth ranges are measured along the left camera's optical axis.
//!
//! # Errors
//! Every [`CalibError`] names the file and, for content errors, the field (as spelled in that
//! file, with the camera side when the key alone does not say it). Cameras go through
//! [`Camera::new`], so a loaded rig never contains NaN, infinite or impossible values, and the rig
//! as a whole is checked: 0 < baseline < 5 m, the cameras see a common point ahead (at the
//! geometric mean of the depth range, or 10 m), and the depth range is positive and ordered.

use std::fmt;
use std::path::{Path, PathBuf};

use nalgebra::Point3;

use crate::geometry::{Camera, CameraError, StereoRig};

mod kitti;
mod middlebury;
mod opencv;
mod rig;
#[cfg(test)]
mod tests;

pub use kitti::{KITTI_CAMERA_HEIGHT, KittiImport, parse_kitti};
pub use middlebury::parse_middlebury;
pub use opencv::{OpenCvImport, Unit, parse_opencv_yaml};
pub use rig::{MAX_RIGHT_ROW_OFFSET, parse_rig_toml};

/// A stereo rig loaded from a calibration file, with what the file implies about the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub rig: StereoRig,
    /// Depth range (metres along the left camera axis) where flies are searched, when the file
    /// implies one.
    pub depth_range: Option<(f64, f64)>,
    /// Whether the scene has a road at y = 0 (false for datasets such as Middlebury: the engine
    /// then disables its road region-of-interest penalties).
    pub has_road: bool,
    /// Where the right image shows a left row, rows (`rectification.right_row_offset_px` of a
    /// rig file; 0 for the other formats): what [`crate::frame::PreparedImage::with_row_shift`]
    /// corrects the right image by.
    pub right_row_offset_px: f64,
    /// Whether flyd measures the residual of a rectified pair's rows itself and corrects it
    /// (`rectification.measure` of a rig file, default true; the other formats: true). Only a
    /// rectified rig is measured ([`crate::geometry::StereoRig::is_rectified`]).
    pub measure_rows: bool,
    /// Where the cameras were placed on the vehicle when nothing placed them (a format that
    /// carries no mount, a rig file's import without `[mount] position`), said for a person;
    /// none when the file gives the mount. A wrong height hides obstacles
    /// ([`crate::perception::mount_check`]): `flyd run` refuses a rig with one.
    pub mount_assumed: Option<&'static str>,
}

/// What [`Calibration::mount_assumed`] says for a file of each format on its own.
pub(crate) const OPENCV_MOUNT: &str = "an OpenCV calibration places no camera on the vehicle: \
     the left camera was taken 1.2 m above the road, level, on the vehicle's axis";
pub(crate) const MIDDLEBURY_MOUNT: &str = "a Middlebury calib.txt places no camera on the \
     vehicle: the left camera was taken at the road's level, in a scene without a road";
pub(crate) const KITTI_MOUNT: &str = "a KITTI calibration places the cameras as on the KITTI \
     car: the left camera 1.65 m above the road, level";

impl Calibration {
    /// What the file says about the search: its depth range replaces the engine's, and a scene
    /// without a road turns the road region of interest off.
    pub fn apply_to(&self, params: &mut crate::engine::EngineParams) {
        if let Some((min, max)) = self.depth_range {
            params.min_depth = min;
            params.max_depth = max;
        }
        if !self.has_road {
            params.roi = None;
        }
    }
}

/// Why a calibration file cannot be used. Each message names the file (and the field); a
/// wrapped cause is its [`std::error::Error::source`], not part of the message.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error("calibration file {}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        error: std::io::Error,
    },
    #[error(
        "calibration file {}: unrecognised format (expected a flyd rig '.toml', an OpenCV \
         FileStorage YAML with a '%YAML' header or '.yml'/'.yaml' extension, a Middlebury \
         calib.txt with 'cam0=', or a KITTI calib_cam_to_cam.txt or odometry calib.txt)",
        file.display()
    )]
    UnknownFormat { file: PathBuf },
    #[error("calibration file {}: field '{field}': {message}", file.display())]
    Field {
        file: PathBuf,
        field: String,
        message: String,
    },
    #[error("calibration file {}: field '{field}'", file.display())]
    Camera {
        file: PathBuf,
        field: String,
        #[source]
        error: CameraError,
    },
    /// A rig TOML's `[opencv]` import failed; `error` names the imported file.
    #[error("calibration file {}: field '{field}'", file.display())]
    Import {
        file: PathBuf,
        field: String,
        #[source]
        error: Box<CalibError>,
    },
}

impl CalibError {
    /// The file the error is about (for an import, the rig TOML that imports it).
    pub fn file(&self) -> &Path {
        match self {
            Self::Io { file, .. }
            | Self::UnknownFormat { file }
            | Self::Field { file, .. }
            | Self::Camera { file, .. }
            | Self::Import { file, .. } => file,
        }
    }

    /// The offending field, when the error is about the content of the file.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::Io { .. } | Self::UnknownFormat { .. } => None,
            Self::Field { field, .. } | Self::Camera { field, .. } | Self::Import { field, .. } => {
                Some(field)
            }
        }
    }
}

/// Shorthand for a content error.
fn field_error(file: &Path, field: impl Into<String>, message: impl Into<String>) -> CalibError {
    CalibError::Field {
        file: file.to_path_buf(),
        field: field.into(),
        message: message.into(),
    }
}

/// Loads a calibration, detecting its format: a `.toml` extension means a flyd rig, a `%YAML`
/// header or a `.yml`/`.yaml` extension an OpenCV file (imported with
/// [`OpenCvImport::default`]), a `cam0=` line a Middlebury `calib.txt`, and `P_rect_0N:`,
/// `K_0N:` or `P0:`/`P1:` lines a KITTI file ([`KittiImport::default`]).
pub fn load(path: &Path) -> Result<Calibration, CalibError> {
    load_file(path, None)
}

/// [`load`] for images of `size`: the size of a file that records none (a KITTI odometry
/// file), checked against the cameras of one that does.
pub fn load_sized(path: &Path, size: (u32, u32)) -> Result<Calibration, CalibError> {
    let cal = load_file(path, Some(size))?;
    for (side, cam) in [("left", &cal.rig.left), ("right", &cal.rig.right)] {
        if (cam.width(), cam.height()) != size {
            return Err(field_error(
                path,
                "image size",
                format!(
                    "the {side} camera is {}x{}, the images are {}x{}",
                    cam.width(),
                    cam.height(),
                    size.0,
                    size.1
                ),
            ));
        }
    }
    Ok(cal)
}

fn load_file(path: &Path, size: Option<(u32, u32)>) -> Result<Calibration, CalibError> {
    let text = crate::textfile::read(path).map_err(|error| CalibError::Io {
        file: path.to_path_buf(),
        error,
    })?;
    // Editors on Windows like to prepend a byte-order mark; it means nothing to any of the formats.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    match Format::of(path, text) {
        Some(Format::Rig) => parse_rig_toml(text, path),
        Some(Format::OpenCv) => {
            let opts = OpenCvImport {
                image_size: size,
                ..OpenCvImport::default()
            };
            parse_opencv_yaml(text, path, &opts)
        }
        Some(Format::Middlebury) => parse_middlebury(text, path),
        Some(Format::Kitti) => {
            let opts = KittiImport {
                image_size: size,
                ..KittiImport::default()
            };
            parse_kitti(text, path, &opts)
        }
        None => Err(CalibError::UnknownFormat {
            file: path.to_path_buf(),
        }),
    }
}

/// The calibration formats [`load`] tells apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Rig,
    OpenCv,
    Middlebury,
    Kitti,
}

impl Format {
    fn of(path: &Path, text: &str) -> Option<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if ext.as_deref() == Some("toml") {
            Some(Self::Rig)
        } else if text.starts_with("%YAML") || matches!(ext.as_deref(), Some("yml" | "yaml")) {
            Some(Self::OpenCv)
        } else if text.lines().any(|line| {
            line.trim_start()
                .strip_prefix("cam0")
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        }) {
            Some(Self::Middlebury)
        } else if kitti::looks_like_kitti(text) {
            Some(Self::Kitti)
        } else {
            None
        }
    }
}

/// Which camera of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Left,
    Right,
}

impl fmt::Display for Side {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Side::Left => "left",
            Side::Right => "right",
        })
    }
}

/// The part of a camera description that [`Camera::new`] refused, so that each format can blame
/// the key that holds it in its own files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Part {
    Width,
    Height,
    /// "fx", "fy", "cx" or "cy".
    Intrinsics(&'static str),
    Distortion,
    Rotation,
    Position,
}

impl Part {
    fn of(error: &CameraError) -> Self {
        match error {
            CameraError::TooSmall { width, .. } if *width < 16 => Part::Width,
            CameraError::TooSmall { .. } => Part::Height,
            CameraError::NotARotation { .. } => Part::Rotation,
            CameraError::PrincipalPointOutside { cx, width, .. } => {
                if (0.0..f64::from(*width)).contains(cx) {
                    Part::Intrinsics("cy")
                } else {
                    Part::Intrinsics("cx")
                }
            }
            CameraError::NotFinite { field, .. } | CameraError::NotPositive { field, .. } => {
                match *field {
                    "fx" => Part::Intrinsics("fx"),
                    "fy" => Part::Intrinsics("fy"),
                    "cx" => Part::Intrinsics("cx"),
                    "cy" => Part::Intrinsics("cy"),
                    "k1" | "k2" | "k3" | "p1" | "p2" => Part::Distortion,
                    "rotation" => Part::Rotation,
                    _ => Part::Position,
                }
            }
        }
    }
}

/// A camera [`Camera::new`] built (or refused), the refusal naming the file's field: `field_of`
/// maps the refused part to the field name as this format spells it.
fn build_camera(
    file: &Path,
    side: Side,
    camera: Result<Camera, CameraError>,
    field_of: impl Fn(Side, Part) -> String,
) -> Result<Camera, CalibError> {
    camera.map_err(|error| CalibError::Camera {
        file: file.to_path_buf(),
        field: field_of(side, Part::of(&error)),
        error,
    })
}

/// Checks a depth range given by the file: finite, positive, ordered.
fn check_depth_range(
    file: &Path,
    (min, max): (f64, f64),
    min_field: &str,
    max_field: &str,
) -> Result<(), CalibError> {
    for (field, value) in [(min_field, min), (max_field, max)] {
        if !(value.is_finite() && value > 0.0) {
            return Err(field_error(
                file,
                field,
                format!("depth must be a positive finite number of metres (got {value})"),
            ));
        }
    }
    if min >= max {
        return Err(field_error(
            file,
            min_field,
            format!(
                "minimum depth {min} m must be smaller than the maximum depth {max} m ({max_field})"
            ),
        ));
    }
    Ok(())
}

/// Largest plausible distance between the two optical centres: a longer baseline is almost
/// certainly a unit mistake (millimetres read as metres).
const MAX_BASELINE_M: f64 = 5.0;

/// Depth of the overlap check when the file gives no depth range.
const DEFAULT_OVERLAP_DEPTH_M: f64 = 10.0;

/// Where a camera on the vehicle can be, metres from the vehicle origin (on the road, at the
/// vehicle's axis): beside the axis, above the road, along it.
const MAX_MOUNT_LATERAL_M: f64 = 2.0;
const MAX_MOUNT_HEIGHT_M: f64 = 5.0;
const MAX_MOUNT_LONGITUDINAL_M: f64 = 10.0;
/// cos 45 degrees: how far from the forward axis a camera may look.
const MIN_FORWARD_COS: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// Which fields to blame when the rig as a whole is inconsistent.
struct RigFields<'a> {
    baseline: &'a str,
    overlap: &'a str,
    /// What places the left and the right camera on the vehicle.
    position: [&'a str; 2],
}

/// Consistency checks on a rig whose cameras are individually valid: a baseline in (0, 5) m and
/// cameras that look at the same scene, tested with the point on the left optical axis at the
/// geometric mean of the depth range (10 m without one), which must land inside the right image.
fn check_rig(
    file: &Path,
    rig: &StereoRig,
    depth_range: Option<(f64, f64)>,
    fields: RigFields<'_>,
) -> Result<(), CalibError> {
    let baseline = rig.baseline();
    if !(baseline > 0.0 && baseline < MAX_BASELINE_M) {
        return Err(field_error(
            file,
            fields.baseline,
            format!(
                "the baseline (distance between the optical centres) is {baseline:.4} m; it must be \
                 more than 0 and less than {MAX_BASELINE_M} m"
            ),
        ));
    }
    for ((side, cam), field) in [("left", &rig.left), ("right", &rig.right)]
        .into_iter()
        .zip(fields.position)
    {
        let c = cam.centre();
        let near = c.x.abs() <= MAX_MOUNT_LATERAL_M
            && (-1.0..=MAX_MOUNT_HEIGHT_M).contains(&c.y)
            && c.z.abs() <= MAX_MOUNT_LONGITUDINAL_M;
        if !near {
            return Err(field_error(
                file,
                field,
                format!(
                    "the {side} camera is at x = {:.2}, y = {:.2}, z = {:.2} m: a camera on the \
                     vehicle is within {MAX_MOUNT_LATERAL_M} m of its axis, -1..={MAX_MOUNT_HEIGHT_M} \
                     m above the road and {MAX_MOUNT_LONGITUDINAL_M} m of its origin",
                    c.x, c.y, c.z
                ),
            ));
        }
        // The optical axis in the vehicle frame (x right, y up, z forward).
        let k = cam.intrinsics();
        let axis = cam
            .vehicle_from_pixel_depth(k.cx, k.cy, 1.0)
            .map(|p| (p - c).normalize());
        if axis.is_none_or(|a| a.z.is_nan() || a.z < MIN_FORWARD_COS) {
            let deg = axis.map_or(f64::NAN, |a| a.z.clamp(-1.0, 1.0).acos().to_degrees());
            return Err(field_error(
                file,
                fields.overlap,
                format!(
                    "the {side} camera looks {deg:.0} degrees away from the vehicle's forward \
                     axis: a camera that detects obstacles ahead looks within 45 degrees of it"
                ),
            ));
        }
    }
    let depth = depth_range.map_or(DEFAULT_OVERLAP_DEPTH_M, |(min, max)| (min * max).sqrt());
    let k = rig.left.intrinsics();
    let problem = match rig.left.vehicle_from_pixel_depth(k.cx, k.cy, depth) {
        None => Some("the left principal point cannot be back-projected".to_string()),
        Some(p) => outside_right_view(&rig.right, &p),
    };
    match problem {
        Some(problem) => Err(field_error(
            file,
            fields.overlap,
            format!(
                "the cameras do not overlap: the point {depth:.2} m ahead on the left camera's \
                 axis must be visible in both images, but {problem}"
            ),
        )),
        None => Ok(()),
    }
}

/// Why the right camera does not see vehicle-frame point `p`, if it does not.
fn outside_right_view(right: &Camera, p: &Point3<f64>) -> Option<String> {
    let cam = right.camera_from_vehicle(p);
    let Some(px) = right.pixel_from_camera(&cam) else {
        return Some("it is behind the right camera".to_string());
    };
    // Far off axis, the distortion polynomial can fold a point back into the image: a point is
    // only seen where the model is invertible, so its pixel must back-project to its direction.
    let seen = right.contains(&px)
        && right
            .normalised_from_pixel(px.x, px.y)
            .is_some_and(|(x, y)| {
                (x - cam.x / cam.z).abs() < 1e-6 && (y - cam.y / cam.z).abs() < 1e-6
            });
    if seen {
        None
    } else if px.x.abs() < 1e6 && px.y.abs() < 1e6 {
        Some(format!(
            "it projects to ({:.1}, {:.1}), outside the {}x{} right image",
            px.x,
            px.y,
            right.width(),
            right.height()
        ))
    } else {
        Some("it is far outside the right camera's field of view".to_string())
    }
}
