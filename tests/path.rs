//! The obstacle stage's corridor follows the vehicle's predicted path
//! (`perception.obstacle.follow_path`): hw-mock's pedestrian
//! standing 4 m ahead in the lane centre, judged with the vehicle going straight, on a gentle
//! bend and on the tightest one a car turns.

use flyd::mock::MockStereo;
use flyd_core::engine::EngineParams;
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::motion::VehicleMotion;
use flyd_core::path::PredictedPath;
use flyd_core::perception::{Obstacle, ObstacleConfig, Perception, PerceptionConfig};

/// The last obstacle estimate of 40 frames of `pedestrian-4m` (320x240, 2000 flies, seed 1),
/// each frame's flies "moved" with `motion` over no time: the vehicle stands, but its path is
/// the motion's, extrapolated as soon as it is seen (`path_hold_s` 0). Returns it with the
/// path the corridor followed.
fn judged(motion: Option<VehicleMotion>) -> (Option<Obstacle>, PredictedPath) {
    judged_holding(motion, 0.0)
}

fn judged_holding(
    motion: Option<VehicleMotion>,
    path_hold_s: f64,
) -> (Option<Obstacle>, PredictedPath) {
    let scenario = hw_mock::Scenario::by_name("pedestrian-4m").expect("scenario");
    let mut mock = MockStereo::new(scenario, 320, 240).expect("mock");
    let mut perception = Perception::new(
        mock.rig(),
        EngineParams {
            flies: 2000,
            seed: 1,
            ..EngineParams::default()
        },
        PerceptionConfig {
            obstacle: ObstacleConfig {
                follow_path: true,
                path_hold_s,
                ..ObstacleConfig::default()
            },
            ..PerceptionConfig::default()
        },
    )
    .expect("perception")
    .with_warmup(30);
    let mut last = None;
    for i in 0..40u32 {
        let (l, r) = mock.frame(i).expect("render");
        let frame = StereoFrame::new(
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, l).expect("left"),
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, r).expect("right"),
            u64::from(i),
        );
        if let Some(m) = motion {
            perception.predict(m, 0.0);
        }
        for _ in 0..3 {
            let report = perception.step(&frame).expect("step");
            if report.estimated {
                last = Some(report.tracked.obstacle);
            }
        }
    }
    (last.flatten(), perception.path())
}

/// Speed and yaw rate for a path of curvature `k` (1/m, left positive).
fn bend(k: f64) -> Option<VehicleMotion> {
    Some(VehicleMotion {
        speed: 2.0,
        yaw_rate: 2.0 * k,
    })
}

#[test]
fn the_corridor_bends_with_the_vehicles_path() {
    let (straight, path) = judged(None);
    assert_eq!(path, PredictedPath::STRAIGHT);
    let straight = straight.expect("the pedestrian ahead is an obstacle going straight");
    assert!(
        (3.3..4.2).contains(&straight.distance) && straight.lateral.abs() < 0.2,
        "{straight:?}"
    );
    // A 20 m left bend: 4 m along it the path is 0.4 m left of the lane centre, the pedestrian
    // 0.4 m right of the path, still in the corridor.
    let (gentle, path) = judged(bend(0.05));
    assert_eq!(path.curvature, 0.05);
    let gentle = gentle.expect("the pedestrian is still on a gentle bend's path");
    assert!(
        (gentle.lateral - straight.lateral - 0.4).abs() < 0.15,
        "{gentle:?} against {straight:?}"
    );
    assert!(
        (gentle.distance - straight.distance).abs() < 0.3,
        "{gentle:?} against {straight:?}"
    );
    // The tightest bend (5 m radius), either way: 1.6 m off the path at 4 m, beyond the
    // corridor's 1.2 m: what the vehicle drives past is no obstacle.
    for k in [0.2, -0.2] {
        let (sharp, path) = judged(bend(k));
        assert_eq!(path.curvature, k);
        assert!(
            sharp.is_none(),
            "k = {k}: the pedestrian 1.6 m off the path is an obstacle: {sharp:?}"
        );
    }
    // A turn held for no time at all (the motion over 0 s each frame) with the default hold:
    // distances and offsets stay straight ahead, and what is off the arc of the moment is
    // still no obstacle (an obstacle must be on both).
    let hold = ObstacleConfig::default().path_hold_s;
    let (unheld, path) = judged_holding(bend(0.05), hold);
    assert_eq!(path, PredictedPath::STRAIGHT);
    let unheld = unheld.expect("the pedestrian is on both the straight and the gentle path");
    assert!(
        (unheld.lateral - straight.lateral).abs() < 0.15,
        "{unheld:?} against {straight:?}"
    );
    let (sharp, path) = judged_holding(bend(0.2), hold);
    assert_eq!(path, PredictedPath::STRAIGHT);
    assert!(sharp.is_none(), "off the arc of the moment: {sharp:?}");
}
