//! flyd's values as Foxglove's schemas: timestamps, the cameras' calibrations and poses in
//! `base_link`, the flies as a point cloud, the road and the obstacle as a scene update.

use std::time::Duration;

use foxglove::schemas::{
    CameraCalibration, Color, CubePrimitive, FrameTransform, LinePrimitive, PackedElementField,
    Point3, PointCloud, Pose, Quaternion, SceneEntity, SceneUpdate, Timestamp, Vector3,
    line_primitive, packed_element_field::NumericType,
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

/// How far ahead the scene draws the corridor's path, metres.
const PATH_DRAWN_M: f64 = 40.0;

/// The road estimate (a 3.5 m x 40 m slab, tilted as measured), the path the corridor
/// followed (a line on the road, 40 m along it) and the obstacle (a box from its bottom to its
/// top, red when confirmed, amber otherwise; on the path: `distance` along it, `lateral` from
/// it).
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
    let path = flyd_core::path::PredictedPath {
        curvature: event.path_curvature.unwrap_or(0.0),
        rate: event.path_curvature_rate.unwrap_or(0.0),
    };
    // The road's height under a vehicle-frame point.
    let road_y =
        |x: f64, z: f64| event.road_height_m + event.road_slope_z * z + event.road_slope_x * x;
    let points = (0..=(PATH_DRAWN_M as u32) / 2)
        .map(|i| {
            let (x, z) = path.point(2.0 * f64::from(i));
            let v = base_link(x, road_y(x, z) + 0.02, z);
            Point3 {
                x: v.x,
                y: v.y,
                z: v.z,
            }
        })
        .collect();
    entities.push(SceneEntity {
        timestamp: ts,
        frame_id: "base_link".into(),
        id: "path".into(),
        lifetime,
        lines: vec![LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: Some(identity_pose()),
            thickness: 0.1,
            scale_invariant: false,
            points,
            color: Some(Color {
                r: 0.2,
                g: 0.9,
                b: 0.4,
                a: if event.path_curvature.is_some() {
                    0.8
                } else {
                    0.3
                },
            }),
            colors: Vec::new(),
            indices: Vec::new(),
        }],
        ..SceneEntity::default()
    });
    if let Some([distance, lateral, bottom, top]) = obstacle {
        let height = (top - bottom).max(0.1);
        // Its near face `distance` along the path, `lateral` right of it, turned with it.
        let along = distance + 0.25;
        let heading = path.effective_curvature(along) * along;
        let (x, z) = path.point_at(along, lateral);
        entities.push(SceneEntity {
            timestamp: ts,
            frame_id: "base_link".into(),
            id: "obstacle".into(),
            lifetime,
            cubes: vec![CubePrimitive {
                pose: Some(Pose {
                    position: Some(base_link(x, bottom + height / 2.0, z)),
                    // Turned left by `heading` about base_link's z (up).
                    orientation: Some(Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: (heading / 2.0).sin(),
                        w: (heading / 2.0).cos(),
                    }),
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

    fn event(path_curvature: Option<f64>) -> super::super::topics::PerceptionEvent {
        super::super::topics::PerceptionEvent {
            seq: 1,
            t_ns: 1,
            generation: 1,
            warming_up: false,
            global_warning: 0.0,
            obstacle_m: None,
            candidate_m: Some(20.0),
            candidate_lateral_m: Some(0.0),
            speed: 8.0,
            latency: 0.0,
            road_height_m: 0.0,
            road_slope_z: 0.0,
            road_slope_x: 0.0,
            road_measured: true,
            matched: 1.0,
            generation_us: 100.0,
            path_curvature,
            path_curvature_now: path_curvature,
            path_curvature_rate: None,
            search_far_m: Some(40.0),
            candidate_speed_mps: None,
            candidate_speed_sigma: None,
            obstacle_speed_mps: None,
            candidate_lateral_speed_mps: None,
            entering_s: None,
        }
    }

    #[test]
    fn the_path_is_drawn_and_the_obstacle_stands_on_it() {
        let at = |k: Option<f64>| {
            let update = scene(1, &event(k), Some([20.0, 0.0, 0.0, 1.7]), true);
            let path = update
                .entities
                .iter()
                .find(|e| e.id == "path")
                .expect("path");
            let end = *path.lines[0].points.last().expect("points");
            let obstacle = update.entities.iter().find(|e| e.id == "obstacle");
            let pose = obstacle.expect("obstacle").cubes[0].pose.expect("pose");
            (end, pose.position.expect("position"))
        };
        // Straight: the line runs 40 m forward, the obstacle 20.25 m ahead on it.
        let (end, p) = at(None);
        assert!((end.x - 40.0).abs() < 1e-9 && end.y.abs() < 1e-9, "{end:?}");
        assert!((p.x - 20.25).abs() < 1e-9 && p.y.abs() < 1e-9, "{p:?}");
        // A 50 m left bend: both bend left (+y in base_link): 20.25 m along the arc is
        // 4 m left of the straight line.
        let (end, p) = at(Some(0.02));
        assert!(end.y > 14.0, "{end:?}");
        assert!(
            (p.y - 4.05).abs() < 0.05 && (p.x - 19.7).abs() < 0.1,
            "{p:?}"
        );
    }
}
