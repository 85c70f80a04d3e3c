//! `VCU_Motion`: the vehicle's own motion, received (flyd encodes it too, as the mock vehicle
//! and the tests send it).

use std::time::Duration;

use super::{AliveCounter, CanMessage, DecodeError, FRAME_LEN, seal, to_raw_signed, unseal};

/// Raw layout constants (the DBC test checks the codec against `config/flyd.dbc`).
use super::dbc::vcu_motion as layout;

/// `VCU_Motion`: the vehicle's own motion, sent by the vehicle (VCU) and received by flyd.
///
/// flyd decodes it ([`crate::can::motion_monitor::MotionMonitor`] checks it further: counter, age,
/// plausibility); it encodes it too, as the mock vehicle and the tests send it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionMsg {
    /// The sender vouches for the values (`MotionValid` = 1); 0 = the VCU does not know its
    /// motion (a wheel-speed sensor fault): the values must be ignored.
    pub valid: bool,
    /// Longitudinal speed, m/s, positive forward, negative reversing (resolution 0.01).
    pub speed: f64,
    /// Yaw rate, rad/s, positive turning left (counter-clockwise seen from above, ISO 8855;
    /// resolution 0.0001).
    pub yaw_rate: f64,
}

impl CanMessage for MotionMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        let valid = self.valid && self.speed.is_finite() && self.yaw_rate.is_finite();
        MOTION_VALID.put(&mut w, u64::from(valid));
        SPEED.put_signed(&mut w, to_raw_signed(self.speed, SPEED_PER_UNIT, SPEED));
        YAW_RATE.put_signed(
            &mut w,
            to_raw_signed(self.yaw_rate, YAW_RATE_PER_UNIT, YAW_RATE),
        );
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let msg = Self {
            valid: MOTION_VALID.get(w) == 1,
            speed: SPEED.get_signed(w) as f64 / SPEED_PER_UNIT,
            yaw_rate: YAW_RATE.get_signed(w) as f64 / YAW_RATE_PER_UNIT,
        };
        Ok((msg, counter))
    }
}
default_codec!(MotionMsg);
