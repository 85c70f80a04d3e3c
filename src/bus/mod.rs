//! The CAN transports: where [`CanBus`](flyd_core::can::bus::CanBus) frames really go.
//!
//! - [`SocketCanBus`]: a Linux SocketCAN raw socket (real `can0` or `vcan0`).
//! - [`CandumpLogBus`]: `candump -l` lines to any [`Write`](std::io::Write) (file, stdout),
//!   replayable with `canplayer`; for running without CAN hardware.
//! - [`MemoryBus`]: records frames in memory for tests, and can be told to fail.
//!
//! And where the vehicle's frames come from
//! ([`CanReceiver`](flyd_core::can::bus::CanReceiver)): [`SocketCanRx`] (a filtered socket of
//! its own), [`CandumpReplayRx`] (a recorded drive's candump log, replayed on the clock),
//! [`MemoryRx`] (tests). [`ReopeningBus`] reopens either kind when the device goes.
//!
//! Errors are classified into [`BusError`]'s retryable and fatal classes by errno
//! ([`classify`]); the classes are documented with the trait, in `flyd_core::can::bus`.
//!
//! One transport a file: `memory.rs`, `candump_log.rs`, `socket.rs`, and `reopening.rs` around
//! either SocketCAN direction.

mod candump_log;
mod memory;
mod reopening;
mod socket;

pub use candump_log::{CandumpLogBus, CandumpReplayRx, ReplayLogError};
pub use memory::{MemoryBus, MemoryRx, RecordedFrame};
pub use reopening::ReopeningBus;
pub use socket::{RetryPolicy, SocketCanBus, SocketCanRx, next_bus_off_state, write_with_retry};

use std::io;

use flyd_core::can::bus::BusError;

/// Classifies an I/O error by its errno (falling back to its kind when there is none).
pub fn classify(e: &io::Error) -> BusError {
    match e.raw_os_error() {
        Some(errno) => from_errno(errno, e),
        None if e.kind() == io::ErrorKind::WouldBlock => BusError::WouldBlock,
        None => BusError::Io {
            errno: None,
            message: e.to_string(),
        },
    }
}

fn from_errno(errno: i32, e: &io::Error) -> BusError {
    match errno {
        libc::EAGAIN => BusError::WouldBlock,
        libc::ENOBUFS => BusError::QueueFull { attempts: 1 },
        libc::ENETDOWN => BusError::InterfaceDown,
        libc::ENODEV | libc::ENXIO => BusError::NoDevice { errno },
        libc::EAFNOSUPPORT | libc::EPROTONOSUPPORT => BusError::Unsupported { errno },
        _ => BusError::Io {
            errno: Some(errno),
            message: e.to_string(),
        },
    }
}

#[cfg(test)]
mod tests;
