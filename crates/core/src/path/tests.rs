use super::*;

#[test]
fn the_fan_holds_every_path_up_to_its_curvature_and_the_straight_box() {
    let k = 1.0 / 55.0;
    // On any path of the fan: offset 0, the distance that path's.
    for c in [-k, -k / 2.0, 0.0, k / 3.0, k] {
        let path = PredictedPath::arc(c);
        let (x, z) = path.point(20.0);
        let (along, off) = nearest_in_fan(k, x as f32, z as f32).locate(x as f32, z as f32);
        assert!(
            off.abs() < 1e-4 && (along - 20.0).abs() < 1e-3,
            "{c}: {along} {off}"
        );
    }
    // Beyond the fan: off its edge on that side, by as much as off that edge's path.
    let edge = PredictedPath::arc(k);
    let (x, z) = edge.point(20.0);
    let (x, z) = (x as f32 - 2.0, z as f32);
    assert_eq!(nearest_in_fan(k, x, z), edge);
    assert_eq!(nearest_in_fan(k, x, z).locate(x, z), edge.locate(x, z));
    // Never farther off than from the straight path: the straight box is in the fan.
    for (x, z) in [(1.1f32, 3.0f32), (-1.1, 30.0), (5.0, 10.0), (-8.0, 40.0)] {
        let off = nearest_in_fan(k, x, z).locate(x, z).1;
        assert!(off.abs() <= x.abs() + 1e-5, "({x}, {z}): {off}");
    }
    // A fan of no curvature is the straight path; the curvature is bounded.
    assert_eq!(nearest_in_fan(0.0, 3.0, 10.0), PredictedPath::STRAIGHT);
    assert_eq!(nearest_in_fan(5.0, 3.0, 1.0).curvature, -MAX_CURVATURE);
    assert_eq!(nearest_in_fan(k, 0.0, 0.0), PredictedPath::STRAIGHT);
}

#[test]
fn a_straight_path_is_the_vehicle_frame_bit_for_bit() {
    let p = PredictedPath::STRAIGHT;
    for (x, z) in [(0.3f32, 12.7f32), (-1.1, 0.5), (0.0, 40.0), (1e-7, 3.3)] {
        let (along, offset) = p.locate(x, z);
        assert_eq!(
            (along.to_bits(), offset.to_bits()),
            (z.to_bits(), x.to_bits())
        );
    }
    assert_eq!(p.point(7.0), (0.0, 7.0));
    assert_eq!(p.point_at(7.0, -1.5), (-1.5, 7.0));
}

#[test]
fn a_point_beside_the_path_is_located_where_it_was_put() {
    for k in [0.05, -0.02, 0.2] {
        let path = PredictedPath::arc(k);
        for (along, offset) in [(3.0, 0.0), (10.0, 1.2), (6.0, -0.8)] {
            let (x, z) = path.point_at(along, offset);
            let (a, o) = path.locate(x as f32, z as f32);
            assert!(
                (f64::from(a) - along).abs() < 1e-3 && (f64::from(o) - offset).abs() < 1e-3,
                "k {k}: ({along}, {offset}) located at ({a}, {o})"
            );
        }
    }
}

#[test]
fn points_on_and_beside_an_arc_are_located_on_it() {
    // A left bend of 50 m radius and a right one of 120 m.
    for k in [0.02, -1.0 / 120.0] {
        let p = PredictedPath::arc(k);
        for s in [0.5, 10.0, 23.0, 41.0] {
            let (x, z) = p.point(s);
            let (along, offset) = p.locate(x as f32, z as f32);
            assert!((f64::from(along) - s).abs() < 1e-3, "k {k}: {along} vs {s}");
            assert!(offset.abs() < 1e-3, "k {k} at {s}: offset {offset}");
            // 1.5 m to the right of the path, along its normal: the heading there is
            // (-sin, cos) of k s, its right (cos, sin).
            let (sin, cos) = (k * s).sin_cos();
            let (xr, zr) = (x + 1.5 * cos, z + 1.5 * sin);
            let (along, offset) = p.locate(xr as f32, zr as f32);
            assert!((f64::from(along) - s).abs() < 1e-3, "k {k}: {along} vs {s}");
            assert!((offset - 1.5).abs() < 1e-3, "k {k} at {s}: offset {offset}");
        }
    }
}

#[test]
fn on_a_bend_the_straight_box_and_the_path_disagree() {
    // 20 m ahead on a 100 m left bend the path is 2 m left of the straight line: a car
    // there is on the path, what stands straight ahead is 2 m right of it.
    let p = PredictedPath::arc(0.01);
    let (x, z) = p.point(20.0);
    assert!(
        (x + 2.0).abs() < 0.05 && (z - 19.87).abs() < 0.05,
        "{x} {z}"
    );
    let (_, offset) = p.locate(0.0, 20.0);
    assert!((offset - 2.0).abs() < 0.05, "{offset}");
}

#[test]
fn the_path_of_a_motion() {
    let m = |speed, yaw_rate| PredictedPath::of_motion(VehicleMotion { speed, yaw_rate });
    assert_eq!(m(10.0, 0.1).curvature, 0.01);
    assert_eq!(m(10.0, -0.1).curvature, -0.01);
    assert_eq!(m(10.0, 0.0), PredictedPath::STRAIGHT);
    // Walking pace, standstill, nonsense: straight.
    assert_eq!(m(0.5, 0.3), PredictedPath::STRAIGHT);
    assert_eq!(m(0.0, 0.3), PredictedPath::STRAIGHT);
    assert_eq!(m(f64::NAN, 0.1), PredictedPath::STRAIGHT);
    assert_eq!(m(10.0, f64::INFINITY), PredictedPath::STRAIGHT);
    // Never tighter than a car turns.
    assert_eq!(m(2.0, 1.0).curvature, MAX_CURVATURE);
    assert_eq!(m(2.0, -1.0).curvature, -MAX_CURVATURE);
}

#[test]
fn a_bend_is_followed_once_held_a_brief_turn_is_not() {
    let motion = |yaw_rate| VehicleMotion {
        speed: 10.0,
        yaw_rate,
    };
    let mut e = PathEstimator::new(2.0);
    // 10 Hz: the first 1.9 s of a bend (0.1 rad/s at 10 m/s: 100 m radius) are not
    // enough, the twentieth sample completes the hold.
    for _ in 0..19 {
        assert_eq!(e.update(motion(0.1), 0.1).held, PredictedPath::STRAIGHT);
    }
    assert_eq!(e.update(motion(0.1), 0.1).held.curvature, 0.01);
    // Tightening: the smallest of the last 2 s until the tighter one is held.
    for _ in 0..19 {
        assert_eq!(e.update(motion(0.2), 0.1).held.curvature, 0.01);
    }
    assert_eq!(e.update(motion(0.2), 0.1).held.curvature, 0.02);
    // One sample the other way (noise, a correction) and the path is straight for 2 s.
    assert_eq!(e.update(motion(-0.01), 0.1).held, PredictedPath::STRAIGHT);
    for _ in 0..19 {
        assert_eq!(e.update(motion(0.2), 0.1).held, PredictedPath::STRAIGHT);
    }
    assert_eq!(e.update(motion(0.2), 0.1).held.curvature, 0.02);
    // A right bend the same way; a reset starts the hold again.
    e.reset();
    for _ in 0..19 {
        assert_eq!(e.update(motion(-0.1), 0.1).held, PredictedPath::STRAIGHT);
    }
    assert_eq!(e.update(motion(-0.1), 0.1).held.curvature, -0.01);
    // Straight: a yaw rate of 0 is no bend either way.
    assert_eq!(e.update(motion(0.0), 0.1).held, PredictedPath::STRAIGHT);
}

#[test]
fn a_lane_change_bends_the_path_far_less_than_its_yaw_rate() {
    // hw-mock's: 2 m left over 5 s at 30 km/h, yaw rate A sin(2 pi t / 5), 30 Hz.
    let (speed, duration, fps) = (30.0 / 3.6, 5.0, 30.0);
    let peak = std::f64::consts::TAU * 2.0 / (speed * duration * duration);
    let mut e = PathEstimator::new(2.0);
    let mut most: f64 = 0.0;
    for f in 0..(duration * fps) as u32 {
        let t = f64::from(f) / fps;
        let yaw_rate = peak * (std::f64::consts::TAU * t / duration).sin();
        let path = e.update(VehicleMotion { speed, yaw_rate }, 1.0 / fps).held;
        most = most.max(path.curvature.abs());
    }
    // The yaw rate's curvature peaks at 0.0072 1/m (3.2 m off at 30 m); what is held
    // for 2 s, about sin(0.1 pi) of it at 30 frames a second (1.1 m).
    let k_peak = peak / speed;
    assert!(most > 0.0 && most < 0.35 * k_peak, "{most} vs {k_peak}");
}

#[test]
fn a_hold_of_zero_is_the_motion_of_the_moment_and_capacity_is_bounded() {
    let m = VehicleMotion {
        speed: 10.0,
        yaw_rate: 0.05,
    };
    assert_eq!(
        PathEstimator::new(0.0).update(m, 0.1).held,
        PredictedPath::of_motion(m)
    );
    // Far more samples than it keeps, each too short to complete the hold: once full,
    // what the samples kept show is held.
    let mut e = PathEstimator::new(5.0);
    let mut last = PredictedPath::STRAIGHT;
    for _ in 0..(3 * HELD_SAMPLES) {
        last = e.update(m, 1e-4).held;
    }
    assert_eq!(last.curvature, 0.005);
    // A nonsense dt neither panics nor counts.
    assert_eq!(
        PathEstimator::new(1.0).update(m, f64::NAN),
        PathEstimate {
            held: PredictedPath::STRAIGHT,
            now: PredictedPath::of_motion(m)
        }
    );
}

#[test]
fn a_clothoid_is_as_far_sideways_as_its_curvature_says_and_ends_straight() {
    // Into a bend: 0 to 0.01 1/m over 10 m, then (the reach) constant.
    let p = PredictedPath {
        curvature: 0.0,
        rate: 0.001,
    };
    assert!((p.effective_curvature(6.0) - 0.002).abs() < 1e-12);
    assert_eq!(p.curvature_at(40.0), 0.001 * CLOTHOID_REACH);
    // Lateral displacement by integration against the effective arc's.
    for s in [5.0, 12.0, 25.0] {
        let (n, mut heading, mut x) = (10_000, 0.0f64, 0.0f64);
        let h = s / f64::from(n);
        for i in 0..n {
            let u = (f64::from(i) + 0.5) * h;
            heading += p.curvature_at(u) * h;
            x -= heading.sin() * h;
        }
        let (px, _) = p.point(s);
        assert!((px - x).abs() < 0.02, "at {s}: {px} vs {x}");
    }
    // Out of a bend: the curvature falls to 0 and stays there, never the other way.
    let out = PredictedPath {
        curvature: 0.04,
        rate: -0.004,
    };
    assert_eq!(out.curvature_at(10.0), 0.0);
    assert_eq!(out.curvature_at(30.0), 0.0);
    assert!(out.effective_curvature(30.0) > 0.0);
    // Located where it was put, beside it too.
    for (along, offset) in [(8.0, 0.0), (15.0, 1.1), (12.0, -2.2)] {
        let (x, z) = out.point_at(along, offset);
        let (a, o) = out.locate(x as f32, z as f32);
        assert!(
            (f64::from(a) - along).abs() < 0.05 && (f64::from(o) - offset).abs() < 0.05,
            "({along}, {offset}) located at ({a}, {o})"
        );
    }
    // Never tighter than a car turns; an arc has no rate.
    let tight = PredictedPath {
        curvature: 0.15,
        rate: 0.02,
    };
    assert_eq!(tight.curvature_at(20.0), MAX_CURVATURE);
    assert!(!PredictedPath::arc(0.0).rate.is_nan() && PredictedPath::arc(0.0).is_straight());
}

/// Into a bend at 10 m/s, 100 Hz, for `steps` updates: the yaw rate grows by 0.05 rad/s
/// each second. The last estimate.
fn into_a_bend(e: &mut PathEstimator, steps: u32) -> PathEstimate {
    let mut last = PathEstimate::STRAIGHT;
    for i in 0..steps {
        let t = f64::from(i) * 0.01;
        let motion = VehicleMotion {
            speed: 10.0,
            yaw_rate: 0.05 * t,
        };
        last = e.update(motion, 0.01);
    }
    last
}

#[test]
fn the_clothoid_estimator_measures_how_the_curvature_changes() {
    // Into a bend at 10 m/s, 100 Hz: the yaw rate grows by 0.05 rad/s each second, the
    // curvature by 0.005 1/m per 10 m: 0.0005 1/m^2.
    let mut e = PathEstimator::with_model(PathModel::Clothoid { window: 0.3 });
    let mut last = into_a_bend(&mut e, 200);
    assert!((last.held.rate - 0.0005).abs() < 1e-6, "{last:?}");
    assert_eq!(last.held, last.now);
    assert!((last.held.curvature - 0.00995).abs() < 1e-4, "{last:?}");
    // A steady bend: no rate; a reset forgets the history (an arc until the window fills).
    for _ in 0..100 {
        last = e.update(
            VehicleMotion {
                speed: 10.0,
                yaw_rate: 0.1,
            },
            0.01,
        );
    }
    assert!(last.held.rate.abs() < 1e-9, "{last:?}");
    e.reset();
    let first = e.update(
        VehicleMotion {
            speed: 10.0,
            yaw_rate: 0.2,
        },
        0.01,
    );
    assert_eq!(first.held, PredictedPath::arc(0.02));
    // Window 0: the arc of the moment.
    let mut arc = PathEstimator::with_model(PathModel::Clothoid { window: 0.0 });
    let m = VehicleMotion {
        speed: 8.0,
        yaw_rate: 0.08,
    };
    assert_eq!(arc.update(m, 0.1).held, PredictedPath::of_motion(m));
}

#[test]
fn the_gated_clothoid_holds_both_plausible_paths_and_says_how_far_apart_they_are() {
    let mut e = PathEstimator::with_model(PathModel::ClothoidGated { window: 0.3 });
    let last = into_a_bend(&mut e, 100);
    // The centre line keeps steering in; the gate is where the vehicle goes if it stops.
    assert!(last.held.rate > 0.0 && last.now.rate == 0.0, "{last:?}");
    assert_eq!(last.held.curvature, last.now.curvature);
    // Apart by rate s^3 / 6 (small angles): 0.0005 * 1000 / 6 at 10 m.
    let spread = last.spread(10.0);
    assert!((spread - 0.0005 * 1000.0 / 6.0).abs() < 0.01, "{spread}");
    assert!(last.spread(20.0) > 7.0 * spread);
    assert_eq!(PathEstimate::STRAIGHT.spread(30.0), 0.0);
    // On the clothoid 15 m ahead: in the corridor of both.
    let (x, z) = last.held.point(15.0);
    assert!(last.spread(15.0) > 0.25);
    assert!(last.locate_in(x as f32, z as f32, 1.2).is_some());
    // The arc bends less (it is right of the clothoid): 1 m left of the clothoid is 1.28 m
    // left of the arc, out; 1 m right of it 0.72 m right of the arc, in.
    let left = last.held.point_at(15.0, -1.0);
    assert!(last.locate_in(left.0 as f32, left.1 as f32, 1.2).is_none());
    let right = last.held.point_at(15.0, 1.0);
    assert!(
        last.locate_in(right.0 as f32, right.1 as f32, 1.2)
            .is_some()
    );
}

#[test]
fn a_step_in_the_curvature_is_no_clothoid() {
    // A bend of constant curvature entered without a transition (hw-mock's bends): the
    // window sees a step, not a steady change; the path is the arc, never a spiral.
    let mut e = PathEstimator::with_model(PathModel::ClothoidGated { window: 0.3 });
    for i in 0..60 {
        let yaw_rate = if i < 30 { 0.0 } else { 0.139 };
        let p = e.update(
            VehicleMotion {
                speed: 8.33,
                yaw_rate,
            },
            1.0 / 30.0,
        );
        assert!(p.held.rate.abs() < 1e-9, "sample {i}: {p:?}");
    }
}

#[test]
fn a_10_hz_feed_takes_the_rate_of_the_whole_window() {
    // A clothoid (curvature up by 0.001 1/m per metre) measured at 10 Hz with noise that
    // alternates in sign: over 0.3 s each half of the window holds two samples, whose
    // rates disagree in sign; the whole window's least squares still finds the rate.
    let mut e = PathEstimator::with_model(PathModel::ClothoidGated { window: 0.3 });
    let (speed, dt, rate) = (12.0, 0.1, 0.001);
    let mut last = None;
    for i in 0..30 {
        let s = speed * dt * f64::from(i);
        let noise = if i % 2 == 0 { 0.0008 } else { -0.0008 };
        let p = e.update(
            VehicleMotion {
                speed,
                yaw_rate: speed * (rate * s + noise),
            },
            dt,
        );
        last = Some(p.held.rate);
    }
    let got = last.unwrap_or(0.0);
    assert!(
        got > 0.3 * rate && got < 3.0 * rate,
        "rate {got} against {rate}"
    );
}
