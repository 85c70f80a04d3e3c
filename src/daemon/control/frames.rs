//! The frames the control thread sends: `FLYD_Command` (the decision each period, an
//! escalation at once), `FLYD_Status`, and what a write's result does to CAN_TX_ERROR.

use std::time::Duration;

use super::{ControlThread, Loop};
use flyd_core::can::bus::{BusError, CanBus};
use flyd_core::can::messages::{CommandMsg, StatusMsg};
use flyd_core::decision::Command;
use flyd_core::perception::RoadSource;
use flyd_core::policy::InputSource;
use flyd_core::status::State;

impl<B: CanBus> ControlThread<B> {
    pub(super) fn send_command(&mut self, s: &mut Loop, now: Duration) {
        // The newest trusted snapshot, asked only when none was taken since the last command.
        // (What it tells the decider at this command's time: read before the step, which
        // asks for it only when no snapshot was taken.)
        let newest = s.latest.filter(|l| !l.warming_up);
        let newest_input = newest.map(|l| self.input_at(&l, self.clock.now()));
        let flyd_core::policy::Decided { chosen, decision } =
            self.decision.decide(now, s.faults, || newest_input);
        let latest = match chosen.from {
            InputSource::Latest => newest.map(|l| (l.generation, chosen.input)),
            _ => None,
        };
        let input = chosen.input;
        let warning = input.global_warning;
        self.record_decision(s, now, chosen.from.into(), latest, &input, &decision);
        if decision.changed {
            s.report.decision_changes += 1;
            tracing::info!(
                from = %decision.previous,
                to = %decision.command,
                reason = %decision.reason,
                global_warning = warning,
                faults = %s.faults,
                obstacle_m = input.obstacle,
                speed_kmh = crate::logging::shown(input.speed * 3.6, 2),
                motion = self.motion_label(s),
                road = %s.latest.map_or(RoadSource::Prior, |l| l.road.source),
                "decision changed"
            );
        }
        s.command = decision.command;
        let r = self.tx.send_command(&CommandMsg::of(&decision, warning));
        if r.is_ok() && decision.command == Command::Stop && s.report.first_stop_at.is_none() {
            s.report.first_stop_at = Some(self.clock.now());
            s.report.first_stop_snapshot_at = s.latest.map(|l| l.taken_at);
            s.report.first_stop_frame_at = s.latest.map(|l| l.capture_time());
            s.report.first_stop_speed = Some(input.speed);
        }
        self.sent(s, r, "FLYD_Command");
        s.report.commands_sent += 1;
        s.report.last_command = Some(decision.command);
    }

    pub(super) fn status_msg(&self, s: &Loop, now: Duration, state: State) -> StatusMsg {
        StatusMsg {
            state,
            faults: s.faults,
            perception_age: s
                .latest
                .map_or(Duration::MAX, |l| now.saturating_sub(l.capture_time())),
            sensor: s.sensor,
            motion_fault: s.motion_fault.is_some(),
            generations_per_sec: s.gen_rate.rate(),
            cam_fps_left: s.left_fps.rate(),
            cam_fps_right: s.right_fps.rate(),
        }
    }

    pub(super) fn send_status(&mut self, s: &mut Loop, now: Duration) {
        let msg = self.status_msg(s, now, s.state);
        let r = self.tx.send_status(&msg);
        self.sent(s, r, "FLYD_Status");
        s.report.statuses_sent += 1;
    }

    /// Counts a send; logs the first failure of an episode and the recovery.
    pub(super) fn sent(
        &mut self,
        s: &mut Loop,
        result: Result<(), BusError>,
        message: &'static str,
    ) {
        match result {
            Ok(()) => {
                s.last_sent_at = Some(self.clock.now());
                if s.can_failing {
                    tracing::info!(errors = s.can_episode_errors, "CAN writes recovered");
                    s.can_failing = false;
                    s.can_episode_errors = 0;
                }
            }
            Err(error) => {
                s.report.can_errors += 1;
                s.can_episode_errors += 1;
                if !s.can_failing {
                    tracing::warn!(
                        %error,
                        can_message = message,
                        retryable = error.is_retryable(),
                        "CAN write failed: sending again every period (logged once until it recovers)"
                    );
                    s.can_failing = true;
                }
            }
        }
    }
}
