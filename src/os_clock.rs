//! The daemon's time, from the operating system's clocks: one injected [`Clock`] shared by all
//! threads.
//!
//! Frame timestamps ([`crate::source::FrameMeta::timestamp`]) and the daemon clock must share a
//! timebase, since the control thread compares them (perception age, reaction time). V4L2 stamps
//! buffers with CLOCK_MONOTONIC, so production uses [`MonotonicClock`]; tests pass a
//! [`flyd_core::clock::ManualClock`] or the monotonic clock, and their sources stamp frames with
//! the same clock. CAN logs are stamped with the wall clock ([`SystemClock`]), as candump does.

use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

pub use flyd_core::clock::Clock;

/// A clock all daemon threads can read.
pub type SharedClock = Arc<dyn Clock + Sync>;

/// CLOCK_MONOTONIC, the kernel's V4L2 buffer timestamp clock.
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now(&self) -> Duration {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
        if rc != 0 {
            return Duration::ZERO;
        }
        Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
    }
}

impl MonotonicClock {
    pub fn shared() -> SharedClock {
        Arc::new(MonotonicClock)
    }
}

/// Wall-clock time since the Unix epoch, as candump logs carry (the daemon's production clock).
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        // A clock before 1970 is a misconfigured machine; 0 keeps the log well-formed.
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_moves_forward() {
        let c = MonotonicClock;
        let a = c.now();
        std::thread::sleep(Duration::from_millis(2));
        let b = c.now();
        assert!(b > a && a > Duration::ZERO);
    }
}
