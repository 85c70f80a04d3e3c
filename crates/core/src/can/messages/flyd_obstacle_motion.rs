//! `FLYD_ObstacleMotion`: how the obstacle of `FLYD_Obstacle` moves, and what the decision
//! made of it: the closing speed and the time to collision.
//!
//! A message of its own: FLYD_Obstacle's eight bytes are taken, and a receiver that does not
//! care about motion keeps decoding FLYD_Obstacle unchanged. Sent with it.
//!
//! | bits   | signal          | type | scale    | range |
//! |--------|-----------------|------|----------|-------|
//! | 12     | `MotionValid`   | u1   | 1 = the confirmed obstacle's motion is established | |
//! | 13     | `ObstacleValid` | u1   | 1 = a confirmed obstacle (else the rest is 0) | |
//! | 16..32 | `ClosingSpeed`  | i16  | 0.01 m/s | positive: the gap shrinks |
//! | 32..48 | `TimeToCollision` | u16 | 0.01 s  | 0..=655.34; 655.35: not closing in |
//! | 48..64 | `Speed`         | i16  | 0.01 m/s | the obstacle's over the ground along the path |

use std::time::Duration;

use super::{
    AliveCounter, CanMessage, DecodeError, FRAME_LEN, seal, to_raw_signed, to_raw_unsigned, unseal,
};
use crate::perception::Tracked;

use super::dbc::flyd_obstacle_motion as layout;

/// The time to collision sent when the vehicle is not closing in, seconds (the raw maximum).
pub const NOT_CLOSING: f64 = layout::TIME_TO_COLLISION_MAX;

/// `FLYD_ObstacleMotion`: the confirmed obstacle's motion as the decision takes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleMotionMsg {
    /// A confirmed obstacle; `false`: the rest is sent as 0 (the time to collision as
    /// [`NOT_CLOSING`]) and must be ignored.
    pub obstacle_valid: bool,
    /// Its motion is established (else it is taken as still, `speed` 0).
    pub motion_valid: bool,
    /// The vehicle's speed less the speed the decision credits the obstacle with, m/s:
    /// positive, the gap shrinks.
    pub closing_speed: f64,
    /// The obstacle's distance (its near bound) over the closing speed, seconds;
    /// [`NOT_CLOSING`] when the gap does not shrink.
    pub time_to_collision: f64,
    /// The obstacle's measured speed over the ground along the path, m/s (0 before its motion
    /// is established).
    pub speed: f64,
}

impl ObstacleMotionMsg {
    /// No confirmed obstacle.
    pub const NONE: Self = Self {
        obstacle_valid: false,
        motion_valid: false,
        closing_speed: 0.0,
        time_to_collision: NOT_CLOSING,
        speed: 0.0,
    };

    /// The message for perception's debounced obstacle at the vehicle's speed `speed` m/s.
    pub fn of(tracked: &Tracked, speed: f64) -> Self {
        let Some(distance) = tracked.decision_distance() else {
            return Self::NONE;
        };
        let motion = tracked.motion.filter(|m| m.established);
        let closing = speed - tracked.decision_speed();
        let time_to_collision = if closing > 0.0 && distance.is_finite() {
            (distance.max(0.0) / closing).min(NOT_CLOSING)
        } else {
            NOT_CLOSING
        };
        Self {
            obstacle_valid: true,
            motion_valid: motion.is_some(),
            closing_speed: closing,
            time_to_collision,
            speed: motion.map_or(0.0, |m| m.speed),
        }
    }
}

impl CanMessage for ObstacleMotionMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        let valid = self.obstacle_valid
            && self.closing_speed.is_finite()
            && !self.time_to_collision.is_nan()
            && self.speed.is_finite();
        if valid {
            OBSTACLE_VALID.put(&mut w, 1);
            MOTION_VALID.put(&mut w, u64::from(self.motion_valid));
            CLOSING_SPEED.put_signed(
                &mut w,
                to_raw_signed(self.closing_speed, CLOSING_SPEED_PER_UNIT, CLOSING_SPEED),
            );
            TIME_TO_COLLISION.put(
                &mut w,
                to_raw_unsigned(
                    self.time_to_collision,
                    TIME_TO_COLLISION_PER_UNIT,
                    TIME_TO_COLLISION.max_unsigned(),
                    0,
                ),
            );
            SPEED.put_signed(&mut w, to_raw_signed(self.speed, SPEED_PER_UNIT, SPEED));
        } else {
            TIME_TO_COLLISION.put(&mut w, TIME_TO_COLLISION.max_unsigned());
        }
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let msg = Self {
            obstacle_valid: OBSTACLE_VALID.get(w) == 1,
            motion_valid: MOTION_VALID.get(w) == 1,
            closing_speed: CLOSING_SPEED.get_signed(w) as f64 / CLOSING_SPEED_PER_UNIT,
            time_to_collision: TIME_TO_COLLISION.get(w) as f64 / TIME_TO_COLLISION_PER_UNIT,
            speed: SPEED.get_signed(w) as f64 / SPEED_PER_UNIT,
        };
        Ok((msg, counter))
    }
}
default_codec!(ObstacleMotionMsg);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::motion::ObstacleMotion;
    use crate::perception::{Obstacle, Tracked};

    fn car(near: f64, motion: Option<ObstacleMotion>) -> Tracked {
        Tracked {
            obstacle: Some(Obstacle {
                distance: near + 0.3,
                near,
                centre: near + 0.5,
                lateral: 0.1,
                bottom: 0.3,
                top: 1.5,
                flies: 20,
                cells: 9,
                confidence: 70.0,
            }),
            confirmed: true,
            seen_frames: 12,
            motion,
            entering: None,
        }
    }

    fn moving(speed: f64, sigma: f64, established: bool) -> Option<ObstacleMotion> {
        Some(ObstacleMotion {
            speed,
            speed_sigma: sigma,
            lateral_speed: 0.0,
            lateral_sigma: 0.1,
            samples: 12,
            span: 0.4,
            established,
            closest_before: f64::INFINITY,
        })
    }

    #[test]
    fn a_followed_car_closes_by_what_is_not_credited_to_it() {
        let c = |v| AliveCounter::new(v).expect("valid counter");
        // Followed at 13.9 m/s, measured at 13.5 +- 0.2: credited 13.1, closing 0.8 m/s.
        let m = ObstacleMotionMsg::of(&car(14.0, moving(13.5, 0.2, true)), 13.9);
        let back = ObstacleMotionMsg::decode(&m.encode(c(4))).expect("decodes");
        assert!(back.obstacle_valid && back.motion_valid, "{back:?}");
        assert!((back.closing_speed - 0.8).abs() < 0.006, "{back:?}");
        assert!(
            (back.time_to_collision - 14.0 / 0.8).abs() < 0.006,
            "{back:?}"
        );
        assert!((back.speed - 13.5).abs() < 0.006, "{back:?}");
        // Not established: taken as still, closing at the vehicle's speed.
        let m = ObstacleMotionMsg::of(&car(14.0, moving(13.5, 2.0, false)), 13.9);
        assert!(
            m.obstacle_valid && !m.motion_valid && m.speed == 0.0,
            "{m:?}"
        );
        assert!((m.closing_speed - 13.9).abs() < 1e-9);
        // Pulling away: not closing.
        let m = ObstacleMotionMsg::of(&car(14.0, moving(20.0, 0.2, true)), 13.9);
        assert!(
            m.closing_speed < 0.0 && m.time_to_collision == NOT_CLOSING,
            "{m:?}"
        );
        let back = ObstacleMotionMsg::decode(&m.encode(c(5))).expect("decodes");
        assert_eq!(back.time_to_collision, NOT_CLOSING);
        // No confirmed obstacle, or values that cannot be sent: NONE.
        let none = Tracked {
            confirmed: false,
            ..car(14.0, None)
        };
        assert_eq!(ObstacleMotionMsg::of(&none, 13.9), ObstacleMotionMsg::NONE);
        assert_eq!(
            ObstacleMotionMsg::decode(&ObstacleMotionMsg::NONE.encode(c(0))),
            Ok(ObstacleMotionMsg::NONE)
        );
        let nan = ObstacleMotionMsg {
            closing_speed: f64::NAN,
            ..m
        };
        assert_eq!(
            ObstacleMotionMsg::decode(&nan.encode(c(1))),
            Ok(ObstacleMotionMsg::NONE)
        );
    }
}
