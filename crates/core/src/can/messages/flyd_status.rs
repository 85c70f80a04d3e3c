//! `FLYD_Status`: flyd's health (state, faults, sensor faults, the motion's, perception's age,
//! generation and frame rates).

use std::time::Duration;

use super::{
    AliveCounter, CanMessage, DecodeError, FRAME_LEN, decode_enum, seal, to_raw_unsigned, unseal,
};
use crate::sensor::SensorFaults;
use crate::status::{FaultBits, State};

/// Raw layout constants (the DBC test checks the codec against `config/flyd.dbc`).
use super::dbc::flyd_status as layout;

/// `FLYD_Status`: flyd's health.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatusMsg {
    pub state: State,
    pub faults: FaultBits,
    /// Age of the perception snapshot the current command was decided from; saturates at
    /// 4095 ms (use [`Duration::MAX`] for "no snapshot yet").
    pub perception_age: Duration,
    /// Which sensor checks failed ([`crate::sensor`]); any of them also sets `CAMERA_ERROR`.
    pub sensor: SensorFaults,
    /// The vehicle's motion is not known (missing, stale, invalid or implausible `VCU_Motion`,
    /// [`crate::kinematics`]): the decision assumes the configured highest speed.
    pub motion_fault: bool,
    /// Evolution rate, generations per second (resolution 2, saturates at 510).
    pub generations_per_sec: f64,
    /// Left camera frame rate, fps (resolution 0.5, saturates at 127.5).
    pub cam_fps_left: f64,
    /// Right camera frame rate, fps (resolution 0.5, saturates at 127.5).
    pub cam_fps_right: f64,
}

impl CanMessage for StatusMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        STATE.put(&mut w, u64::from(self.state.raw()));
        MOTION_FAULT.put(&mut w, u64::from(self.motion_fault));
        FAULT_BITS.put(&mut w, u64::from(self.faults.bits()));
        let age_ms = u64::try_from(self.perception_age.as_millis()).unwrap_or(u64::MAX);
        PERCEPTION_AGE_MS.put(&mut w, age_ms.min(PERCEPTION_AGE_MS.max_unsigned()));
        SENSOR_FAULTS.put(&mut w, u64::from(self.sensor.bits()));
        GENERATIONS_PER_SEC.put(
            &mut w,
            to_raw_unsigned(
                self.generations_per_sec,
                GENERATIONS_PER_SEC_PER_UNIT,
                GENERATIONS_PER_SEC.max_unsigned(),
                0,
            ),
        );
        CAM_FPS_LEFT.put(
            &mut w,
            to_raw_unsigned(
                self.cam_fps_left,
                CAM_FPS_LEFT_PER_UNIT,
                CAM_FPS_LEFT.max_unsigned(),
                0,
            ),
        );
        CAM_FPS_RIGHT.put(
            &mut w,
            to_raw_unsigned(
                self.cam_fps_right,
                CAM_FPS_RIGHT_PER_UNIT,
                CAM_FPS_RIGHT.max_unsigned(),
                0,
            ),
        );
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let msg = Self {
            state: decode_enum(STATE.get(w), STATE_NAME, State::from_raw)?,
            faults: FaultBits::from_bits(FAULT_BITS.get(w) as u8),
            perception_age: Duration::from_millis(PERCEPTION_AGE_MS.get(w)),
            sensor: SensorFaults::from_bits(SENSOR_FAULTS.get(w) as u8),
            motion_fault: MOTION_FAULT.get(w) == 1,
            generations_per_sec: GENERATIONS_PER_SEC.get(w) as f64 / GENERATIONS_PER_SEC_PER_UNIT,
            cam_fps_left: CAM_FPS_LEFT.get(w) as f64 / CAM_FPS_LEFT_PER_UNIT,
            cam_fps_right: CAM_FPS_RIGHT.get(w) as f64 / CAM_FPS_RIGHT_PER_UNIT,
        };
        Ok((msg, counter))
    }
}
default_codec!(StatusMsg);
