//! The obstacle stage's corridor follows the vehicle's predicted path
//! (`perception.obstacle.follow_path`): hw-mock's pedestrian
//! standing 4 m ahead in the lane centre, judged with the vehicle going straight, on a gentle
//! bend and on the tightest one a car turns.

use flyd::mock::MockStereo;
use flyd_core::engine::EngineParams;
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::kinematics::VehicleMotion;
use flyd_core::path::PredictedPath;
use flyd_core::perception::{Obstacle, ObstacleConfig, PathKind, Perception, PerceptionConfig};

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
    judged_with(
        motion,
        ObstacleConfig {
            follow_path: true,
            path_model: PathKind::Held,
            path_hold_s,
            ..ObstacleConfig::default()
        },
    )
}

/// [`judged`] with the obstacle stage's `config`.
fn judged_with(
    motion: Option<VehicleMotion>,
    config: ObstacleConfig,
) -> (Option<Obstacle>, PredictedPath) {
    let (perception, seen) = run("pedestrian-4m", (320, 240), 2000, config, 0..40, 3, |p| {
        if let Some(m) = motion {
            p.predict(m, 0.0);
        }
    });
    (seen.last().copied().flatten(), perception.path())
}

/// `scenario` at `size` with `flies` flies (seed 1, 30 generations of warm-up) over `frames`,
/// `per_frame` generations each, each frame given to `before` first: the perception as it
/// ended and every obstacle estimate.
fn run(
    scenario: &str,
    (w, h): (u32, u32),
    flies: usize,
    obstacle: ObstacleConfig,
    frames: std::ops::Range<u32>,
    per_frame: u32,
    mut before: impl FnMut(&mut Perception),
) -> (Perception, Vec<Option<Obstacle>>) {
    let scenario = hw_mock::Scenario::by_name(scenario).expect("scenario");
    let mut mock = MockStereo::new(scenario, w, h).expect("mock");
    let mut perception = Perception::new(
        mock.rig(),
        EngineParams {
            flies,
            seed: 1,
            ..EngineParams::default()
        },
        PerceptionConfig {
            obstacle,
            ..PerceptionConfig::default()
        },
    )
    .expect("perception")
    .with_warmup(30);
    let mut seen = Vec::new();
    for i in frames {
        let (l, r) = mock.frame(i).expect("render");
        let frame = StereoFrame::new(
            PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, l).expect("left"),
            PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, r).expect("right"),
            u64::from(i),
        );
        before(&mut perception);
        for _ in 0..per_frame {
            let report = perception.step(&frame).expect("step");
            if report.estimated {
                seen.push(report.tracked.obstacle);
            }
        }
    }
    (perception, seen)
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
    // The tightest bend (5 m radius), either way: the pedestrian's axis is 1.4 m off the path
    // at 4 m, its near side 1.15 m. In a corridor 0.9 m either side, what the vehicle drives
    // past is no obstacle; in the default 1.1 m one at most that near side is in the corridor,
    // and an obstacle found there is that side, not the pedestrian's middle.
    let narrow = ObstacleConfig {
        corridor_half_width: 0.9,
        path_hold_s: 0.0,
        ..ObstacleConfig::default()
    };
    for k in [0.2, -0.2] {
        let (sharp, path) = judged(bend(k));
        assert_eq!(path.curvature, k);
        assert!(
            sharp.is_none_or(|o| o.lateral.abs() > 1.0),
            "k = {k}: more than the near side of the pedestrian 1.4 m off the path: {sharp:?}"
        );
        let (sharp, _) = judged_with(bend(k), narrow);
        assert!(
            sharp.is_none(),
            "k = {k}: the pedestrian 1.15 m off the path is in a 0.9 m corridor: {sharp:?}"
        );
    }
    // With the held model, a turn held for no time at all (the motion over 0 s each frame):
    // distances and offsets stay straight ahead, and what is off the arc of the moment is
    // still no obstacle (an obstacle must be on both); the pedestrian's near side, 1.15 m off
    // that arc, is inside its 1.2 m corridor, and an obstacle found there is that side (0.25
    // m left of the straight path), not the pedestrian's middle.
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
    assert!(
        sharp.is_none_or(|o| o.lateral < -0.15),
        "off the arc of the moment, more than its near side: {sharp:?}"
    );
}

/// The nearest obstacle of `bend-30-to-pedestrian` (a pedestrian on the centre line of a 60 m
/// left bend, 640x480, 5000 flies, seed 1) over frames 40-90 (29 m along the bend to 15 m: 1.9
/// m left of straight ahead there), 5 generations a frame, the flies moved with the bend's
/// motion and the frame then given to `corridor`: what that corridor finds on the bend.
fn nearest_on_the_bend(
    config: ObstacleConfig,
    corridor: impl Fn(&mut Perception),
) -> Option<Obstacle> {
    let scenario = hw_mock::Scenario::by_name("bend-30-to-pedestrian").expect("scenario");
    let motion = VehicleMotion {
        speed: scenario.speed_at(40),
        yaw_rate: scenario.yaw_rate_at(40),
    };
    let dt = 1.0 / scenario.fps();
    let (_, seen) = run(scenario.name(), (640, 480), 5000, config, 40..91, 5, |p| {
        p.predict(motion, dt);
        corridor(p);
    });
    seen.into_iter()
        .flatten()
        .min_by(|a, b| a.distance.total_cmp(&b.distance))
}

/// A motion fault (the yaw rate not trusted) on a 60 m bend at 30 km/h: the corridor is the
/// fan of every path up to `fault_yaw_rate` (0.15 rad/s, a 56 m radius at the assumed
/// 30 km/h), which holds the pedestrian on the bend (3.3 m left of straight ahead 20 m
/// along); the straight box does not (the flies moved alike in both: only the corridor
/// differs). Both hold the guard rail, straight ahead 25 m away.
#[test]
fn a_motion_fault_fans_the_corridor_out_over_the_paths_the_vehicle_could_take() {
    let assumed = 30.0 / 3.6;
    let fan = nearest_on_the_bend(ObstacleConfig::default(), |p| p.motion_unknown(assumed))
        .expect("the pedestrian on the bend is in the fan");
    assert!(
        (14.0..21.0).contains(&fan.distance) && fan.lateral.abs() < 0.5,
        "the pedestrian on the bend: {fan:?}"
    );
    let straight_box = ObstacleConfig {
        follow_path: false,
        ..ObstacleConfig::default()
    };
    let straight = nearest_on_the_bend(straight_box, |_| {});
    assert!(
        straight.is_none_or(|o| o.distance > 21.0),
        "the straight box holds what is on the bend: {straight:?}"
    );
}

/// The fan holds the straight box: the pedestrian standing 4 m ahead is an obstacle on a
/// motion fault as without one.
#[test]
fn the_fan_is_never_less_than_the_straight_box() {
    let (straight, _) = judged(None);
    let straight = straight.expect("the pedestrian ahead");
    let fault = |p: &mut Perception| p.motion_unknown(30.0 / 3.6);
    let config = ObstacleConfig::default();
    let (perception, seen) = run("pedestrian-4m", (320, 240), 2000, config, 0..40, 3, fault);
    let last = seen.last().copied();
    assert!(perception.fan().is_some_and(|k| (k - 0.018).abs() < 1e-3));
    let fan = last.flatten().expect("the pedestrian ahead is in the fan");
    assert!(
        (fan.distance - straight.distance).abs() < 0.3 && fan.lateral.abs() < 0.2,
        "{fan:?} against {straight:?}"
    );
}

/// A drive that starts in a bend (issue 44, item 3): with the default path model the corridor
/// bends with the vehicle's motion from the first frame that has one (the arc of the moment
/// until the curvature's change is measured), never straight while the vehicle turns; the
/// held model stays straight for its hold.
#[test]
fn a_drive_that_starts_in_a_bend_has_a_bent_corridor_from_its_first_trusted_frame() {
    let scenario = hw_mock::Scenario::by_name("bend-30").expect("scenario");
    let motion = VehicleMotion {
        speed: scenario.speed_at(0),
        yaw_rate: scenario.yaw_rate_at(0),
    };
    let k = motion.yaw_rate / motion.speed;
    assert!(
        k > 0.015,
        "bend-30 is a 60 m bend from its first frame: {k}"
    );
    let dt = 1.0 / scenario.fps();
    let first = |config: ObstacleConfig| {
        let mut paths = Vec::new();
        let (_, _) = run(scenario.name(), (320, 240), 500, config, 0..4, 1, |p| {
            paths.push(p.path_estimate());
            p.predict(motion, dt);
        });
        paths
    };
    // Before frame 0 nothing was predicted: no path (straight); from frame 1 on, the bend.
    let clothoid = first(ObstacleConfig::default());
    assert_eq!(clothoid[0], None);
    for estimate in &clothoid[1..] {
        let held = estimate.expect("a path from the first trusted motion").held;
        assert!((held.curvature - k).abs() < 1e-9, "{estimate:?}");
        assert!(held.rate.abs() < 1e-9, "a steady bend: {estimate:?}");
    }
    let held = first(ObstacleConfig {
        path_model: PathKind::Held,
        ..ObstacleConfig::default()
    });
    assert!(
        held[1..]
            .iter()
            .all(|e| e.is_some_and(|e| e.held == PredictedPath::STRAIGHT)),
        "{held:?}"
    );
}

/// `flyd bench --path`'s measure: flyd's path prediction against where a real car went.
mod bench {
    use std::path::{Path, PathBuf};

    use flyd::path_bench::{Drive, PathBenchConfig, PathReport, Row, Stage};
    use flyd_core::decision::DecisionConfig;
    use flyd_core::path::PathModel;

    fn fixture() -> Vec<Drive> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/kitti_poses");
        Drive::load(&dir).expect("the fixture's drive")
    }

    fn row<'a>(report: &'a PathReport, stage: Stage, band: &str) -> &'a Row {
        report
            .rows
            .iter()
            .find(|r| r.stage == stage && r.band == band)
            .expect("a row for every stage and band")
    }

    fn bench(
        drives: &[Drive],
        model: PathModel,
        decision: DecisionConfig,
        half: f64,
    ) -> PathReport {
        flyd::path_bench::run(
            drives,
            &PathBenchConfig {
                decision,
                half_width: half,
                model,
                yaw_noise: 0.0,
            },
        )
    }

    /// The decisions the issue's table was measured with: SLOW 1.5, STOP 4 m/s^2.
    fn before() -> DecisionConfig {
        DecisionConfig {
            slow_decel: 1.5,
            stop_decel: 4.0,
            ..DecisionConfig::default()
        }
    }

    const ARC: PathModel = PathModel::Clothoid { window: 0.0 };

    #[test]
    fn on_a_real_drive_the_arc_of_the_moment_is_right_near_and_wrong_far() {
        // KITTI odometry 03 (83 s, residential, 18-34 km/h).
        let r = bench(&fixture(), ARC, before(), 1.2);
        assert_eq!(r.drives, 1);
        assert!((r.seconds - 83.0).abs() < 1.0, "{}", r.seconds);
        let ttc = row(&r, Stage::Ttc1s, "all");
        let stop = row(&r, Stage::Stop, "all");
        let slow = row(&r, Stage::Slow, "all");
        assert!(ttc.moments > 500, "{ttc:?}");
        // About one second ahead the arc holds; at the SLOW distance it does not.
        assert!(ttc.on_path_inside_pct > 99.0, "{ttc:?}");
        assert!(
            stop.on_path_inside_pct <= ttc.on_path_inside_pct,
            "{stop:?}"
        );
        assert!(slow.on_path_inside_pct < 80.0, "{slow:?}");
        assert!(
            slow.offset_p95_m > 2.0 * stop.offset_p95_m,
            "{slow:?} {stop:?}"
        );
        // Every band is reported, empty ones as such (03 never reaches 40 km/h).
        let fast = row(&r, Stage::Stop, "50+");
        assert_eq!(fast.moments, 0);
        assert!(fast.on_path_inside_pct.is_nan());
    }

    /// Staged decisions: SLOW (partial braking) at 6 m/s^2, STOP (full braking) at 9 m/s^2.
    fn staged() -> DecisionConfig {
        DecisionConfig {
            slow_decel: 6.0,
            stop_decel: 9.0,
            ..DecisionConfig::default()
        }
    }

    #[test]
    fn at_the_staged_distances_the_clothoid_corridor_holds_on_a_real_drive() {
        let r = bench(
            &fixture(),
            PathModel::Clothoid { window: 0.3 },
            staged(),
            1.1,
        );
        for stage in [Stage::Stop, Stage::Slow] {
            let row = row(&r, stage, "all");
            assert!(row.moments > 500, "{row:?}");
            assert!(row.on_path_inside_pct >= 99.0, "{row:?}");
            assert!(row.beside_inside_pct[1] <= 1.0, "{row:?}");
            assert!(row.offset_p99_m < 1.0, "{row:?}");
        }
    }

    fn shared() -> Option<PathBuf> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti_poses");
        if dir.is_dir() {
            Some(dir)
        } else {
            eprintln!(
                "SKIP: {} is not there: the issue's table over 38 minutes of KITTI \
                 trajectories is not reproduced (the fixture's tests above still run)",
                dir.display()
            );
            None
        }
    }

    /// The table the path issue measured (arc of the moment, +-1.2 m, SLOW 1.5 and STOP 4
    /// m/s^2, moments above 18 km/h): the bench measures what it says within a few points
    /// (the issue's yaw rate of a moment was taken from the poses slightly differently).
    #[test]
    fn the_bench_reproduces_the_issues_table_on_all_of_kitti_poses() {
        let Some(dir) = shared() else { return };
        let drives = Drive::load(&dir).expect("kitti_poses");
        let r = bench(&drives, ARC, before(), 1.2);
        assert_eq!(r.drives, 10);
        let check = |stage, median: f64, outside: f64, beside: f64| {
            let row = row(&r, stage, "all");
            assert!((18_800..19_200).contains(&row.moments), "{row:?}");
            assert!((row.median_distance_m - median).abs() < 0.3, "{row:?}");
            assert!(
                (100.0 - row.on_path_inside_pct - outside).abs() < 3.0,
                "{row:?}: {outside} % outside"
            );
            assert!(
                (row.beside_inside_pct[1] - beside).abs() < 2.0,
                "{row:?}: {beside} % inside"
            );
        };
        check(Stage::Stop, 17.5, 14.5, 17.4);
        check(Stage::Slow, 35.5, 61.0, 33.0);
        check(Stage::Ttc1s, 9.3, 0.4, 0.8);
    }

    /// Over all of kitti_poses: the default path model keeps more of what is on the real path
    /// and less of what is beside it in the STOP corridor than the held path it replaced; and
    /// the staged decisions of docs/path.md (clothoid, +-1.1 m, SLOW 6 and STOP 9 m/s^2) meet
    /// the path issue's targets.
    #[test]
    fn the_default_path_beats_the_held_one_and_the_staged_decisions_meet_the_targets() {
        let Some(dir) = shared() else { return };
        let drives = Drive::load(&dir).expect("kitti_poses");
        let obstacle = flyd_core::perception::ObstacleConfig::default();
        let decision = DecisionConfig::default();
        let half = obstacle.corridor_half_width;
        let default = bench(&drives, obstacle.path(), decision, half);
        let held = bench(&drives, PathModel::Held { hold: 2.0 }, decision, half);
        let (d, h) = (
            row(&default, Stage::Stop, "all"),
            row(&held, Stage::Stop, "all"),
        );
        assert!(
            d.on_path_inside_pct > h.on_path_inside_pct + 2.0,
            "{d:?} vs {h:?}"
        );
        assert!(
            d.beside_inside_pct[1] < h.beside_inside_pct[1] - 1.0,
            "{d:?} vs {h:?}"
        );
        let staged = bench(&drives, PathModel::Clothoid { window: 0.3 }, staged(), 1.1);
        let stop = row(&staged, Stage::Stop, "all");
        assert!(stop.on_path_inside_pct >= 99.0, "{stop:?}");
        assert!(stop.beside_inside_pct[1] <= 1.0, "{stop:?}");
        let slow = row(&staged, Stage::Slow, "all");
        assert!(slow.on_path_inside_pct >= 90.0, "{slow:?}");
        assert!(slow.beside_inside_pct[1] <= 5.0, "{slow:?}");
    }
}
