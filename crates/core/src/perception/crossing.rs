//! Who may step into the corridor: obstacles beside it that move towards it.
//!
//! The corridor's obstacle stage sees a pedestrian crossing from the side only once they stand
//! in it: on hw-mock's Euro NCAP CPNA-25 at 30 km/h, 0.5 s before the impact, when no braking
//! can stop the vehicle (the STOP reach is 14.9 m, the pedestrian steps in 6 m ahead). So two
//! zones are watched, one either side of the corridor out to
//! [`super::ObstacleConfig::watch_half_width`] (the flies' region of interest reaches 4 m),
//! each with its own obstacle finder ([`super::ObstacleFinder::watching`]) and tracker: the
//! nearest obstacle there and how it moves across ([`super::motion`]).
//!
//! A watched obstacle **enters** ([`entry`]) when its motion is established along the path
//! (as a corridor obstacle's: where the rig cannot place it along, it cannot place it across)
//! and across it ([`super::motion::MIN_SAMPLES`] sightings over
//! [`super::motion::MIN_SPAN`], a standard error of at most [`MAX_LATERAL_SIGMA`]; a
//! full window of 16, tried, found the crossing pedestrians too late: contact on 3 of 3
//! CPNA/CPFA runs, seed 1) and
//! surely towards the corridor (its speed across less [`CREDIT_SIGMAS`] standard errors is at
//! least [`MIN_TOWARDS`]: a parked car, a post, a pedestrian walking along the kerb never
//! enter), and nearer the path than it ever was before the last
//! [`super::motion::PROGRESS_S`] seconds (but once: [`super::motion::ObstacleMotion::closest_before`]).
//! The last because a watched obstacle's inner edge is read from the flies on it, which miss
//! that edge more often than they stray nearer the path than it: the readings of a parked
//! car stray outwards and come back, and the fit of a stray and its return reads as walking
//! in. On hw-mock's car parked on a 60 m bend, its near side 1.7 m off the path, they read
//! 2.3-2.4 m for 0.3 s, then 1.65-1.7 m again 8 m ahead: 1.6 m/s towards the path, a STOP at
//! 9 m/s^2 (`bend-parked-car-outside`, seed 1). Someone who walks in comes nearer on every
//! frame; it is
//! predicted to reach the corridor's edge after `gap / (speed + 2 sigma)` seconds, the earliest
//! its motion allows. It is **in the path** ([`in_path`]) when that is before the vehicle, at
//! its speed, has passed it: its arrival at the obstacle's near distance plus
//! [`PASSING_S`]. Then the decision takes it at its near distance, with the speed along the
//! path its track shows, a stage later than an obstacle in the corridor: SLOW where that one
//! would be STOPped for, and STOP at the latest moment the brakes still stop short of it
//! ([`crate::decision::DecisionInput::obstacle_entering`]: its reach at `max_decel`) (Euro
//! NCAP's AEB systems brake for a pedestrian on a collision course before they enter the
//! path; Autoware's AEB checks each object's predicted path against the ego's).
//!
//! The price: a pedestrian who walks towards the road and stops at its kerb is braked for
//! until they stop (`pedestrian-stops-at-kerb`), as a driver would lift off. At 30 km/h on
//! hw-mock the one of Euro NCAP's CPNA-25 who stops 1.2 m short of the corridor does so 1.4 s
//! before the vehicle would arrive; the STOP for the one who walks on must come 1.3 s before
//! (its reach at 9 m/s^2 and a frame's latency), and the motion fit sees a stop a few frames
//! after it: the two cannot be told apart in time.
//!
//! Off by default (`watch_half_width = 0`): with 4 m, hw-mock's crossing pedestrians are
//! stopped for (18 of 18 runs, seeds 1-2) and nothing watched is braked for on its
//! false-activation runs (44 of seeds 1-4), but the flies the zones draw beside the corridor
//! sit on a real roadside's repeated textures: the 250 fittest flies of a KITTI pair agree
//! less with its LiDAR truth (78.5 % within 1 px against 88.1 % on one pair), and those at
//! the corridor's edge brought two STOPs on hw-mock's empty road and steel plate
//! (docs/traffic.md). Nothing here runs then, and the decision is the corridor's alone.

use super::motion::{MIN_SAMPLES, MIN_SPAN};

/// The largest standard error of a motion across that establishes it, m/s.
pub const MAX_LATERAL_SIGMA: f64 = 1.0;
use super::track::{CREDIT_SIGMAS, Tracked};

/// Seconds after the vehicle's front reaches a crossing obstacle's distance that it still
/// occupies that line (a car's length at 30 km/h is 0.5 s), and the prediction's slack.
pub const PASSING_S: f64 = 1.0;

/// A watched obstacle enters only when its speed across, less two standard errors, is at
/// least this towards the corridor, m/s. A slow walk is 1 m/s (Euro NCAP's pedestrians cross
/// at 1.4 and 2.2); the flies on a car parked beside the lane drift 0.35-0.85 m/s towards the
/// path as more of its side shows (hw-mock's `between-parked-cars` and
/// `bend-parked-car-inside`, seed 1), 0.1-0.5 m/s once two standard errors are taken off.
pub const MIN_TOWARDS: f64 = 0.5;

/// Below this speed, m/s, the vehicle is taken as never passing anything: whatever enters
/// is in its path.
const CREEPING: f64 = 0.1;

/// In how many seconds the confirmed obstacle of `watched`, beside a corridor of
/// `half_width` metres either side of the path, may enter it (0: it is at its edge); none
/// unless its motion across is established and surely towards the corridor.
pub fn entry(watched: &Tracked, half_width: f64) -> Option<f64> {
    let o = watched.confirmed()?;
    let m = watched.motion?;
    // Along the path too: where the rig cannot place it along to 1.5 m/s, it cannot place it
    // across either (on hw-mock's rig at 30 m a parked car's inner edge read 1.9-3.3 m off
    // the path from one frame to the next, walking in at 2 m/s).
    let established = m.established
        && m.samples as usize >= MIN_SAMPLES
        && m.span >= MIN_SPAN
        && m.lateral_sigma.is_finite()
        && m.lateral_sigma <= MAX_LATERAL_SIGMA;
    if !(established && o.lateral.is_finite() && o.lateral != 0.0) {
        return None;
    }
    // Towards the path: against the sign of the offset.
    let towards = -o.lateral.signum() * m.lateral_speed;
    let spread = CREDIT_SIGMAS * m.lateral_sigma;
    // NaN speeds fail this too.
    let surely_towards = towards - spread >= MIN_TOWARDS;
    // And nearer the path than it was before (NaN fails).
    let nearer = o.lateral.abs() < m.closest_before;
    if !(surely_towards && nearer) {
        return None;
    }
    let gap = (o.lateral.abs() - half_width).max(0.0);
    Some(gap / (towards + spread))
}

/// Whether an obstacle `near` metres ahead that enters the corridor in `entry_s` seconds is
/// in the path of a vehicle at `speed` m/s (none: not known; taken as never passing): it
/// enters before the vehicle has passed it.
pub fn in_path(entry_s: f64, near: f64, speed: Option<f64>) -> bool {
    match speed.filter(|v| v.is_finite() && *v > CREEPING) {
        Some(v) => entry_s <= near.max(0.0) / v + PASSING_S,
        None => true,
    }
}

/// The obstacle the decision takes: the corridor's confirmed one, or the nearer of the
/// watched ones in the path (its [`Tracked::entering`] set), whichever is nearer.
pub fn nearest_in_path(
    corridor: Tracked,
    watched: impl IntoIterator<Item = Tracked>,
    half_width: f64,
    speed: Option<f64>,
) -> Tracked {
    let mut best = corridor;
    for w in watched {
        let (Some(o), Some(e)) = (w.confirmed(), entry(&w, half_width)) else {
            continue;
        };
        if !in_path(e, o.near, speed) {
            continue;
        }
        if best.decision_distance().is_none_or(|d| o.near < d) {
            best = Tracked {
                entering: Some(e),
                ..w
            };
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::motion::ObstacleMotion;
    use crate::perception::obstacle::Obstacle;

    fn watched(near: f64, lateral: f64, lateral_speed: f64, sigma: f64) -> Tracked {
        Tracked {
            obstacle: Some(Obstacle {
                distance: near + 0.5,
                near,
                centre: near + 0.5,
                lateral,
                bottom: 0.1,
                top: 1.7,
                flies: 20,
                cells: 9,
                confidence: 60.0,
            }),
            confirmed: true,
            seen_frames: 12,
            motion: Some(ObstacleMotion {
                speed: 0.0,
                speed_sigma: 0.8,
                lateral_speed,
                lateral_sigma: sigma,
                samples: 16,
                span: 0.5,
                established: true,
                closest_before: f64::INFINITY,
            }),
            entering: None,
        }
    }

    #[test]
    fn a_pedestrian_walking_towards_the_corridor_enters_it_at_the_earliest_their_motion_allows() {
        // 3.2 m right of the path, walking left at 1.39 m/s (5 km/h), known within 0.2 m/s:
        // 2.0 m to the edge at up to 1.79 m/s.
        let e = entry(&watched(16.7, 3.2, -1.39, 0.2), 1.2).expect("an entry");
        assert!((e - 2.0 / 1.79).abs() < 1e-9, "{e}");
        // From the left, walking right: the same.
        let e = entry(&watched(16.7, -3.2, 1.39, 0.2), 1.2).expect("an entry");
        assert!((e - 2.0 / 1.79).abs() < 1e-9, "{e}");
        // Walking away, along the kerb, or not surely towards: never.
        assert_eq!(entry(&watched(16.7, 3.2, 1.39, 0.2), 1.2), None);
        assert_eq!(entry(&watched(16.7, 3.2, 0.0, 0.2), 1.2), None);
        assert_eq!(entry(&watched(16.7, 3.2, -0.3, 0.2), 1.2), None);
        // A parked car's flies drifting towards the path as more of its side shows.
        assert_eq!(entry(&watched(9.8, -2.3, 0.85, 0.2), 1.2), None);
        // Back where it was 0.25 s ago or nearer before (a parked car's inner edge read
        // farther out on a few frames): not entering.
        let mut back = watched(16.7, 3.2, -1.39, 0.2);
        back.motion = back.motion.map(|m| ObstacleMotion {
            closest_before: 3.2,
            ..m
        });
        assert_eq!(entry(&back, 1.2), None);
        back.motion = back.motion.map(|m| ObstacleMotion {
            closest_before: 3.3,
            ..m
        });
        assert!(entry(&back, 1.2).is_some());
        // A motion across not established, a track not confirmed: never.
        let mut few = watched(16.7, 3.2, -1.39, 0.2);
        few.motion = few.motion.map(|m| ObstacleMotion { samples: 5, ..m });
        assert_eq!(entry(&few, 1.2), None);
        let noisy = watched(16.7, 3.2, -1.39, 1.5);
        assert_eq!(entry(&noisy, 1.2), None);
        let unconfirmed = Tracked {
            confirmed: false,
            ..watched(16.7, 3.2, -1.39, 0.2)
        };
        assert_eq!(entry(&unconfirmed, 1.2), None);
        let nan = watched(16.7, f64::NAN, -1.39, 0.2);
        assert_eq!(entry(&nan, 1.2), None);
    }

    #[test]
    fn it_is_in_the_path_when_it_enters_before_the_vehicle_has_passed() {
        // 16.7 m ahead at 8.33 m/s (30 km/h): the vehicle is there in 2.0 s, past at 3.0 s.
        assert!(in_path(1.1, 16.7, Some(8.33)));
        assert!(in_path(2.9, 16.7, Some(8.33)));
        assert!(!in_path(3.1, 16.7, Some(8.33)));
        // Standing or unknown speed: whatever enters.
        assert!(in_path(100.0, 16.7, Some(0.0)));
        assert!(in_path(100.0, 16.7, None));
        assert!(in_path(100.0, 16.7, Some(f64::NAN)));
    }

    #[test]
    fn the_decision_takes_the_nearer_of_the_corridors_obstacle_and_who_steps_in() {
        let crossing = watched(16.7, 3.2, -1.39, 0.2);
        let none = Tracked::NONE;
        let t = nearest_in_path(none, [crossing], 1.2, Some(8.33));
        assert_eq!(t.decision_distance(), Some(16.7));
        assert!(t.entering.is_some_and(|e| e > 1.0 && e < 1.2), "{t:?}");
        // A car 10 m ahead in the corridor is nearer: it stays.
        let car = Tracked {
            entering: None,
            ..watched(10.0, 0.2, 0.0, 0.2)
        };
        let t = nearest_in_path(car, [crossing], 1.2, Some(8.33));
        assert_eq!((t.decision_distance(), t.entering), (Some(10.0), None));
        // 5.5 m aside, ahead of a vehicle at 50 km/h: it is past before they can step in
        // (4.3 s to the edge at the most likely speed, 3.1 s at the fastest; past in 2.2 s).
        let early = watched(16.7, 5.5, -1.0, 0.2);
        let t = nearest_in_path(none, [early], 1.2, Some(13.9));
        assert_eq!(t.decision_distance(), None, "{t:?}");
    }
}
