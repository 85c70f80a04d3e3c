//! [`ReopeningBus`]: a transport (either direction) reopened with backoff when its device
//! goes away or is not there yet.

use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver, ReceivedFrame};
use flyd_core::clock::Clock;

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
    pub fn new(name: &str, open: F, clock: impl Clock + 'static) -> Result<Self, BusError> {
        Self::opened(name, open, clock, true)
    }

    /// [`ReopeningBus::new`] for a second socket on an interface another one already waits
    /// for (the vehicle's frames beside flyd's): a missing device is logged at DEBUG, so the
    /// WARN says it once.
    pub fn beside(name: &str, open: F, clock: impl Clock + 'static) -> Result<Self, BusError> {
        Self::opened(name, open, clock, false)
    }

    fn opened(
        name: &str,
        mut open: F,
        clock: impl Clock + 'static,
        loud: bool,
    ) -> Result<Self, BusError> {
        let now = clock.now();
        let (bus, last_error) = match open() {
            Ok(bus) => (
                Some(bus),
                BusError::NoDevice {
                    errno: libc::ENODEV,
                },
            ),
            Err(e @ BusError::NoDevice { .. }) => {
                if loud {
                    tracing::warn!(
                        interface = name, error = %e,
                        "CAN interface missing: waiting for it (safe command and status as soon \
                         as it appears; CAN_TX_ERROR meanwhile)"
                    );
                } else {
                    tracing::debug!(interface = name, error = %e, "CAN interface missing");
                }
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
