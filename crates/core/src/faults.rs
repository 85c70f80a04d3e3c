//! Fault detection (pure: the control thread passes the time and what it observed).
//!
//! | bit | raised while | clears when |
//! |-----|--------------|-------------|
//! | LEFT/RIGHT_CAMERA_STALE | no frame from that camera for `stale_timeout` (after start-up: since start) | a frame arrives |
//! | STEREO_SKEW | the newest snapshot reports too many consecutive rejected pairs | a pair is made |
//! | EVOLUTION_OVERRUN | the newest generation took longer than the maximum | a generation is in time |
//! | SNAPSHOT_STALE | no snapshot for `snapshot_timeout` (after start-up) | a snapshot arrives |
//! | CAMERA_ERROR | a capture thread reports a device error (format, disconnect), or a sensor check fails ([`crate::sensor`]: an image uniform or without texture, frozen, exposures far apart, or the stereo pair matching nowhere; which one is `FLYD_Status.SensorFaults`) | that camera delivers again; the images are healthy again |
//! | CAN_TX_ERROR | the last CAN write failed | a write succeeds |
//! | INTERNAL | the newest snapshot says the declared mount is off by more than the road estimator absorbs ([`crate::perception::mount_check`]: the camera's height, over 30 measured frames) | the road agrees with the mount again |
//!
//! During start-up (until the daemon is running, at most `startup_timeout`), missing frames and
//! snapshots are not faults: the state is INIT and the decider is already at its safe command.
//! After `startup_timeout` without running, they are.
//!
//! The state in the status frame: INIT before running, FAULT when no perception can be trusted
//! at all (no fresh snapshot, or both cameras stale), DEGRADED with any other fault, RUNNING.

use std::time::Duration;

use crate::sensor::SensorFaults;
use crate::status::{FaultBits, State};

/// What the control thread saw, at time `now`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Observation {
    pub now: Duration,
    /// Arrival time of each camera's newest frame (`None`: none yet).
    pub left_frame_at: Option<Duration>,
    pub right_frame_at: Option<Duration>,
    pub left_error: bool,
    pub right_error: bool,
    /// When the newest snapshot arrived, and its flags.
    pub snapshot_at: Option<Duration>,
    pub skew_fault: bool,
    pub overrun: bool,
    /// The newest snapshot's sensor faults (uniform, frozen, mismatched, blind).
    pub sensor: SensorFaults,
    pub can_failing: bool,
    /// The declared mount is off by more than the road estimator absorbs
    /// ([`crate::perception::mount_check::MountReport::hides`]).
    pub mount_fault: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultConfig {
    pub stale_timeout: Duration,
    pub snapshot_timeout: Duration,
    pub startup_timeout: Duration,
}

#[derive(Debug, Clone)]
pub struct FaultMonitor {
    config: FaultConfig,
    started_at: Duration,
    running: bool,
}

impl FaultMonitor {
    pub fn new(config: FaultConfig, started_at: Duration) -> Self {
        Self {
            config,
            started_at,
            running: false,
        }
    }

    /// Leaves start-up (both cameras delivered and a generation ran).
    pub fn set_running(&mut self) {
        self.running = true;
    }

    pub fn is_running(&self) -> bool {
        self.running
    }

    /// The fault bits for `o`.
    pub fn evaluate(&self, o: &Observation) -> FaultBits {
        let c = &self.config;
        let judged = self.running || o.now.saturating_sub(self.started_at) >= c.startup_timeout;
        // Before any frame, time counts from start.
        let stale = |at: Option<Duration>, timeout: Duration| {
            judged && o.now.saturating_sub(at.unwrap_or(self.started_at)) > timeout
        };
        let mut f = FaultBits::empty();
        f.set(
            FaultBits::LEFT_CAMERA_STALE,
            stale(o.left_frame_at, c.stale_timeout),
        );
        f.set(
            FaultBits::RIGHT_CAMERA_STALE,
            stale(o.right_frame_at, c.stale_timeout),
        );
        f.set(
            FaultBits::SNAPSHOT_STALE,
            stale(o.snapshot_at, c.snapshot_timeout),
        );
        f.set(FaultBits::STEREO_SKEW, o.skew_fault);
        f.set(FaultBits::EVOLUTION_OVERRUN, o.overrun);
        f.set(
            FaultBits::CAMERA_ERROR,
            o.left_error || o.right_error || !o.sensor.is_empty(),
        );
        f.set(FaultBits::CAN_TX_ERROR, o.can_failing);
        f.set(FaultBits::INTERNAL, o.mount_fault);
        f
    }

    /// The status frame's state for `faults`.
    pub fn state(&self, faults: FaultBits) -> State {
        let both_stale =
            faults.contains(FaultBits::LEFT_CAMERA_STALE | FaultBits::RIGHT_CAMERA_STALE);
        if !self.running && faults.is_empty() {
            State::Init
        } else if faults.contains(FaultBits::SNAPSHOT_STALE) || both_stale {
            State::Fault
        } else if faults.is_empty() {
            State::Running
        } else {
            State::Degraded
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn monitor() -> FaultMonitor {
        FaultMonitor::new(
            FaultConfig {
                stale_timeout: 100 * MS,
                snapshot_timeout: 50 * MS,
                startup_timeout: 1000 * MS,
            },
            Duration::ZERO,
        )
    }

    fn fresh(now_ms: u32) -> Observation {
        let now = MS * now_ms;
        Observation {
            now,
            left_frame_at: Some(now),
            right_frame_at: Some(now),
            snapshot_at: Some(now),
            ..Observation::default()
        }
    }

    #[test]
    fn start_up_is_init_without_faults_until_the_timeout() {
        let m = monitor();
        let o = Observation {
            now: 999 * MS,
            ..Observation::default()
        };
        assert_eq!(m.evaluate(&o), FaultBits::empty());
        assert_eq!(m.state(FaultBits::empty()), State::Init);
        let o = Observation {
            now: 1001 * MS,
            right_frame_at: Some(1000 * MS),
            ..Observation::default()
        };
        let f = m.evaluate(&o);
        assert_eq!(f, FaultBits::LEFT_CAMERA_STALE | FaultBits::SNAPSHOT_STALE);
        assert_eq!(m.state(f), State::Fault);
    }

    #[test]
    fn stale_camera_raises_its_bit_and_clears_on_a_frame() {
        let mut m = monitor();
        m.set_running();
        let mut o = fresh(5000);
        o.left_frame_at = Some(4900 * MS);
        assert_eq!(
            m.evaluate(&o),
            FaultBits::empty(),
            "exactly the timeout is not stale"
        );
        o.left_frame_at = Some(4899 * MS);
        let f = m.evaluate(&o);
        assert_eq!(f, FaultBits::LEFT_CAMERA_STALE);
        assert_eq!(m.state(f), State::Degraded);
        o.right_frame_at = Some(Duration::ZERO);
        assert_eq!(m.state(m.evaluate(&o)), State::Fault, "both cameras stale");
        assert_eq!(m.evaluate(&fresh(5001)), FaultBits::empty());
        assert_eq!(m.state(FaultBits::empty()), State::Running);
    }

    #[test]
    fn snapshot_skew_overrun_camera_and_can_bits() {
        let mut m = monitor();
        m.set_running();
        let check = |change: fn(&mut Observation), bit: FaultBits| {
            let mut o = fresh(2000);
            change(&mut o);
            assert_eq!(m.evaluate(&o), bit);
        };
        check(
            |o| o.snapshot_at = Some(1949 * MS),
            FaultBits::SNAPSHOT_STALE,
        );
        check(|o| o.skew_fault = true, FaultBits::STEREO_SKEW);
        check(|o| o.overrun = true, FaultBits::EVOLUTION_OVERRUN);
        check(|o| o.right_error = true, FaultBits::CAMERA_ERROR);
        check(|o| o.sensor = SensorFaults::BLIND, FaultBits::CAMERA_ERROR);
        check(|o| o.sensor = SensorFaults::FROZEN, FaultBits::CAMERA_ERROR);
        check(|o| o.can_failing = true, FaultBits::CAN_TX_ERROR);
        check(|o| o.mount_fault = true, FaultBits::INTERNAL);
    }
}
