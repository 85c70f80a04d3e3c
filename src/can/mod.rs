//! flyd on the CAN bus: the message contract, its E2E protection, and the transports.
//!
//! - [`crc`]: the CRC.

pub mod crc;
