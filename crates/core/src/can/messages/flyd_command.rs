//! `FLYD_Command`: the request to the vehicle (the command, the deceleration and why), built
//! from the decision.

use std::time::Duration;

use super::{
    AliveCounter, CanMessage, DecodeError, FRAME_LEN, decode_enum, seal, to_raw_unsigned, unseal,
};
use crate::decision::{Command, CommandReason, Decision};

/// Raw layout constants (the DBC test checks the codec against `config/flyd.dbc`).
use super::dbc::flyd_command as layout;

/// `FLYD_Command`: the request to the vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandMsg {
    pub command: Command,
    /// Requested deceleration magnitude, m/s² (>= 0).
    pub requested_decel: f64,
    /// The global warning the command was decided from (dimensionless); NaN = invalid.
    pub global_warning: f64,
    pub reason: CommandReason,
}

impl CommandMsg {
    /// The frame content for `decision`, decided on `global_warning`.
    pub fn of(decision: &Decision, global_warning: f64) -> Self {
        Self {
            command: decision.command,
            requested_decel: decision.requested_decel,
            global_warning,
            reason: decision.reason,
        }
    }

    /// Largest `GlobalWarning` that can be sent; larger values saturate to it.
    pub const GLOBAL_WARNING_MAX: f64 = 65.534;
    /// Raw `GlobalWarning` meaning "invalid" (NaN).
    pub const GLOBAL_WARNING_INVALID_RAW: u16 = 0xFFFF;
}

impl CanMessage for CommandMsg {
    const NAME: &'static str = layout::NAME;
    const DEFAULT_ID: u32 = layout::ID;
    const DEFAULT_DATA_ID: u16 = layout::DATA_ID;
    const DEFAULT_PERIOD: Duration = Duration::from_millis(layout::PERIOD_MS);

    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
        use layout::*;
        let mut w = 0u64;
        COMMAND.put(&mut w, u64::from(self.command.raw()));
        REQUESTED_DECEL.put(
            &mut w,
            to_raw_unsigned(
                self.requested_decel,
                REQUESTED_DECEL_PER_UNIT,
                REQUESTED_DECEL.max_unsigned(),
                0,
            ),
        );
        let invalid = u64::from(Self::GLOBAL_WARNING_INVALID_RAW);
        GLOBAL_WARNING.put(
            &mut w,
            to_raw_unsigned(
                self.global_warning,
                GLOBAL_WARNING_PER_UNIT,
                invalid - 1,
                invalid,
            ),
        );
        COMMAND_REASON.put(&mut w, u64::from(self.reason.raw()));
        seal(w, counter, data_id)
    }

    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError> {
        use layout::*;
        let (w, counter) = unseal(data, data_id)?;
        let warning_raw = GLOBAL_WARNING.get(w);
        let global_warning = if warning_raw == u64::from(Self::GLOBAL_WARNING_INVALID_RAW) {
            f64::NAN
        } else {
            warning_raw as f64 / GLOBAL_WARNING_PER_UNIT
        };
        let msg = Self {
            command: decode_enum(COMMAND.get(w), COMMAND_NAME, Command::from_raw)?,
            requested_decel: REQUESTED_DECEL.get(w) as f64 / REQUESTED_DECEL_PER_UNIT,
            global_warning,
            reason: decode_enum(
                COMMAND_REASON.get(w),
                COMMAND_REASON_NAME,
                CommandReason::from_raw,
            )?,
        };
        Ok((msg, counter))
    }
}
default_codec!(CommandMsg);
