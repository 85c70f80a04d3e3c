//! `FLYD_Path`: the path the obstacle corridor follows ([`crate::path`]), so that the vehicle
//! and a recording know what FLYD_Obstacle's `Distance` is along and `Lateral` is from.
//!
//! A message of its own: FLYD_Obstacle's eight bytes are taken (one reserved bit left), and
//! a receiver that does not care about the path keeps decoding FLYD_Obstacle unchanged.
//!
//! | bits   | signal         | type | scale       | range |
//! |--------|----------------|------|-------------|-------|
//! | 12     | `PathValid`    | u1   | 1 = the corridor follows the vehicle's trusted motion | |
//! | 16..32 | `Curvature`    | i16  | 0.00001 1/m | -0.32768..=0.32767 (positive turning left) |
//! | 32..48 | `CurvatureNow` | i16  | 0.00001 1/m | as `Curvature` |

use std::time::Duration;

use super::{AliveCounter, CanMessage, DecodeError, FRAME_LEN, seal, to_raw_signed, unseal};
use crate::path::PathEstimate;

use super::dbc::flyd_path as layout;

/// `FLYD_Path`: the corridor's centre line and the arc of the moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathMsg {
    /// The corridor follows the vehicle's path from its trusted speed and yaw rate; `false`:
    /// straight ahead (no trusted motion on the latest frame, or `follow_path` off), the
    /// curvatures are sent as 0.
    pub valid: bool,
    /// The path the vehicle has held (the corridor's centre line: FLYD_Obstacle's `Distance`
    /// is along it, `Lateral` from it), 1/m, positive turning left; 0: straight.
    pub curvature: f64,
    /// The arc of the speed and yaw rate of the moment: an obstacle is on both paths.
    pub curvature_now: f64,
}

impl PathMsg {
    /// Straight ahead, not from the vehicle's motion.
    pub const NONE: Self = Self {
        valid: false,
        curvature: 0.0,
        curvature_now: 0.0,
    };

    /// The message for the paths of the latest frame (`None`: no trusted motion).
    pub fn of(estimate: Option<PathEstimate>) -> Self {
        estimate.map_or(Self::NONE, |e| Self {
            valid: true,
            curvature: e.held.curvature,
            curvature_now: e.now.curvature,
        })
    }
}

impl CanMessage for PathMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        // A path without a finite curvature is no path a receiver could follow.
        let valid = self.valid && self.curvature.is_finite() && self.curvature_now.is_finite();
        if valid {
            PATH_VALID.put(&mut w, 1);
            CURVATURE.put_signed(
                &mut w,
                to_raw_signed(self.curvature, CURVATURE_PER_UNIT, CURVATURE),
            );
            CURVATURE_NOW.put_signed(
                &mut w,
                to_raw_signed(self.curvature_now, CURVATURE_PER_UNIT, CURVATURE_NOW),
            );
        }
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let msg = Self {
            valid: PATH_VALID.get(w) == 1,
            curvature: CURVATURE.get_signed(w) as f64 / CURVATURE_PER_UNIT,
            curvature_now: CURVATURE_NOW.get_signed(w) as f64 / CURVATURE_PER_UNIT,
        };
        Ok((msg, counter))
    }
}
default_codec!(PathMsg);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::path::PredictedPath;

    #[test]
    fn a_path_round_trips_at_its_resolution_and_saturates() {
        let c = |v| AliveCounter::new(v).expect("valid counter");
        let bend = PathMsg::of(Some(PathEstimate {
            held: PredictedPath::arc(1.0 / 60.0),
            now: PredictedPath::arc(-0.2),
        }));
        let back = PathMsg::decode(&bend.encode(c(3))).expect("decodes");
        assert!(back.valid);
        assert!((back.curvature - 1.0 / 60.0).abs() <= 0.5e-5, "{back:?}");
        assert_eq!(back.curvature_now, -0.2);
        assert_eq!(
            PathMsg::decode(&PathMsg::of(None).encode(c(0))),
            Ok(PathMsg::NONE)
        );
        // Beyond the signal: clamped, never wrapped; not finite: not valid.
        let wild = PathMsg {
            valid: true,
            curvature: 1.0,
            curvature_now: -1.0,
        };
        let back = PathMsg::decode(&wild.encode(c(1))).expect("decodes");
        assert_eq!((back.curvature, back.curvature_now), (0.32767, -0.32768));
        let nan = PathMsg {
            curvature: f64::NAN,
            ..wild
        };
        assert_eq!(PathMsg::decode(&nan.encode(c(2))), Ok(PathMsg::NONE));
    }
}
