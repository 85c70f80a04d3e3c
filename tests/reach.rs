//! The search follows the speed (`perception::range`): at a speed whose SLOW distance lies
//! beyond the configured ranges, the flies and the obstacle stage reach it, up to what the rig
//! searches; without a trusted motion the configured ranges stand.

use flyd::mock::MockStereo;
use flyd_core::decision::{Command, DecisionConfig, DecisionMode};
use flyd_core::engine::EngineParams;
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::kinematics::VehicleMotion;
use flyd_core::perception::{Perception, PerceptionConfig};

const W: u32 = 640;
const H: u32 = 480;

/// hw-mock's empty road at 640x480 (f B = 156 px m: the search is capped at 78 m).
fn perception(decision: Option<DecisionConfig>) -> (Perception, MockStereo) {
    let scenario = hw_mock::Scenario::by_name("empty-road").expect("scenario");
    let mock = MockStereo::new(scenario, W, H).expect("mock");
    let p = Perception::new(
        mock.rig(),
        EngineParams {
            flies: 1000,
            seed: 3,
            ..EngineParams::default()
        },
        PerceptionConfig::default(),
    )
    .expect("perception");
    let p = match decision {
        Some(d) => p.with_reach(d),
        None => p,
    };
    (p, mock)
}

/// Runs `frames` new frames of 5 generations each from frame `from`, each preceded by
/// `motion` (if any); returns the farthest fly depth drawn (ahead, metres).
fn drive(
    p: &mut Perception,
    mock: &mut MockStereo,
    from: u32,
    frames: u32,
    motion: Option<VehicleMotion>,
) -> f32 {
    let mut farthest = 0.0f32;
    for i in from..from + frames {
        let (l, r) = mock.frame(i).expect("render");
        let frame = StereoFrame::new(
            PreparedImage::from_pixels(W, H, PixelFormat::Rgb8, l).expect("left"),
            PreparedImage::from_pixels(W, H, PixelFormat::Rgb8, r).expect("right"),
            u64::from(i),
        );
        if let Some(m) = motion {
            p.follow(m, 1.0 / 30.0);
        }
        for _ in 0..5 {
            p.step(&frame).expect("step");
            farthest = p
                .engine()
                .population()
                .z
                .iter()
                .fold(farthest, |a, &z| a.max(z));
        }
    }
    farthest
}

fn at_kmh(kmh: f64) -> Option<VehicleMotion> {
    Some(VehicleMotion {
        speed: kmh / 3.6,
        yaw_rate: 0.0,
    })
}

#[test]
fn the_search_reaches_the_slow_distance_at_the_measured_speed() {
    let decision = DecisionConfig::default();
    let slow_43 = decision.reach(Command::Slow, 43.0 / 3.6);
    assert!(slow_43 > 50.0, "{slow_43}");
    let (mut p, mut mock) = perception(Some(decision));
    assert_eq!(p.search_far(), 40.0);
    // 30 km/h: the SLOW distance (29.3 m) is within the configured 40 m.
    drive(&mut p, &mut mock, 0, 3, at_kmh(30.0));
    assert_eq!(p.search_far(), 40.0);
    // 43 km/h: every range reaches the SLOW distance, and new flies are drawn out there.
    let farthest = drive(&mut p, &mut mock, 3, 10, at_kmh(43.0));
    assert!(
        (p.search_far() - slow_43).abs() < 1e-9,
        "{}",
        p.search_far()
    );
    let params = p.engine().params();
    assert_eq!(params.max_depth, p.search_far());
    assert_eq!(params.roi.map(|r| r.max_ahead), Some(p.search_far()));
    assert!(f64::from(farthest) > 42.0, "farthest fly {farthest} m");
    // 120 km/h: capped at what the rig searches (2 px of disparity).
    drive(&mut p, &mut mock, 13, 1, at_kmh(120.0));
    assert!((p.search_far() - 78.0).abs() < 1e-6, "{}", p.search_far());
    // A frame without a trusted motion: the configured ranges again.
    drive(&mut p, &mut mock, 14, 1, None);
    assert_eq!(p.search_far(), 40.0);
    assert_eq!(p.engine().params().max_depth, 40.0);
}

#[test]
fn without_a_reach_or_in_the_global_warning_mode_the_configured_ranges_stand() {
    let global = DecisionConfig {
        mode: DecisionMode::GlobalWarning,
        ..DecisionConfig::default()
    };
    for decision in [None, Some(global)] {
        let (mut p, mut mock) = perception(decision);
        let farthest = drive(&mut p, &mut mock, 0, 6, at_kmh(43.0));
        assert_eq!(p.search_far(), 40.0, "{decision:?}");
        assert!(
            f64::from(farthest) <= 40.5,
            "{decision:?}: farthest fly {farthest} m"
        );
    }
}
