//! A synthetic road world with ground truth, rendered through calibrated cameras: the mock
//! hardware behind flyd's tests and demo.
//!
//! # Contract
//! - **Frames and units.** The world is given in the vehicle frame, metres: x to the right, y up
//!   from the road surface (the road is the plane y = 0), z forward. The vehicle stands still,
//!   except in the `driving*` scenarios ([`Scenario`]), where road and roadside come towards it.
//!   Images are RGB8, interleaved, row-major, `width * height * 3` bytes, pixel (u, v) with u to
//!   the right and v down. Depth ground truth is per pixel, `f32`: the vehicle-frame **z** of the
//!   surface point the pixel centre sees, `f32::INFINITY` for sky, NaN where the camera model
//!   yields no ray.
//! - **Cameras.** Rendering goes through the [`RayCamera`] trait: the caller's own calibrated
//!   model (flyd implements it for its camera, distortion included), so images are exactly what
//!   that model predicts and a fly projected through it lands where the renderer put the surface.
//! - **Stereo consistency.** Every surface's colour depends only on the surface point, never on
//!   the viewer (see [`world`]); cameras differ only through their sensor response and noise.
//! - **Determinism.** No global state, no RNG state, no clocks: the same scene, camera, sensor
//!   model, frame number and camera index always give the same bytes. Noise comes from
//!   splitmix64 hashes of (seed, frame, camera index, sample index).
//! - **Performance.** [`CameraRenderer`] precomputes rays and the static world once, caches the
//!   noise-free render of the last scene, and per frame only applies the sensor model (about a
//!   millisecond for 640x480 in release); a changed scene re-traces only the obstacles' tiles.
//!   A moving vehicle re-renders the static world each frame: 5-14 stereo pairs a second at
//!   640x480 on one core, bit for bit the reference ([`render`]); `README.md` and the
//!   `render_bench` example have the figures. See the `mock_timing` example of the flyd crate
//!   for flyd's own numbers.
//! - **Errors.** Rendering never panics: wrong buffer sizes, an unknown camera index or an
//!   invalid sensor model are [`RenderError`]s. Invalid obstacles (non-finite or degenerate) are
//!   simply not drawn.

pub mod closed_loop;
mod noise;
mod render;
mod scenario;
pub mod vehicle;
pub mod world;

pub use noise::splitmix64;
pub use render::{CameraRenderer, RenderError, Response, SensorModel, render};
pub use scenario::Scenario;
pub use world::{
    IN_LANE_MAX_RANGE, KERB_WIDTH, LANE_HALF_WIDTH, Material, Obstacle, Pattern, ROAD_HALF_WIDTH,
    Ray, Scene, roadside, roadside_at,
};

/// A calibrated camera as the renderer needs it: implemented by flyd's `geometry::Camera`, so
/// scenes are ray-cast through the very same model (distortion included) that the fly engine
/// projects through.
pub trait RayCamera {
    fn size(&self) -> (u32, u32);
    /// Ray through pixel centre (u, v) in the vehicle frame: origin and unit direction; None if
    /// the model cannot be inverted there.
    fn ray(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])>;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A level (unpitched), undistorted pinhole camera: enough to test the renderer without
    /// flyd, with projection for checking where world points land.
    struct Pinhole {
        w: u32,
        h: u32,
        f: f64,
        cx: f64,
        cy: f64,
        centre: [f64; 3],
    }

    impl Pinhole {
        fn new(x: f64) -> Self {
            Self {
                w: 160,
                h: 120,
                f: 100.0,
                cx: 79.5,
                cy: 60.0,
                centre: [x, 1.2, 0.0],
            }
        }

        /// Pixel of a vehicle-frame point (vehicle y is up, image v is down).
        fn project(&self, p: [f64; 3]) -> Option<(f64, f64)> {
            let z = p[2] - self.centre[2];
            (z > 1e-6).then(|| {
                (
                    self.cx + self.f * (p[0] - self.centre[0]) / z,
                    self.cy - self.f * (p[1] - self.centre[1]) / z,
                )
            })
        }
    }

    impl RayCamera for Pinhole {
        fn size(&self) -> (u32, u32) {
            (self.w, self.h)
        }
        fn ray(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])> {
            let d = [(u - self.cx) / self.f, -(v - self.cy) / self.f, 1.0];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            Some((self.centre, [d[0] / n, d[1] / n, d[2] / n]))
        }
    }

    fn clean_render(scene: &Scene, cam: &Pinhole, index: u8, sensor: &SensorModel) -> Vec<u8> {
        let mut rgb = vec![0; (cam.w * cam.h * 3) as usize];
        render(scene, cam, sensor, 0, index, &mut rgb, None).expect("renders");
        rgb
    }

    fn depth_of(scene: &Scene, cam: &Pinhole) -> Vec<f32> {
        let mut rgb = vec![0; (cam.w * cam.h * 3) as usize];
        let mut depth = vec![0.0; (cam.w * cam.h) as usize];
        render(
            scene,
            cam,
            &SensorModel::ideal(),
            0,
            0,
            &mut rgb,
            Some(&mut depth),
        )
        .expect("renders");
        depth
    }

    #[test]
    fn road_depth_is_the_ray_plane_intersection() {
        let cam = Pinhole::new(0.0);
        let depth = depth_of(&Scene::empty(), &cam);
        // Rows below the horizon (v > cy) in the lane, away from the roadside.
        for (u, v) in [(80u32, 100u32), (60, 119), (100, 75), (79, 61)] {
            let (o, d) = cam.ray(f64::from(u), f64::from(v)).expect("ray");
            let t = -o[1] / d[1];
            let z = o[2] + t * d[2];
            let got = f64::from(depth[(v * cam.w + u) as usize]);
            assert!((got - z).abs() < 1e-4 * z, "({u},{v}): {got} vs {z}");
        }
        // Above the horizon in the middle: sky.
        assert_eq!(depth[(10 * cam.w + 80) as usize], f32::INFINITY);
    }

    #[test]
    fn driving_brings_the_road_towards_the_cameras() {
        let cam = Pinhole::new(0.0);
        let sensor = SensorModel::ideal();
        // Depth is in the vehicle frame: the road plane is where it was (the roadside moves).
        let moved = depth_of(&Scene::driving(6.0, vec![]), &cam);
        let still = depth_of(&Scene::empty(), &cam);
        for (u, v) in [(80u32, 100u32), (60, 119), (100, 75), (79, 61)] {
            let i = (v * cam.w + u) as usize;
            assert_eq!(moved[i], still[i], "road depth at ({u},{v})");
        }
        // The road's texture is fixed to the ground: after driving half a metre every road row
        // of the image shows something else.
        let (a, b) = (
            clean_render(&Scene::empty(), &cam, 0, &sensor),
            clean_render(&Scene::driving(0.5, vec![]), &cam, 0, &sensor),
        );
        let rows_changed = (cam.h / 2 + 2..cam.h)
            .filter(|&v| {
                let row = (v * cam.w * 3) as usize..((v + 1) * cam.w * 3) as usize;
                a[row.clone()] != b[row]
            })
            .count();
        assert_eq!(
            rows_changed as u32,
            cam.h - (cam.h / 2 + 2),
            "every road row changes"
        );
        // A roadside pole 4 m ahead on the right, then 2 m after driving 2 m.
        let pole = |d: f64| {
            roadside_at(d)
                .into_iter()
                .find_map(|o| match o {
                    Obstacle::Cylinder { x, z, .. } if x == 6.2 && z < 5.0 => Some(z),
                    _ => None,
                })
                .expect("the first right pole")
        };
        assert_eq!(pole(0.0), 4.0);
        assert_eq!(pole(2.0), 2.0);
    }

    #[test]
    fn pedestrian_depth_at_its_centre() {
        let cam = Pinhole::new(0.0);
        let (u, v) = cam.project([0.0, 0.875, 4.0]).expect("in front");
        let i = (v.round() as u32 * cam.w + u.round() as u32) as usize;
        let s = Scenario::by_name("pedestrian-4m").expect("exists");
        let with = depth_of(&s.scene_at(0), &cam);
        let empty = depth_of(&Scene::empty(), &cam);
        // Body axis at 4 m, radius 0.25: the front surface is at 3.75 m.
        assert!((with[i] - 3.75).abs() < 0.01, "{}", with[i]);
        assert!(empty[i] > 5.0 && empty[i].is_finite(), "{}", empty[i]);
    }

    /// Left pixel (u, v) and right pixel (u', v) see the very same world point whenever the
    /// point's disparity is an integer; there, after undoing the right camera's gain and offset,
    /// the noise-free colours must agree up to quantisation: the two rays meet the surface within
    /// a micrometre of each other (f32 ray storage), which can tip a value that sits on a rounding
    /// boundary by one level, and the right camera's response rounds once more. Checked on the
    /// road and on a box.
    #[test]
    fn both_cameras_see_the_same_texture_at_the_same_point() {
        let (left, right) = (Pinhole::new(-0.15), Pinhole::new(0.15));
        let sensor = SensorModel {
            noise_sigma: 0.0,
            ..SensorModel::default()
        };
        let r = sensor.response[1];
        // Front face at z = f * b / d = 100 * 0.3 / 10: disparity 10 px exactly. Lifted off the
        // road so that no pixel sees a road/board tie at the contact line.
        let board = Obstacle::Box {
            min: [-1.0, 0.2, 3.0],
            max: [1.0, 2.0, 3.5],
            material: Material {
                colour: [180, 150, 120],
                pattern: Pattern::Noise {
                    cell: 0.2,
                    contrast: 0.8,
                },
                seed: 1,
            },
        };
        for scene in [Scene::empty(), Scene::with(vec![board])] {
            let l = clean_render(&scene, &left, 0, &sensor);
            let rr = clean_render(&scene, &right, 1, &sensor);
            let ld = depth_of(&scene, &left);
            let rd = depth_of(&scene, &right);
            let mut compared = 0;
            let (mut abs_sum, mut channels) = (0.0, 0usize);
            let mut seen = std::collections::HashSet::new();
            for v in 0..left.h {
                for u in 0..left.w {
                    let i = (v * left.w + u) as usize;
                    if !ld[i].is_finite() {
                        continue;
                    }
                    let (o, d) = left.ray(f64::from(u), f64::from(v)).expect("ray");
                    let t = (f64::from(ld[i]) - o[2]) / d[2];
                    let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                    let Some((ur, vr)) = right.project(p) else {
                        continue;
                    };
                    let (ui, vi) = (ur.round(), vr.round());
                    if (ur - ui).abs() > 1e-3 || (vr - vi).abs() > 1e-3 || ui < 0.0 {
                        continue;
                    }
                    let j = (vi as u32 * right.w + ui as u32) as usize;
                    if (rd[j] - ld[i]).abs() > 1e-3 * ld[i] {
                        continue; // occluded in the right view
                    }
                    for c in 0..3 {
                        if rr[3 * j + c] == 255 {
                            continue; // the brighter right camera saturated: nothing to undo
                        }
                        let undone = (f64::from(rr[3 * j + c]) - r.offset) / r.gain;
                        let lv = f64::from(l[3 * i + c]);
                        abs_sum += (undone - lv).abs();
                        channels += 1;
                        assert!(
                            (undone - lv).abs() <= 1.0 + 0.5 / r.gain + 1e-9,
                            "({u},{v}) c{c}: {undone} vs {lv} depth {} {}",
                            ld[i],
                            rd[j]
                        );
                    }
                    seen.insert(l[3 * i]);
                    compared += 1;
                }
            }
            // Plenty of points, and textured ones (not one flat colour).
            assert!(compared > 300, "{compared}");
            assert!(seen.len() > 10, "{}", seen.len());
            // Differences beyond the response's own rounding (at most 0.47) are rare.
            let mean = abs_sum / channels as f64;
            assert!(mean < 0.3, "mean |difference| {mean}");
        }
    }

    #[test]
    fn a_turned_vehicle_sees_the_road_turned_and_depth_stays_in_its_frame() {
        let cam = Pinhole::new(0.0);
        let sensor = SensorModel::ideal();
        let scene = Scene::posed(5.0, -0.7, 0.1, vec![]);
        // A pose moves points and back.
        let p = [1.5, 0.4, 12.0];
        let back = scene.vehicle_point(scene.world_point(p));
        assert!((0..3).all(|a| (back[a] - p[a]).abs() < 1e-12), "{back:?}");
        // The road plane does not move in the vehicle frame when it turns: same depths.
        let (turned, still) = (depth_of(&scene, &cam), depth_of(&Scene::empty(), &cam));
        for (u, v) in [(80u32, 100u32), (60, 119), (100, 75)] {
            let i = (v * cam.w + u) as usize;
            let (a, b) = (turned[i], still[i]);
            assert!(
                (a - b).abs() < 1e-4 * b,
                "road depth at ({u},{v}): {a} vs {b}"
            );
        }
        // A roadside pole is where the pose puts it: a ray from the eye towards its axis in
        // the vehicle frame meets it within a radius of that point, and nothing else does.
        let (px, pz, radius) = world::roadside()
            .into_iter()
            .find_map(|o| match o {
                Obstacle::Cylinder { x, z, radius, .. } if x == 6.2 && z > 12.0 => {
                    Some((x, z, radius))
                }
                _ => None,
            })
            .expect("a right pole ahead");
        let axis = scene.vehicle_point([px, 1.0, pz]);
        let eye = world::NOMINAL_EYE;
        let to = [axis[0] - eye[0], axis[1] - eye[1], axis[2] - eye[2]];
        let n = (to[0] * to[0] + to[1] * to[1] + to[2] * to[2]).sqrt();
        let ray = Ray {
            origin: eye,
            dir: [to[0] / n, to[1] / n, to[2] / n],
        };
        let seen = world::trace_scene(&ray, &scene.props(), &scene);
        assert!(
            (seen.t - (n - radius)).abs() < 0.05,
            "{} vs {}",
            seen.t,
            n - radius
        );
        assert!((f64::from(seen.depth) - ray.at(seen.t)[2]).abs() < 1e-4);
        // Unturned, the same ray misses the pole.
        let straight = Scene::driving(5.0, vec![]);
        let missed = world::trace_scene(&ray, &straight.props(), &straight);
        assert!((missed.t - (n - radius)).abs() > 0.5, "{}", missed.t);
        // The image changes with the heading.
        let a = clean_render(&Scene::posed(5.0, -0.7, 0.0, vec![]), &cam, 0, &sensor);
        let b = clean_render(&scene, &cam, 0, &sensor);
        assert!(a != b);
    }

    #[test]
    fn fast_renderer_matches_the_reference() {
        let cam = Pinhole::new(-0.15);
        let sensor = SensorModel::default();
        let mut fast = CameraRenderer::new(&cam).expect("valid");
        let scenes = [
            Scene::empty(),
            Scene::with(vec![Obstacle::pedestrian(0.3, 4.0)]),
            // Overlapping obstacles: the nearer must win in both paths.
            Scene::with(vec![
                Obstacle::car(0.0, 9.0),
                Obstacle::pedestrian(0.5, 6.0),
            ]),
            Scene::with(vec![Obstacle::car(0.5, 2.5)]),
            Scene::with(vec![Obstacle::Cylinder {
                x: 0.0,
                z: f64::NAN,
                radius: 1.0,
                height: 1.0,
                material: *Obstacle::car(0.0, 0.0).material(),
            }]),
            // Back to nothing: every tile an obstacle touched must be restored.
            Scene::empty(),
            // Driving: a new background, with and without an obstacle, and back to standing.
            Scene::driving(3.7, vec![]),
            Scene::driving(7.0, vec![Obstacle::pedestrian(0.0, 5.0)]),
            Scene::driving(7.0, vec![]),
            // Turned and off the centre line: the static world traced in the road's frame,
            // an obstacle in the vehicle's.
            Scene::posed(12.0, -0.8, 0.09, vec![]),
            Scene::posed(12.0, -0.8, 0.09, vec![Obstacle::pedestrian(0.0, 6.0)]),
            Scene::posed(13.0, -1.9, -0.05, vec![]),
            Scene::empty(),
        ];
        let n = (cam.w * cam.h) as usize;
        for (k, scene) in scenes.iter().enumerate() {
            for index in [0u8, 1] {
                let frame = 3 + k as u32;
                let (mut a, mut b) = (vec![0; n * 3], vec![0; n * 3]);
                let (mut da, mut db) = (vec![0.0; n], vec![0.0; n]);
                render(scene, &cam, &sensor, frame, index, &mut a, Some(&mut da)).expect("ok");
                fast.render(scene, &sensor, frame, index, &mut b, Some(&mut db))
                    .expect("ok");
                assert!(a == b, "scene {k} camera {index}: images differ");
                let same = da.iter().zip(&db).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(same, "scene {k}: depths differ");
            }
        }
    }

    #[test]
    fn noise_is_deterministic_per_frame_and_camera() {
        let cam = Pinhole::new(0.0);
        let scene = Scenario::by_name("pedestrian-4m")
            .expect("exists")
            .scene_at(0);
        let sensor = SensorModel::default();
        let mut r = CameraRenderer::new(&cam).expect("valid");
        let mut frame = |f: u32, cam_index: u8| {
            let mut rgb = vec![0; (cam.w * cam.h * 3) as usize];
            r.render(&scene, &sensor, f, cam_index, &mut rgb, None)
                .expect("ok");
            rgb
        };
        let a = frame(7, 0);
        assert_eq!(a, frame(7, 0));
        assert_ne!(a, frame(8, 0));
        let other_seed = SensorModel { seed: 99, ..sensor };
        let mut c = vec![0; a.len()];
        render(&scene, &cam, &other_seed, 7, 0, &mut c, None).expect("ok");
        assert_ne!(a, c);
    }

    #[test]
    fn noise_has_the_configured_sigma() {
        let cam = Pinhole::new(0.0);
        let scene = Scene::empty();
        let sigma = 2.0;
        let noisy = SensorModel {
            noise_sigma: sigma,
            ..SensorModel::ideal()
        };
        let mut r = CameraRenderer::new(&cam).expect("valid");
        let n = (cam.w * cam.h * 3) as usize;
        let (mut clean, mut out) = (vec![0; n], vec![0; n]);
        r.render(&scene, &SensorModel::ideal(), 0, 0, &mut clean, None)
            .expect("ok");
        r.render(&scene, &noisy, 1, 0, &mut out, None).expect("ok");
        let diffs: Vec<f64> = clean
            .iter()
            .zip(&out)
            .filter(|(c, _)| (10..245).contains(*c))
            .map(|(c, o)| f64::from(*o) - f64::from(*c))
            .collect();
        let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let sd =
            (diffs.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / diffs.len() as f64).sqrt();
        assert!(mean.abs() < 0.05, "{mean}");
        // Rounding to integers adds 1/12 of variance.
        let expected = (sigma * sigma + 1.0 / 12.0).sqrt();
        assert!((sd - expected).abs() < 0.05, "{sd} vs {expected}");
    }

    #[test]
    fn bad_buffers_and_inputs_are_errors() {
        let cam = Pinhole::new(0.0);
        let scene = Scene::empty();
        let s = SensorModel::default();
        let n = (cam.w * cam.h) as usize;
        let mut short = vec![0; n * 3 - 1];
        assert!(matches!(
            render(&scene, &cam, &s, 0, 0, &mut short, None),
            Err(RenderError::RgbBufferSize { .. })
        ));
        let mut rgb = vec![0; n * 3];
        let mut depth = vec![0.0; n + 1];
        assert!(matches!(
            render(&scene, &cam, &s, 0, 0, &mut rgb, Some(&mut depth)),
            Err(RenderError::DepthBufferSize { .. })
        ));
        let mut r = CameraRenderer::new(&cam).expect("valid");
        assert!(matches!(
            r.render(&scene, &s, 0, 0, &mut short, None),
            Err(RenderError::RgbBufferSize { .. })
        ));
        assert!(matches!(
            r.render(&scene, &s, 0, 2, &mut rgb, None),
            Err(RenderError::UnknownCamera(2))
        ));
        let bad = SensorModel {
            noise_sigma: f64::NAN,
            ..s
        };
        assert!(matches!(
            r.render(&scene, &bad, 0, 0, &mut rgb, None),
            Err(RenderError::BadSensor(_))
        ));
        let empty = Pinhole {
            w: 0,
            ..Pinhole::new(0.0)
        };
        assert!(matches!(
            CameraRenderer::new(&empty),
            Err(RenderError::BadCameraSize { .. })
        ));
    }
}
