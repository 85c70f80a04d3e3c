//! The simulated vehicle: flyd's camera model plugged into the `hw-mock` renderer.
//!
//! Scenes are ray-cast through [`Camera::ray_from_pixel`], the exact inverse of the projection
//! the fly engine uses, distortion included, so a fly placed on a rendered surface projects onto
//! that surface's pixels in both images. Frames, units and determinism are hw-mock's: vehicle
//! frame in metres (x right, y up from the road, z forward), RGB8 images, per-pixel ground-truth
//! z, and bytes that depend only on (scenario, frame index, rig, sensor model).
//!
//! Cost: [`MockStereo::new`] precomputes two ray tables and static backgrounds (a fraction of a
//! second at 640x480); afterwards a frame pair costs a few milliseconds when the scene is
//! unchanged and a few more when obstacles moved (`cargo run --release --example mock_timing`).

pub mod camera;
pub mod vehicle;

use hw_mock::{CameraRenderer, RayCamera, RenderError, Scenario, SensorModel};
use nalgebra::Point3;

use flyd_core::geometry::{
    Camera, CameraError, Distortion, Intrinsics, StereoRig, rotation_from_angles,
};

/// A flyd camera as hw-mock's renderer sees it: the rays of its model.
pub struct Rays<'a>(pub &'a Camera);

impl RayCamera for Rays<'_> {
    fn size(&self) -> (u32, u32) {
        (self.0.width(), self.0.height())
    }

    fn ray(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])> {
        let (o, d) = self.0.ray_from_pixel(u, v)?;
        Some(([o.x, o.y, o.z], [d.x, d.y, d.z]))
    }
}

/// Height of the simulated cameras' optical centres above the road, metres.
pub const MOCK_CAMERA_HEIGHT: f64 = 1.3;
/// Distance between the simulated cameras' optical centres, metres.
pub const MOCK_BASELINE: f64 = 0.30;
/// Downward pitch of both simulated cameras, degrees.
pub const MOCK_PITCH_DEG: f64 = 5.0;

/// The stereo rig of the simulated vehicle at `width` x `height` pixels: both cameras 1.3 m above
/// the road at z = 0, optical centres at x = -0.15 (left) and +0.15 (right), pitched 5 degrees
/// down, fx = fy = 0.8125 * width (about 63 degrees of horizontal field of view), principal point
/// slightly off centre and mild barrel distortion, so that the distortion path of the camera
/// model is exercised rather than bypassed. Fails only for sizes [`Camera::new`] rejects.
pub fn mock_rig(width: u32, height: u32) -> Result<StereoRig, CameraError> {
    let (w, h) = (f64::from(width), f64::from(height));
    let f = 0.8125 * w;
    let k = Intrinsics {
        fx: f,
        fy: f,
        // A few pixels off centre, as calibrated real cameras are.
        cx: 0.5 * (w - 1.0) + 0.004 * w,
        cy: 0.5 * (h - 1.0) - 0.003 * h,
    };
    let distortion = Distortion {
        k1: -0.05,
        k2: 0.01,
        p1: 0.0005,
        p2: -0.0003,
        k3: 0.0,
    };
    let rotation = rotation_from_angles(MOCK_PITCH_DEG, 0.0, 0.0);
    let half = 0.5 * MOCK_BASELINE;
    let camera = |x: f64| {
        Camera::new(
            width,
            height,
            k,
            distortion,
            rotation,
            Point3::new(x, MOCK_CAMERA_HEIGHT, 0.0),
        )
    };
    Ok(StereoRig {
        left: camera(-half)?,
        right: camera(half)?,
    })
}

/// A rig like a vehicle's, for what the mock rig cannot resolve (its 0.30 m baseline judges
/// about 18 m; a STOP at 50 km/h needs 33): KITTI's, the cameras level 1.65 m above the road,
/// 0.54 m apart, 1242x375 pixels, a 721.5 px focal length, principal point (609.6, 172.9) and
/// no distortion (KITTI's images are rectified). Fails only for sizes [`Camera::new`] rejects.
pub fn vehicle_rig() -> Result<StereoRig, CameraError> {
    let k = Intrinsics {
        fx: VEHICLE_FOCAL_PX,
        fy: VEHICLE_FOCAL_PX,
        cx: 609.56,
        cy: 172.85,
    };
    let half = 0.5 * VEHICLE_BASELINE;
    let camera = |x: f64| {
        Camera::new(
            VEHICLE_SIZE.0,
            VEHICLE_SIZE.1,
            k,
            Distortion::default(),
            rotation_from_angles(0.0, 0.0, 0.0),
            Point3::new(x, VEHICLE_CAMERA_HEIGHT, 0.0),
        )
    };
    Ok(StereoRig {
        left: camera(-half)?,
        right: camera(half)?,
    })
}

/// [`vehicle_rig`]'s image size, baseline, focal length and height.
pub const VEHICLE_SIZE: (u32, u32) = (1242, 375);
pub const VEHICLE_BASELINE: f64 = 0.54;
pub const VEHICLE_FOCAL_PX: f64 = 721.54;
pub const VEHICLE_CAMERA_HEIGHT: f64 = 1.65;

/// Why the mock stereo feed failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MockError {
    #[error("mock camera")]
    Camera(#[from] CameraError),
    #[error("mock render")]
    Render(#[from] RenderError),
    #[error("the rig's cameras differ in size ({left:?} vs {right:?})")]
    SizeMismatch { left: (u32, u32), right: (u32, u32) },
}

/// A scenario rendered through a stereo rig: the mock replacement for two synchronised cameras.
pub struct MockStereo {
    scenario: Scenario,
    rig: StereoRig,
    sensor: SensorModel,
    left: CameraRenderer,
    right: CameraRenderer,
    left_rgb: Vec<u8>,
    right_rgb: Vec<u8>,
    left_depth: Vec<f32>,
    ground_truth: bool,
    /// Whether `left_depth` belongs to the last frame rendered.
    depth_current: bool,
}

impl std::fmt::Debug for MockStereo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MockStereo")
            .field("scenario", &self.scenario.name())
            .field("size", &self.size())
            .field("sensor", &self.sensor)
            .field("ground_truth", &self.ground_truth)
            .finish_non_exhaustive()
    }
}

impl MockStereo {
    /// The scenario through [`mock_rig`] at the given size with the default sensor model.
    pub fn new(scenario: Scenario, width: u32, height: u32) -> Result<Self, MockError> {
        Self::with_rig(scenario, mock_rig(width, height)?, SensorModel::default())
    }

    /// The scenario through any rig (the left camera is camera 0 of the sensor model, the right
    /// camera 1).
    pub fn with_rig(
        scenario: Scenario,
        rig: StereoRig,
        sensor: SensorModel,
    ) -> Result<Self, MockError> {
        let (l, r) = (Rays(&rig.left).size(), Rays(&rig.right).size());
        if l != r {
            return Err(MockError::SizeMismatch { left: l, right: r });
        }
        let left = CameraRenderer::new(&Rays(&rig.left))?;
        let right = CameraRenderer::new(&Rays(&rig.right))?;
        let pixels = l.0 as usize * l.1 as usize;
        Ok(Self {
            scenario,
            rig,
            sensor,
            left,
            right,
            left_rgb: vec![0; pixels * 3],
            right_rgb: vec![0; pixels * 3],
            left_depth: Vec::new(),
            ground_truth: false,
            depth_current: false,
        })
    }

    /// Also produce the left image's ground-truth depth with each frame (costs a 1.2 MB copy
    /// per frame at 640x480, so it is off by default).
    pub fn set_ground_truth(&mut self, enabled: bool) {
        self.ground_truth = enabled;
        let (w, h) = self.size();
        let pixels = w as usize * h as usize;
        if enabled && self.left_depth.len() != pixels {
            self.left_depth = vec![0.0; pixels];
        }
        self.depth_current = false;
    }

    /// Renders frame `index` of the scenario: (left, right) RGB8 images, `width * height * 3`
    /// bytes each. Indices past the scenario's end keep its last scene (with fresh noise).
    pub fn frame(&mut self, index: u32) -> Result<(&[u8], &[u8]), MockError> {
        let scene = self.scenario.scene_at(index);
        self.render_scene(&scene, index)
    }

    /// Renders `scene` as frame `index` (the frame number keys the sensor noise): what
    /// [`MockStereo::frame`] does with the scenario's scene, for a scene made elsewhere (a
    /// closed loop's, rendered from where its vehicle really is).
    pub fn render_scene(
        &mut self,
        scene: &hw_mock::Scene,
        index: u32,
    ) -> Result<(&[u8], &[u8]), MockError> {
        self.depth_current = false;
        let depth = self.ground_truth.then_some(self.left_depth.as_mut_slice());
        self.left
            .render(scene, &self.sensor, index, 0, &mut self.left_rgb, depth)?;
        self.right
            .render(scene, &self.sensor, index, 1, &mut self.right_rgb, None)?;
        self.depth_current = self.ground_truth;
        Ok((&self.left_rgb, &self.right_rgb))
    }

    /// Ground-truth depth (vehicle-frame z per pixel, `f32::INFINITY` for sky) of the last
    /// frame's left image, if ground truth is enabled and a frame has been rendered since.
    pub fn left_depth(&self) -> Option<&[f32]> {
        self.depth_current.then_some(self.left_depth.as_slice())
    }

    pub fn rig(&self) -> &StereoRig {
        &self.rig
    }

    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    pub fn sensor(&self) -> &SensorModel {
        &self.sensor
    }

    /// Image size (width, height) of both cameras.
    pub fn size(&self) -> (u32, u32) {
        self.left.size()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rig_matches_its_description() {
        let rig = mock_rig(640, 480).expect("valid");
        assert!((rig.baseline() - 0.30).abs() < 1e-12);
        assert_eq!(rig.left.centre(), Point3::new(-0.15, 1.3, 0.0));
        assert!((rig.left.intrinsics().fx - 520.0).abs() < 1e-12);
        // The horizon (a far point at camera height) lies about f * tan(5 deg) above centre.
        let far = rig
            .left
            .pixel_from_vehicle(&Point3::new(-0.15, 1.3, 1e4))
            .expect("in front");
        let expected = rig.left.intrinsics().cy - 520.0 * 5f64.to_radians().tan();
        assert!((far.y - expected).abs() < 1.0, "{} vs {expected}", far.y);
        assert!(matches!(mock_rig(8, 8), Err(CameraError::TooSmall { .. })));
    }

    /// Both cameras see the whole corridor from 2.2 m on (its sides set the bound): the
    /// pedestrians of the scenarios, 3.7 m and farther, are judged from their first sighting.
    #[test]
    fn the_mock_rig_judges_obstacles_from_about_two_metres() {
        use flyd_core::perception::{ObstacleConfig, judgeable_distance};
        let rig = mock_rig(640, 480).expect("valid");
        let d = judgeable_distance(&rig, &ObstacleConfig::default(), 1.0);
        assert!((2.0..2.6).contains(&d), "{d}");
        // Half the width: the same field of view, the same distance within a step.
        let small = judgeable_distance(
            &mock_rig(320, 240).expect("valid"),
            &ObstacleConfig::default(),
            1.0,
        );
        assert!((small - d).abs() < 0.11, "{small} vs {d}");
        // A wider corridor is seen whole only farther away.
        let wide = ObstacleConfig {
            corridor_half_width: 2.0,
            ..ObstacleConfig::default()
        };
        assert!(judgeable_distance(&rig, &wide, 1.0) > d + 1.0);
    }

    #[test]
    fn mock_stereo_can_move_to_a_capture_thread() {
        fn send<T: Send>() {}
        send::<MockStereo>();
    }

    #[test]
    fn frames_are_deterministic_and_sized() {
        let scenario = Scenario::by_name("pedestrian-steps-in").expect("exists");
        let mut a = MockStereo::new(scenario.clone(), 64, 48).expect("valid");
        let mut b = MockStereo::new(scenario, 64, 48).expect("valid");
        assert!(a.left_depth().is_none());
        let (l, r) = a.frame(40).expect("renders");
        assert_eq!(l.len(), 64 * 48 * 3);
        assert_ne!(
            l, r,
            "the cameras see different views and have different sensors"
        );
        let (l, r) = (l.to_vec(), r.to_vec());
        let (l2, r2) = b.frame(40).expect("renders");
        assert_eq!((l.as_slice(), r.as_slice()), (l2, r2));
        a.set_ground_truth(true);
        assert!(a.left_depth().is_none(), "no frame rendered since enabling");
        a.frame(41).expect("renders");
        assert_eq!(a.left_depth().map(<[f32]>::len), Some(64 * 48));
    }

    /// The fast renderer's tile culling is derived from the rays it is given; with a pitched,
    /// distorted camera it must still reproduce the uncached reference exactly.
    #[test]
    fn fast_renderer_matches_reference_through_the_distorted_rig() {
        let rig = mock_rig(96, 72).expect("valid");
        let sensor = SensorModel::default();
        let mut fast = CameraRenderer::new(&Rays(&rig.right)).expect("valid");
        let n = 96 * 72;
        for name in ["car-approaching", "pedestrian-steps-in"] {
            let scenario = Scenario::by_name(name).expect("exists");
            for frame in [0, 45, 149] {
                let scene = scenario.scene_at(frame);
                let (mut a, mut b) = (vec![0; n * 3], vec![0; n * 3]);
                hw_mock::render(&scene, &Rays(&rig.right), &sensor, frame, 1, &mut a, None)
                    .expect("renders");
                fast.render(&scene, &sensor, frame, 1, &mut b, None)
                    .expect("renders");
                assert!(a == b, "{name} frame {frame}");
            }
        }
    }

    /// The renderer and flyd's camera model agree: a pedestrian-4m surface point found by
    /// ray-casting a left pixel to its ground-truth depth projects, through the right camera's
    /// `pixel_from_vehicle`, onto right-image pixels with the same texture.
    #[test]
    fn renderer_and_camera_model_agree() {
        let (w, h) = (640u32, 480u32);
        let scenario = Scenario::by_name("pedestrian-4m").expect("exists");
        let sensor = SensorModel {
            noise_sigma: 0.0,
            ..SensorModel::default()
        };
        let rig = mock_rig(w, h).expect("valid");
        let mut stereo = MockStereo::with_rig(scenario, rig, sensor).expect("valid");
        stereo.set_ground_truth(true);
        let (left, right) = stereo.frame(0).expect("renders");
        let (left, right) = (left.to_vec(), right.to_vec());
        let depth = stereo.left_depth().expect("enabled").to_vec();
        let rig = stereo.rig().clone();

        // Centre-bottom region: the pedestrian's front at ~3.75 m.
        let near_4m = (240..440)
            .flat_map(|v| (260..380).map(move |u| (u, v)))
            .filter(|&(u, v)| (3.7..4.3).contains(&depth[(v * w + u) as usize]))
            .count();
        assert!(near_4m > 2000, "{near_4m} pixels at ~4 m");

        let r = sensor.response[1];
        let grey = |img: &[u8], i: usize| {
            (f64::from(img[3 * i]) + f64::from(img[3 * i + 1]) + f64::from(img[3 * i + 2])) / 3.0
        };
        // Bilinear sample of the right image (grey), undoing its gain and offset.
        let right_at = |x: f64, y: f64| {
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = (x - x0, y - y0);
            let (x0, y0) = (x0 as u32, y0 as u32);
            let p = |u: u32, v: u32| (grey(&right, (v * w + u) as usize) - r.offset) / r.gain;
            (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x0 + 1, y0))
                + fy * ((1.0 - fx) * p(x0, y0 + 1) + fx * p(x0 + 1, y0 + 1))
        };
        // Mean absolute difference over pedestrian pixels when the right sample is shifted by
        // `dx` pixels from where the camera model says the point projects.
        let error_at_shift = |dx: f64| {
            let (mut sum, mut n) = (0.0, 0usize);
            for v in (150..360).step_by(3) {
                for u in (280..360).step_by(2) {
                    let i = (v * w + u) as usize;
                    let z = f64::from(depth[i]);
                    if !(3.7..4.1).contains(&z) {
                        continue;
                    }
                    let (o, d) = rig
                        .left
                        .ray_from_pixel(f64::from(u), f64::from(v))
                        .expect("ray");
                    let p = o + d * ((z - o.z) / d.z);
                    let px = rig.right.pixel_from_vehicle(&p).expect("in front");
                    if !(1.0..f64::from(w) - 2.0).contains(&(px.x + dx)) {
                        continue;
                    }
                    let l = grey(&left, i);
                    if l > 230.0 {
                        continue; // would saturate in the brighter right camera
                    }
                    sum += (right_at(px.x + dx, px.y) - l).abs();
                    n += 1;
                }
            }
            assert!(n > 500, "{n} samples");
            sum / n as f64
        };
        let at_projection = error_at_shift(0.0);
        eprintln!("mean |left - right| at the model's projection: {at_projection:.2} grey levels");
        // The texture is sharp (plaid), so a bilinear sample between pixel centres differs a
        // little from the left pixel; a wrong correspondence differs a lot.
        assert!(at_projection < 4.0, "{at_projection}");
        for dx in [-3.0, -1.5, 1.5, 3.0] {
            let off = error_at_shift(dx);
            eprintln!("  shifted by {dx:+} px: {off:.2}");
            assert!(
                off > 3.0 * at_projection,
                "shift {dx}: {off} vs {at_projection}"
            );
        }
    }
}
