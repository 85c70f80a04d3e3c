//! Typed flyd CAN messages and their 8-byte encoding (the contract of `config/flyd.dbc`).
//!
//! The layout below is the DBC's, and the code takes it from there: `build.rs` writes every
//! message's name, ID, Data ID and period and every signal's bits, steps per unit and bounds
//! into constants (module `dbc`); a message's file says which value goes in which signal.
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

/// The contract's layout, written by `build.rs` from `config/flyd.dbc`: per message its name,
/// IDs and period, per signal its bits, raw steps per unit and physical bounds. The messages'
/// files say only which value goes in which signal (tests/dbc.rs checks that they do, against
/// the DBC itself).
mod dbc {
    use super::Field;

    include!(concat!(env!("OUT_DIR"), "/dbc.rs"));
}

mod layout {
    use super::Field;

    /// Every message's `AliveCounter` (the DBC gives it to each; they agree: tests/dbc.rs).
    pub const COUNTER: Field = super::dbc::flyd_command::ALIVE_COUNTER;
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
mod flyd_obstacle_motion;
mod flyd_path;
mod flyd_status;
mod vcu_motion;

pub use flyd_command::CommandMsg;
pub use flyd_obstacle::ObstacleMsg;
pub use flyd_obstacle_motion::{NOT_CLOSING, ObstacleMotionMsg};
pub use flyd_path::PathMsg;
pub use flyd_status::StatusMsg;
pub use vcu_motion::MotionMsg;

#[cfg(test)]
mod tests;
