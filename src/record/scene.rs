//! flyd's values as Foxglove's schemas: timestamps, the cameras' calibrations and poses in
//! `base_link`, the flies as a point cloud, the road and the obstacle as a scene update.

use std::time::Duration;

use foxglove::schemas::{
    CameraCalibration, Color, CubePrimitive, FrameTransform, PackedElementField, PointCloud, Pose,
    Quaternion, SceneEntity, SceneUpdate, Timestamp, Vector3, packed_element_field::NumericType,
};

use super::FLY_FLOATS;
use flyd_core::geometry::Camera;

pub(super) fn timestamp_of(ns: u64) -> Timestamp {
    Timestamp::new(
        u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
        (ns % 1_000_000_000) as u32,
    )
}

/// flyd's vehicle frame (x right, y up, z forward) into `base_link` (x forward, y left, z up).
pub(super) fn base_link(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x: z, y: -x, z: y }
}

/// A camera's calibration as `foxglove.CameraCalibration` (plumb_bob distortion).
pub(super) fn calibration(camera: &Camera, frame_id: &str) -> CameraCalibration {
    let k = camera.intrinsics();
    let d = camera.distortion();
    CameraCalibration {
        timestamp: None,
        frame_id: frame_id.into(),
        width: camera.width(),
        height: camera.height(),
        distortion_model: "plumb_bob".into(),
        d: vec![d.k1, d.k2, d.p1, d.p2, d.k3],
        k: vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![
            k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    }
}

/// Where `camera`'s optical frame (`frame_id`: x right, y down, z forward) is in `base_link`.
pub(super) fn camera_pose(camera: &Camera, frame_id: &str) -> FrameTransform {
    use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
    // vehicle (x right, y up, z forward) -> base_link (x forward, y left, z up)
    let a = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    let (m, _) = camera.camera_from_vehicle_affine();
    // p_cam = M p_vehicle + t, p_vehicle = A^T b: b = A M^T p_cam + A c.
    let r = a * m.transpose();
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let c = camera.centre();
    FrameTransform {
        timestamp: None,
        parent_frame_id: "base_link".into(),
        child_frame_id: frame_id.into(),
        translation: Some(base_link(c.x, c.y, c.z)),
        rotation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// The flies as a point cloud in `base_link`: x, y, z, fitness, warning (float32).
pub(super) fn point_cloud(t: u64, points: &[f32]) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * 4);
    for fly in points.chunks_exact(FLY_FLOATS) {
        let [x, y, z, fitness, warning] = [fly[0], fly[1], fly[2], fly[3], fly[4]];
        for v in [z, -x, y, fitness, warning] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let field = |name: &str, i: u32| PackedElementField {
        name: name.into(),
        offset: 4 * i,
        r#type: NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(timestamp_of(t)),
        frame_id: "base_link".into(),
        pose: Some(identity_pose()),
        point_stride: 4 * FLY_FLOATS as u32,
        fields: vec![
            field("x", 0),
            field("y", 1),
            field("z", 2),
            field("fitness", 3),
            field("warning", 4),
        ],
        data: data.into(),
    }
}

pub(super) fn identity_pose() -> Pose {
    Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// The road estimate (a 3.5 m x 40 m slab, tilted as measured) and the obstacle (a box from
/// its bottom to its top, red when confirmed, amber otherwise).
pub(super) fn scene(
    t: u64,
    event: &super::topics::PerceptionEvent,
    obstacle: Option<[f64; 4]>,
    confirmed: bool,
) -> SceneUpdate {
    let ts = Some(timestamp_of(t));
    let lifetime = foxglove::schemas::Duration::try_from(Duration::from_millis(500)).ok();
    // Pitch about the lateral axis (y in base_link), roll about forward (x), small angles.
    let pitch = -event.road_slope_z.atan();
    let roll = event.road_slope_x.atan();
    let (sp, cp) = ((pitch / 2.0).sin(), (pitch / 2.0).cos());
    let (sr, cr) = ((roll / 2.0).sin(), (roll / 2.0).cos());
    let road = CubePrimitive {
        pose: Some(Pose {
            position: Some(base_link(
                0.0,
                event.road_height_m + 20.0 * event.road_slope_z,
                20.0,
            )),
            orientation: Some(Quaternion {
                x: sr * cp,
                y: cr * sp,
                z: -sr * sp,
                w: cr * cp,
            }),
        }),
        size: Some(Vector3 {
            x: 40.0,
            y: 3.5,
            z: 0.02,
        }),
        color: Some(Color {
            r: 0.3,
            g: 0.6,
            b: 1.0,
            a: if event.road_measured { 0.35 } else { 0.15 },
        }),
    };
    let mut entities = vec![SceneEntity {
        timestamp: ts,
        frame_id: "base_link".into(),
        id: "road".into(),
        lifetime,
        cubes: vec![road],
        ..SceneEntity::default()
    }];
    if let Some([distance, lateral, bottom, top]) = obstacle {
        let height = (top - bottom).max(0.1);
        entities.push(SceneEntity {
            timestamp: ts,
            frame_id: "base_link".into(),
            id: "obstacle".into(),
            lifetime,
            cubes: vec![CubePrimitive {
                pose: Some(Pose {
                    position: Some(base_link(lateral, bottom + height / 2.0, distance + 0.25)),
                    ..identity_pose()
                }),
                size: Some(Vector3 {
                    x: 0.5,
                    y: 0.8,
                    z: height,
                }),
                color: Some(if confirmed {
                    Color {
                        r: 1.0,
                        g: 0.1,
                        b: 0.1,
                        a: 0.7,
                    }
                } else {
                    Color {
                        r: 1.0,
                        g: 0.7,
                        b: 0.0,
                        a: 0.5,
                    }
                }),
            }],
            ..SceneEntity::default()
        });
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_point_cloud_is_in_base_link() {
        let cloud = point_cloud(5, &[1.0, 0.5, 10.0, 3.0, 0.25]);
        let f: Vec<f32> = cloud
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(f, vec![10.0, -1.0, 0.5, 3.0, 0.25]);
        assert_eq!(cloud.point_stride, 20);
    }

    #[test]
    fn a_camera_pose_maps_its_optical_axis_forward_and_its_centre_into_base_link() {
        let rig = crate::mock::mock_rig(320, 240).expect("rig");
        let tf = camera_pose(&rig.left, "left");
        let q = tf.rotation.expect("rotation");
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q.w, q.x, q.y, q.z,
        ));
        // The optical axis (camera z) points along base_link x (forward), image down along -z.
        let forward = q * nalgebra::Vector3::z();
        let down = q * nalgebra::Vector3::y();
        assert!(forward.x > 0.95, "{forward:?}");
        assert!(down.z < -0.95, "{down:?}");
        let t = tf.translation.expect("translation");
        let c = rig.left.centre();
        assert_eq!((t.x, t.y, t.z), (c.z, -c.x, c.y));
    }
}
