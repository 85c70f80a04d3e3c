//! `FLYD_Obstacle`: the nearest obstacle in the corridor, built from perception's debounced
//! obstacle and road.

use std::time::Duration;

use super::{
    AliveCounter, CanMessage, DecodeError, FRAME_LEN, seal, to_raw_signed, to_raw_unsigned, unseal,
};
use crate::perception::{RoadEstimate, Tracked};

/// Raw layout constants (the DBC test checks the codec against `config/flyd.dbc`).
use super::dbc::flyd_obstacle as layout;

/// `FLYD_Obstacle`: the nearest obstacle in the corridor, in the vehicle frame of
/// [`crate::geometry`], and whether the road it stands on was measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleMsg {
    /// `false`: no obstacle; the obstacle's fields are sent as 0 and must be ignored.
    pub valid: bool,
    /// Distance along the corridor's path ([`PathMsg`]; straight: vehicle-frame z), m.
    ///
    /// [`PathMsg`]: super::PathMsg
    pub distance: f64,
    /// Offset from that path (straight: vehicle-frame x), m, positive to the right.
    pub lateral: f64,
    /// Confidence, percent (0..=100).
    pub confidence: f64,
    /// Seen on enough consecutive frames: what the decision acts on.
    pub confirmed: bool,
    /// Height of the obstacle's top above the road, m.
    pub height: f64,
    /// The road was measured on the latest frame (else heights are from the calibration's
    /// mount); sent with or without an obstacle.
    pub road_measured: bool,
}

impl ObstacleMsg {
    /// "No obstacle", road not measured.
    pub const NONE: Self = Self {
        valid: false,
        distance: 0.0,
        lateral: 0.0,
        confidence: 0.0,
        confirmed: false,
        height: 0.0,
        road_measured: false,
    };

    /// The message for perception's debounced obstacle and road.
    pub fn of(tracked: &Tracked, road: &RoadEstimate) -> Self {
        let base = Self {
            road_measured: road.measured(),
            ..Self::NONE
        };
        match tracked.obstacle {
            Some(o) => Self {
                valid: true,
                distance: o.distance,
                lateral: o.lateral,
                confidence: o.confidence,
                confirmed: tracked.confirmed,
                height: o.top,
                ..base
            },
            None => base,
        }
    }
}

impl CanMessage for ObstacleMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        // An obstacle without a finite position is no obstacle a receiver could act on.
        let valid = self.valid
            && self.distance.is_finite()
            && self.lateral.is_finite()
            && self.confidence.is_finite();
        if valid {
            OBSTACLE_VALID.put(&mut w, 1);
            DISTANCE.put(
                &mut w,
                to_raw_unsigned(self.distance, DISTANCE_PER_UNIT, DISTANCE.max_unsigned(), 0),
            );
            LATERAL.put_signed(
                &mut w,
                to_raw_signed(self.lateral, LATERAL_PER_UNIT, LATERAL),
            );
            CONFIDENCE.put(
                &mut w,
                to_raw_unsigned(
                    self.confidence,
                    CONFIDENCE_PER_UNIT,
                    CONFIDENCE_MAX as u64,
                    0,
                ),
            );
            OBSTACLE_CONFIRMED.put(&mut w, u64::from(self.confirmed));
            if self.height.is_finite() {
                HEIGHT.put(
                    &mut w,
                    to_raw_unsigned(self.height, HEIGHT_PER_UNIT, HEIGHT.max_unsigned(), 0),
                );
            }
        }
        ROAD_MEASURED.put(&mut w, u64::from(self.road_measured));
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let confidence = CONFIDENCE.get(w);
        if confidence > CONFIDENCE_MAX as u64 {
            return Err(DecodeError::OutOfRange {
                signal: CONFIDENCE_NAME,
                raw: confidence,
            });
        }
        let msg = Self {
            valid: OBSTACLE_VALID.get(w) == 1,
            distance: DISTANCE.get(w) as f64 / DISTANCE_PER_UNIT,
            lateral: LATERAL.get_signed(w) as f64 / LATERAL_PER_UNIT,
            confidence: confidence as f64,
            confirmed: OBSTACLE_CONFIRMED.get(w) == 1,
            height: HEIGHT.get(w) as f64 / HEIGHT_PER_UNIT,
            road_measured: ROAD_MEASURED.get(w) == 1,
        };
        Ok((msg, counter))
    }
}
default_codec!(ObstacleMsg);
