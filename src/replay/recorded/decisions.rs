//! The second pass of a recording's replay: the recorded snapshots and vehicle frames, with
//! the replayed perception's outcomes, through the decider each command period as the daemon's
//! control thread did (`flyd_core::policy`), each command compared with the recorded one.

use std::time::Duration;

use super::{Outcome, RecordedSummary};
use crate::bus::MemoryBus;
use crate::config::DaemonConfig;
use crate::record::nanos;
use crate::record::read::ControlEvent;
use crate::record::topics::InputFrom;
use crate::replay::ReplayError;
use flyd_core::can::Transmitter;
use flyd_core::can::messages::CommandMsg;
use flyd_core::can::motion_monitor::MotionMonitor;
use flyd_core::clock::ManualClock;
use flyd_core::decision::DecisionInput;
use flyd_core::policy::{DecisionStep, InputSource, untrusted};
use flyd_core::status::FaultBits;

/// Same bits, for the comparison of a replayed value with a recorded one; JSON keeps no NaN
/// or infinity (they are recorded as null, read back as NaN), so any two non-finite values
/// compare equal.
pub(super) fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (!a.is_finite() && !b.is_finite())
}

pub(super) fn same_opt(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => same(a, b),
        (None, None) => true,
        _ => false,
    }
}

pub(super) fn replay_decisions(
    config: &DaemonConfig,
    events: &crate::record::read::Events,
    outcomes: &[Option<Outcome>],
    start: u64,
    recorder: Option<&crate::record::Recorder>,
    summary: &mut RecordedSummary,
) -> Result<(), ReplayError> {
    let mut step = DecisionStep::new(config.decision)?;
    let bus = MemoryBus::new(ManualClock::new(Duration::ZERO));
    let mut tx = Transmitter::new(bus.clone(), config.can.messages)?;
    let command_id = config.can.messages.command.id;
    let sent: Vec<&crate::record::topics::CanEvent> =
        events.sent.iter().filter(|e| e.id == command_id).collect();
    summary.commands_recorded = sent.len();
    let mut monitor = config.motion().map(MotionMonitor::new);
    let assumed = config.vehicle.assumed_speed;
    let outcome = |g: u64| {
        outcomes
            .get(usize::try_from(g).unwrap_or(usize::MAX))
            .copied()
            .flatten()
    };
    for event in &events.control {
        match event {
            ControlEvent::Received(frame) => {
                if let Some(m) = monitor.as_mut()
                    && frame.id == config.can.messages.motion.id
                {
                    let data = unhex(&frame.data);
                    let _ = m.receive(&data, Duration::from_nanos(frame.t_ns));
                }
            }
            ControlEvent::Perception(p) => {
                if p.warming_up {
                    continue;
                }
                let t = Duration::from_nanos(p.t_ns);
                let Some(o) = outcome(p.generation) else {
                    summary.diverge(
                        "recording",
                        secs_after(nanos(t), start),
                        Some(p.generation),
                        "a snapshot of a generation the replay did not run".into(),
                    );
                    break;
                };
                summary.snapshots += 1;
                if same(o.global_warning, p.global_warning) && same_opt(o.obstacle, p.obstacle_m) {
                    summary.snapshots_identical += 1;
                } else {
                    summary.diverge(
                        "perception",
                        secs_after(nanos(t), start),
                        Some(p.generation),
                        format!(
                            "global warning {} / obstacle {:?} m recorded, {} / {:?} replayed",
                            p.global_warning, p.obstacle_m, o.global_warning, o.obstacle
                        ),
                    );
                }
                if let Some(m) = &monitor {
                    let speed = m.decision_speed(t, assumed);
                    if !same(speed, p.speed) {
                        summary.diverge(
                            "speed",
                            secs_after(nanos(t), start),
                            Some(p.generation),
                            format!(
                                "the recorded VCU_Motion frames give {speed} m/s, the daemon \
                                 decided at {} m/s",
                                p.speed
                            ),
                        );
                    }
                }
                let input = o.tracked.credit(DecisionInput {
                    global_warning: o.global_warning,
                    latency: p.latency,
                    ..DecisionInput::at_speed(o.obstacle, p.speed)
                });
                if let Some(r) = recorder {
                    let observed = crate::record::Observed {
                        generation: p.generation,
                        warming_up: false,
                        global_warning: o.global_warning,
                        matched: o.matched,
                        generation_time: Duration::from_secs_f64(p.generation_us.max(0.0) * 1e-6),
                        road: &o.road,
                        tracked: &o.tracked,
                        path: o.path,
                        search_far: o.search_far,
                    };
                    r.snapshot(p.seq, t, observed, &input);
                }
                step.observe(input);
            }
            ControlEvent::Decision(d) => {
                let t = Duration::from_nanos(d.t_ns);
                let (decision, warning, used) = match d.from {
                    InputFrom::Shutdown => (
                        step.shutdown(),
                        d.global_warning,
                        DecisionInput {
                            global_warning: d.global_warning,
                            ..untrusted()
                        },
                    ),
                    from => {
                        // The newest snapshot again, as the daemon recorded it.
                        let latest = || {
                            d.latest_generation.and_then(outcome).map(|o| {
                                o.tracked.credit(DecisionInput {
                                    global_warning: o.global_warning,
                                    latency: d.latest_latency.unwrap_or(f64::NAN),
                                    ..DecisionInput::at_speed(
                                        o.obstacle,
                                        d.latest_speed.unwrap_or(f64::NAN),
                                    )
                                })
                            })
                        };
                        // The daemon's choice, as it recorded it: a recording that dropped
                        // snapshots must not make the replay choose otherwise.
                        let source = match from {
                            InputFrom::Taken => InputSource::Taken,
                            InputFrom::Latest => InputSource::Latest,
                            _ => InputSource::Untrusted,
                        };
                        let chosen = step.replayed_choice(source, latest);
                        let faults = FaultBits::from_bits(d.faults as u8);
                        let decision = step.decide_chosen(chosen, faults, t).decision;
                        (decision, chosen.input.global_warning, chosen.input)
                    }
                };
                let _ = tx.send_command(&CommandMsg::of(&decision, warning));
                let replayed = bus.take_frames();
                if let Some(r) = recorder {
                    let faults = FaultBits::from_bits(d.faults as u8);
                    let state = if faults.is_empty() {
                        flyd_core::status::State::Running
                    } else {
                        flyd_core::status::State::Degraded
                    };
                    let input = DecisionInput { faults, ..used };
                    // A command decided on the newest snapshot again carries what it was
                    // decided from, as the daemon records it.
                    let latest = match d.from {
                        InputFrom::Latest => d.latest_generation.map(|g| (g, used)),
                        _ => None,
                    };
                    r.command(d.seq, t, d.from, latest, faults, state, &input, &decision);
                    for f in &replayed {
                        r.can(true, d.seq, t, f.id, &f.data);
                    }
                }
                let i = summary.commands_replayed;
                summary.commands_replayed += 1;
                if decision.changed {
                    summary.changes.push(format!(
                        "{:.3}:{}",
                        secs_after(nanos(t), start),
                        decision.command.name()
                    ));
                }
                if decision.command == flyd_core::decision::Command::Stop
                    && summary.first_stop_s.is_none()
                {
                    summary.first_stop_s = Some(secs_after(nanos(t), start));
                }
                let recorded = sent.get(i).map(|e| unhex(&e.data));
                let mine = replayed.last().map(|f| f.data.clone());
                if recorded.is_some() && recorded == mine {
                    summary.commands_identical += 1;
                } else {
                    summary.diverge(
                        "command",
                        secs_after(nanos(t), start),
                        None,
                        format!(
                            "command {} ({} {}): sent {} recorded, {} replayed ({} {})",
                            i + 1,
                            d.command,
                            d.reason,
                            recorded.map_or("nothing".into(), |r| crate::record::topics::hex(&r)),
                            mine.map_or("nothing".into(), |r| crate::record::topics::hex(&r)),
                            decision.command.name(),
                            decision.reason.name(),
                        ),
                    );
                }
            }
        }
    }
    if summary.commands_replayed != summary.commands_recorded {
        summary.diverge(
            "command",
            f64::NAN,
            None,
            format!(
                "{} FLYD_Command frames recorded, {} decisions replayed",
                summary.commands_recorded, summary.commands_replayed
            ),
        );
    }
    Ok(())
}

/// Seconds from `start` to `ns` (both clock nanoseconds).
pub(super) fn secs_after(ns: u64, start: u64) -> f64 {
    (ns as f64 - start as f64) * 1e-9
}

/// The bytes of a candump-style hex payload (odd or invalid digits are dropped).
pub(super) fn unhex(text: &str) -> Vec<u8> {
    text.as_bytes()
        .chunks_exact(2)
        .filter_map(|pair| {
            std::str::from_utf8(pair)
                .ok()
                .and_then(|s| u8::from_str_radix(s, 16).ok())
        })
        .collect()
}
