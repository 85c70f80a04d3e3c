//! Typed flyd CAN messages and their 8-byte encoding (the contract of `config/flyd.dbc`).
//!
//! # Frame layout common to every message
//! Classic CAN, standard 11-bit IDs, DLC 8, all signals Intel (little-endian): a signal with DBC
//! start bit `s` and length `n` occupies bits `s..s+n` of the frame read as one little-endian
//! `u64` (bit 0 = LSB of byte 0).
//!
//! | bits    | signal         | meaning |
//! |---------|----------------|---------|
//! | 0..8    | `CRC8`         | CRC-8 SAE J1850 over Data ID (lo, hi) then bytes 1..=7, see [`super::crc`] |
//! | 8..12   | `AliveCounter` | 0..=14, +1 per transmission of this message, 14 wraps to 0 ([`AliveCounter`]) |
//!
//! This is the AUTOSAR E2E profile 1 arrangement (CRC in byte 0, counter in the low nibble of
//! byte 1, a 16-bit Data ID folded into the CRC but not transmitted). It is *in the style of*
//! E2E, not a certified E2E library: the exact computation is the one in [`super::crc::e2e_crc`].
//!
//! # Per-message layout
//! `FLYD_Command` (default ID 0x120, Data ID 0x0120, every 20 ms):
//!
//! | bits   | signal           | type | scale              | range |
//! |--------|------------------|------|--------------------|-------|
//! | 12..16 | `Command`        | u4   | enum [`Command`](crate::decision::Command) | 0..=2 |
//! | 16..32 | `RequestedDecel` | u16  | 0.01 m/s²          | 0..=655.35 |
//! | 32..48 | `GlobalWarning`  | u16  | 0.001 (no unit)    | 0..=65.534; raw 0xFFFF = invalid (NaN) |
//! | 48..52 | `CommandReason`  | u4   | enum [`CommandReason`](crate::decision::CommandReason) | 0..=2 |
//!
//! `FLYD_Status` (default ID 0x121, Data ID 0x0121, every 20 ms):
//!
//! | bits   | signal              | type | scale | range |
//! |--------|---------------------|------|-------|-------|
//! | 12..15 | `State`             | u3   | enum [`State`] | 0..=4 |
//! | 15     | `MotionFault`       | u1   | 1 = vehicle motion unknown | 0..=1 |
//! | 16..24 | `FaultBits`         | u8   | bitfield [`FaultBits`] | any |
//! | 24..36 | `PerceptionAgeMs`   | u12  | 1 ms  | 0..=4095 (4095 = that old or older, or never) |
//! | 36..40 | `SensorFaults`      | u4   | bitfield [`SensorFaults`] | any (each also sets `CAMERA_ERROR`) |
//! | 40..48 | `GenerationsPerSec` | u8   | 2 /s  | 0..=510 |
//! | 48..56 | `CamFpsLeft`        | u8   | 0.5 fps | 0..=127.5 |
//! | 56..64 | `CamFpsRight`       | u8   | 0.5 fps | 0..=127.5 |
//!
//! `FLYD_Obstacle` (default ID 0x122, Data ID 0x0122, every 100 ms):
//!
//! | bits   | signal          | type | scale  | range |
//! |--------|-----------------|------|--------|-------|
//! | 12..13 | `ObstacleValid` | u1   | 0 none / 1 valid | |
//! | 16..32 | `Distance`      | u16  | 0.01 m | 0..=655.35 (along the path of `FLYD_Path`; straight: vehicle-frame z) |
//! | 32..48 | `Lateral`       | i16  | 0.01 m | -327.68..=327.67 (offset from that path, positive right; straight: vehicle-frame x) |
//! | 48..56 | `Confidence`    | u8   | 1 %    | 0..=100 |
//!
//! `FLYD_Path` (default ID 0x123, Data ID 0x0123, every 100 ms): see [`PathMsg`].
//!
//! `VCU_Motion` (received; default ID 0x110, Data ID 0x0110, every 20 ms, sent by the VCU):
//!
//! | bits   | signal        | type | scale       | range |
//! |--------|---------------|------|-------------|-------|
//! | 12     | `MotionValid` | u1   | 1 = values valid | |
//! | 16..32 | `Speed`       | i16  | 0.01 m/s    | -327.68..=327.67 (positive forward) |
//! | 32..48 | `YawRate`     | i16  | 0.0001 rad/s | -3.2768..=3.2767 (positive turning left) |
//!
//! Bits not listed are reserved: sent as 0, ignored on decode (so a later version can use them
//! without breaking older receivers).
//!
//! # Saturation, not wrapping
//! Physical values are rounded to the nearest raw step and **clamped** to the signal's range
//! (negative values of unsigned signals become 0): an out-of-range value must never wrap into a
//! plausible small one (a 700 m distance would otherwise read as 44.64 m). Non-finite inputs:
//! `GlobalWarning` NaN is sent as raw 0xFFFF (`INVALID`), ±inf clamp like large values; an
//! obstacle with a non-finite distance, lateral offset or confidence is sent as "no obstacle"
//! (`ObstacleValid` = 0, other fields 0), since it has no position; other NaNs are sent as 0.
//!
//! # Decoding
//! [`CanMessage::decode_with`] checks, in this order: length 8, CRC (with the expected Data ID),
//! alive counter in 0..=14, enum signals in range, `Confidence` <= 100. The receiver-side counter
//! check (repetition, loss) is the caller's business: it gets the counter back.
//!
//! [`State`]: crate::status::State
//! [`FaultBits`]: crate::status::FaultBits
//! [`SensorFaults`]: crate::sensor::SensorFaults

use std::time::Duration;

use thiserror::Error;

use super::crc::e2e_crc;

/// Every flyd frame is classic CAN with 8 data bytes.
pub const FRAME_LEN: usize = 8;

/// Why a received frame was rejected.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DecodeError {
    #[error("frame has {actual} data bytes, expected {FRAME_LEN}")]
    WrongLength { actual: usize },
    #[error(
        "CRC mismatch: frame has {received:#04x}, expected {expected:#04x} (corrupt, or wrong Data ID)"
    )]
    CrcMismatch { received: u8, expected: u8 },
    #[error("alive counter {0} out of range 0..={max}", max = AliveCounter::MAX)]
    InvalidCounter(u8),
    #[error("signal {signal} has raw value {raw}, outside its defined range")]
    OutOfRange { signal: &'static str, raw: u64 },
}

// ---------------------------------------------------------------------------------------------
// Alive counter

/// The 4-bit E2E alive counter: 0..=14, then back to 0.
///
/// 15 is never sent, as in AUTOSAR E2E profile 1, so a stuck-at-ones nibble (0xF) is detectable
/// and decoding rejects it. Receivers compute the gap with [`AliveCounter::delta`]
/// (modulo 15): 0 = repeated frame, 1 = next, >1 = lost frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct AliveCounter(u8);

impl AliveCounter {
    /// Largest value sent.
    pub const MAX: u8 = 14;
    /// Number of distinct values (the modulus of the counter).
    pub const MODULUS: u8 = Self::MAX + 1;
    pub const ZERO: Self = Self(0);

    /// `None` when `value` > [`Self::MAX`].
    pub const fn new(value: u8) -> Option<Self> {
        if value <= Self::MAX {
            Some(Self(value))
        } else {
            None
        }
    }

    pub const fn value(self) -> u8 {
        self.0
    }

    /// The following counter value (14 wraps to 0).
    #[must_use]
    pub const fn next(self) -> Self {
        if self.0 >= Self::MAX {
            Self(0)
        } else {
            Self(self.0 + 1)
        }
    }

    /// Returns the current value and steps to the next: one call per transmission.
    pub fn advance(&mut self) -> Self {
        let current = *self;
        *self = self.next();
        current
    }

    /// How far `newer` is ahead of `self`, modulo 15 (0 = same value).
    pub const fn delta(self, newer: Self) -> u8 {
        (newer.0 + Self::MODULUS - self.0) % Self::MODULUS
    }
}

/// An enum signal's raw value as `T`, or [`DecodeError::OutOfRange`] naming the signal.
fn decode_enum<T>(
    raw: u64,
    signal: &'static str,
    from_raw: fn(u8) -> Option<T>,
) -> Result<T, DecodeError> {
    u8::try_from(raw)
        .ok()
        .and_then(from_raw)
        .ok_or(DecodeError::OutOfRange { signal, raw })
}

// ---------------------------------------------------------------------------------------------
// Bit fields and physical <-> raw conversion

/// An Intel signal: `len` bits starting at bit `start` of the little-endian frame word.
#[derive(Debug, Clone, Copy)]
struct Field {
    start: u32,
    len: u32,
}

impl Field {
    const fn mask(self) -> u64 {
        if self.len >= 64 {
            u64::MAX
        } else {
            (1u64 << self.len) - 1
        }
    }

    const fn max_unsigned(self) -> u64 {
        self.mask()
    }

    const fn min_signed(self) -> i64 {
        -(1i64 << (self.len - 1))
    }

    const fn max_signed(self) -> i64 {
        (1i64 << (self.len - 1)) - 1
    }

    fn put(self, word: &mut u64, raw: u64) {
        *word |= (raw & self.mask()) << self.start;
    }

    fn put_signed(self, word: &mut u64, raw: i64) {
        // Two's complement truncated to the field; the value was clamped to the field first.
        self.put(word, raw as u64);
    }

    fn get(self, word: u64) -> u64 {
        (word >> self.start) & self.mask()
    }

    fn get_signed(self, word: u64) -> i64 {
        let raw = self.get(word);
        let sign = 1u64 << (self.len - 1);
        if raw & sign != 0 {
            (raw | !self.mask()) as i64
        } else {
            raw as i64
        }
    }
}

// Scales are given as raw steps per physical unit (the inverse of the DBC factor) so that
// decoding divides by an exact integer: 1234 / 100.0 is the f64 nearest 12.34, whereas
// 1234.0 * 0.01 is not.

/// Physical -> raw for an unsigned signal, clamped to `0..=max_raw`; NaN gives `nan_raw`.
fn to_raw_unsigned(phys: f64, per_unit: f64, max_raw: u64, nan_raw: u64) -> u64 {
    if phys.is_nan() {
        return nan_raw;
    }
    let steps = (phys * per_unit).round();
    if steps <= 0.0 {
        0
    } else if steps >= max_raw as f64 {
        max_raw
    } else {
        steps as u64
    }
}

/// Physical -> raw for a signed signal, clamped to the field's range; NaN gives 0.
fn to_raw_signed(phys: f64, per_unit: f64, field: Field) -> i64 {
    if phys.is_nan() {
        return 0;
    }
    let steps = (phys * per_unit).round();
    let (lo, hi) = (field.min_signed(), field.max_signed());
    if steps <= lo as f64 {
        lo
    } else if steps >= hi as f64 {
        hi
    } else {
        steps as i64
    }
}

/// Raw layout constants. Kept private: the DBC test checks the encoder against
/// `config/flyd.dbc`, not against these.
mod layout {
    use super::Field;

    pub const COUNTER: Field = Field { start: 8, len: 4 };
}

/// Puts the counter in, then the CRC over Data ID + bytes 1..=7 into byte 0.
fn seal(mut word: u64, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN] {
    layout::COUNTER.put(&mut word, u64::from(counter.value()));
    let mut bytes = word.to_le_bytes();
    bytes[0] = e2e_crc(data_id, &bytes[1..]);
    bytes
}

/// Checks length, CRC and counter; returns the frame word and the counter.
fn unseal(data: &[u8], data_id: u16) -> Result<(u64, AliveCounter), DecodeError> {
    let bytes: [u8; FRAME_LEN] = data
        .try_into()
        .map_err(|_| DecodeError::WrongLength { actual: data.len() })?;
    let expected = e2e_crc(data_id, &bytes[1..]);
    if bytes[0] != expected {
        return Err(DecodeError::CrcMismatch {
            received: bytes[0],
            expected,
        });
    }
    let word = u64::from_le_bytes(bytes);
    let raw_counter = layout::COUNTER.get(word) as u8;
    let counter = AliveCounter::new(raw_counter).ok_or(DecodeError::InvalidCounter(raw_counter))?;
    Ok((word, counter))
}

// ---------------------------------------------------------------------------------------------
// Messages

/// What every flyd message shares: defaults for its CAN ID, E2E Data ID and period, and the
/// framing (CRC + counter) around its signals.
///
/// The Data ID defaults to the default CAN ID, but the two are independent settings: moving a
/// message to another CAN ID keeps its Data ID unless both ends change it.
pub trait CanMessage: Sized {
    /// Message name in `config/flyd.dbc`.
    const NAME: &'static str;
    /// Default standard CAN ID.
    const DEFAULT_ID: u32;
    /// Default E2E Data ID (folded into the CRC, not transmitted).
    const DEFAULT_DATA_ID: u16;
    /// Default transmission period (`GenMsgCycleTime` in the DBC).
    const DEFAULT_PERIOD: Duration;

    /// The 8 data bytes, CRC computed with `data_id`.
    fn encode_with(&self, counter: AliveCounter, data_id: u16) -> [u8; FRAME_LEN];

    /// Checks and decodes a frame's data, CRC checked with `data_id`; returns the counter too.
    fn decode_with(data: &[u8], data_id: u16) -> Result<(Self, AliveCounter), DecodeError>;
}

/// `encode`/`decode` with the default Data ID, as inherent methods so callers need no trait
/// import for the common case.
macro_rules! default_codec {
    ($ty:ty) => {
        impl $ty {
            /// The 8 data bytes, with the default Data ID.
            pub fn encode(&self, counter: AliveCounter) -> [u8; FRAME_LEN] {
                self.encode_with(counter, <Self as CanMessage>::DEFAULT_DATA_ID)
            }

            /// Checks (length, CRC with the default Data ID, counter, ranges) and decodes.
            pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
                Self::decode_with(data, <Self as CanMessage>::DEFAULT_DATA_ID).map(|(m, _)| m)
            }
        }
    };
}

// One file a message, named after it: its layout, its fields and its codec over the framing
// above.
mod flyd_command;
mod flyd_obstacle;
mod flyd_path;
mod flyd_status;
mod vcu_motion;

pub use flyd_command::CommandMsg;
pub use flyd_obstacle::ObstacleMsg;
pub use flyd_path::PathMsg;
pub use flyd_status::StatusMsg;
pub use vcu_motion::MotionMsg;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decision::{Command, CommandReason};
    use crate::sensor::SensorFaults;
    use crate::status::{FaultBits, State};

    #[test]
    fn command_msg_carries_the_decision() {
        use crate::decision::{Decider, DecisionConfig, DecisionInput};
        let mut decider = Decider::new(DecisionConfig::default()).expect("valid");
        let input = DecisionInput {
            global_warning: 9.0,
            ..DecisionInput::at_speed(Some(3.0), 30.0 / 3.6)
        };
        let d = decider.update(input, Duration::ZERO);
        let msg = CommandMsg::of(&d, 9.0);
        assert_eq!(
            (
                msg.command,
                msg.requested_decel,
                msg.global_warning,
                msg.reason
            ),
            // 3 m ahead at 30 km/h leaves no room: the most a STOP asks for.
            (Command::Stop, 9.0, 9.0, CommandReason::Perception)
        );
    }
    use crate::can::crc::crc8_j1850;

    fn c(v: u8) -> AliveCounter {
        AliveCounter::new(v).expect("valid counter")
    }

    fn sample_command() -> CommandMsg {
        CommandMsg {
            command: Command::Stop,
            requested_decel: 4.25,
            global_warning: 0.734,
            reason: CommandReason::Perception,
        }
    }

    #[test]
    fn counter_wraps_after_14_and_never_yields_15() {
        let mut counter = AliveCounter::ZERO;
        let seen: Vec<u8> = (0..31).map(|_| counter.advance().value()).collect();
        let want: Vec<u8> = (0..31).map(|i| (i % 15) as u8).collect();
        assert_eq!(seen, want);
        assert_eq!(AliveCounter::new(15), None);
        assert_eq!(c(14).next(), c(0));
    }

    #[test]
    fn counter_delta_is_modulo_15() {
        assert_eq!(c(3).delta(c(3)), 0);
        assert_eq!(c(3).delta(c(4)), 1);
        assert_eq!(c(14).delta(c(0)), 1);
        assert_eq!(c(13).delta(c(2)), 4);
    }

    #[test]
    fn known_command_frame() {
        // Hand-computed: Command=2 in the high nibble of byte 1 with counter 5 in the low
        // nibble; decel 4.25 -> 425 = 0x01A9; warning 0.734 -> 734 = 0x02DE; reason 0.
        let bytes = sample_command().encode(c(5));
        assert_eq!(&bytes[1..], &[0x25, 0xA9, 0x01, 0xDE, 0x02, 0x00, 0x00]);
        let mut crc_input = vec![0x20, 0x01];
        crc_input.extend_from_slice(&bytes[1..]);
        assert_eq!(bytes[0], crc8_j1850(&crc_input));
    }

    #[test]
    fn roundtrips() {
        let cmd = sample_command();
        let (back, counter) = CommandMsg::decode_with(&cmd.encode(c(9)), 0x0120).expect("decodes");
        assert_eq!(counter, c(9));
        assert_eq!(back, cmd);

        let status = StatusMsg {
            state: State::Fault,
            faults: FaultBits::STEREO_SKEW | FaultBits::INTERNAL,
            perception_age: Duration::from_millis(987),
            sensor: SensorFaults::FROZEN | SensorFaults::BLIND,
            motion_fault: true,
            generations_per_sec: 64.0,
            cam_fps_left: 14.5,
            cam_fps_right: 15.0,
        };
        assert_eq!(StatusMsg::decode(&status.encode(c(14))), Ok(status));

        let obstacle = ObstacleMsg {
            valid: true,
            distance: 12.34,
            lateral: -1.5,
            confidence: 87.0,
            confirmed: true,
            height: 1.76,
            road_measured: true,
        };
        assert_eq!(ObstacleMsg::decode(&obstacle.encode(c(0))), Ok(obstacle));
        let road_only = ObstacleMsg {
            road_measured: true,
            ..ObstacleMsg::NONE
        };
        assert_eq!(ObstacleMsg::decode(&road_only.encode(c(2))), Ok(road_only));
        assert_eq!(
            ObstacleMsg::decode(&ObstacleMsg::NONE.encode(c(1))),
            Ok(ObstacleMsg::NONE)
        );
    }

    #[test]
    fn every_enum_value_roundtrips() {
        for &command in Command::ALL {
            for &reason in CommandReason::ALL {
                let msg = CommandMsg {
                    command,
                    reason,
                    ..sample_command()
                };
                assert_eq!(CommandMsg::decode(&msg.encode(c(1))), Ok(msg));
            }
        }
        for &state in State::ALL {
            let msg = StatusMsg {
                state,
                faults: FaultBits::all(),
                perception_age: Duration::ZERO,
                sensor: SensorFaults::from_bits(0x0F),
                motion_fault: false,
                generations_per_sec: 0.0,
                cam_fps_left: 0.0,
                cam_fps_right: 0.0,
            };
            assert_eq!(StatusMsg::decode(&msg.encode(c(1))), Ok(msg));
        }
    }

    #[test]
    fn values_saturate_instead_of_wrapping() {
        let cmd = CommandMsg {
            requested_decel: 1e9,
            global_warning: 1e9,
            ..sample_command()
        };
        let back = CommandMsg::decode(&cmd.encode(c(0))).expect("decodes");
        assert_eq!(back.requested_decel, 655.35);
        assert_eq!(back.global_warning, CommandMsg::GLOBAL_WARNING_MAX);

        let neg = CommandMsg {
            requested_decel: -3.0,
            global_warning: -1.0,
            ..sample_command()
        };
        let back = CommandMsg::decode(&neg.encode(c(0))).expect("decodes");
        assert_eq!((back.requested_decel, back.global_warning), (0.0, 0.0));

        let inf = CommandMsg {
            global_warning: f64::INFINITY,
            ..sample_command()
        };
        let back = CommandMsg::decode(&inf.encode(c(0))).expect("decodes");
        assert_eq!(back.global_warning, CommandMsg::GLOBAL_WARNING_MAX);

        let status = StatusMsg {
            state: State::Running,
            faults: FaultBits::empty(),
            perception_age: Duration::MAX,
            sensor: SensorFaults::empty(),
            motion_fault: false,
            generations_per_sec: 5000.0,
            cam_fps_left: 1000.0,
            cam_fps_right: -5.0,
        };
        let back = StatusMsg::decode(&status.encode(c(0))).expect("decodes");
        assert_eq!(back.perception_age, Duration::from_millis(4095));
        assert_eq!(back.generations_per_sec, 510.0);
        assert_eq!(back.cam_fps_left, 127.5);
        assert_eq!(back.cam_fps_right, 0.0);

        let far = ObstacleMsg {
            valid: true,
            distance: 700.0,
            lateral: -400.0,
            confidence: 250.0,
            confirmed: false,
            height: 9.0,
            road_measured: false,
        };
        let back = ObstacleMsg::decode(&far.encode(c(0))).expect("decodes");
        assert_eq!(back.height, 5.1);
        assert_eq!(back.distance, 655.35);
        assert_eq!(back.lateral, -327.68);
        assert_eq!(back.confidence, 100.0);
        let right = ObstacleMsg {
            lateral: 400.0,
            ..far
        };
        let back = ObstacleMsg::decode(&right.encode(c(0))).expect("decodes");
        assert_eq!(back.lateral, 327.67);
    }

    #[test]
    fn nan_warning_is_sent_as_invalid() {
        let cmd = CommandMsg {
            global_warning: f64::NAN,
            ..sample_command()
        };
        let bytes = cmd.encode(c(0));
        assert_eq!(&bytes[4..6], &[0xFF, 0xFF]);
        let back = CommandMsg::decode(&bytes).expect("decodes");
        assert!(back.global_warning.is_nan());
    }

    #[test]
    fn obstacle_without_finite_position_is_sent_as_none() {
        for bad in [f64::NAN, f64::INFINITY] {
            let msg = ObstacleMsg {
                valid: true,
                distance: bad,
                lateral: 0.0,
                confidence: 50.0,
                confirmed: true,
                height: 1.7,
                road_measured: false,
            };
            assert_eq!(
                ObstacleMsg::decode(&msg.encode(c(2))),
                Ok(ObstacleMsg::NONE)
            );
        }
    }

    #[test]
    fn decode_rejects_bad_frames() {
        let good = sample_command().encode(c(3));
        assert_eq!(
            CommandMsg::decode(&good[..7]),
            Err(DecodeError::WrongLength { actual: 7 })
        );

        // Any single bit flip in bytes 0..=7 must be caught by the CRC.
        for byte in 0..FRAME_LEN {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                assert!(
                    matches!(
                        CommandMsg::decode(&bad),
                        Err(DecodeError::CrcMismatch { .. })
                    ),
                    "flip byte {byte} bit {bit} not detected"
                );
            }
        }

        // Right layout, wrong Data ID (e.g. a Status frame read as a Command).
        assert!(matches!(
            CommandMsg::decode_with(&good, StatusMsg::DEFAULT_DATA_ID),
            Err(DecodeError::CrcMismatch { .. })
        ));
    }

    /// Frames with a correct CRC but a field out of range (as a faulty sender could produce).
    #[test]
    fn decode_rejects_out_of_range_values() {
        fn resealed(mut bytes: [u8; 8], data_id: u16) -> [u8; 8] {
            bytes[0] = e2e_crc(data_id, &bytes[1..]);
            bytes
        }
        let good = sample_command().encode(c(3));

        let mut counter15 = good;
        counter15[1] |= 0x0F;
        assert_eq!(
            CommandMsg::decode(&resealed(counter15, 0x0120)),
            Err(DecodeError::InvalidCounter(15))
        );

        let mut command3 = good;
        command3[1] = (command3[1] & 0x0F) | 0x30;
        assert_eq!(
            CommandMsg::decode(&resealed(command3, 0x0120)),
            Err(DecodeError::OutOfRange {
                signal: "Command",
                raw: 3
            })
        );

        let mut reason7 = good;
        reason7[6] = 0x07;
        assert_eq!(
            CommandMsg::decode(&resealed(reason7, 0x0120)),
            Err(DecodeError::OutOfRange {
                signal: "CommandReason",
                raw: 7
            })
        );

        let status = StatusMsg {
            state: State::Running,
            faults: FaultBits::empty(),
            perception_age: Duration::ZERO,
            sensor: SensorFaults::empty(),
            motion_fault: false,
            generations_per_sec: 0.0,
            cam_fps_left: 0.0,
            cam_fps_right: 0.0,
        }
        .encode(c(0));
        let mut state6 = status;
        state6[1] = 0x60;
        assert_eq!(
            StatusMsg::decode(&resealed(state6, 0x0121)),
            Err(DecodeError::OutOfRange {
                signal: "State",
                raw: 6
            })
        );
        // Bit 15 is MotionFault, not part of State.
        let mut motion = status;
        motion[1] = 0x90;
        let decoded = StatusMsg::decode(&resealed(motion, 0x0121)).expect("decodes");
        assert_eq!(
            (decoded.state, decoded.motion_fault),
            (State::Running, true)
        );

        let mut conf = ObstacleMsg::NONE.encode(c(0));
        conf[6] = 101;
        assert_eq!(
            ObstacleMsg::decode(&resealed(conf, 0x0122)),
            Err(DecodeError::OutOfRange {
                signal: "Confidence",
                raw: 101
            })
        );
    }

    #[test]
    fn reserved_bits_are_zero_and_ignored() {
        let bytes = sample_command().encode(c(0));
        assert_eq!(bytes[6] & 0xF0, 0);
        assert_eq!(bytes[7], 0);
        let mut with_reserved = bytes;
        with_reserved[7] = 0xAB;
        with_reserved[0] = e2e_crc(0x0120, &with_reserved[1..]);
        assert_eq!(CommandMsg::decode(&with_reserved), Ok(sample_command()));
    }

    #[test]
    fn fault_bits_behave_like_flags() {
        let mut f = FaultBits::empty();
        assert!(f.is_empty());
        f.insert(FaultBits::STEREO_SKEW | FaultBits::INTERNAL);
        assert_eq!(f.bits(), 0b1000_0100);
        assert!(f.contains(FaultBits::STEREO_SKEW));
        assert!(!f.contains(FaultBits::STEREO_SKEW | FaultBits::CAN_TX_ERROR));
        assert!(f.intersects(FaultBits::STEREO_SKEW | FaultBits::CAN_TX_ERROR));
        f.set(FaultBits::INTERNAL, false);
        assert_eq!(f, FaultBits::STEREO_SKEW);
        assert_eq!(format!("{f:?}"), "FaultBits(STEREO_SKEW)");
        assert_eq!(
            (FaultBits::LEFT_CAMERA_STALE | FaultBits::SNAPSHOT_STALE).to_string(),
            "LEFT_CAMERA_STALE|SNAPSHOT_STALE"
        );
        assert_eq!(FaultBits::empty().to_string(), "none");
        assert_eq!(FaultBits::all().names().count(), 8);
    }

    #[test]
    fn motion_roundtrips_and_saturates() {
        let msg = MotionMsg {
            valid: true,
            speed: -2.5,
            yaw_rate: 0.1234,
        };
        let (back, counter) = MotionMsg::decode_with(&msg.encode(c(6)), 0x0110).expect("decodes");
        assert_eq!((back, counter), (msg, c(6)));
        // 12.34 m/s = 1234 = 0x04D2 in bytes 2-3; valid in bit 12.
        let bytes = MotionMsg {
            valid: true,
            speed: 12.34,
            yaw_rate: 0.0,
        }
        .encode(c(1));
        assert_eq!(&bytes[1..4], &[0x11, 0xD2, 0x04]);
        let fast = MotionMsg {
            valid: true,
            speed: 1e6,
            yaw_rate: -1e6,
        };
        let back = MotionMsg::decode(&fast.encode(c(0))).expect("decodes");
        assert_eq!((back.speed, back.yaw_rate), (327.67, -3.2768));
        let nan = MotionMsg {
            valid: true,
            speed: f64::NAN,
            yaw_rate: 0.0,
        };
        assert!(!MotionMsg::decode(&nan.encode(c(0))).expect("decodes").valid);
        assert!(matches!(
            MotionMsg::decode(&fast.encode(c(0))[..6]),
            Err(DecodeError::WrongLength { actual: 6 })
        ));
    }

    #[test]
    fn command_severity_order() {
        assert!(Command::Clear < Command::Slow && Command::Slow < Command::Stop);
        assert_eq!(Command::Slow.max(Command::Stop), Command::Stop);
    }
}
