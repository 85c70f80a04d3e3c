//! A recorded drive's motion from KITTI odometry poses (`poses.txt`): one line a frame, the
//! 3x4 row-major transform from the left camera at that frame to the world (the first
//! frame's camera), camera axes x right, y down, z forward.
//!
//! Between two frames the vehicle moved by `T_i^-1 T_(i+1)`: its translation's length over
//! the frame interval is the speed, its rotation about the camera's vertical axis over the
//! interval the yaw rate (positive turning left, as `VCU_Motion` reports it). The camera is
//! taken as looking along the vehicle's axis (KITTI's are, within a degree).

use flyd_core::kinematics::VehicleMotion;
use nalgebra::{Matrix3, Vector3};

/// Why a poses file cannot be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PosesError {
    #[error("line {line}: {found} numbers, a pose is 12 (3x4, row-major)")]
    Count { line: usize, found: usize },
    #[error("line {line}: {text:?} is not a number")]
    Number { line: usize, text: String },
    #[error("line {line}: the rotation is not one (|R^T R - I| = {error:.3})")]
    NotRotation { line: usize, error: f64 },
}

/// A camera pose: rotation and position in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub rotation: Matrix3<f64>,
    pub position: Vector3<f64>,
}

/// The poses of `text` (blank lines skipped).
pub fn parse(text: &str) -> Result<Vec<Pose>, PosesError> {
    let mut poses = Vec::new();
    for (n, l) in text.lines().enumerate() {
        let line = n + 1;
        if l.trim().is_empty() {
            continue;
        }
        let values: Vec<f64> = l
            .split_whitespace()
            .map(|t| {
                t.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| PosesError::Number {
                        line,
                        text: t.to_string(),
                    })
            })
            .collect::<Result<_, _>>()?;
        if values.len() != 12 {
            return Err(PosesError::Count {
                line,
                found: values.len(),
            });
        }
        let m = |r: usize, c: usize| values[4 * r + c];
        let rotation = Matrix3::from_fn(m);
        let error = (rotation.transpose() * rotation - Matrix3::identity())
            .abs()
            .max();
        if error > 1e-3 {
            return Err(PosesError::NotRotation { line, error });
        }
        poses.push(Pose {
            rotation,
            position: Vector3::new(m(0, 3), m(1, 3), m(2, 3)),
        });
    }
    Ok(poses)
}

/// The vehicle's motion from pose `a` to pose `b`, `dt` seconds later.
pub fn motion_between(a: &Pose, b: &Pose, dt: f64) -> VehicleMotion {
    if !(dt.is_finite() && dt > 0.0) {
        return VehicleMotion::STANDSTILL;
    }
    // b in a's camera frame.
    let rotation = a.rotation.transpose() * b.rotation;
    let moved = a.rotation.transpose() * (b.position - a.position);
    // Forward is +z; reversing is a negative speed.
    let speed = moved.norm().copysign(moved.z) / dt;
    // b's forward axis seen from a: turning left points it to -x (x right, y down).
    let forward = rotation.column(2);
    let yaw = (-forward.x).atan2(forward.z);
    VehicleMotion {
        speed,
        yaw_rate: yaw / dt,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose_line(yaw: f64, x: f64, z: f64) -> String {
        // Turning left by `yaw` about the camera's y (down) axis: forward goes to -x.
        let (s, c) = yaw.sin_cos();
        let r = [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]];
        format!(
            "{} {} {} {x} {} {} {} 0 {} {} {} {z}\n",
            r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2]
        )
    }

    #[test]
    fn speed_and_yaw_rate_from_two_poses() {
        // 1.2 m ahead in 0.1 s: 12 m/s; then a left turn of 0.01 rad while moving 1.2 m.
        let text = pose_line(0.0, 0.0, 0.0)
            + &pose_line(0.0, 0.0, 1.2)
            + "\n"
            + &pose_line(0.01, -0.006, 2.4);
        let p = parse(&text).expect("parses");
        assert_eq!(p.len(), 3);
        let m = motion_between(&p[0], &p[1], 0.1);
        assert!(
            (m.speed - 12.0).abs() < 1e-9 && m.yaw_rate.abs() < 1e-12,
            "{m:?}"
        );
        let m = motion_between(&p[1], &p[2], 0.1);
        assert!((m.yaw_rate - 0.1).abs() < 1e-9, "{m:?}");
        assert!((m.speed - 12.0).abs() < 0.01, "{m:?}");
        // Backwards is a negative speed.
        let m = motion_between(&p[1], &p[0], 0.1);
        assert!((m.speed + 12.0).abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn bad_lines_are_named() {
        assert_eq!(
            parse("1 2 3\n"),
            Err(PosesError::Count { line: 1, found: 3 })
        );
        assert!(matches!(
            parse(&(pose_line(0.0, 0.0, 0.0) + "1 0 0 0 0 1 0 0 0 0 x 0\n")),
            Err(PosesError::Number { line: 2, .. })
        ));
        assert!(matches!(
            parse("2 0 0 0 0 1 0 0 0 0 1 0\n"),
            Err(PosesError::NotRotation { line: 1, .. })
        ));
    }

    /// The real drive: KITTI odometry 06's first poses, ~43 km/h, straight.
    #[test]
    fn the_kitti_drive_is_12_metres_a_second_and_straight() {
        let text = "1.000000e+00 1.197625e-11 1.704638e-10 0.000000e+00 1.197625e-11 1.000000e+00 3.562503e-10 -1.110223e-16 1.704638e-10 3.562503e-10 1.000000e+00 2.220446e-16
9.999995e-01 7.196824e-04 -6.870876e-04 -1.401751e-02 -7.197717e-04 9.999997e-01 -1.295633e-04 -2.820321e-02 6.869946e-04 1.300585e-04 9.999998e-01 1.198998e+00";
        let p = parse(text).expect("parses");
        let m = motion_between(&p[0], &p[1], 0.1);
        assert!((m.speed * 3.6 - 43.2).abs() < 0.3, "{m:?}");
        assert!(m.yaw_rate.abs() < 0.01, "{m:?}");
    }
}
