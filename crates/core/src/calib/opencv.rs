//! OpenCV FileStorage YAML stereo calibrations, as saved by `cv::stereoCalibrate` users.
//!
//! ```yaml
//! %YAML:1.0
//! ---
//! image_width: 1280
//! image_height: 720
//! K1: !!opencv-matrix
//!    rows: 3
//!    cols: 3
//!    dt: d
//!    data: [ 1052.8, 0., 641.3, 0., 1053.4, 359.9, 0., 0., 1. ]
//! D1: !!opencv-matrix   # 4, 5, 8, 12 or 14 coefficients; only k1 k2 p1 p2 k3 may be non-zero
//! K2: ...
//! D2: ...
//! R: !!opencv-matrix    # 3x3, p_right_cam = R * p_left_cam + T
//! T: !!opencv-matrix    # 3x1, in the unit of the calibration target's square size
//! ```
//!
//! Other keys (`R1`, `P1`, `Q`, `E`, `F`, `rms`, ...) are ignored. The image size comes from
//! `image_width`/`image_height`, or `imageSize`/`image_size` (`[w, h]` or a matrix), or else
//! from [`OpenCvImport::image_size`].

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Point3, Vector3};
use serde_json::Value;
use serde_saphyr::options::NonFiniteFloatPolicy;

use super::{
    CalibError, Calibration, MAX_BASELINE_M, Part, RigFields, Side, build_camera, check_rig,
    field_error,
};
use crate::geometry::{Camera, Distortion, Intrinsics, StereoRig, rotation_from_angles};

/// Unit of a length in a calibration file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
pub enum Unit {
    #[default]
    #[serde(rename = "m")]
    Metre,
    #[serde(rename = "cm")]
    Centimetre,
    #[serde(rename = "mm")]
    Millimetre,
}

impl Unit {
    /// Length of one unit in metres.
    pub fn in_metres(self) -> f64 {
        match self {
            Unit::Metre => 1.0,
            Unit::Centimetre => 0.01,
            Unit::Millimetre => 0.001,
        }
    }
}

/// What an OpenCV calibration does not say: the unit of `T` (OpenCV uses whatever unit the
/// calibration target was measured in), possibly the image size, and where the rig is on the
/// vehicle (the file only relates the two cameras to each other).
#[derive(Debug, Clone, PartialEq)]
pub struct OpenCvImport {
    /// Unit of `T` in the file.
    pub translation_unit: Unit,
    /// Image size `(width, height)` for files that do not record it. When the file records one,
    /// this must agree with it.
    pub image_size: Option<(u32, u32)>,
    /// Optical centre of the left camera in the vehicle frame, metres.
    pub left_position: Point3<f64>,
    /// Orientation of the left camera (see [`rotation_from_angles`]), degrees.
    pub pitch_deg: f64,
    pub yaw_deg: f64,
    pub roll_deg: f64,
}

impl Default for OpenCvImport {
    /// Metres; the left camera 1.2 m above the road on the vehicle's axis, looking straight ahead.
    fn default() -> Self {
        Self {
            translation_unit: Unit::Metre,
            image_size: None,
            left_position: Point3::new(0.0, 1.2, 0.0),
            pitch_deg: 0.0,
            yaw_deg: 0.0,
            roll_deg: 0.0,
        }
    }
}

/// Parses an OpenCV FileStorage YAML stereo calibration and places it on the vehicle with `opts`.
/// `origin` names the file in errors. The scene is assumed to have a road; the file implies no
/// depth range.
pub fn parse_opencv_yaml(
    text: &str,
    origin: &Path,
    opts: &OpenCvImport,
) -> Result<Calibration, CalibError> {
    for (field, value) in [
        ("OpenCvImport::left_position.x", opts.left_position.x),
        ("OpenCvImport::left_position.y", opts.left_position.y),
        ("OpenCvImport::left_position.z", opts.left_position.z),
        ("OpenCvImport::pitch_deg", opts.pitch_deg),
        ("OpenCvImport::yaw_deg", opts.yaw_deg),
        ("OpenCvImport::roll_deg", opts.roll_deg),
    ] {
        if !value.is_finite() {
            return Err(field_error(
                origin,
                field,
                format!("must be a finite number (got {value})"),
            ));
        }
    }
    Ok(Calibration {
        rig: build_rig(text, origin, opts, None)?,
        depth_range: None,
        has_road: true,
        right_row_offset_px: 0.0,
        measure_rows: true,
        mount_assumed: Some(crate::calib::OPENCV_MOUNT),
    })
}

/// The rig described by an OpenCV file, checked for overlap at `depth_range` (see
/// [`super::check_rig`]). `opts` must hold finite numbers.
pub(super) fn build_rig(
    text: &str,
    origin: &Path,
    opts: &OpenCvImport,
    depth_range: Option<(f64, f64)>,
) -> Result<StereoRig, CalibError> {
    let doc = Document::parse(text, origin)?;
    let k1 = doc.intrinsics("K1")?;
    let d1 = doc.distortion("D1")?;
    let k2 = doc.intrinsics("K2")?;
    let d2 = doc.distortion("D2")?;
    let r = doc.matrix("R", 3, 3)?;
    let r = Matrix3::from_row_slice(&r);
    let t = Vector3::from_column_slice(&doc.vector("T", 3)?);
    let image_size = doc.image_size(opts.image_size)?;
    let (width, height) = image_size.size;

    // A baseline of metres is implausible; such a T is millimetres read as metres, the commonest
    // mistake with these files (OpenCV keeps the unit of the target's square size).
    if opts.translation_unit == Unit::Metre && t.norm() > MAX_BASELINE_M {
        return Err(field_error(
            origin,
            "T",
            format!(
                "|T| = {:.3} would be a baseline of {:.3} m, which looks like millimetres; declare \
                 the unit: translation_unit = \"mm\" in the rig TOML's [opencv] section \
                 (OpenCvImport::translation_unit = Unit::Millimetre)",
                t.norm(),
                t.norm()
            ),
        ));
    }
    let t = t * opts.translation_unit.in_metres();

    let field_of = |side: Side, part: Part| {
        let (k, d) = match side {
            Side::Left => ("K1", "D1"),
            Side::Right => ("K2", "D2"),
        };
        match (part, side) {
            (Part::Width, _) => image_size.width_key.to_string(),
            (Part::Height, _) => image_size.height_key.to_string(),
            (Part::Intrinsics(_), _) => format!("{k} ({side} camera)"),
            (Part::Distortion, _) => format!("{d} ({side} camera)"),
            (Part::Rotation, Side::Right) => "R".to_string(),
            (Part::Position, Side::Right) => "T".to_string(),
            // The left pose comes from the import options, which the caller has checked.
            (Part::Rotation, Side::Left) => "OpenCvImport::pitch_deg/yaw_deg/roll_deg".to_string(),
            (Part::Position, Side::Left) => "OpenCvImport::left_position".to_string(),
        }
    };
    let left_rotation = rotation_from_angles(opts.pitch_deg, opts.yaw_deg, opts.roll_deg);
    let left = Camera::new(width, height, k1, d1, left_rotation, opts.left_position);
    let left = build_camera(origin, Side::Left, left, field_of)?;
    // p_right = R p_left + T: the right optical centre (p_right = 0) is at -Rᵀ T in the left
    // camera frame. If R is not a rotation, Rᵀ is not its inverse and this centre is wrong, but
    // Camera::new then refuses R * left_rotation and the error blames R.
    let right_centre = left.vehicle_from_camera(&Point3::from(-(r.transpose() * t)));
    let right = Camera::new(width, height, k2, d2, r * left_rotation, right_centre);
    let right = build_camera(origin, Side::Right, right, field_of)?;
    let rig = StereoRig { left, right };
    check_rig(
        origin,
        &rig,
        depth_range,
        RigFields {
            baseline: "T",
            overlap: "R, T",
            position: ["T", "T"],
        },
    )?;
    Ok(rig)
}

/// Names of the distortion coefficients in OpenCV's order.
const DISTORTION_NAMES: [&str; 14] = [
    "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "taux", "tauy",
];

/// The top-level mapping of a FileStorage document.
struct Document<'a> {
    file: &'a Path,
    /// A generic tree (serde_json's `Value` is the only one at hand) rather than a typed struct,
    /// so that each key is checked on its own and its errors can name it.
    keys: BTreeMap<String, Value>,
}

impl<'a> Document<'a> {
    fn parse(text: &str, file: &'a Path) -> Result<Self, CalibError> {
        let text = without_opencv_directive(text);
        // Non-finite numbers come through as strings (".nan") so that the matrix reader can name
        // the key that holds them; the default policy fails the whole document with a position.
        let options = serde_saphyr::options! {
            non_finite_float_policy: NonFiniteFloatPolicy::AsString,
        };
        let keys = serde_saphyr::from_str_with_options(&text, options).map_err(|error| {
            let blame = error
                .location()
                .and_then(|l| usize::try_from(l.line()).ok())
                .map(|line| blame_line(&text, line))
                .unwrap_or_default();
            field_error(
                file,
                blame.field.unwrap_or("(document)"),
                format!(
                    "invalid YAML: {}{}",
                    error.without_snippet(),
                    blame
                        .previous
                        .map(|p| format!(" (or an unterminated value at the end of '{p}')"))
                        .unwrap_or_default()
                ),
            )
        })?;
        Ok(Self { file, keys })
    }

    fn error(&self, key: &str, message: impl Into<String>) -> CalibError {
        field_error(self.file, key, message)
    }

    fn get(&self, key: &str) -> Result<&Value, CalibError> {
        self.keys.get(key).ok_or_else(|| self.error(key, "missing"))
    }

    /// The data of an `!!opencv-matrix`, with its shape.
    fn any_matrix(&self, key: &str) -> Result<(usize, usize, Vec<f64>), CalibError> {
        let value = self.get(key)?;
        let Some(map) = value.as_object() else {
            return Err(self.error(
                key,
                "expected an !!opencv-matrix (a mapping with rows, cols, dt and data)",
            ));
        };
        let dimension = |name: &str| {
            map.get(name)
                .and_then(Value::as_u64)
                .and_then(|n| usize::try_from(n).ok())
                .ok_or_else(|| {
                    self.error(key, format!("'{name}' must be a whole number of elements"))
                })
        };
        let (rows, cols) = (dimension("rows")?, dimension("cols")?);
        let Some(data) = map.get("data").and_then(Value::as_array) else {
            return Err(self.error(key, "'data' must be a sequence of numbers"));
        };
        let expected = rows.saturating_mul(cols);
        if data.len() != expected {
            return Err(self.error(
                key,
                format!(
                    "expected {expected} numbers ({rows}x{cols} matrix), got {}",
                    data.len()
                ),
            ));
        }
        let numbers = data
            .iter()
            .enumerate()
            .map(|(i, v)| match v {
                Value::Number(n) => n.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                    self.error(key, format!("element {i} ({n}) is not a finite number"))
                }),
                Value::String(s) => {
                    Err(self.error(key, format!("element {i} is '{s}', not a finite number")))
                }
                other => Err(self.error(key, format!("element {i} ({other}) is not a number"))),
            })
            .collect::<Result<Vec<f64>, _>>()?;
        Ok((rows, cols, numbers))
    }

    fn matrix(&self, key: &str, rows: usize, cols: usize) -> Result<Vec<f64>, CalibError> {
        let (r, c, data) = self.any_matrix(key)?;
        if (r, c) != (rows, cols) {
            return Err(self.error(key, format!("expected a {rows}x{cols} matrix, got {r}x{c}")));
        }
        Ok(data)
    }

    /// A row or column vector of `len` elements.
    fn vector(&self, key: &str, len: usize) -> Result<Vec<f64>, CalibError> {
        let (r, c, data) = self.any_matrix(key)?;
        if !(r == 1 || c == 1) || data.len() != len {
            return Err(self.error(
                key,
                format!("expected a vector of {len} numbers, got a {r}x{c} matrix"),
            ));
        }
        Ok(data)
    }

    fn intrinsics(&self, key: &str) -> Result<Intrinsics, CalibError> {
        let m = self.matrix(key, 3, 3)?;
        // stereoCalibrate never estimates skew, and the camera model has none.
        if m[1] != 0.0 || m[3] != 0.0 || m[6] != 0.0 || m[7] != 0.0 || m[8] != 1.0 {
            return Err(self.error(
                key,
                format!("expected the form [fx 0 cx; 0 fy cy; 0 0 1] (no skew), got {m:?}"),
            ));
        }
        Ok(Intrinsics {
            fx: m[0],
            fy: m[4],
            cx: m[2],
            cy: m[5],
        })
    }

    fn distortion(&self, key: &str) -> Result<Distortion, CalibError> {
        let (r, c, d) = self.any_matrix(key)?;
        if !(r == 1 || c == 1) || ![4, 5, 8, 12, 14].contains(&d.len()) {
            return Err(self.error(
                key,
                format!(
                    "expected 4, 5, 8, 12 or 14 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 \
                     s4 [taux tauy]]]]), got a {r}x{c} matrix"
                ),
            ));
        }
        if let Some((name, value)) = DISTORTION_NAMES
            .iter()
            .zip(&d)
            .skip(5)
            .find(|(_, v)| **v != 0.0)
        {
            return Err(self.error(
                key,
                format!(
                    "{name} = {value} is not zero, but the camera model only has k1, k2, p1, p2 \
                     and k3 (recalibrate without CALIB_RATIONAL_MODEL, CALIB_THIN_PRISM_MODEL and \
                     CALIB_TILTED_MODEL)"
                ),
            ));
        }
        Ok(Distortion {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d.get(4).copied().unwrap_or(0.0),
        })
    }

    /// The image size: from the file, else from the import options.
    fn image_size(&self, option: Option<(u32, u32)>) -> Result<ImageSize, CalibError> {
        let pixels = |key: &'static str, value: &Value| {
            // A matrix stores the size as floating point; 640.0 is fine, 640.5 is not.
            let whole = value.as_u64().or_else(|| {
                value
                    .as_f64()
                    .filter(|x| x.fract() == 0.0 && *x >= 0.0 && *x <= f64::from(u32::MAX))
                    .map(|x| x as u64)
            });
            whole.and_then(|n| u32::try_from(n).ok()).ok_or_else(|| {
                self.error(
                    key,
                    format!("expected a whole number of pixels, got {value}"),
                )
            })
        };
        let separate = match (self.keys.get("image_width"), self.keys.get("image_height")) {
            (Some(w), Some(h)) => Some(ImageSize {
                width_key: "image_width",
                height_key: "image_height",
                size: (pixels("image_width", w)?, pixels("image_height", h)?),
            }),
            (None, None) => None,
            (Some(_), None) => {
                return Err(self.error("image_height", "missing (image_width is given)"));
            }
            (None, Some(_)) => {
                return Err(self.error("image_width", "missing (image_height is given)"));
            }
        };
        let pair_key = ["imageSize", "image_size"]
            .into_iter()
            .find(|k| self.keys.contains_key(*k));
        let pair = match pair_key {
            None => None,
            Some(key) => {
                // cv::Size is written as a flow sequence; tolerate a matrix too.
                let items: Vec<Value> = match self.get(key)? {
                    Value::Array(items) => items.clone(),
                    _ => self
                        .any_matrix(key)?
                        .2
                        .into_iter()
                        .map(Value::from)
                        .collect(),
                };
                let [w, h] = items.as_slice() else {
                    return Err(self.error(key, "expected [width, height]"));
                };
                Some(ImageSize {
                    width_key: key,
                    height_key: key,
                    size: (pixels(key, w)?, pixels(key, h)?),
                })
            }
        };
        let from_file = match (separate, pair) {
            (Some(a), Some(b)) if a.size != b.size => {
                return Err(self.error(
                    b.width_key,
                    format!(
                        "says {} but image_width/image_height say {}",
                        b.describe(),
                        a.describe()
                    ),
                ));
            }
            (a, b) => a.or(b),
        };
        match (from_file, option) {
            (Some(found), Some(given)) if found.size != given => Err(self.error(
                found.width_key,
                format!(
                    "the file says {} but the import asks for {}x{}; they must agree",
                    found.describe(),
                    given.0,
                    given.1
                ),
            )),
            (Some(found), _) => Ok(found),
            (None, Some(size)) => Ok(ImageSize {
                width_key: "OpenCvImport::image_size",
                height_key: "OpenCvImport::image_size",
                size,
            }),
            (None, None) => Err(self.error(
                "image_width",
                "missing: the file does not record the image size (image_width/image_height or \
                 imageSize); give it as width/height in the rig TOML's [opencv] section \
                 (OpenCvImport::image_size)",
            )),
        }
    }
}

/// An image size and the keys it came from, to blame them if the cameras refuse it.
#[derive(Debug, Clone, Copy)]
struct ImageSize {
    width_key: &'static str,
    height_key: &'static str,
    size: (u32, u32),
}

impl ImageSize {
    fn describe(&self) -> String {
        format!("{}x{}", self.size.0, self.size.1)
    }
}

/// OpenCV writes a non-standard `%YAML:1.0` directive. serde-saphyr accepts it when a `---`
/// follows, as OpenCV 3 and later write it, but OpenCV 2.x omitted the `---`, and a directive
/// without a document start is a syntax error. The directive says nothing we need, so it becomes
/// a comment (on the same line, so error line numbers still match the file).
fn without_opencv_directive(text: &str) -> Cow<'_, str> {
    match text.strip_prefix("%YAML:") {
        Some(rest) => Cow::Owned(format!("#YAML:{rest}")),
        None => Cow::Borrowed(text),
    }
}

/// Where a YAML syntax error at a line is: the top-level key whose block holds it and, when
/// the line is that key's own line, the key before it (an unclosed `[` there is only detected
/// at the next key).
#[derive(Default)]
struct Blame<'t> {
    field: Option<&'t str>,
    previous: Option<&'t str>,
}

/// See [`Blame`]; `line` is 1-based.
fn blame_line(text: &str, line: usize) -> Blame<'_> {
    let mut blame = Blame::default();
    for (index, l) in text.lines().take(line).enumerate() {
        if l.starts_with([' ', '\t', '#', '%', '-']) {
            continue;
        }
        if let Some((key, _)) = l.split_once(':').filter(|(k, _)| !k.trim().is_empty()) {
            let previous = blame.field.replace(key.trim());
            blame.previous = if index + 1 == line { previous } else { None };
        }
    }
    blame
}
