//! Linux SocketCAN: [`SocketCanBus`] sends on a raw socket (a real `can0` or a `vcan0`) with
//! the bounded retry of a full queue and the bus-off tracking, [`SocketCanRx`] receives the
//! vehicle's IDs on a filtered socket of its own.

use std::io::{self};
use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver, ReceivedFrame, check_frame};
use flyd_core::can::candump::{CAN_EFF_FLAG, CAN_EFF_MAX, CAN_SFF_MAX as CAN_SFF_MASK};

use super::classify;

/// Bounded retry of a full transmit queue inside one `send`.
///
/// socketcan's `write_frame_insist` retries only EAGAIN and forever; ENOBUFS (qdisc full, the
/// usual symptom near bus-off on Linux) needs its own retry, and it must be bounded: a blocked
/// 20 ms control loop is worse than one lost frame (the next period sends fresh data anyway).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RetryPolicy {
    /// Total write attempts for one frame (at least 1).
    pub max_attempts: u32,
    /// Pause between attempts.
    pub delay: Duration,
}

impl Default for RetryPolicy {
    /// 3 attempts 200 µs apart: at most ~0.4 ms of a 20 ms period.
    fn default() -> Self {
        Self {
            max_attempts: 3,
            delay: Duration::from_micros(200),
        }
    }
}

/// Runs `write` until it succeeds, fails with a non-transient error, or the attempts run out.
/// EAGAIN, ENOBUFS and EINTR are transient; `sleep` is injected so tests do not wait.
pub fn write_with_retry(
    policy: RetryPolicy,
    mut write: impl FnMut() -> io::Result<()>,
    mut sleep: impl FnMut(Duration),
) -> Result<(), BusError> {
    let max = policy.max_attempts.max(1);
    let mut attempt = 1;
    loop {
        let error = match write() {
            Ok(()) => return Ok(()),
            Err(e) => e,
        };
        let transient = matches!(
            error.raw_os_error(),
            Some(libc::EAGAIN | libc::ENOBUFS | libc::EINTR)
        ) || error.kind() == io::ErrorKind::WouldBlock;
        if !transient || attempt >= max {
            return Err(match classify(&error) {
                BusError::QueueFull { .. } => BusError::QueueFull { attempts: attempt },
                // EINTR on the last attempt: nothing is wrong with the bus.
                BusError::Io {
                    errno: Some(libc::EINTR),
                    ..
                } => BusError::WouldBlock,
                other => other,
            });
        }
        attempt += 1;
        sleep(policy.delay);
    }
}

/// Tracks bus-off from the controller's error frames: set by `CAN_ERR_BUSOFF`, cleared by
/// `CAN_ERR_RESTARTED` (automatic `restart-ms` or a manual restart).
pub fn next_bus_off_state(bus_off: bool, error_class_bits: u32) -> bool {
    if error_class_bits & socketcan::errors::CAN_ERR_RESTARTED != 0 {
        false
    } else if error_class_bits & socketcan::errors::CAN_ERR_BUSOFF != 0 {
        true
    } else {
        bus_off
    }
}

/// A SocketCAN raw socket, non-blocking, transmit-only.
///
/// The socket receives no data frames (filter drops all) but subscribes to bus-off and restart
/// error frames, read without blocking before each send, so that write failures while the
/// controller is bus-off are reported as [`BusError::BusOff`] rather than a plain full queue.
/// An interface taken down and up without a restart frame clears the state at the next
/// ENETDOWN.
pub struct SocketCanBus {
    socket: socketcan::CanSocket,
    iface: String,
    policy: RetryPolicy,
    bus_off: bool,
}

impl SocketCanBus {
    /// At most this many error frames are drained per send, so a babbling controller cannot
    /// stall the loop.
    const MAX_ERROR_FRAMES_PER_SEND: usize = 16;

    /// Opens `iface` (e.g. `can0`, `vcan0`). Fails with [`BusError::NoDevice`] when it does not
    /// exist and [`BusError::Unsupported`] on a kernel without CAN.
    pub fn open(iface: &str, policy: RetryPolicy) -> Result<Self, BusError> {
        use socketcan::{Socket, SocketOptions};
        let io = |e: io::Error| classify(&e);
        let socket = socketcan::CanSocket::open(iface).map_err(io)?;
        socket.set_nonblocking(true).map_err(io)?;
        socket.set_filter_drop_all().map_err(io)?;
        socket
            .set_error_filter(
                socketcan::errors::CAN_ERR_BUSOFF | socketcan::errors::CAN_ERR_RESTARTED,
            )
            .map_err(io)?;
        Ok(Self {
            socket,
            iface: iface.to_owned(),
            policy,
            bus_off: false,
        })
    }

    pub fn iface(&self) -> &str {
        &self.iface
    }

    /// Whether the controller last reported bus-off.
    pub fn is_bus_off(&self) -> bool {
        self.bus_off
    }

    fn drain_error_frames(&mut self) {
        use socketcan::{CanFrame, Socket};
        for _ in 0..Self::MAX_ERROR_FRAMES_PER_SEND {
            match self.socket.read_frame() {
                Ok(CanFrame::Error(frame)) => {
                    self.bus_off = next_bus_off_state(self.bus_off, frame.error_bits());
                }
                Ok(_) => {}
                // WouldBlock: nothing pending. Other read errors do not concern sending.
                Err(_) => break,
            }
        }
    }

    pub(super) fn make_frame(id: u32, data: &[u8]) -> Result<socketcan::CanFrame, BusError> {
        use socketcan::{EmbeddedFrame, ExtendedId, Id, StandardId};
        let invalid = || BusError::InvalidFrame {
            id,
            len: data.len(),
        };
        check_frame(id, data)?;
        let can_id: Id = if id & CAN_EFF_FLAG != 0 {
            ExtendedId::new(id & CAN_EFF_MAX)
                .ok_or_else(invalid)?
                .into()
        } else {
            let sid = u16::try_from(id).map_err(|_| invalid())?;
            StandardId::new(sid).ok_or_else(invalid)?.into()
        };
        socketcan::CanFrame::new(can_id, data).ok_or_else(invalid)
    }
}

impl CanBus for SocketCanBus {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        use socketcan::Socket;
        let frame = Self::make_frame(id, data)?;
        self.drain_error_frames();
        let socket = &self.socket;
        let result = write_with_retry(
            self.policy,
            || socket.write_frame(&frame),
            std::thread::sleep,
        );
        match result {
            Err(BusError::InterfaceDown) => {
                self.bus_off = false;
                Err(BusError::InterfaceDown)
            }
            Err(BusError::QueueFull { .. } | BusError::WouldBlock) if self.bus_off => {
                Err(BusError::BusOff)
            }
            other => other,
        }
    }
}

/// A SocketCAN raw socket that receives only the given standard IDs, non-blocking.
///
/// A socket of its own (not the sender's): the kernel filters for it, so the sender's error
/// frame handling never sees the vehicle's frames and a flood of them never delays a send.
pub struct SocketCanRx {
    socket: socketcan::CanSocket,
}

impl SocketCanRx {
    /// Opens `iface` receiving data frames of the standard `ids` only (no extended, no remote
    /// frames).
    pub fn open(iface: &str, ids: &[u32]) -> Result<Self, BusError> {
        use socketcan::{CanFilter, Socket, SocketOptions};
        let io = |e: io::Error| classify(&e);
        let socket = socketcan::CanSocket::open(iface).map_err(io)?;
        socket.set_nonblocking(true).map_err(io)?;
        let mask = CAN_SFF_MASK | CAN_EFF_FLAG | libc::CAN_RTR_FLAG;
        let filters: Vec<CanFilter> = ids.iter().map(|&id| CanFilter::new(id, mask)).collect();
        socket.set_filters(&filters).map_err(io)?;
        socket.set_error_filter_drop_all().map_err(io)?;
        Ok(Self { socket })
    }
}

impl CanReceiver for SocketCanRx {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        use socketcan::{CanFrame, EmbeddedFrame, Frame, Socket};
        loop {
            match self.socket.read_frame() {
                Ok(CanFrame::Data(frame)) => {
                    let mut id = frame.raw_id();
                    if frame.is_extended() {
                        id |= CAN_EFF_FLAG;
                    }
                    return Ok(ReceivedFrame::new(id, frame.data()));
                }
                // Filtered out by the kernel already; skipped should one slip through.
                Ok(_) => continue,
                Err(e) => {
                    return match classify(&e) {
                        BusError::WouldBlock => Ok(None),
                        other => Err(other),
                    };
                }
            }
        }
    }
}
