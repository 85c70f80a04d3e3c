//! KITTI calibration files: the raw dataset's `calib_cam_to_cam.txt` and the odometry
//! benchmark's `calib.txt`.
//!
//! ```text
//! S_rect_02: 1.242000e+03 3.750000e+02                     calib_cam_to_cam.txt: rectified
//! P_rect_02: 7.215377e+02 0 6.095593e+02 4.485728e+01 ...   3x4, row-major
//! K_02: ... D_02: ... R_02: ... T_02: ... S_02: ...         the same camera unrectified
//! P0: 7.188560e+02 0 6.071928e+02 0 ...                    odometry calib.txt (no size)
//! ```
//!
//! Cameras are numbered as KITTI does: 0/1 the grey pair, 2/3 the colour pair (default). A
//! rectified camera's `P = K [I | t]` gives its intrinsics and, in the rectified frame of camera
//! 0, its optical centre `-t`; an unrectified one has `x_i = R_0i x_0 + T_0i` and distortion
//! `D_0i` (k1 k2 p1 p2 k3). Rectified images need the `P` matrices, raw ones the `K/D/R/T`.
//!
//! Placement: KITTI's recording car, camera 0 on the centre line 1.65 m above the road, level
//! (Geiger et al., "Vision meets Robotics: The KITTI Dataset", IJRR 2013); a rig TOML's
//! `[import]` with a `[mount]` places the pair anywhere else. The image size comes from
//! `S_rect_0N`/`S_0N`, or from the caller when the file has none (odometry files).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Point3, Vector3};

use super::{CalibError, Calibration, Part, RigFields, Side, build_camera, check_rig, field_error};
use crate::geometry::{Camera, Distortion, Intrinsics, StereoRig};

/// Height of KITTI's camera 0 above the road, metres.
pub const KITTI_CAMERA_HEIGHT: f64 = 1.65;

/// What to take from a KITTI file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KittiImport {
    /// Left and right camera numbers (0-3); (2, 3), the colour pair, by default.
    pub cameras: (u8, u8),
    /// Use the rectified `P` matrices (true, the default: KITTI's `sync` and benchmark images
    /// are rectified) or the unrectified `K/D/R/T` (raw `extract` images).
    pub rectified: bool,
    /// Image size, when the file records none (it is checked when it does).
    pub image_size: Option<(u32, u32)>,
}

impl Default for KittiImport {
    fn default() -> Self {
        Self {
            cameras: (2, 3),
            rectified: true,
            image_size: None,
        }
    }
}

/// Whether `text` looks like a KITTI calibration file: `P_rect_0N:` / `K_0N:` lines of
/// `calib_cam_to_cam.txt`, or the odometry file's `P0:` and `P1:`.
pub fn looks_like_kitti(text: &str) -> bool {
    let keys: Vec<&str> = text
        .lines()
        .filter_map(|l| l.split_once(':').map(|(k, _)| k.trim()))
        .collect();
    keys.iter()
        .any(|k| k.starts_with("P_rect_0") || k.starts_with("K_0"))
        || (keys.contains(&"P0") && keys.contains(&"P1"))
}

/// The `key: numbers` lines of a file (comments after `#`; non-numeric values, such as
/// `calib_time`, are kept as errors reported only if the key is used).
struct Keys<'a> {
    file: &'a Path,
    values: BTreeMap<&'a str, Result<Vec<f64>, String>>,
}

impl<'a> Keys<'a> {
    fn parse(text: &'a str, file: &'a Path) -> Result<Self, CalibError> {
        let mut values = BTreeMap::new();
        for (index, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let Some((key, rest)) = line.split_once(':') else {
                return Err(field_error(
                    file,
                    format!("line {}", index + 1),
                    format!("expected 'key: values', got '{line}'"),
                ));
            };
            let numbers: Result<Vec<f64>, String> = rest
                .split_whitespace()
                .map(|t| match t.parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(v),
                    _ => Err(format!("'{t}' is not a finite number")),
                })
                .collect();
            if values.insert(key.trim(), numbers).is_some() {
                return Err(field_error(file, key.trim(), "given twice"));
            }
        }
        Ok(Self { file, values })
    }

    /// The `n` numbers of `key`.
    fn numbers(&self, key: &str, n: usize) -> Result<&[f64], CalibError> {
        match self.values.get(key) {
            None => Err(field_error(self.file, key, "missing")),
            Some(Err(message)) => Err(field_error(self.file, key, message.clone())),
            Some(Ok(v)) if v.len() != n => Err(field_error(
                self.file,
                key,
                format!("expected {n} numbers, got {}", v.len()),
            )),
            Some(Ok(v)) => Ok(v),
        }
    }

    fn has(&self, key: &str) -> bool {
        self.values.contains_key(key)
    }
}

/// One camera as the file describes it, in the frame of camera 0 (x right, y down, z forward).
struct KittiCamera {
    intrinsics: Intrinsics,
    distortion: Distortion,
    /// Camera 0's frame -> this camera's frame.
    rotation: Matrix3<f64>,
    /// Optical centre in camera 0's frame.
    centre: Vector3<f64>,
    size: Option<(u32, u32)>,
}

/// Parses a KITTI calibration file and places its pair at KITTI's mount (see the module docs).
pub fn parse_kitti(
    text: &str,
    origin: &Path,
    opts: &KittiImport,
) -> Result<Calibration, CalibError> {
    let keys = Keys::parse(text, origin)?;
    let (l, r) = opts.cameras;
    if l > 3 || r > 3 || l == r {
        return Err(field_error(
            origin,
            "cameras",
            format!("KITTI cameras are 0-3, two different ones; got ({l}, {r})"),
        ));
    }
    let odometry = !keys.has("P_rect_00") && keys.has("P0");
    let read = |n: u8| {
        if !opts.rectified {
            unrectified(&keys, n)
        } else if odometry {
            rectified(&keys, &format!("P{n}"), None)
        } else {
            rectified(&keys, &format!("P_rect_0{n}"), Some(format!("S_rect_0{n}")))
        }
    };
    let (left, right) = (read(l)?, read(r)?);
    let size = match (left.size.or(right.size), opts.image_size) {
        (Some(file), Some(given)) if file != given => {
            return Err(field_error(
                origin,
                "image size",
                format!(
                    "the file says {}x{}, the images are {}x{}",
                    file.0, file.1, given.0, given.1
                ),
            ));
        }
        (Some(size), _) | (None, Some(size)) => size,
        (None, None) => {
            return Err(field_error(
                origin,
                "image size",
                "the file records none: give width and height in the rig TOML's [import]",
            ));
        }
    };
    let key_of = |side: Side| match side {
        Side::Left => l,
        Side::Right => r,
    };
    let field_of = |side: Side, part: Part| {
        let n = key_of(side);
        let prefix = match (opts.rectified, odometry) {
            (true, true) => format!("P{n}"),
            (true, false) => format!("P_rect_0{n}"),
            (false, _) => match part {
                Part::Distortion => format!("D_0{n}"),
                Part::Rotation => format!("R_0{n}"),
                Part::Position => format!("T_0{n}"),
                _ => format!("K_0{n}"),
            },
        };
        match part {
            Part::Width | Part::Height => "image size".to_string(),
            _ => prefix,
        }
    };
    // Camera 0's frame is the forward-looking frame of a level camera at KITTI's mount.
    let mount = Point3::new(0.0, KITTI_CAMERA_HEIGHT, 0.0);
    let camera = |side: Side, c: &KittiCamera| {
        let centre = mount + Vector3::new(c.centre.x, -c.centre.y, c.centre.z);
        let cam = Camera::new(
            size.0,
            size.1,
            c.intrinsics,
            c.distortion,
            c.rotation,
            centre,
        );
        build_camera(origin, side, cam, field_of)
    };
    let rig = StereoRig {
        left: camera(Side::Left, &left)?,
        right: camera(Side::Right, &right)?,
    };
    check_rig(
        origin,
        &rig,
        None,
        RigFields {
            baseline: "cameras",
            overlap: "cameras",
            position: ["cameras", "cameras"],
        },
    )?;
    Ok(Calibration {
        rig,
        depth_range: None,
        has_road: true,
        right_row_offset_px: 0.0,
        measure_rows: true,
        mount_assumed: Some(crate::calib::KITTI_MOUNT),
    })
}

/// Rectified camera from its 3x4 `P = K [I | t]` (the optical centre is `-t`); the size from
/// `size_key` if given.
fn rectified(
    keys: &Keys<'_>,
    key: &str,
    size_key: Option<String>,
) -> Result<KittiCamera, CalibError> {
    let p = keys.numbers(key, 12)?;
    let error = |message: &str| field_error(keys.file, key, message);
    let (fx, skew, cx, fy, cy) = (p[0], p[1], p[2], p[5], p[6]);
    if p[4] != 0.0 || p[8] != 0.0 || p[9] != 0.0 || p[10] != 1.0 || skew != 0.0 {
        return Err(error(
            "not a rectified camera: expected [fx 0 cx tx; 0 fy cy ty; 0 0 1 tz]",
        ));
    }
    if !(fx > 0.0 && fy > 0.0) {
        return Err(error("fx and fy must be positive"));
    }
    let tz = p[11];
    let ty = (p[7] - cy * tz) / fy;
    let tx = (p[3] - cx * tz) / fx;
    let size = size_key
        .filter(|k| keys.has(k))
        .map(|k| image_size(keys, &k))
        .transpose()?;
    Ok(KittiCamera {
        intrinsics: Intrinsics { fx, fy, cx, cy },
        distortion: Distortion::default(),
        rotation: Matrix3::identity(),
        centre: -Vector3::new(tx, ty, tz),
        size,
    })
}

/// Unrectified camera `n` from `K_0n`, `D_0n`, `R_0n`, `T_0n` and `S_0n`.
fn unrectified(keys: &Keys<'_>, n: u8) -> Result<KittiCamera, CalibError> {
    let k = keys.numbers(&format!("K_0{n}"), 9)?;
    let d = keys.numbers(&format!("D_0{n}"), 5)?;
    let r = Matrix3::from_row_slice(keys.numbers(&format!("R_0{n}"), 9)?);
    let t = Vector3::from_column_slice(keys.numbers(&format!("T_0{n}"), 3)?);
    let size_key = format!("S_0{n}");
    Ok(KittiCamera {
        intrinsics: Intrinsics {
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
        },
        distortion: Distortion {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
        },
        rotation: r,
        // x_n = R x_0 + T: the optical centre (x_n = 0) is at -R^T T.
        centre: -(r.transpose() * t),
        size: keys
            .has(&size_key)
            .then(|| image_size(keys, &size_key))
            .transpose()?,
    })
}

/// An `S_*` size line: two positive whole numbers written as floats (`1.242000e+03`).
fn image_size(keys: &Keys<'_>, key: &str) -> Result<(u32, u32), CalibError> {
    let s = keys.numbers(key, 2)?;
    let whole = |v: f64| (v > 0.0 && v.fract() == 0.0 && v <= 65535.0).then_some(v as u32);
    match (whole(s[0]), whole(s[1])) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(field_error(
            keys.file,
            key,
            format!("expected a size in whole pixels, got {} {}", s[0], s[1]),
        )),
    }
}
