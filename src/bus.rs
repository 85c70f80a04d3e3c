//! The CAN transports: where [`CanBus`] frames really go.
//!
//! - [`SocketCanBus`]: a Linux SocketCAN raw socket (real `can0` or `vcan0`).
//! - [`CandumpLogBus`]: `candump -l` lines to any [`Write`] (file, stdout), replayable with
//!   `canplayer`; for running without CAN hardware.
//! - [`MemoryBus`]: records frames in memory for tests, and can be told to fail.
//!
//! And where the vehicle's frames come from ([`CanReceiver`]): [`SocketCanRx`] (a filtered
//! socket of its own), [`CandumpReplayRx`] (a recorded drive's candump log, replayed on the
//! clock), [`MemoryRx`] (tests). [`ReopeningBus`] reopens either kind when the device goes.
//!
//! Errors are classified into [`BusError`]'s retryable and fatal classes by errno
//! ([`classify`]); the classes are documented with the trait, in `flyd_core::can::bus`.

use std::collections::VecDeque;
use std::io::{self, Write};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver, ReceivedFrame, check_frame};
use flyd_core::can::candump::{
    CAN_EFF_FLAG, CAN_EFF_MAX, CAN_SFF_MAX as CAN_SFF_MASK, format_candump_line, parse_candump_line,
};
use flyd_core::clock::Clock;

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

// ---------------------------------------------------------------------------------------------
// MemoryBus

/// A frame [`MemoryBus`] accepted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedFrame {
    pub timestamp: Duration,
    pub id: u32,
    pub data: Vec<u8>,
}

struct MemoryState {
    clock: Box<dyn Clock>,
    frames: Vec<RecordedFrame>,
    /// Failures for the next sends, in order (one each).
    scripted: VecDeque<BusError>,
    /// Failure for every send while set (after the scripted ones).
    persistent: Option<BusError>,
    attempts: u64,
}

/// In-memory bus for tests. Clones are handles to the same recording, so a test keeps one
/// handle and gives the other to the code under test.
#[derive(Clone)]
pub struct MemoryBus {
    state: Arc<Mutex<MemoryState>>,
}

impl MemoryBus {
    pub fn new(clock: impl Clock + 'static) -> Self {
        Self {
            state: Arc::new(Mutex::new(MemoryState {
                clock: Box::new(clock),
                frames: Vec::new(),
                scripted: VecDeque::new(),
                persistent: None,
                attempts: 0,
            })),
        }
    }

    fn lock(&self) -> MutexGuard<'_, MemoryState> {
        // A panic while holding the lock cannot leave the state half-updated (every update is
        // a single push or pop), so a poisoned lock is still usable.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Frames sent so far.
    pub fn frames(&self) -> Vec<RecordedFrame> {
        self.lock().frames.clone()
    }

    /// Frames sent so far, clearing the recording.
    pub fn take_frames(&self) -> Vec<RecordedFrame> {
        std::mem::take(&mut self.lock().frames)
    }

    /// Makes the next send fail with `error` (queue several for several sends).
    pub fn fail_next(&self, error: BusError) {
        self.lock().scripted.push_back(error);
    }

    /// Makes every send fail with `error` until called with `None`.
    pub fn set_failing(&self, error: Option<BusError>) {
        self.lock().persistent = error;
    }

    /// Number of `send` calls, failed ones included.
    pub fn attempts(&self) -> u64 {
        self.lock().attempts
    }
}

impl CanBus for MemoryBus {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        let mut state = self.lock();
        state.attempts += 1;
        check_frame(id, data)?;
        if let Some(error) = state.scripted.pop_front() {
            return Err(error);
        }
        if let Some(error) = &state.persistent {
            return Err(error.clone());
        }
        let timestamp = state.clock.now();
        state.frames.push(RecordedFrame {
            timestamp,
            id,
            data: data.to_vec(),
        });
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// CandumpLogBus

/// Writes every frame as a `candump -l` line, flushed at once (a crash loses no frame, and a
/// pipe to `canplayer` or a viewer sees frames live).
pub struct CandumpLogBus<W: Write + Send, C: Clock> {
    out: W,
    iface: String,
    clock: C,
}

impl<W: Write + Send, C: Clock> CandumpLogBus<W, C> {
    /// `iface` is the interface name written into each line (what `canplayer` replays onto,
    /// unless remapped with `canplayer vcan0=can0`).
    pub fn new(out: W, iface: impl Into<String>, clock: C) -> Self {
        Self {
            out,
            iface: iface.into(),
            clock,
        }
    }

    /// Writes one frame with an explicit timestamp (for callers that already hold one).
    pub fn write_frame_at(
        &mut self,
        timestamp: Duration,
        id: u32,
        data: &[u8],
    ) -> Result<(), BusError> {
        check_frame(id, data)?;
        let mut line = format_candump_line(timestamp, &self.iface, id, data);
        line.push('\n');
        self.out
            .write_all(line.as_bytes())
            .and_then(|()| self.out.flush())
            .map_err(|e| classify(&e))
    }

    pub fn get_ref(&self) -> &W {
        &self.out
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}

impl<W: Write + Send, C: Clock> CanBus for CandumpLogBus<W, C> {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        let now = self.clock.now();
        self.write_frame_at(now, id, data)
    }
}

// ---------------------------------------------------------------------------------------------
// SocketCAN

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

    fn make_frame(id: u32, data: &[u8]) -> Result<socketcan::CanFrame, BusError> {
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

// ---------------------------------------------------------------------------------------------
// ReopeningBus

/// A bus that is reopened when its device goes away: a USB CAN adapter re-enumerating, an
/// interface deleted and created again, or one that does not exist yet when flyd starts.
///
/// A send on a missing device (ENODEV/ENXIO, [`BusError::NoDevice`]) drops the handle; later
/// sends try to open it again, at most once per backoff (50 ms doubling to 2 s, reset by a
/// successful open), and fail with `NoDevice` meanwhile (CAN_TX_ERROR, the frame is lost: the
/// next period sends a fresh one). Opening and reopening are logged once per episode.
pub struct ReopeningBus<B, F> {
    open: F,
    bus: Option<B>,
    clock: Box<dyn Clock>,
    /// When the next open may be tried, and the backoff after it.
    next_try: Duration,
    backoff: Duration,
    name: String,
    /// The error of the last failed open.
    last_error: BusError,
}

const REOPEN_BACKOFF_MIN: Duration = Duration::from_millis(50);
const REOPEN_BACKOFF_MAX: Duration = Duration::from_secs(2);

impl<B, F: FnMut() -> Result<B, BusError> + Send> ReopeningBus<B, F> {
    /// Opens the bus with `open` now; a missing device is not an error (it is waited for),
    /// any other failure is (a kernel without CAN, a permission denied).
    pub fn new(name: &str, mut open: F, clock: impl Clock + 'static) -> Result<Self, BusError> {
        let now = clock.now();
        let (bus, last_error) = match open() {
            Ok(bus) => (
                Some(bus),
                BusError::NoDevice {
                    errno: libc::ENODEV,
                },
            ),
            Err(e @ BusError::NoDevice { .. }) => {
                tracing::warn!(
                    interface = name, error = %e,
                    "CAN interface missing: waiting for it (safe command and status as soon as it \
                     appears; CAN_TX_ERROR meanwhile)"
                );
                (None, e)
            }
            Err(e) => return Err(e),
        };
        Ok(Self {
            open,
            bus,
            clock: Box::new(clock),
            next_try: now + REOPEN_BACKOFF_MIN,
            backoff: REOPEN_BACKOFF_MIN,
            name: name.to_owned(),
            last_error,
        })
    }

    /// Whether a handle is open.
    pub fn is_open(&self) -> bool {
        self.bus.is_some()
    }

    fn try_open(&mut self) -> Result<&mut B, BusError> {
        let now = self.clock.now();
        if self.bus.is_none() {
            if now < self.next_try {
                return Err(self.last_error.clone());
            }
            match (self.open)() {
                Ok(bus) => {
                    tracing::info!(interface = %self.name, "CAN interface (re)opened");
                    self.backoff = REOPEN_BACKOFF_MIN;
                    self.bus = Some(bus);
                }
                Err(e) => {
                    self.backoff = (self.backoff * 2).min(REOPEN_BACKOFF_MAX);
                    self.next_try = now + self.backoff;
                    self.last_error = e.clone();
                    return Err(e);
                }
            }
        }
        self.bus.as_mut().ok_or_else(|| self.last_error.clone())
    }
}

impl<B, F: FnMut() -> Result<B, BusError> + Send> ReopeningBus<B, F> {
    /// After `result` of an operation on the open handle: a vanished device drops it.
    fn after<T>(&mut self, result: Result<T, BusError>) -> Result<T, BusError> {
        if let Err(e @ BusError::NoDevice { .. }) = &result {
            tracing::warn!(
                interface = %self.name, error = %e,
                "CAN interface gone: reopening it with backoff"
            );
            self.bus = None;
            self.last_error = e.clone();
            self.next_try = self.clock.now() + REOPEN_BACKOFF_MIN;
            self.backoff = REOPEN_BACKOFF_MIN;
        }
        result
    }
}

impl<B: CanBus, F: FnMut() -> Result<B, BusError> + Send> CanBus for ReopeningBus<B, F> {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        let result = self.try_open()?.send(id, data);
        self.after(result)
    }
}

impl<B: CanReceiver, F: FnMut() -> Result<B, BusError> + Send> CanReceiver for ReopeningBus<B, F> {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        let result = self.try_open()?.try_recv();
        self.after(result)
    }
}

// ---------------------------------------------------------------------------------------------
// Receivers

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

/// Frames of a candump log (`candump -l` / `-L` lines, as `canplayer` reads them), released
/// on the clock at their times relative to the first frame: a recorded drive's bus replayed
/// into flyd without a kernel. Frames of every ID are returned; the caller picks.
pub struct CandumpReplayRx<C: Clock> {
    frames: VecDeque<(Duration, ReceivedFrame)>,
    clock: C,
    start: Duration,
}

/// Why a candump log could not be read as input.
#[derive(Debug, thiserror::Error)]
pub enum ReplayLogError {
    #[error("reading {path}")]
    Read {
        path: String,
        #[source]
        error: io::Error,
    },
    #[error("{path}:{line}: not a candump line")]
    Line {
        path: String,
        line: usize,
        #[source]
        error: flyd_core::can::candump::CandumpParseError,
    },
}

impl<C: Clock> CandumpReplayRx<C> {
    /// Reads the whole log now (at most the text-file limit, [`flyd_core::textfile`]); its
    /// first frame is due at `clock.now()`.
    pub fn open(path: &std::path::Path, clock: C) -> Result<Self, ReplayLogError> {
        let shown = path.display().to_string();
        let text = flyd_core::textfile::read(path).map_err(|error| ReplayLogError::Read {
            path: shown.clone(),
            error,
        })?;
        Self::parse(&text, clock).map_err(|(line, error)| ReplayLogError::Line {
            path: shown,
            line,
            error,
        })
    }

    /// The log's text; errors carry the 1-based line.
    pub fn parse(
        text: &str,
        clock: C,
    ) -> Result<Self, (usize, flyd_core::can::candump::CandumpParseError)> {
        let mut frames = VecDeque::new();
        let mut first = None;
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let (t, _iface, id, data) = parse_candump_line(line).map_err(|e| (i + 1, e))?;
            let t0 = *first.get_or_insert(t);
            let at = Duration::try_from_secs_f64((t - t0).max(0.0)).unwrap_or(Duration::ZERO);
            if let Some(frame) = ReceivedFrame::new(id, &data) {
                frames.push_back((at, frame));
            }
        }
        let start = clock.now();
        Ok(Self {
            frames,
            clock,
            start,
        })
    }

    /// Frames not yet released.
    pub fn remaining(&self) -> usize {
        self.frames.len()
    }

    /// The frames not yet released, each with its time from the log's first frame.
    pub fn into_frames(self) -> impl Iterator<Item = (Duration, ReceivedFrame)> {
        self.frames.into_iter()
    }
}

impl<C: Clock + Send> CanReceiver for CandumpReplayRx<C> {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        let elapsed = self.clock.now().saturating_sub(self.start);
        match self.frames.front() {
            Some(&(at, frame)) if at <= elapsed => {
                self.frames.pop_front();
                Ok(Some(frame))
            }
            _ => Ok(None),
        }
    }
}

/// Frames pushed by a test (or any producer) into a shared queue.
#[derive(Clone, Default)]
pub struct MemoryRx(Arc<Mutex<VecDeque<ReceivedFrame>>>);

impl MemoryRx {
    pub fn push(&self, id: u32, data: &[u8]) {
        if let Some(frame) = ReceivedFrame::new(id, data) {
            self.0
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push_back(frame);
        }
    }
}

impl CanReceiver for MemoryRx {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        Ok(self
            .0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop_front())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flyd_core::can::candump::parse_candump_line;
    use flyd_core::clock::ManualClock;

    fn os(errno: i32) -> io::Error {
        io::Error::from_raw_os_error(errno)
    }

    #[test]
    fn errno_classification() {
        let cases = [
            (libc::EAGAIN, BusError::WouldBlock, true),
            (libc::ENOBUFS, BusError::QueueFull { attempts: 1 }, true),
            (libc::ENETDOWN, BusError::InterfaceDown, true),
            (
                libc::ENODEV,
                BusError::NoDevice {
                    errno: libc::ENODEV,
                },
                false,
            ),
            (
                libc::ENXIO,
                BusError::NoDevice { errno: libc::ENXIO },
                false,
            ),
            (
                libc::EAFNOSUPPORT,
                BusError::Unsupported {
                    errno: libc::EAFNOSUPPORT,
                },
                false,
            ),
        ];
        for (errno, want, retryable) in cases {
            let got = classify(&os(errno));
            assert_eq!(got, want, "errno {errno}");
            assert_eq!(got.is_retryable(), retryable, "errno {errno}");
        }
        let other = classify(&os(libc::EPERM));
        assert!(matches!(other, BusError::Io { errno: Some(e), .. } if e == libc::EPERM));
        assert!(other.is_fatal());
        assert!(BusError::BusOff.is_retryable());
        assert!(BusError::InvalidFrame { id: 0x800, len: 0 }.is_fatal());
        assert_eq!(
            classify(&io::Error::from(io::ErrorKind::WouldBlock)),
            BusError::WouldBlock
        );
    }

    #[test]
    fn retry_is_bounded_and_only_for_transient_errors() {
        let policy = RetryPolicy {
            max_attempts: 3,
            delay: Duration::from_micros(7),
        };

        // ENOBUFS forever: exactly max_attempts writes, max_attempts - 1 pauses.
        let (mut writes, mut sleeps) = (0, Vec::new());
        let result = write_with_retry(
            policy,
            || {
                writes += 1;
                Err(os(libc::ENOBUFS))
            },
            |d| sleeps.push(d),
        );
        assert_eq!(result, Err(BusError::QueueFull { attempts: 3 }));
        assert_eq!((writes, sleeps.len()), (3, 2));
        assert!(sleeps.iter().all(|&d| d == Duration::from_micros(7)));

        // Transient then success.
        let mut script = vec![Err(os(libc::EAGAIN)), Err(os(libc::ENOBUFS)), Ok(())].into_iter();
        let result = write_with_retry(policy, || script.next().unwrap_or(Ok(())), |_| {});
        assert_eq!(result, Ok(()));

        // Writes failing with `errno` under `policy`: the result and how many writes it made.
        let failing = |policy, errno| {
            let mut writes = 0;
            let result = write_with_retry(
                policy,
                || Err(os(errno)).inspect_err(|_| writes += 1),
                |_| {},
            );
            (result, writes)
        };
        // Not transient: no retry.
        assert_eq!(
            failing(policy, libc::ENETDOWN),
            (Err(BusError::InterfaceDown), 1)
        );
        // max_attempts 0 still writes once.
        let zero = RetryPolicy {
            max_attempts: 0,
            delay: Duration::ZERO,
        };
        assert_eq!(failing(zero, libc::ENOBUFS).1, 1);

        // EINTR exhausting the attempts is reported as retryable, not as an I/O failure.
        let result = write_with_retry(policy, || Err(os(libc::EINTR)), |_| {});
        assert_eq!(result, Err(BusError::WouldBlock));
    }

    #[test]
    fn bus_off_tracking_from_error_frames() {
        use socketcan::errors::{CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED};
        assert!(next_bus_off_state(false, CAN_ERR_BUSOFF));
        assert!(next_bus_off_state(true, CAN_ERR_CRTL));
        assert!(!next_bus_off_state(true, CAN_ERR_RESTARTED));
        assert!(!next_bus_off_state(false, CAN_ERR_CRTL));
    }

    #[test]
    fn socketcan_frames_are_built_and_checked() {
        use socketcan::{EmbeddedFrame, Id, StandardId};
        let frame = SocketCanBus::make_frame(0x120, &[1, 2, 3]).expect("valid");
        assert_eq!(
            frame.id(),
            Id::Standard(StandardId::new(0x120).expect("id"))
        );
        assert_eq!(frame.data(), &[1, 2, 3]);
        let ext = SocketCanBus::make_frame(0x1234_5678 | CAN_EFF_FLAG, &[]).expect("valid");
        assert!(ext.is_extended());
        assert!(SocketCanBus::make_frame(0x800, &[]).is_err());
        assert!(SocketCanBus::make_frame(0x120, &[0; 9]).is_err());
    }

    /// This machine has no CAN in its kernel: opening must fail cleanly and be classified as
    /// fatal, not panic. (On a machine with vcan the open may succeed; then nothing to check.)
    #[test]
    fn opening_a_missing_interface_is_a_fatal_error() {
        match SocketCanBus::open("flydnotacan0", RetryPolicy::default()) {
            Ok(_) => panic!("an interface that does not exist opened"),
            Err(e) => assert!(e.is_fatal(), "{e:?}"),
        }
    }

    #[test]
    fn memory_bus_records_with_injected_time_and_shares_state() {
        let clock = ManualClock::new(Duration::from_millis(1000));
        let handle = MemoryBus::new(clock.clone());
        let mut bus: Box<dyn CanBus> = Box::new(handle.clone());

        bus.send(0x120, &[1, 2]).expect("sent");
        clock.advance(Duration::from_millis(20));
        bus.send(0x121, &[3]).expect("sent");

        assert_eq!(
            handle.frames(),
            vec![
                RecordedFrame {
                    timestamp: Duration::from_millis(1000),
                    id: 0x120,
                    data: vec![1, 2]
                },
                RecordedFrame {
                    timestamp: Duration::from_millis(1020),
                    id: 0x121,
                    data: vec![3]
                },
            ]
        );
        assert_eq!(handle.take_frames().len(), 2);
        assert!(handle.frames().is_empty());
    }

    #[test]
    fn memory_bus_simulates_failures() {
        let handle = MemoryBus::new(|| Duration::ZERO);
        let mut bus = handle.clone();
        handle.fail_next(BusError::QueueFull { attempts: 3 });
        handle.fail_next(BusError::BusOff);
        assert_eq!(
            bus.send(0x120, &[]),
            Err(BusError::QueueFull { attempts: 3 })
        );
        assert_eq!(bus.send(0x120, &[]), Err(BusError::BusOff));
        assert_eq!(bus.send(0x120, &[]), Ok(()));

        handle.set_failing(Some(BusError::InterfaceDown));
        assert_eq!(bus.send(0x120, &[]), Err(BusError::InterfaceDown));
        assert_eq!(bus.send(0x120, &[]), Err(BusError::InterfaceDown));
        handle.set_failing(None);
        assert_eq!(bus.send(0x120, &[]), Ok(()));

        assert_eq!(
            bus.send(0x800, &[]),
            Err(BusError::InvalidFrame { id: 0x800, len: 0 })
        );
        assert_eq!(handle.frames().len(), 2);
        assert_eq!(handle.attempts(), 7);
    }

    #[test]
    fn candump_bus_writes_replayable_lines() {
        let clock = ManualClock::new(Duration::new(1_700_000_000, 123_456_000));
        let mut bus = CandumpLogBus::new(Vec::new(), "vcan0", clock.clone());
        bus.send(0x120, &[1, 2, 3, 4, 5, 6, 7, 8]).expect("written");
        clock.advance(Duration::from_millis(20));
        bus.send(0x121, &[0xAB; 8]).expect("written");
        assert!(bus.send(0x120, &[0; 9]).is_err());

        let text = String::from_utf8(bus.into_inner()).expect("utf8");
        assert_eq!(
            text,
            "(1700000000.123456) vcan0 120#0102030405060708\n\
             (1700000000.143456) vcan0 121#ABABABABABABABAB\n"
        );
        let parsed: Vec<_> = text
            .lines()
            .map(|l| parse_candump_line(l).expect("parses"))
            .collect();
        assert_eq!(parsed[1].2, 0x121);
        assert!((parsed[1].0 - parsed[0].0 - 0.020).abs() < 1e-6);
    }

    #[test]
    fn candump_bus_classifies_write_errors() {
        struct Full;
        impl Write for Full {
            fn write(&mut self, _: &[u8]) -> io::Result<usize> {
                Err(io::Error::from_raw_os_error(libc::ENOSPC))
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let mut bus = CandumpLogBus::new(Full, "vcan0", crate::clock::SystemClock);
        let err = bus.send(0x120, &[]).expect_err("disk full");
        assert!(err.is_fatal(), "{err:?}");
    }

    /// The daemon-without-hardware path: Transmitter into a candump log, read back with the
    /// parser and decoded, as a canplayer replay would deliver it.
    #[test]
    fn candump_log_from_transmitter_decodes_back() {
        use flyd_core::can::messages::{CanMessage, CommandMsg, StatusMsg};
        use flyd_core::can::{CanConfig, Transmitter};
        use flyd_core::clock::ManualClock;
        use flyd_core::decision::{Command, CommandReason};
        use flyd_core::status::State;

        let status = StatusMsg {
            state: State::Running,
            faults: flyd_core::status::FaultBits::empty(),
            perception_age: Duration::from_millis(30),
            sensor: flyd_core::sensor::SensorFaults::empty(),
            motion_fault: false,
            generations_per_sec: 100.0,
            cam_fps_left: 30.0,
            cam_fps_right: 30.0,
        };
        let clock = ManualClock::new(Duration::from_secs(1_700_000_000));
        let log = CandumpLogBus::new(Vec::new(), "vcan0", clock.clone());
        let mut tx = Transmitter::new(log, CanConfig::default()).expect("valid");
        for _ in 0..3 {
            tx.send_command(&CommandMsg {
                command: Command::Slow,
                requested_decel: 1.5,
                global_warning: 0.42,
                reason: CommandReason::Perception,
            })
            .expect("written");
            tx.send_status(&status).expect("written");
            clock.advance(Duration::from_millis(20));
        }
        let text = String::from_utf8(tx.into_bus().into_inner()).expect("utf8");

        let mut commands = 0;
        for line in text.lines() {
            let (_, iface, id, data) = parse_candump_line(line).expect("parses");
            assert_eq!(iface, "vcan0");
            match id {
                0x120 => {
                    let (msg, counter) =
                        CommandMsg::decode_with(&data, CommandMsg::DEFAULT_DATA_ID).expect("ok");
                    assert_eq!(msg.command, Command::Slow);
                    assert_eq!(msg.reason, CommandReason::Perception);
                    assert_eq!(counter.value(), commands);
                    commands += 1;
                }
                0x121 => assert_eq!(StatusMsg::decode(&data), Ok(status)),
                other => panic!("unexpected id {other:#x}"),
            }
        }
        assert_eq!(commands, 3);
    }

    /// An adapter that vanishes (ENODEV) is reopened with backoff, and one missing at start is
    /// waited for; other open failures stay errors.
    #[test]
    fn a_candump_log_is_received_at_its_recorded_pace() {
        let clock = ManualClock::new(Duration::from_secs(5));
        let log = "(1700000000.100000) vcan0 110#0102030405060708\n\n\
                   (1700000000.120000) vcan0 121#AA\n\
                   (1700000000.600000) vcan0 110#01\n";
        let mut rx = CandumpReplayRx::parse(log, clock.clone()).expect("parses");
        assert_eq!(rx.remaining(), 3);
        let first = rx.try_recv().expect("ok").expect("due at once");
        assert_eq!(
            (first.id, first.payload()),
            (0x110, &[1, 2, 3, 4, 5, 6, 7, 8][..])
        );
        assert_eq!(rx.try_recv(), Ok(None), "the next is due 20 ms later");
        clock.advance(Duration::from_millis(20));
        assert_eq!(rx.try_recv().expect("ok").map(|f| f.len), Some(1));
        clock.advance(Duration::from_millis(480));
        let short = rx.try_recv().expect("ok").expect("due");
        assert_eq!(
            short.payload(),
            &[1],
            "a wrong DLC is kept for the decoder to reject"
        );
        assert_eq!(rx.try_recv(), Ok(None));
        let bad = CandumpReplayRx::parse("(1.0) vcan0 110#01\nnot a frame\n", clock);
        assert_eq!(bad.err().map(|(line, _)| line), Some(2));
    }

    #[test]
    fn a_vanished_interface_is_reopened_with_backoff() {
        let clock = ManualClock::new(Duration::from_secs(1));
        let present = Arc::new(Mutex::new(false));
        let opens = Arc::new(Mutex::new(0u32));
        let bus = MemoryBus::new(clock.clone());
        let (p, o, b) = (present.clone(), opens.clone(), bus.clone());
        let mut r = ReopeningBus::new(
            "vcan0",
            move || {
                *o.lock().unwrap_or_else(PoisonError::into_inner) += 1;
                if *p.lock().unwrap_or_else(PoisonError::into_inner) {
                    Ok(b.clone())
                } else {
                    Err(BusError::NoDevice {
                        errno: libc::ENODEV,
                    })
                }
            },
            clock.clone(),
        )
        .expect("a missing interface is waited for");
        let count = || *opens.lock().unwrap_or_else(PoisonError::into_inner);
        assert!(!r.is_open());
        assert!(matches!(
            r.send(0x120, &[1]),
            Err(BusError::NoDevice { .. })
        ));
        assert_eq!(count(), 1, "no retry before the backoff");
        clock.advance(Duration::from_millis(50));
        assert!(r.send(0x120, &[1]).is_err());
        assert_eq!(count(), 2);
        clock.advance(Duration::from_millis(60));
        assert!(r.send(0x120, &[1]).is_err());
        assert_eq!(count(), 2, "the backoff doubled to 100 ms");
        *present.lock().unwrap_or_else(PoisonError::into_inner) = true;
        clock.advance(Duration::from_millis(40));
        assert_eq!(r.send(0x120, &[2]), Ok(()));
        assert_eq!(count(), 3);
        assert_eq!(bus.frames().len(), 1);
        // The adapter vanishes: the send fails, the handle is dropped and reopened later.
        bus.fail_next(BusError::NoDevice { errno: libc::ENXIO });
        assert!(r.send(0x120, &[3]).is_err());
        assert!(!r.is_open());
        clock.advance(Duration::from_millis(50));
        assert_eq!(r.send(0x120, &[4]), Ok(()));
        assert_eq!(count(), 4);
        // Other open failures are errors at start.
        let e = ReopeningBus::new(
            "x",
            || Err::<MemoryBus, _>(BusError::Unsupported { errno: 97 }),
            clock,
        );
        assert!(e.is_err());
    }
}
