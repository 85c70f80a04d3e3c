//! Time spent in each step of a generation, for profiling (`--features phase-timers`; without
//! the feature every timer compiles to nothing). The counters are process-wide: read them from
//! a single-engine benchmark (`flyd bench` prints them when the feature is on).

/// The steps of [`super::Engine::step`] that are timed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum Phase {
    Refresh,
    Select,
    Compact,
    Mates,
    Breed,
    Mutate,
    Immigrate,
    Evaluate,
    Share,
    Warnings,
}

impl Phase {
    pub const ALL: [Phase; 10] = [
        Phase::Refresh,
        Phase::Select,
        Phase::Compact,
        Phase::Mates,
        Phase::Breed,
        Phase::Mutate,
        Phase::Immigrate,
        Phase::Evaluate,
        Phase::Share,
        Phase::Warnings,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Phase::Refresh => "refresh",
            Phase::Select => "select",
            Phase::Compact => "compact",
            Phase::Mates => "mates",
            Phase::Breed => "breed",
            Phase::Mutate => "mutate",
            Phase::Immigrate => "immigrate",
            Phase::Evaluate => "evaluate",
            Phase::Share => "share",
            Phase::Warnings => "warnings",
        }
    }
}

#[cfg(feature = "phase-timers")]
mod imp {
    use super::Phase;
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::time::Instant;

    static NANOS: [AtomicU64; 10] = [const { AtomicU64::new(0) }; 10];

    pub struct Timer(Phase, Instant);

    #[inline]
    pub fn start(p: Phase) -> Timer {
        Timer(p, Instant::now())
    }

    impl Timer {
        /// Ends the timing (so does dropping it).
        #[inline]
        pub fn stop(self) {}
    }

    impl Drop for Timer {
        #[inline]
        fn drop(&mut self) {
            let ns = self.1.elapsed().as_nanos() as u64;
            NANOS[self.0 as usize].fetch_add(ns, Ordering::Relaxed);
        }
    }

    /// Nanoseconds spent in each phase so far, and resets them.
    pub fn take() -> Option<[(Phase, u64); 10]> {
        Some(Phase::ALL.map(|p| (p, NANOS[p as usize].swap(0, Ordering::Relaxed))))
    }
}

#[cfg(not(feature = "phase-timers"))]
mod imp {
    use super::Phase;

    pub struct Timer;

    impl Timer {
        #[inline(always)]
        pub fn stop(self) {}
    }

    #[inline(always)]
    pub fn start(_: Phase) -> Timer {
        Timer
    }

    /// Always `None`: built without the `phase-timers` feature.
    pub fn take() -> Option<[(Phase, u64); 10]> {
        None
    }
}

pub use imp::{Timer, start, take};
