//! How much of the gap to an obstacle ahead an encounter uses, when the obstacle moves.
//!
//! The encounter (RSS's, Shalev-Shwartz et al. 2017, with the obstacle's braking an
//! assumption rather than a worst case): now the gap is `gap` metres, the vehicle drives at `v`
//! m/s and the obstacle ahead at `u` m/s along the same path. The vehicle drives on for its
//! reaction time `rho`, then brakes at `a` until it stops; the obstacle brakes at `b` from now
//! until it stops. [`consumed`] is how much of the gap that uses at its worst moment:
//! `gap - min over t of gap(t)`. For a still obstacle (`u = 0`) it is the vehicle's stopping
//! distance `v rho + v^2 / (2 a)`, today's rule; for an obstacle driven ahead at the
//! vehicle's speed it is what the vehicle closes in while it reacts to the obstacle's braking.
//!
//! RSS compares only where the two stop, which is right when the obstacle brakes at least
//! as hard as the vehicle (`b >= a`); with `b < a` the nearest moment can come before either
//! stops (when their speeds are equal). This takes the minimum over the whole encounter: the
//! gap is piecewise quadratic in time, and its minimum is at a breakpoint or where the speeds
//! are equal.

/// The most of the gap the encounter uses, metres (see the module docs). `v`, `u` and `rho`
/// at least 0, `a` and `b` above 0 (`b` = 0: the obstacle keeps its speed); values outside
/// are taken at those bounds.
pub fn consumed(v: f64, u: f64, rho: f64, a: f64, b: f64) -> f64 {
    let (v, u, rho) = (v.max(0.0), u.max(0.0), rho.max(0.0));
    let (a, b) = (a.max(1e-6), b.max(1e-6));
    // The vehicle's and the obstacle's travel and speed at time t.
    let ego = |t: f64| {
        if t <= rho {
            (v * t, v)
        } else {
            let s = (t - rho).min(v / a);
            (v * rho + v * s - 0.5 * a * s * s, (v - a * s).max(0.0))
        }
    };
    let lead = |t: f64| {
        let s = t.min(u / b);
        (u * s - 0.5 * b * s * s, (u - b * s).max(0.0))
    };
    let closed = |t: f64| ego(t).0 - lead(t).0;
    let (t_lead, t_ego) = (u / b, rho + v / a);
    let mut breaks = [0.0, rho, t_lead, t_ego];
    breaks.sort_by(f64::total_cmp);
    // At the breakpoints, and where the speeds are equal inside a piece (the relative
    // acceleration is constant there).
    let mut most = breaks.iter().map(|&t| closed(t)).fold(0.0_f64, f64::max);
    for w in breaks.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        if t1 <= t0 {
            continue;
        }
        let mid = 0.5 * (t0 + t1);
        let accel_ego = if mid <= rho || mid >= t_ego { 0.0 } else { -a };
        let accel_lead = if mid >= t_lead { 0.0 } else { -b };
        let relative = accel_ego - accel_lead;
        let closing = ego(t0).1 - lead(t0).1;
        if relative < 0.0 && closing > 0.0 {
            let t = t0 + closing / -relative;
            if t < t1 {
                most = most.max(closed(t));
            }
        }
    }
    // After both stop the gap stays.
    most.max(closed(t_ego.max(t_lead)))
}

/// The least deceleration that keeps `room` metres of the gap unused (the margin left at
/// the nearest moment), braking after `rho`, with the obstacle at `u` braking at
/// `b(a)` (the assumption may follow the vehicle's own braking): m/s^2; infinite when no
/// deceleration up to `limit` does, 0 when none is needed.
pub fn needed(v: f64, u: f64, rho: f64, room: f64, b: impl Fn(f64) -> f64, limit: f64) -> f64 {
    let fits = |a: f64| consumed(v, u, rho, a, b(a)) <= room;
    if room.is_nan() || room <= 0.0 || !fits(limit) {
        return f64::INFINITY;
    }
    // Driving on for ever would need nothing: the obstacle is not closed on.
    let (mut lo, mut hi) = (0.0, limit);
    if fits(1e-3) {
        return 0.0;
    }
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if fits(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same encounter stepped at 0.1 ms.
    fn stepped(v: f64, u: f64, rho: f64, a: f64, b: f64) -> f64 {
        let dt = 1e-4;
        let (mut xe, mut ve, mut xl, mut vl, mut t, mut most) = (0.0, v, 0.0, u, 0.0, 0.0_f64);
        while ve > 0.0 || vl > 0.0 {
            let ae = if t < rho { 0.0 } else { a };
            let ve2 = (ve - ae * dt).max(0.0);
            let vl2 = (vl - b * dt).max(0.0);
            xe += 0.5 * (ve + ve2) * dt;
            xl += 0.5 * (vl + vl2) * dt;
            ve = ve2;
            vl = vl2;
            t += dt;
            most = most.max(xe - xl);
        }
        most
    }

    #[test]
    fn a_still_obstacle_uses_the_stopping_distance() {
        for v in [0.0, 5.0, 8.33, 13.9, 25.0] {
            let c = consumed(v, 0.0, 0.5, 4.0, 4.0);
            assert!((c - (v * 0.5 + v * v / 8.0)).abs() < 1e-9, "{v}: {c}");
        }
    }

    #[test]
    fn the_closed_form_is_the_stepped_encounter() {
        for &(v, u) in &[
            (13.9, 13.9),
            (13.9, 5.6),
            (8.3, 13.9),
            (13.9, 0.5),
            (20.0, 19.0),
            (0.0, 5.0),
        ] {
            for &(rho, a, b) in &[
                (0.5, 4.0, 4.0),
                (0.5, 1.5, 1.5),
                (0.5, 4.0, 6.0),
                (0.5, 4.0, 1.0),
                (0.0, 2.0, 8.0),
                (1.0, 9.0, 2.0),
            ] {
                let (c, s) = (consumed(v, u, rho, a, b), stepped(v, u, rho, a, b));
                assert!(
                    (c - s).abs() < 0.01,
                    "v {v} u {u} rho {rho} a {a} b {b}: {c} vs {s}"
                );
            }
        }
    }

    #[test]
    fn following_at_the_same_speed_uses_what_the_reaction_closes() {
        // Both brake alike: the vehicle closes b rho per second for as long as both brake.
        let c = consumed(13.9, 13.9, 0.5, 4.0, 4.0);
        assert!((c - 13.9 * 0.5).abs() < 1e-9, "{c}");
        // The obstacle braking harder than the vehicle: they stop where RSS says.
        let c = consumed(13.9, 13.9, 0.5, 4.0, 6.0);
        let rss = 13.9 * 0.5 + 13.9 * 13.9 / 8.0 - 13.9 * 13.9 / 12.0;
        assert!((c - rss).abs() < 1e-9, "{c} vs {rss}");
    }

    #[test]
    fn an_obstacle_that_keeps_its_speed_uses_only_the_closing_speed() {
        assert!(consumed(13.9, 13.9, 0.5, 1.5, 0.0).abs() < 1e-6);
        let closing = 13.9 - 5.56;
        let c = consumed(13.9, 5.56, 0.5, 1.5, 0.0);
        let expected = closing * 0.5 + closing * closing / 3.0;
        assert!((c - expected).abs() < 1e-3, "{c} vs {expected}");
    }

    #[test]
    fn the_deceleration_needed_keeps_the_room_and_no_more() {
        let b = |_: f64| 4.0;
        let a = needed(13.9, 5.0, 0.5, 20.0, b, 9.0);
        assert!(
            (consumed(13.9, 5.0, 0.5, a, 4.0) - 20.0).abs() < 1e-6,
            "{a}"
        );
        // A still obstacle: the closed form.
        let a = needed(10.0, 0.0, 0.5, 20.0, b, 9.0);
        assert!((a - 100.0 / (2.0 * 15.0)).abs() < 1e-6, "{a}");
        assert_eq!(needed(10.0, 0.0, 0.5, 4.0, b, 9.0), f64::INFINITY);
        assert_eq!(needed(10.0, 0.0, 0.5, -1.0, b, 9.0), f64::INFINITY);
        // Driving away faster than the vehicle: nothing needed.
        assert_eq!(needed(10.0, 15.0, 0.5, 2.0, |_| 0.001, 9.0), 0.0);
    }
}
