//! The hw-mock vehicle's side of the bus: `VCU_Motion` frames with the scenario's speed and
//! yaw rate, one every period on the daemon clock, as a VCU would send them (E2E counter and
//! CRC included). What the mock cameras are to the capture threads, this is to the control
//! thread's receiver.
//!
//! Frame `k` is due at `start + k period` and carries the motion of the scenario frame shown
//! then; a receiver that polls late gets the frames it missed, in order, stamped by when it
//! reads them (as a socket's queue would hand them over).

use std::time::Duration;

use hw_mock::Scenario;

use crate::os_clock::SharedClock;
use flyd_core::can::MessageConfig;
use flyd_core::can::bus::{BusError, CanReceiver, ReceivedFrame};
use flyd_core::can::messages::{AliveCounter, CanMessage, MotionMsg};

/// A frame of a queue longer than this was never read: older ones are dropped, as a full
/// socket receive buffer drops them.
const BACKLOG: u64 = 16;

/// `VCU_Motion` of a hw-mock scenario.
pub struct MockVehicle {
    scenario: Scenario,
    message: MessageConfig,
    clock: SharedClock,
    start: Duration,
    next: u64,
    counter: AliveCounter,
}

impl MockVehicle {
    /// Sends from now on `clock`, with `message`'s ID, Data ID and period.
    pub fn new(scenario: Scenario, message: MessageConfig, clock: SharedClock) -> Self {
        let start = clock.now();
        Self {
            scenario,
            message,
            clock,
            start,
            next: 0,
            counter: AliveCounter::ZERO,
        }
    }

    fn period(&self) -> Duration {
        self.message.period().max(Duration::from_millis(1))
    }
}

impl CanReceiver for MockVehicle {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        let elapsed = self.clock.now().saturating_sub(self.start);
        let period = self.period();
        let due = (elapsed.as_nanos() / period.as_nanos()) as u64;
        if self.next > due {
            return Ok(None);
        }
        if due - self.next >= BACKLOG {
            let skipped = due + 1 - BACKLOG - self.next;
            for _ in 0..skipped % u64::from(AliveCounter::MODULUS) {
                self.counter.advance();
            }
            self.next = due + 1 - BACKLOG;
        }
        let t = period.as_secs_f64() * self.next as f64;
        let frame = (t * self.scenario.fps()).floor() as u32;
        let msg = MotionMsg {
            valid: true,
            speed: self.scenario.speed_at(frame),
            yaw_rate: self.scenario.yaw_rate_at(frame),
        };
        self.next += 1;
        let data = msg.encode_with(self.counter.advance(), self.message.data_id);
        Ok(ReceivedFrame::new(self.message.id, &data))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flyd_core::can::motion_monitor::{MotionConfig, MotionMonitor};
    use flyd_core::clock::{Clock, ManualClock};
    use std::sync::Arc;

    #[test]
    fn sends_the_scenario_speed_every_period() {
        let clock = ManualClock::new(Duration::ZERO);
        let shared: SharedClock = Arc::new(clock.clone());
        let scenario = Scenario::by_name("driving").expect("known");
        let message = MessageConfig::default_for::<MotionMsg>();
        let mut vehicle = MockVehicle::new(scenario, message, shared);
        let mut monitor = MotionMonitor::new(MotionConfig::default());
        let mut frames = 0;
        for _ in 0..10 {
            while let Some(f) = vehicle.try_recv().expect("never fails") {
                assert_eq!(f.id, MotionMsg::DEFAULT_ID);
                monitor.receive(f.payload(), clock.now()).expect("accepted");
                frames += 1;
            }
            clock.advance(Duration::from_millis(20));
        }
        assert_eq!(frames, 10);
        assert_eq!(monitor.decision_speed(clock.now(), 20.0), 8.0);
        // A reader a second late gets the newest frames, still accepted.
        clock.advance(Duration::from_secs(1));
        let mut late = 0;
        while let Some(f) = vehicle.try_recv().expect("never fails") {
            monitor.receive(f.payload(), clock.now()).expect("accepted");
            late += 1;
        }
        assert_eq!(late, BACKLOG);
    }
}
