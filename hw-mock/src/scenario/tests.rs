use super::*;

#[test]
fn every_name_resolves() {
    for name in Scenario::names() {
        let s = Scenario::by_name(name).expect("listed names resolve");
        assert_eq!(s.name(), name);
        assert_eq!(s.fps(), 30.0);
        assert!(s.frame_count() >= 120);
    }
    assert!(Scenario::by_name("nope").is_none());
}

#[test]
fn speed_follows_the_scene() {
    let at = |n, f| Scenario::by_name(n).map(|s| s.speed_at(f));
    assert_eq!(at("pedestrian-4m", 10), Some(0.0));
    assert_eq!(at("driving", 10), Some(DRIVING_SPEED));
    assert_eq!(
        at("driving", 150),
        Some(0.0),
        "the scene holds past the end"
    );
    // The travelled distance the scenes are rendered at is the speed's integral.
    let s = Scenario::by_name("driving-to-pedestrian").expect("known");
    let travelled: f64 = (0..30).map(|f| s.speed_at(f) / FPS).sum();
    assert!((travelled - s.scene_at(30).travelled).abs() < 1e-9);
}

#[test]
fn the_lane_change_turns_left_then_right_and_ends_two_metres_left() {
    let s = Scenario::by_name("drive-30-lane-change").expect("exists");
    assert!(!s.live());
    assert_eq!(s.yaw_rate_at(0), 0.0);
    let rates: Vec<f64> = (0..s.frame_count()).map(|f| s.yaw_rate_at(f)).collect();
    let peak = rates.iter().cloned().fold(0.0, f64::max);
    let trough = rates.iter().cloned().fold(0.0, f64::min);
    assert!(
        (peak - 0.0603).abs() < 0.001 && (trough + 0.0603).abs() < 0.001,
        "{peak} {trough}"
    );
    // Left first (positive), right after.
    let first = rates.iter().position(|&r| r != 0.0).expect("turns");
    assert!(rates[first] > 0.0 && rates[first] < 1e-2);
    let end = s.scene_at(s.frame_count() - 1);
    assert!((end.lateral + 2.0).abs() < 0.05, "{end:?}");
    assert!(end.heading.abs() < 1e-3, "{end:?}");
    let most = (0..s.frame_count())
        .map(|f| s.scene_at(f).heading)
        .fold(0.0, f64::max);
    assert!(
        (most.to_degrees() - 5.5).abs() < 0.2,
        "{}",
        most.to_degrees()
    );
    // At constant speed the road-frame distance is nearly the path's length.
    assert!(
        (end.travelled - KMH_30 * 179.0 / FPS).abs() < 0.1,
        "{end:?}"
    );
}

#[test]
fn first_obstacle_frames() {
    let first = |n| Scenario::by_name(n).and_then(|s| s.first_obstacle_frame());
    assert_eq!(first("empty-road"), None);
    assert_eq!(first("pedestrian-4m"), Some(0));
    assert_eq!(first("pedestrian-steps-in"), Some(30));
    assert_eq!(first("car-approaching"), Some(0));
    assert_eq!(first("driving"), None);
    assert_eq!(first("driving-to-pedestrian"), Some(0));
    // In the lane within the range that counts (IN_LANE_MAX_RANGE) from the first frame.
    assert!(first("drive-40-to-pedestrian").is_some());
}

#[test]
fn driving_moves_the_world_and_keeps_obstacles_in_the_vehicle_frame() {
    let s = Scenario::by_name("driving").expect("exists");
    assert_eq!(s.scene_at(0).travelled, 0.0);
    assert_eq!(s.scene_at(30).travelled, 8.0);
    assert!(!s.live() && Scenario::by_name("empty-road").is_some_and(|e| e.live()));
    assert!(s.scene_at(30).obstacles.is_empty());
    let p = Scenario::by_name("driving-to-pedestrian").expect("exists");
    let ahead = |f| p.scene_at(f).obstacles[0].footprint().2 + 0.25;
    assert_eq!(ahead(0), 30.0);
    assert_eq!(ahead(30), 25.0);
    assert_eq!(p.scene_at(30).travelled, 5.0);
    assert!((ahead(149) - 5.17).abs() < 0.01, "{}", ahead(149));
}

#[test]
fn pedestrian_steps_in_and_stays() {
    let s = Scenario::by_name("pedestrian-steps-in").expect("exists");
    assert!(s.scene_at(29).obstacles.is_empty());
    let x_at = |f| match s.scene_at(f).obstacles[0] {
        Obstacle::Cylinder { x, z, .. } => {
            assert_eq!(z, 4.0);
            x
        }
        _ => panic!("a pedestrian is a cylinder"),
    };
    assert_eq!(x_at(30), 0.6);
    assert!(x_at(35) < 0.6 && x_at(35) > 0.0);
    assert_eq!(x_at(60), 0.0);
    assert_eq!(x_at(149), 0.0);
    // Past the end: the last scene.
    assert_eq!(s.scene_at(10_000), s.scene_at(149));
}

#[test]
fn roads_of_changing_curvature_are_followed_frame_by_frame() {
    for (name, k, speed) in [
        ("ramp-30", 1.0 / 25.0, KMH_30),
        ("ramp-40", 1.0 / 50.0, KMH_40),
        ("s-bend-40", 1.0 / 80.0, KMH_40),
    ] {
        let s = Scenario::by_name(name).expect("exists");
        assert!(!s.live());
        let road = match s.kind {
            Kind::Road { geometry, .. } => geometry.road(),
            _ => panic!("{name} is on a road of a profile"),
        };
        // The yaw rate is the speed times the curvature where the vehicle is.
        let rates: Vec<f64> = (0..s.frame_count()).map(|f| s.yaw_rate_at(f)).collect();
        let most = rates.iter().fold(0.0_f64, |m, r| m.max(r.abs()));
        assert!((most - speed * k).abs() < 1e-9, "{name}: {most}");
        for f in [0, 40, 90, 149] {
            let along = speed * (f64::from(f) / FPS);
            let scene = s.scene_at(f);
            let (x, z) = road.point(along, 0.0);
            assert_eq!((scene.lateral, scene.travelled), (x, z), "{name} {f}");
            assert_eq!(scene.heading, road.heading(along));
            assert_eq!(s.yaw_rate_at(f), speed * road.curvature(along));
        }
        // Integrating the reported yaw rate frame by frame stays with the road's heading.
        let heading: f64 = rates.iter().map(|r| r / FPS).sum();
        let end = s.frame_count() as f64 * speed / FPS;
        assert!(
            (heading - road.heading(end)).abs() < 0.02,
            "{name}: {heading} vs {}",
            road.heading(end)
        );
    }
    // The ramp's yaw rate: nothing on the first 10 m, rising to 0.33 rad/s at 30 m.
    let ramp = Scenario::by_name("ramp-30").expect("exists");
    assert_eq!(ramp.yaw_rate_at(30), 0.0);
    assert!((ramp.yaw_rate_at(108) - KMH_30 / 25.0).abs() < 1e-12);
    // The S-bend turns left, then right.
    let s = Scenario::by_name("s-bend-40").expect("exists");
    assert!(s.yaw_rate_at(70) > 0.1 && s.yaw_rate_at(149) < -0.1);
}

#[test]
fn what_stands_on_the_new_roads_stands_where_said() {
    let road = Geometry::Ramp30.road();
    // The stopped car: laid on the centre line, its rear 40 m along, straight ahead of
    // the vehicle along the road 4.2 m at the last frame.
    let s = Scenario::by_name("ramp-30-stopped-car").expect("exists");
    let last = s.scene_at(s.frame_count() - 1);
    assert!(!last.fixed.is_empty() && last.fixed.iter().all(Obstacle::is_valid));
    let eye = last.world_point([0.0, 1.0, 0.0]);
    let ahead = last.world_point([0.0, 1.0, 1.0]);
    let ray = crate::world::Ray {
        origin: eye,
        dir: [ahead[0] - eye[0], 0.0, ahead[2] - eye[2]],
    };
    let hit = last
        .fixed
        .iter()
        .filter_map(|o| o.intersect(&ray))
        .map(|h| h.t)
        .fold(f64::INFINITY, f64::min);
    assert!((hit - 4.17).abs() < 0.05, "{hit}");
    // The kerb pedestrian: 2.7 m left of the centre line, 35 m along.
    let k = Scenario::by_name("ramp-30-pedestrian-on-kerb").expect("exists");
    for f in [0, 60, 120] {
        let scene = k.scene_at(f);
        let Obstacle::Cylinder { x, z, .. } = scene.obstacles[0] else {
            panic!("a pedestrian");
        };
        let w = scene.world_point([x, 0.0, z]);
        let (along, offset) = road.locate(w[0], w[2]);
        assert!((along - 35.0).abs() < 1e-9 && (offset + 2.7).abs() < 1e-9);
    }
    // The S-bend's pedestrian: on the centre line where the road already bends right.
    let p = Scenario::by_name("s-bend-40-to-pedestrian").expect("exists");
    let Obstacle::Cylinder { x, z, .. } = p.scene_at(0).obstacles[0] else {
        panic!("a pedestrian");
    };
    let w = p.scene_at(0).world_point([x, 0.0, z]);
    let road = Geometry::SBend40.road();
    let (along, offset) = road.locate(w[0], w[2]);
    assert!((along - 50.0).abs() < 1e-9 && offset.abs() < 1e-9);
    assert!(road.curvature(along) < 0.0);
    let last = p.scene_at(p.frame_count() - 1);
    let Obstacle::Cylinder { z, .. } = last.obstacles[0] else {
        panic!("a pedestrian");
    };
    assert!(z > 3.0 && z < 5.0, "{z}");
}

#[test]
fn car_closes_from_25_to_5() {
    let s = Scenario::by_name("car-approaching").expect("exists");
    let rear = |f| s.scene_at(f).obstacles[0].footprint().2;
    assert_eq!(rear(0), 25.0);
    assert!((rear(s.frame_count() - 1) - 5.0).abs() < 1e-12);
    assert!(rear(75) < rear(74));
}
