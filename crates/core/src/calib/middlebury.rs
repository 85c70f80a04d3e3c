//! Middlebury `calib.txt` (stereo datasets 2014 and later).
//!
//! ```text
//! cam0=[994.978 0 311.193; 0 994.978 254.877; 0 0 1]
//! cam1=[994.978 0 342.279; 0 994.978 254.877; 0 0 1]
//! doffs=31.086
//! baseline=193.001
//! width=741
//! height=500
//! ndisp=68
//! ```
//!
//! The pair is rectified: both cameras look along +z with the same f and cy, and a left pixel
//! (x, y) with disparity d matches the right pixel (x - d, y). Because cx differs between the
//! cameras (`doffs` = cx1 - cx0), depth is Z = baseline * f / (d + doffs).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Point3};

use super::{
    CalibError, Calibration, Part, RigFields, Side, build_camera, check_depth_range, check_rig,
    field_error,
};
use crate::geometry::{Camera, Distortion, Intrinsics, StereoRig};

/// Disparity margin (pixels) put around `[vmin, vmax]`: those bounds are the exact extremes of
/// the ground truth, and flies at the extreme depths need a little room to converge.
const VMIN_VMAX_MARGIN_PX: f64 = 2.0;

/// Smallest total disparity `d + doffs` (pixels) used for the far end of the depth range. A
/// disparity range that reaches `d + doffs <= 0` extends to infinity; beyond one pixel of total
/// disparity the rig cannot tell depths apart anyway, so the far end stops there.
const MIN_TOTAL_DISPARITY_PX: f64 = 1.0;

/// Tolerance on `doffs` = cx1 - cx0 and on the rectification (equal f and cy), in pixels.
const PIXEL_TOLERANCE: f64 = 0.5;

/// The `key=value` lines of a file.
struct Fields<'a> {
    file: &'a Path,
    values: BTreeMap<&'a str, &'a str>,
}

impl<'a> Fields<'a> {
    fn parse(text: &'a str, file: &'a Path) -> Result<Self, CalibError> {
        let mut values = BTreeMap::new();
        let mut lines = BTreeMap::new();
        for (index, line) in text.lines().enumerate() {
            let line_no = index + 1;
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let Some((key, value)) = line.split_once('=') else {
                return Err(field_error(
                    file,
                    format!("line {line_no}"),
                    format!("expected key=value, got '{line}'"),
                ));
            };
            let key = key.trim();
            if let Some(first) = lines.insert(key, line_no) {
                return Err(field_error(
                    file,
                    key,
                    format!("given twice (lines {first} and {line_no})"),
                ));
            }
            values.insert(key, value.trim());
        }
        Ok(Self { file, values })
    }

    fn raw(&self, key: &str) -> Result<&'a str, CalibError> {
        self.values
            .get(key)
            .copied()
            .ok_or_else(|| field_error(self.file, key, "missing"))
    }

    fn number(&self, key: &str) -> Result<f64, CalibError> {
        parse_finite(self.file, key, self.raw(key)?)
    }

    fn optional_number(&self, key: &str) -> Result<Option<f64>, CalibError> {
        self.values
            .get(key)
            .map(|raw| parse_finite(self.file, key, raw))
            .transpose()
    }

    /// A positive whole number (image size, number of disparities).
    fn count(&self, key: &str) -> Result<u32, CalibError> {
        let raw = self.raw(key)?;
        match raw.parse::<u32>() {
            Ok(n) if n > 0 => Ok(n),
            _ => Err(field_error(
                self.file,
                key,
                format!("expected a positive whole number, got '{raw}'"),
            )),
        }
    }

    /// A 3x3 intrinsic matrix `[fx 0 cx; 0 fy cy; 0 0 1]`.
    fn intrinsics(&self, key: &str) -> Result<Intrinsics, CalibError> {
        let raw = self.raw(key)?;
        let error = |message: String| field_error(self.file, key, message);
        let inner = raw
            .strip_prefix('[')
            .and_then(|r| r.strip_suffix(']'))
            .ok_or_else(|| error(format!("expected [f 0 cx; 0 f cy; 0 0 1], got '{raw}'")))?;
        let tokens: Vec<&str> = inner
            .split(|c: char| c == ';' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .collect();
        if tokens.len() != 9 {
            return Err(error(format!("expected 9 numbers, got {}", tokens.len())));
        }
        let mut m = [0.0; 9];
        for (slot, token) in m.iter_mut().zip(&tokens) {
            *slot = parse_finite(self.file, key, token)?;
        }
        // The camera model has no skew, and a calib.txt matrix always has this form: anything else
        // is a corrupt file, not a camera to approximate.
        if m[1] != 0.0 || m[3] != 0.0 || m[6] != 0.0 || m[7] != 0.0 || m[8] != 1.0 {
            return Err(error(format!(
                "expected the form [f 0 cx; 0 f cy; 0 0 1] (no skew), got '{raw}'"
            )));
        }
        Ok(Intrinsics {
            fx: m[0],
            fy: m[4],
            cx: m[2],
            cy: m[5],
        })
    }
}

fn parse_finite(file: &Path, key: &str, raw: &str) -> Result<f64, CalibError> {
    match raw.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(field_error(
            file,
            key,
            format!("expected a finite number, got '{raw}'"),
        )),
    }
}

/// Parses a Middlebury `calib.txt`. `origin` names the file in errors.
///
/// The left camera (`cam0`) is placed at the vehicle origin looking along +z, the right one
/// (`cam1`) at x = `baseline` / 1000 m; each keeps its own intrinsics. The depth range is what the
/// disparity range maps to: `[vmin, vmax]` widened by 2 px (clamped at 0) when the file has them,
/// else `[0, ndisp]`. The scene has no road.
pub fn parse_middlebury(text: &str, origin: &Path) -> Result<Calibration, CalibError> {
    let fields = Fields::parse(text, origin)?;
    let k0 = fields.intrinsics("cam0")?;
    let k1 = fields.intrinsics("cam1")?;
    let doffs = fields.number("doffs")?;
    let baseline_mm = fields.number("baseline")?;
    let width = fields.count("width")?;
    let height = fields.count("height")?;
    let ndisp = f64::from(fields.count("ndisp")?);
    let vmin = fields.optional_number("vmin")?;
    let vmax = fields.optional_number("vmax")?;
    // Not needed for the geometry, but a garbled value there means a garbled file.
    for key in ["isint", "dyavg", "dymax"] {
        fields.optional_number(key)?;
    }

    let field_of = |side: Side, part: Part| match part {
        Part::Width => "width".to_string(),
        Part::Height => "height".to_string(),
        Part::Position => "baseline".to_string(),
        Part::Intrinsics(_) | Part::Distortion | Part::Rotation => match side {
            Side::Left => "cam0 (left camera)".to_string(),
            Side::Right => "cam1 (right camera)".to_string(),
        },
    };
    let camera = |side, intrinsics, x| {
        let (distortion, rotation) = (Distortion::default(), Matrix3::identity());
        let centre = Point3::new(x, 0.0, 0.0);
        let camera = Camera::new(width, height, intrinsics, distortion, rotation, centre);
        build_camera(origin, side, camera, field_of)
    };
    let baseline = baseline_mm / 1000.0;
    let rig = StereoRig {
        left: camera(Side::Left, k0, 0.0)?,
        right: camera(Side::Right, k1, baseline)?,
    };

    if (k0.fx - k1.fx).abs() > PIXEL_TOLERANCE
        || (k0.fy - k1.fy).abs() > PIXEL_TOLERANCE
        || (k0.cy - k1.cy).abs() > PIXEL_TOLERANCE
    {
        return Err(field_error(
            origin,
            "cam1",
            format!(
                "a rectified pair has the same f and cy in both cameras, but cam0 has fx {}, fy {}, \
                 cy {} and cam1 has fx {}, fy {}, cy {}",
                k0.fx, k0.fy, k0.cy, k1.fx, k1.fy, k1.cy
            ),
        ));
    }
    let cx_offset = k1.cx - k0.cx;
    if (doffs - cx_offset).abs() > PIXEL_TOLERANCE {
        return Err(field_error(
            origin,
            "doffs",
            format!(
                "doffs is {doffs} px but cam1's cx - cam0's cx is {cx_offset:.3} px; they must agree"
            ),
        ));
    }
    if baseline_mm <= 0.0 {
        return Err(field_error(
            origin,
            "baseline",
            format!("must be a positive number of millimetres (got {baseline_mm})"),
        ));
    }

    let depth_range = depth_range(origin, baseline * k0.fx, doffs, ndisp, vmin, vmax)?;
    check_rig(
        origin,
        &rig,
        Some(depth_range),
        RigFields {
            baseline: "baseline",
            overlap: "baseline",
            position: ["baseline", "baseline"],
        },
    )?;
    Ok(Calibration {
        rig,
        depth_range: Some(depth_range),
        has_road: false,
        right_row_offset_px: 0.0,
        measure_rows: true,
        mount_assumed: Some(crate::calib::MIDDLEBURY_MOUNT),
    })
}

/// Depth range from the disparity range, with `bf` = baseline (m) * f (px).
fn depth_range(
    file: &Path,
    bf: f64,
    doffs: f64,
    ndisp: f64,
    vmin: Option<f64>,
    vmax: Option<f64>,
) -> Result<(f64, f64), CalibError> {
    if let (Some(lo), Some(hi)) = (vmin, vmax)
        && lo > hi
    {
        return Err(field_error(
            file,
            "vmin",
            format!("vmin ({lo}) must not exceed vmax ({hi})"),
        ));
    }
    let d_near = vmax.map_or(ndisp, |v| v + VMIN_VMAX_MARGIN_PX);
    let d_far = vmin.map_or(0.0, |v| (v - VMIN_VMAX_MARGIN_PX).max(0.0));
    let near_field = if vmax.is_some() { "vmax" } else { "ndisp" };
    if d_near + doffs <= MIN_TOTAL_DISPARITY_PX {
        return Err(field_error(
            file,
            near_field,
            format!(
                "the largest disparity searched ({d_near} px) plus doffs ({doffs} px) must exceed \
                 {MIN_TOTAL_DISPARITY_PX} px for any depth to be finite"
            ),
        ));
    }
    let range = (
        bf / (d_near + doffs),
        bf / (d_far + doffs).max(MIN_TOTAL_DISPARITY_PX),
    );
    let far_field = if vmin.is_some() { "vmin" } else { "doffs" };
    check_depth_range(file, range, near_field, far_field)?;
    Ok(range)
}
