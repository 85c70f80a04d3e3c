//! Where frames go: the [`CanBus`] trait every transport implements, and its error classes.
//!
//! The transports (SocketCAN, candump log, in memory) live in the runtime crate (`flyd::bus`);
//! the protocol needs only this trait.
//!
//! IDs follow Linux `canid_t`: bit 31 ([`CAN_EFF_FLAG`]) set = 29-bit extended, otherwise
//! 11-bit standard; every transport rejects IDs and lengths a classic CAN frame cannot carry
//! ([`check_frame`]).
//!
//! # Error classes
//! [`BusError::is_retryable`] tells whether sending the *same frame on the same bus later* may
//! work, so the caller keeps the bus and tries again next period:
//!
//! | class | errors | typical cause |
//! |-------|--------|---------------|
//! | retryable | [`BusError::WouldBlock`] (EAGAIN), [`BusError::QueueFull`] (ENOBUFS) | TX queue full: bus saturated, unacknowledged frames (no other node), or around bus-off |
//! | retryable | [`BusError::InterfaceDown`] (ENETDOWN) | `ip link set can0 down`, or the driver took it down after bus-off |
//! | retryable | [`BusError::BusOff`] | the controller reported bus-off (error frame) and writes fail |
//! | fatal | [`BusError::InvalidFrame`] | a bug: ID or length not sendable |
//! | fatal | [`BusError::NoDevice`] (ENODEV, ENXIO) | interface does not exist or was removed: reopen needed |
//! | fatal | [`BusError::Unsupported`] (EAFNOSUPPORT, EPROTONOSUPPORT) | kernel without CAN |
//! | fatal | [`BusError::Io`] | anything else (EBADF, EPERM, a log file's ENOSPC, ...) |
//!
//! Fatal means "this handle will not send this frame": the daemon reports it (fault bit 6) and
//! decides whether to reopen the bus; retrying in a loop would not help.

use thiserror::Error;

use super::candump::{CAN_EFF_FLAG, CAN_EFF_MAX, CAN_MAX_DLEN, CAN_SFF_MAX};

/// A destination for CAN frames.
pub trait CanBus: Send {
    /// Queues one classic CAN data frame for transmission. `id` uses the [`CAN_EFF_FLAG`]
    /// convention; `data` is at most 8 bytes. Must not block for long: flyd sends from a 20 ms
    /// loop.
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError>;
}

impl<B: CanBus + ?Sized> CanBus for Box<B> {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        (**self).send(id, data)
    }
}

/// A classic CAN data frame received.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReceivedFrame {
    /// [`CAN_EFF_FLAG`] convention, as for sending.
    pub id: u32,
    /// Data length (0..=8): a wrong DLC is the decoder's to reject, so it is kept.
    pub len: u8,
    pub data: [u8; CAN_MAX_DLEN],
}

impl ReceivedFrame {
    /// `None` when `data` is longer than a classic frame.
    pub fn new(id: u32, data: &[u8]) -> Option<Self> {
        let len = u8::try_from(data.len())
            .ok()
            .filter(|&l| usize::from(l) <= CAN_MAX_DLEN)?;
        let mut bytes = [0u8; CAN_MAX_DLEN];
        bytes[..data.len()].copy_from_slice(data);
        Some(Self {
            id,
            len,
            data: bytes,
        })
    }

    /// The frame's data bytes.
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.len).min(CAN_MAX_DLEN)]
    }
}

/// A source of received CAN frames (the vehicle's messages to flyd).
pub trait CanReceiver: Send {
    /// The next received frame, or `None` when none is pending. Never blocks: flyd polls it
    /// from the loop that sends. Errors are classified as for [`CanBus::send`].
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError>;
}

impl<R: CanReceiver + ?Sized> CanReceiver for Box<R> {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        (**self).try_recv()
    }
}

/// A failed send, classified (see the module docs for the classes).
///
/// It is `Clone + PartialEq` (it keeps the errno, not the `io::Error`) so that tests can make
/// the runtime's `MemoryBus` fail with any of them and compare.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum BusError {
    #[error("CAN socket send buffer full (EAGAIN)")]
    WouldBlock,
    #[error("CAN transmit queue full (ENOBUFS) after {attempts} attempt(s)")]
    QueueFull { attempts: u32 },
    #[error("CAN interface is down (ENETDOWN)")]
    InterfaceDown,
    #[error("CAN controller is bus-off")]
    BusOff,
    #[error("invalid CAN frame: id {id:#x} with {len} data bytes")]
    InvalidFrame { id: u32, len: usize },
    #[error("CAN interface not found or removed (errno {errno})")]
    NoDevice { errno: i32 },
    #[error("CAN is not supported by this kernel (errno {errno})")]
    Unsupported { errno: i32 },
    #[error("CAN I/O error: {message}")]
    Io { errno: Option<i32>, message: String },
}

impl BusError {
    /// `true`: keep the bus and try again later; `false`: this handle cannot send the frame.
    pub fn is_retryable(&self) -> bool {
        matches!(
            self,
            Self::WouldBlock | Self::QueueFull { .. } | Self::InterfaceDown | Self::BusOff
        )
    }

    pub fn is_fatal(&self) -> bool {
        !self.is_retryable()
    }
}

/// Rejects what a classic CAN data frame cannot carry, before any backend sees it.
pub fn check_frame(id: u32, data: &[u8]) -> Result<(), BusError> {
    let id_ok = if id & CAN_EFF_FLAG != 0 {
        id & !CAN_EFF_FLAG <= CAN_EFF_MAX
    } else {
        id <= CAN_SFF_MAX
    };
    if id_ok && data.len() <= CAN_MAX_DLEN {
        Ok(())
    } else {
        Err(BusError::InvalidFrame {
            id,
            len: data.len(),
        })
    }
}
