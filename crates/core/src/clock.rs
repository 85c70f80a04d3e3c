//! Time as the pure logic sees it: a [`Clock`] it is handed, never the system's.
//!
//! The decision, the CAN log transport and the daemon's fault monitor take their time from a
//! `Clock`, so tests drive them with a [`ManualClock`]. The production clocks (CLOCK_MONOTONIC,
//! the wall clock of candump logs) live in the runtime crate.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Where log and test backends get timestamps from, so that the logic never reads the system
/// clock itself and tests are deterministic.
pub trait Clock: Send {
    /// Time since the clock's epoch.
    fn now(&self) -> Duration;
}

impl<F: Fn() -> Duration + Send> Clock for F {
    fn now(&self) -> Duration {
        self()
    }
}

/// A clock tests set by hand; clones share the same time.
#[derive(Debug, Clone, Default)]
pub struct ManualClock(Arc<AtomicU64>);

impl ManualClock {
    pub fn new(start: Duration) -> Self {
        let clock = Self::default();
        clock.set(start);
        clock
    }

    pub fn set(&self, t: Duration) {
        self.0.store(saturating_nanos(t), Ordering::Relaxed);
    }

    pub fn advance(&self, dt: Duration) {
        let _ = self
            .0
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| {
                Some(n.saturating_add(saturating_nanos(dt)))
            });
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(self.0.load(Ordering::Relaxed))
    }
}

fn saturating_nanos(t: Duration) -> u64 {
    u64::try_from(t.as_nanos()).unwrap_or(u64::MAX)
}
