//! A rig file's `[import]`: a calibration in another format (OpenCV, KITTI, Middlebury) read
//! as its format says, then placed on the vehicle by the file's `[mount]`.

use super::{
    CalibError, ImportToml, KittiImport, Matrix3, MountToml, OpenCvImport, OpenCvToml, Path,
    Point3, RigFields, StereoRig, check_rig, field_error, finite_angles, kitti, opencv, paired,
    rotation_from_angles,
};

/// An `[import]`: the file read as its format says, then placed by `mount` if given; and
/// what was assumed of the mount when `mount` gives no position
/// ([`crate::calib::Calibration::mount_assumed`]).
pub(super) fn import_any(
    file: &Path,
    import: &ImportToml,
    mount: Option<MountToml>,
    depth_range: Option<(f64, f64)>,
) -> Result<(StereoRig, Option<&'static str>), CalibError> {
    let size = paired(
        file,
        (import.width, "import.width"),
        (import.height, "import.height"),
    )?;
    let path = file
        .parent()
        .unwrap_or_else(|| Path::new(""))
        .join(&import.file);
    let as_import = |error: CalibError| CalibError::Import {
        file: file.to_path_buf(),
        field: "import.file".to_string(),
        error: Box::new(error),
    };
    let text = crate::textfile::read(&path).map_err(|error| {
        as_import(CalibError::Io {
            file: path.clone(),
            error,
        })
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let format = crate::calib::Format::of(&path, text);
    let only = |key: &str, given: bool, wanted: crate::calib::Format| {
        if given && format != Some(wanted) {
            Err(field_error(file, key, "only for that format's files"))
        } else {
            Ok(())
        }
    };
    only(
        "import.cameras",
        import.cameras.is_some(),
        crate::calib::Format::Kitti,
    )?;
    only(
        "import.rectified",
        import.rectified.is_some(),
        crate::calib::Format::Kitti,
    )?;
    let unit = import.translation_unit.is_some();
    only(
        "import.translation_unit",
        unit,
        crate::calib::Format::OpenCv,
    )?;
    let imported = match format {
        Some(crate::calib::Format::Kitti) => {
            let defaults = KittiImport::default();
            let opts = KittiImport {
                cameras: import.cameras.map_or(defaults.cameras, |[l, r]| (l, r)),
                rectified: import.rectified.unwrap_or(defaults.rectified),
                image_size: size,
            };
            kitti::parse_kitti(text, &path, &opts)
        }
        Some(crate::calib::Format::OpenCv) => {
            let opts = OpenCvImport {
                translation_unit: import.translation_unit.unwrap_or_default(),
                image_size: size,
                ..OpenCvImport::default()
            };
            crate::calib::parse_opencv_yaml(text, &path, &opts)
        }
        Some(crate::calib::Format::Middlebury) => {
            if mount.as_ref().is_none_or(|m| m.position.is_none()) {
                return Err(field_error(
                    file,
                    "mount.position",
                    "missing: a Middlebury calib.txt does not say where the cameras are",
                ));
            }
            crate::calib::parse_middlebury(text, &path)
        }
        Some(crate::calib::Format::Rig) => {
            return Err(field_error(
                file,
                "import.file",
                "a rig TOML cannot import another",
            ));
        }
        None => Err(CalibError::UnknownFormat { file: path.clone() }),
    }
    .map_err(as_import)?;
    let assumed = if mount.as_ref().is_some_and(|m| m.position.is_some()) {
        None
    } else {
        imported.mount_assumed
    };
    let Some(mount) = mount else {
        return Ok((imported.rig, assumed));
    };
    let (centre, rotation) = mount_pose(file, &mount, imported.rig.left.centre())?;
    let rig = imported
        .rig
        .placed(centre, rotation)
        .map_err(|error| CalibError::Camera {
            file: file.to_path_buf(),
            field: "mount".to_string(),
            error,
        })?;
    check_rig(
        file,
        &rig,
        depth_range,
        RigFields {
            baseline: "import.file",
            overlap: "mount",
            position: ["mount", "mount"],
        },
    )?;
    Ok((rig, assumed))
}

/// The left camera's pose a `[mount]` gives: its position (`default` if none) and orientation.
fn mount_pose(
    file: &Path,
    mount: &MountToml,
    default: Point3<f64>,
) -> Result<(Point3<f64>, Matrix3<f64>), CalibError> {
    let (centre, [pitch, yaw, roll]) = mount_position_angles(file, mount, default)?;
    Ok((centre, rotation_from_angles(pitch, yaw, roll)))
}

/// A `[mount]`'s position (`default` if none) and its pitch, yaw and roll in degrees, checked
/// finite.
fn mount_position_angles(
    file: &Path,
    mount: &MountToml,
    default: Point3<f64>,
) -> Result<(Point3<f64>, [f64; 3]), CalibError> {
    let centre = match mount.position {
        Some(p) if p.iter().any(|v| !v.is_finite()) => {
            return Err(field_error(
                file,
                "mount.position",
                format!("must be finite numbers of metres (got {p:?})"),
            ));
        }
        Some(p) => Point3::from(p),
        None => default,
    };
    let mount_key = |name: &str| format!("mount.{name}");
    let angles = finite_angles(
        file,
        &mount_key,
        [
            ("pitch_deg", mount.pitch_deg),
            ("yaw_deg", mount.yaw_deg),
            ("roll_deg", mount.roll_deg),
        ],
    )?;
    Ok((centre, angles))
}

pub(super) fn imported_rig(
    file: &Path,
    import: &OpenCvToml,
    mount: MountToml,
    depth_range: Option<(f64, f64)>,
) -> Result<StereoRig, CalibError> {
    let defaults = OpenCvImport::default();
    let (left_position, [pitch_deg, yaw_deg, roll_deg]) =
        mount_position_angles(file, &mount, defaults.left_position)?;
    let image_size = paired(
        file,
        (import.width, "opencv.width"),
        (import.height, "opencv.height"),
    )?;
    let opts = OpenCvImport {
        translation_unit: import.translation_unit.unwrap_or_default(),
        image_size,
        left_position,
        pitch_deg,
        yaw_deg,
        roll_deg,
    };
    let yaml_path = file
        .parent()
        .unwrap_or_else(|| Path::new(""))
        .join(&import.file);
    let text = crate::textfile::read(&yaml_path).map_err(|e| {
        field_error(
            file,
            "opencv.file",
            format!("cannot read {}: {e}", yaml_path.display()),
        )
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    opencv::build_rig(text, &yaml_path, &opts, depth_range).map_err(|error| CalibError::Import {
        file: file.to_path_buf(),
        field: "opencv.file".to_string(),
        error: Box::new(error),
    })
}
