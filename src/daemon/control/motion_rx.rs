//! What the vehicle sends: `VCU_Motion` read without blocking into the motion monitor, the
//! speed the stopping distances use, and the transitions logged.

use std::time::Duration;

use super::{ControlThread, Loop, MAX_RX_PER_TURN, next_seq};
use flyd_core::can::bus::CanBus;
use flyd_core::decision::Command;

impl<B: CanBus> ControlThread<B> {
    /// Where the decision's speed comes from, for the logs.
    pub(super) fn motion_label(&self, s: &Loop) -> &'static str {
        match (&self.motion, s.motion_fault) {
            (None, _) => "not-configured",
            (Some(_), None) => "measured",
            (Some(_), Some(f)) => f.name(),
        }
    }

    /// The speed the stopping distances are computed with at `now`, m/s.
    pub(super) fn speed(&self, now: Duration) -> f64 {
        self.motion.as_ref().map_or(self.assumed_speed, |m| {
            m.monitor.decision_speed(now, self.assumed_speed)
        })
    }

    /// Reads what the vehicle sent (without blocking), then the motion's state at `now`, with
    /// its transitions logged.
    pub(super) fn receive(&mut self, s: &mut Loop, now: Duration) {
        let Some(motion) = self.motion.as_mut() else {
            return;
        };
        if let Some(rx) = motion.rx.as_mut() {
            for _ in 0..MAX_RX_PER_TURN {
                match rx.try_recv() {
                    Ok(Some(frame)) => {
                        if s.rx_failing {
                            tracing::info!("CAN receive recovered");
                            s.rx_failing = false;
                        }
                        if let Some(recorder) = &self.recorder {
                            let seq = next_seq(s);
                            recorder.can(false, seq, now, frame.id, frame.payload());
                        }
                        if frame.id != motion.id {
                            continue;
                        }
                        if let Err(rejection) = motion.monitor.receive(frame.payload(), now) {
                            tracing::debug!(
                                ?rejection,
                                data = ?frame.payload(),
                                "VCU_Motion frame rejected"
                            );
                        }
                    }
                    Ok(None) => break,
                    Err(error) => {
                        if !s.rx_failing {
                            tracing::warn!(
                                %error,
                                "CAN receive failed: the vehicle's motion goes stale (logged once until it recovers)"
                            );
                            s.rx_failing = true;
                        }
                        break;
                    }
                }
            }
        }
        let status = motion.monitor.status(now);
        motion.shared.publish(status.motion());
        let fault = status.fault();
        let counters = motion.monitor.counters();
        s.report.motion_accepted = counters.accepted;
        s.report.motion_rejected = counters.rejected();
        if fault != s.motion_fault {
            match (fault, status.motion()) {
                (None, Some(m)) => {
                    s.motion_known_once = true;
                    tracing::info!(
                        speed_kmh = crate::logging::shown(m.speed * 3.6, 2),
                        yaw_rate = m.yaw_rate,
                        "vehicle motion known: stopping distances at the measured speed"
                    );
                }
                (Some(f), _) => {
                    if s.motion_known_once {
                        s.report.motion_lost = true;
                    }
                    tracing::warn!(
                        motion_fault = %f,
                        assumed_speed_kmh = crate::logging::shown(self.assumed_speed * 3.6, 2),
                        accepted = counters.accepted,
                        rejected = counters.rejected(),
                        "vehicle motion unknown: stopping distances at the assumed speed"
                    );
                }
                (None, None) => {}
            }
            s.motion_fault = fault;
        }
        let speed = self.speed(now);
        let reach = self.decision.decider().config().reach(Command::Slow, speed);
        let beyond = reach > self.range;
        if beyond != s.beyond_range {
            if beyond {
                tracing::warn!(
                    speed_kmh = crate::logging::shown(speed * 3.6, 2),
                    slow_distance_m = crate::logging::shown(reach, 2),
                    range_m = crate::logging::shown(self.range, 2),
                    "speed beyond what flyd sees in time: the SLOW distance exceeds the farthest \
                     the rig searches for obstacles (vehicle.assumed_speed_kmh is the highest \
                     speed the configuration was checked for)"
                );
            } else {
                tracing::info!(
                    speed_kmh = crate::logging::shown(speed * 3.6, 2),
                    "speed within the range searched again"
                );
            }
            s.beyond_range = beyond;
        }
    }
}
