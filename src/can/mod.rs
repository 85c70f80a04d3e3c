//! flyd on the CAN bus: the message contract, its E2E protection, and the transports.
//!
//! Every frame: 8 bytes, byte 0 = CRC-8 SAE J1850 over (Data ID lo, Data ID hi, bytes 1..=7),
//! byte 1 low nibble = alive counter 0..=14 (AUTOSAR E2E profile 1 style).
//!
//! - [`crc`]: the CRC.
//! - [`messages`]: typed messages, byte layout, saturation rules, decoding checks.
//! - [`bus`]: the [`bus::CanBus`] trait, SocketCAN / candump-log / in-memory backends, error
//!   classes (retryable vs fatal).
//! - [`candump`]: the `candump -l` line format, both ways.

pub mod bus;
pub mod candump;
pub mod crc;
pub mod messages;
