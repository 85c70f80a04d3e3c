//! Named threads and the stop flag they share.
//!
//! Every daemon thread has a name (it shows in `top -H`, `ps -L`, panics and core dumps);
//! `clippy.toml` bans `std::thread::spawn` so none escapes this.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{Builder, JoinHandle};
use std::time::Duration;

/// Spawns a thread named `name`.
pub fn spawn_named<T, F>(name: &str, f: F) -> std::io::Result<JoinHandle<T>>
where
    F: FnOnce() -> T + Send + 'static,
    T: Send + 'static,
{
    Builder::new().name(name.to_string()).spawn(f)
}

/// A shutdown request: set by a signal handler, a `--duration` timer, a test, or the daemon
/// itself (end of a mock scenario). Clones share the flag.
#[derive(Debug, Clone, Default)]
pub struct Shutdown(Arc<AtomicBool>);

impl Shutdown {
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks the daemon to stop (idempotent, async-signal-safe: one atomic store).
    pub fn request(&self) {
        self.0.store(true, Ordering::Release);
    }

    pub fn is_requested(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }

    /// The flag itself, for `signal_hook::flag::register`.
    pub fn flag(&self) -> &Arc<AtomicBool> {
        &self.0
    }

    /// Sleeps up to `duration` in short steps, returning early (`true`) once a stop is
    /// requested: how daemon threads wait, so shutdown is never delayed by a sleep.
    pub fn sleep(&self, duration: Duration) -> bool {
        const STEP: Duration = Duration::from_millis(10);
        let mut left = duration;
        while !left.is_zero() {
            if self.is_requested() {
                return true;
            }
            let step = left.min(STEP);
            std::thread::sleep(step);
            left -= step;
        }
        self.is_requested()
    }
}
