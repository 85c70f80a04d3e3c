//! systemd notification (`Type=notify`): READY, WATCHDOG and STATUS lines via `sd-notify`.
//!
//! - `READY=1` once, when both cameras have delivered and the first generation ran (the control
//!   thread's first snapshot).
//! - `WATCHDOG=1` from the control thread only, and only while generations complete and frames
//!   are fresh ([`WatchdogGate`]): a hung evolution thread or dead cameras stop the pings, and
//!   systemd restarts the service (`WatchdogSec=`). No thread of its own pings blindly.
//! - `STATUS=...` on state changes and with each stats event, for `systemctl status`.
//! - `EXTEND_TIMEOUT_USEC=` every [`EXTEND_EVERY`] while not ready yet (a camera plugged in
//!   late): the daemon is alive and already sending FAULT status on CAN, so systemd's start
//!   timeout should not kill it.
//! - `STOPPING=1` at shutdown.
//!
//! Where the notifications go is given to [`crate::daemon::run`]: `flyd run` reads
//! `NOTIFY_SOCKET` and `WATCHDOG_USEC` once ([`ServiceNotifier::from_env`]), a test names its
//! own socket ([`ServiceNotifier::new`]) or none ([`ServiceNotifier::none`]: every call is a
//! no-op, as without `NOTIFY_SOCKET`). A failing socket is logged once, never fatal.

use std::ffi::OsString;
use std::fmt::Write as _;
use std::os::unix::net::UnixDatagram;
use std::time::Duration;

use sd_notify::NotifyState;

/// While not ready, the start timeout is extended this often...
pub const EXTEND_EVERY: Duration = Duration::from_secs(5);
/// ...by this much.
pub const EXTEND_BY: Duration = Duration::from_secs(15);

/// Decides when the watchdog may be pinged (pure).
#[derive(Debug, Clone, Copy)]
pub struct WatchdogGate {
    interval: Duration,
    last: Option<(Duration, u64)>,
}

impl WatchdogGate {
    /// Pings every `interval` at most (systemd's `WatchdogSec` / 2).
    pub fn new(interval: Duration) -> Self {
        Self {
            interval,
            last: None,
        }
    }

    /// Whether to ping now: `interval` passed since the last ping, at least one generation
    /// completed since (`generation` grew), and the cameras are fresh.
    pub fn should_ping(&mut self, now: Duration, generation: u64, fresh: bool) -> bool {
        let due = match self.last {
            None => generation > 0,
            Some((t, g)) => now.saturating_sub(t) >= self.interval && generation > g,
        };
        if due && fresh {
            self.last = Some((now, generation));
            true
        } else {
            false
        }
    }
}

/// The daemon's line to systemd.
#[derive(Debug)]
pub struct ServiceNotifier {
    /// systemd's socket (`NOTIFY_SOCKET`); `None`: not under systemd.
    socket: Option<OsString>,
    watchdog: Option<WatchdogGate>,
    ready_sent: bool,
    failed_once: bool,
    last_extend: Option<Duration>,
}

impl ServiceNotifier {
    /// What systemd says in the environment: `NOTIFY_SOCKET`, and `WATCHDOG_USEC` (with
    /// `WATCHDOG_PID`, through `sd-notify`), read once.
    pub fn from_env() -> Self {
        Self::new(
            std::env::var_os("NOTIFY_SOCKET"),
            sd_notify::watchdog_enabled(),
        )
    }

    /// Notifications to `socket` (the path of systemd's datagram socket); with a
    /// `watchdog` interval (`WatchdogSec`), pings every half of it.
    pub fn new(socket: Option<impl Into<OsString>>, watchdog: Option<Duration>) -> Self {
        Self {
            socket: socket.map(Into::into),
            watchdog: watchdog.map(|d| WatchdogGate::new(d / 2)),
            ready_sent: false,
            failed_once: false,
            last_extend: None,
        }
    }

    /// Not under systemd: nothing is sent.
    pub fn none() -> Self {
        Self::new(None::<OsString>, None)
    }

    fn send(&mut self, states: &[NotifyState]) {
        let Some(socket) = &self.socket else {
            return;
        };
        // As `sd_notify::notify` writes them: one state a line, one datagram.
        let mut message = String::new();
        for state in states {
            let _ = writeln!(message, "{state}");
        }
        let sent = UnixDatagram::unbound()
            .and_then(|s| s.connect(socket).map(|()| s))
            .and_then(|s| s.send(message.as_bytes()))
            .and_then(|n| {
                if n == message.len() {
                    Ok(())
                } else {
                    Err(std::io::Error::new(
                        std::io::ErrorKind::WriteZero,
                        "incomplete write",
                    ))
                }
            });
        if let Err(error) = sent
            && !self.failed_once
        {
            tracing::warn!(%error, "systemd notification failed (not retried in the log)");
            self.failed_once = true;
        }
    }

    pub fn is_ready(&self) -> bool {
        self.ready_sent
    }

    /// `READY=1` with a status line (once; later calls only update the status).
    pub fn ready(&mut self, status: &str) {
        if self.ready_sent {
            self.status(status);
        } else {
            self.ready_sent = true;
            self.send(&[NotifyState::Ready, NotifyState::Status(status)]);
        }
    }

    pub fn status(&mut self, status: &str) {
        self.send(&[NotifyState::Status(status)]);
    }

    /// Pings the watchdog if it is enabled and [`WatchdogGate::should_ping`] agrees.
    pub fn watchdog(&mut self, now: Duration, generation: u64, fresh: bool) {
        let ping = self
            .watchdog
            .as_mut()
            .is_some_and(|gate| gate.should_ping(now, generation, fresh));
        if ping {
            self.send(&[NotifyState::Watchdog]);
        }
    }

    /// Before READY: asks systemd for more start time, every [`EXTEND_EVERY`].
    pub fn extend_startup(&mut self, now: Duration) {
        let due = self
            .last_extend
            .is_none_or(|t| now.saturating_sub(t) >= EXTEND_EVERY);
        if !self.ready_sent && due {
            self.last_extend = Some(now);
            let usec = u32::try_from(EXTEND_BY.as_micros()).unwrap_or(u32::MAX);
            self.send(&[NotifyState::ExtendTimeoutUsec(usec)]);
        }
    }

    pub fn stopping(&mut self, status: &str) {
        self.send(&[NotifyState::Stopping, NotifyState::Status(status)]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn watchdog_needs_progress_fresh_frames_and_the_interval() {
        let mut g = WatchdogGate::new(100 * MS);
        assert!(!g.should_ping(Duration::ZERO, 0, true), "no generation yet");
        assert!(g.should_ping(10 * MS, 1, true));
        assert!(!g.should_ping(50 * MS, 5, true), "interval not over");
        assert!(
            !g.should_ping(200 * MS, 1, true),
            "no generation since the last ping"
        );
        assert!(!g.should_ping(200 * MS, 9, false), "stale frames");
        assert!(g.should_ping(210 * MS, 9, true));
    }
}
