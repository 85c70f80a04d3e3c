use super::*;

fn parse(text: &str) -> Result<Vec<Case>, String> {
    let file: CaseFile = toml::from_str(text).map_err(|e| e.to_string())?;
    file.cases().map_err(|e| e.to_string())
}

const CAR: &str = r#"
[[case]]
name = "car"
road = "straight"
speed_kmh = [10, 20.5]
expect = "no-contact"

[[case.actor]]
kind = "car"
at = 30.0
overlap = 50
"#;

#[test]
fn a_case_is_one_a_speed_and_overlap_places_the_actor_as_euro_ncap_does() {
    let cases = parse(CAR).expect("valid");
    let names: Vec<&str> = cases.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["car-10kmh", "car-20.5kmh"]);
    assert!((cases[0].speed - 10.0 / 3.6).abs() < 1e-12);
    // Both 1.8 m wide, half the vehicle's width covered: centres 0.9 m apart, to the right.
    let a = cases[0].actors[0];
    assert!((a.offset - 0.9).abs() < 1e-12, "{}", a.offset);
    let left = parse(&CAR.replace("overlap = 50", "overlap = -50")).expect("valid");
    assert!((left[0].actors[0].offset + 0.9).abs() < 1e-12);
    let centred = parse(&CAR.replace("overlap = 50", "overlap = 100")).expect("valid");
    assert_eq!(centred[0].actors[0].offset, 0.0);
    // Placed by the time to collision: from the bumper, at least 20 m.
    let ttc = parse(&CAR.replace("at = 30.0", "ttc_s = 4.0")).expect("valid");
    let (slow, fast) = (&ttc[0], &ttc[1]);
    assert_eq!(slow.actors[0].at, 20.0);
    let want = 4.0 * fast.speed + fast.body.front;
    assert!((fast.actors[0].at - want).abs() < 1e-9);
    // Followed 1.5 s ahead at the vehicle's speed.
    let followed =
        parse(&CAR.replace("at = 30.0", "gap_s = 1.5\nsame_speed = true")).expect("valid");
    let f = &followed[1];
    assert!((f.actors[0].at - (1.5 * f.speed + f.body.front)).abs() < 1e-9);
    assert_eq!(f.actors[0].speed, f.speed);
    // Time to pass it, and to stop at 1 m/s^2 from the set speed.
    let c = &cases[0];
    let want = (30.0 + 4.2 + c.body.length) / c.speed + c.speed + 2.0;
    assert!((c.seconds - want.min(40.0)).abs() < 1e-9, "{}", c.seconds);
    assert!(!c.all_passed(30.0, 0.0));
    assert!(c.all_passed(30.0 + 4.2 + c.body.length - c.body.front + 0.1, 0.0));
}

#[test]
fn the_gap_runs_from_the_front_bumper_to_the_near_end_until_the_rear_is_past() {
    let cases = parse(CAR).expect("valid");
    let c = &cases[0];
    let g = c.nearest(10.0, 0.0).expect("ahead");
    assert!((g.distance - (30.0 - 10.0 - c.body.front)).abs() < 1e-12);
    assert_eq!(g.kind, ActorKind::Car);
    // Touching, then beside it, then past.
    assert!(
        c.nearest(30.0 - c.body.front, 0.0)
            .is_some_and(|g| g.distance == 0.0)
    );
    assert!(c.nearest(36.0, 0.0).is_some_and(|g| g.distance < 0.0));
    assert!(c.nearest(40.0, 0.0).is_none());
    // A car beside the vehicle's width is no gap at all.
    let beside = parse(&CAR.replace("overlap = 50", "offset = 1.9")).expect("valid");
    assert!(beside[0].nearest(10.0, 0.0).is_none());
    // A plate is driven over.
    let plate = parse(&CAR.replace("kind = \"car\"", "kind = \"plate\"")).expect("valid");
    assert!(plate[0].nearest(10.0, 0.0).is_none());
}

#[test]
fn actors_move_at_their_speed_along_and_across() {
    let text = CAR
        .replace(
            "overlap = 50",
            "offset = -3.0\ncross_kmh = 3.6\nspeed_kmh = 36",
        )
        .replace("kind = \"car\"", "kind = \"pedestrian\"");
    let cases = parse(&text).expect("valid");
    let a = cases[0].actors[0];
    assert_eq!(a.place(2.0), (30.0 + 20.0, -3.0 + 2.0));
    // One who stops short of the lane, and a car that brakes to a stop from 1 s.
    let kerb = parse(&text.replace("cross_kmh = 3.6", "cross_kmh = 3.6\ncross_until = -2.5"))
        .expect("valid");
    assert_eq!(kerb[0].actors[0].place(2.0).1, -2.5);
    assert_eq!(kerb[0].actors[0].place(0.2).1, -3.0 + 0.2);
    let braking = parse(&text.replace("cross_kmh = 3.6", "brake_decel = 5.0\nbrake_at_s = 1.0"))
        .expect("valid");
    let b = braking[0].actors[0];
    assert_eq!(b.speed_at(0.5), 10.0);
    assert_eq!(b.speed_at(1.4), 8.0);
    assert_eq!(b.speed_at(9.0), 0.0);
    // 10 m in the first second, then 10^2 / (2 * 5) = 10 m to a stop.
    assert!(
        (b.place(9.0).0 - (30.0 + 20.0)).abs() < 1e-9,
        "{:?}",
        b.place(9.0)
    );
    assert!((b.place(1.4).0 - (30.0 + 10.0 + 4.0 - 0.4)).abs() < 1e-9);
}

#[test]
fn the_scene_puts_each_actor_where_the_road_has_it() {
    // Straight: the car in the vehicle frame, as hw-mock's scenarios put one.
    let cases = parse(CAR).expect("valid");
    let scene = cases[0].scene(12.0, 0.0);
    assert_eq!(scene.travelled, 12.0);
    assert_eq!(
        scene.obstacles,
        vec![Obstacle::Box {
            min: [0.0, 0.0, 18.0],
            max: [1.8, 1.5, 30.0 + 4.2 - 12.0],
            material: Material::CAR
        }]
    );
    // On a bend, the car is fixed to the road, the pedestrian where the road point is.
    let text = CAR
        .replace("road = \"straight\"", "road = { bend_radius = 60 }")
        .replace("overlap = 50", "offset = 0.0")
        + "\n[[case.actor]]\nkind = \"pedestrian\"\nat = 20.0\n";
    let cases = parse(&text).expect("valid");
    let c = &cases[0];
    let scene = c.scene(5.0, 0.0);
    assert_eq!(scene.bend, 1.0 / 60.0);
    assert!(matches!(scene.fixed[..], [Obstacle::Bent { .. }]));
    let (x, z) = bend::point(1.0 / 60.0, 20.25, 0.0);
    let [x, _, z] = scene.vehicle_point([x, 0.0, z]);
    assert_eq!(scene.obstacles, vec![Obstacle::pedestrian(x, z)]);
    // 15.25 m along the bend ahead, on the centre line: nearly straight ahead.
    assert!(z > 15.0 && z < 15.25 && x.abs() < 2.0, "{x} {z}");
    assert!((c.yaw_rate(5.0, 10.0) - 10.0 / 60.0).abs() < 1e-12);
    // On a road of changing curvature, laid along it.
    let ramp = CAR.replace("road = \"straight\"", "road = \"ramp-30\"");
    let cases = parse(&ramp).expect("valid");
    let scene = cases[0].scene(5.0, 0.0);
    assert!(scene.road.is_some() && !scene.fixed.is_empty());
    assert!(
        scene
            .fixed
            .iter()
            .all(|o| matches!(o, Obstacle::Laid { .. }))
    );
}

#[test]
fn bad_cases_say_what_is_wrong() {
    for (from, to, says) in [
        (
            "expect = \"no-contact\"",
            "expect = \"fine\"",
            "must be one of",
        ),
        (
            "expect = \"no-contact\"",
            "expect = \"impact-below\"",
            "needs impact_kmh",
        ),
        ("road = \"straight\"", "road = \"moon\"", "road = \"moon\""),
        (
            "road = \"straight\"",
            "road = { bend_radius = 2 }",
            "at least 10 m",
        ),
        (
            "speed_kmh = [10, 20.5]",
            "speed_kmh = [0]",
            "within 1..=130",
        ),
        ("overlap = 50", "overlap = 0", "not 0"),
        ("overlap = 50", "overlap = 50\noffset = 1", "not both"),
        ("at = 30.0", "at = -3.0", "at must be >= 0"),
        ("at = 30.0", "ttc_s = 0.0", "must be > 0"),
        ("at = 30.0", "", "needs one of `at`, `ttc_s`, `gap_s`"),
        ("at = 30.0", "at = 3.0\ngap_s = 1.0", "needs one of"),
    ] {
        let text = CAR.replace(from, to);
        let e = parse(&text).expect_err(to);
        assert!(e.contains(says), "{to}: {e}");
    }
    // Unknown keys are refused by the format itself.
    assert!(parse(&CAR.replace("overlap = 50", "overlapp = 50")).is_err());
    let twice = format!(
        "{CAR}\n{}",
        CAR.replace("speed_kmh = [10, 20.5]", "speed_kmh = [10]")
    );
    let e = parse(&twice.replace(
        "name = \"car\"\nroad = \"straight\"\nspeed_kmh = [10]",
        "name = \"car-10kmh\"\nroad = \"straight\"\nspeed_kmh = [10]",
    ))
    .expect_err("a name twice");
    assert!(e.contains("a second case"), "{e}");
}
