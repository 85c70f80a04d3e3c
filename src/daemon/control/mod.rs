//! The control thread: snapshots in, CAN frames out, at fixed periods.
//!
//! Every turn (when a snapshot arrives, and at most 5 ms apart): drain the snapshot channel,
//! evaluate the faults ([`FaultMonitor`]) at the clock's time, log fault and state transitions,
//! and send whatever is due: `FLYD_Command` and `FLYD_Status` every 20 ms, `FLYD_Obstacle`
//! every 100 ms by default (the [`CanConfig`] periods), whether or not anything changed. A
//! warning that escalates the command (CLEAR to SLOW, SLOW to STOP) sends `FLYD_Command` at
//! once, between two periodic frames: a stop order does not wait for the period. The command is
//! decided by the [`Decider`](flyd_core::decision::Decider) (in metres by default: the confirmed obstacle against the stopping
//! distance, see [`flyd_core::decision`]) fed with
//!
//! - the **worst snapshot** since the previous command ([`DecisionInput::worst`]: the nearest
//!   confirmed obstacle, the highest global warning; a spike between two commands is not lost,
//!   releases stay conservative), or the newest snapshot's when none arrived;
//! - the vehicle's speed: the measured one while `VCU_Motion` is trusted
//!   ([`flyd_core::can::motion_monitor::MotionMonitor`]: CRC, counter, age, plausibility), else the
//!   configured highest (`vehicle.assumed_speed_kmh`) with `FLYD_Status.MotionFault` set;
//! - the current fault bits: any fault makes the decider fall back to its safe command.
//!
//! Snapshots of a population still warming up (fewer than `warmup_generations`) carry no
//! trusted evidence: the decider gets an invalid input (its fault path: the safe command,
//! reason FAULT_FALLBACK) and the state stays INIT. `READY=1` goes to systemd with the first
//! snapshot (both cameras deliver, a generation ran); RUNNING follows the warm-up.
//!
//! The command frame's `GlobalWarning` signal carries the paper's global warning (the mean
//! warning; what the `global-warning` decision mode compares with its thresholds). The
//! engine's `danger` (a fitness-weighted mean of the geometric factor) says where the evidence
//! is, not how much there is, so it is logged, never decided on.
//!
//! CAN write errors never stop the loop: they are counted, logged once per episode (and once
//! when writes recover), raise CAN_TX_ERROR, and the next period simply sends again.
//!
//! Received frames (the vehicle's motion) are read in the same loop, without blocking, at most
//! [`MAX_RX_PER_TURN`] a turn, so a flood of them never delays a send.
//!
//! This is the only thread that writes to the bus and talks to systemd ([`ServiceNotifier`]).
//! At shutdown it sends a last command (reason SHUTDOWN) and a last status (state SHUTDOWN).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use crossbeam_channel::Receiver;

use super::capture::CameraHealth;
use super::evolution::EvolutionCounters;
use super::notify::ServiceNotifier;
use super::ring::RingCounters;
use super::snapshot::Snapshot;
use super::stats::{RateMeter, SampleWindow};
use crate::logging::shown;
use crate::os_clock::SharedClock;
use crate::record::Observed;
use crate::record::topics::{InputFrom, StatsEvent};
use crate::thread::Shutdown;
use flyd_core::can::bus::{CanBus, CanReceiver};
use flyd_core::can::messages::{CommandMsg, ObstacleMotionMsg, ObstacleMsg, PathMsg};
use flyd_core::can::motion_monitor::{MotionFault, MotionMonitor};
use flyd_core::can::{CanConfig, Transmitter};
use flyd_core::decision::Command;
use flyd_core::decision::DecisionInput;
use flyd_core::faults::{FaultMonitor, Observation};
use flyd_core::perception::RoadSource;
use flyd_core::policy::DecisionStep;
use flyd_core::sensor::SensorFaults;
use flyd_core::status::{FaultBits, State};

mod frames;
mod motion_rx;

/// The next recorded event's number.
fn next_seq(s: &mut Loop) -> u64 {
    s.record_seq += 1;
    s.record_seq
}

/// Longest sleep between turns: bounds the reaction to a due frame and to shutdown.
const MAX_TURN: Duration = Duration::from_millis(5);
/// Received frames handled per turn at most (a 20 ms sender gives one per turn).
pub const MAX_RX_PER_TURN: usize = 64;
/// Window of the rates in the status frame.
const RATE_WINDOW: Duration = Duration::from_secs(1);

/// A fixed-rate schedule (pure).
#[derive(Debug, Clone, Copy)]
pub struct Periodic {
    period: Duration,
    next: Duration,
}

impl Periodic {
    /// First due at `start`.
    pub fn new(period: Duration, start: Duration) -> Self {
        Self {
            period: period.max(Duration::from_micros(100)),
            next: start,
        }
    }

    /// Whether the slot is due at `now`; if so, schedules the next one. Late by more than a
    /// period (a stalled loop), it skips the missed slots rather than sending a burst.
    pub fn due(&mut self, now: Duration) -> bool {
        if now < self.next {
            return false;
        }
        self.next += self.period;
        if self.next <= now {
            self.next = now + self.period;
        }
        true
    }

    pub fn next(&self) -> Duration {
        self.next
    }
}

/// What the control thread reads from the other threads.
pub struct Inputs {
    pub snapshots: Receiver<Snapshot>,
    pub left: Arc<CameraHealth>,
    pub right: Arc<CameraHealth>,
    pub left_ring: Arc<RingCounters>,
    pub right_ring: Arc<RingCounters>,
    pub evolution: Arc<EvolutionCounters>,
}

/// The vehicle's motion as the control thread reads it.
pub struct MotionInputs {
    pub monitor: MotionMonitor,
    /// `VCU_Motion`'s CAN ID.
    pub id: u32,
    /// Where its frames come from (`None`: nothing sends them: MotionFault throughout).
    pub rx: Option<Box<dyn CanReceiver>>,
    /// Where the evolution thread reads the trusted motion (to move the flies with it).
    pub shared: super::shared_motion::SharedMotion,
}

/// What the control thread did, for [`super::RunReport`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ControlReport {
    pub commands_sent: u64,
    pub statuses_sent: u64,
    pub obstacles_sent: u64,
    /// FLYD_Path frames sent.
    pub paths_sent: u64,
    pub can_errors: u64,
    pub snapshots: u64,
    pub decision_changes: u64,
    /// Every fault bit raised at some point.
    pub faults_seen: FaultBits,
    /// Clock time of the first STOP command that left the control thread.
    pub first_stop_at: Option<Duration>,
    /// For that STOP, the newest snapshot then: when its generation finished, and the capture
    /// time of its frames (what splits a reaction into evolution and pipeline latency).
    pub first_stop_snapshot_at: Option<Duration>,
    pub first_stop_frame_at: Option<Duration>,
    /// The speed that STOP was decided at, m/s.
    pub first_stop_speed: Option<f64>,
    pub last_command: Option<Command>,
    /// `VCU_Motion` frames accepted and rejected (bad DLC, CRC, counter, implausible).
    pub motion_accepted: u64,
    pub motion_rejected: u64,
    /// Whether the motion was ever unknown after it had been known.
    pub motion_lost: bool,
    pub reached_running: bool,
}

pub struct ControlThread<B: CanBus> {
    pub tx: Transmitter<B>,
    /// The decision's step (the period's input and the decider).
    pub decision: DecisionStep,
    pub monitor: FaultMonitor,
    pub notifier: ServiceNotifier,
    pub inputs: Inputs,
    pub clock: SharedClock,
    /// The speed the decision assumes while the measured one is not known, m/s.
    pub assumed_speed: f64,
    /// The cameras' frame period: how long until the next evidence (the decision's latency).
    pub frame_period: Duration,
    /// How far ahead obstacles can be searched and seen, m (the least of the depth range, the
    /// region of interest and the obstacle range, or farther up to what the rig searches as
    /// the speed asks: `perception::range`): a speed whose SLOW distance exceeds it is logged
    /// as beyond what flyd sees in time.
    pub range: f64,
    /// The vehicle's motion: its checks, and where its frames come from (`None`: not
    /// configured, `vehicle.motion = "none"`).
    pub motion: Option<MotionInputs>,
    pub can: CanConfig,
    /// No frame sent for this long: the watchdog is withheld.
    pub can_silence: Duration,
    pub stats_interval: Duration,
    /// External shutdown request (signal, test, `--duration`).
    pub shutdown: Shutdown,
    /// Internal end request (end of stream).
    pub finish: Shutdown,
    /// Gets every snapshot taken, command decided, frame received and the stats.
    pub recorder: Option<crate::record::Recorder>,
}

/// Mutable state of the loop.
struct Loop {
    latest: Option<Snapshot>,
    latest_at: Option<Duration>,
    faults: FaultBits,
    /// The sensor faults behind CAMERA_ERROR, as the status frame reports them.
    sensor: SensorFaults,
    /// Why the motion is unknown (`None`: known, or not configured).
    motion_fault: Option<MotionFault>,
    /// Whether the motion was known once (its loss is then logged as a warning).
    motion_known_once: bool,
    rx_failing: bool,
    /// The speed's SLOW distance is beyond `range` (logged once per episode).
    beyond_range: bool,
    /// When a frame last went out (any message).
    last_sent_at: Option<Duration>,
    state: State,
    command: Command,
    can_failing: bool,
    can_episode_errors: u64,
    gen_times: SampleWindow,
    gen_rate: RateMeter,
    /// Number of the next event recorded (snapshots, commands, received frames: their order).
    record_seq: u64,
    left_fps: RateMeter,
    right_fps: RateMeter,
    report: ControlReport,
}

impl<B: CanBus> ControlThread<B> {
    pub fn run(mut self) -> ControlReport {
        let start = self.clock.now();
        let mut command_slot = Periodic::new(self.can.command.period(), start);
        let mut status_slot = Periodic::new(self.can.status.period(), start);
        let mut obstacle_slot = Periodic::new(self.can.obstacle.period(), start);
        let mut path_slot = Periodic::new(self.can.path.period(), start);
        let mut obstacle_motion_slot = Periodic::new(self.can.obstacle_motion.period(), start);
        let mut stats_slot = Periodic::new(self.stats_interval, start + self.stats_interval);
        let mut s = Loop {
            latest: None,
            latest_at: None,
            faults: FaultBits::empty(),
            sensor: SensorFaults::empty(),
            motion_fault: self.motion.as_ref().map(|_| MotionFault::Missing),
            motion_known_once: false,
            rx_failing: false,
            beyond_range: false,
            last_sent_at: None,
            state: State::Init,
            command: self.decision.command(),
            can_failing: false,
            can_episode_errors: 0,
            gen_times: SampleWindow::new(1024),
            gen_rate: RateMeter::default(),
            record_seq: 0,
            left_fps: RateMeter::default(),
            right_fps: RateMeter::default(),
            report: ControlReport::default(),
        };
        self.notifier
            .status("INIT: waiting for both cameras and the first generation");
        self.notifier.extend_startup(start);

        while !(self.shutdown.is_requested() || self.finish.is_requested()) {
            // The vehicle's frames first: a snapshot is decided at the speed the bus says now,
            // not at the one known before a late turn (frames waiting in the socket are news).
            let now = self.clock.now();
            self.receive(&mut s, now);
            self.drain(&mut s);
            self.update_rates(&mut s, now);
            self.supervise(&mut s, now);
            let escalation = self.decision.escalates();
            if command_slot.due(now) || escalation {
                self.send_command(&mut s, now);
            }
            if status_slot.due(now) {
                self.send_status(&mut s, now);
            }
            if obstacle_slot.due(now) {
                let msg = s.latest.map_or(ObstacleMsg::NONE, |l| l.obstacle_msg());
                let r = self.tx.send_obstacle(&msg);
                self.sent(&mut s, r, "FLYD_Obstacle");
                s.report.obstacles_sent += 1;
            }
            if obstacle_motion_slot.due(now) {
                // How that obstacle moves, at the speed the decision takes now.
                let speed = self.speed(now);
                let msg = s.latest.map_or(ObstacleMotionMsg::NONE, |l| {
                    ObstacleMotionMsg::of(&l.tracked, speed)
                });
                let r = self.tx.send_obstacle_motion(&msg);
                self.sent(&mut s, r, "FLYD_ObstacleMotion");
            }
            if path_slot.due(now) {
                let msg = s.latest.map_or(PathMsg::NONE, |l| l.path_msg());
                let r = self.tx.send_path(&msg);
                self.sent(&mut s, r, "FLYD_Path");
                s.report.paths_sent += 1;
            }
            if stats_slot.due(now) {
                self.stats(&mut s);
            }
            let fresh = !s.faults.intersects(
                FaultBits::LEFT_CAMERA_STALE
                    | FaultBits::RIGHT_CAMERA_STALE
                    | FaultBits::SNAPSHOT_STALE,
            );
            // A daemon whose frames do not go out is not alive for the vehicle: systemd
            // restarts it when the pings stop.
            let sending = s
                .last_sent_at
                .is_some_and(|t| now.saturating_sub(t) <= self.can_silence);
            let generation = s.latest.map_or(0, |l| l.generation);
            self.notifier.watchdog(
                now,
                generation,
                fresh && sending && s.report.reached_running,
            );
            self.notifier.extend_startup(now);

            let next = command_slot
                .next()
                .min(status_slot.next())
                .min(obstacle_slot.next())
                .min(path_slot.next());
            let wait = next.saturating_sub(self.clock.now()).min(MAX_TURN);
            if !wait.is_zero() {
                // Wakes on the next snapshot: an escalation leaves without waiting for the turn.
                if let Ok(snapshot) = self.inputs.snapshots.recv_timeout(wait) {
                    let now = self.clock.now();
                    self.receive(&mut s, now);
                    self.take(&mut s, snapshot);
                }
            }
        }
        self.shut_down(&mut s);
        s.report
    }

    fn drain(&mut self, s: &mut Loop) {
        while let Ok(snapshot) = self.inputs.snapshots.try_recv() {
            self.take(s, snapshot);
        }
    }

    fn take(&mut self, s: &mut Loop, snapshot: Snapshot) {
        s.report.snapshots += 1;
        s.gen_times.push(snapshot.generation_time);
        s.latest = Some(snapshot);
        s.latest_at = Some(self.clock.now());
        if !self.notifier.is_ready() {
            tracing::info!(
                generation = snapshot.generation,
                "ready: both cameras deliver and the first generation ran"
            );
            self.notifier.ready("INIT: warming up");
        }
        let now = self.clock.now();
        let input = self.input_at(&snapshot, now);
        self.record_snapshot(s, &snapshot, &input, now);
        if snapshot.warming_up {
            return;
        }
        self.decision.observe(input);
        if !s.report.reached_running {
            s.report.reached_running = true;
            self.monitor.set_running();
            tracing::info!(generation = snapshot.generation, "running: warm-up done");
        }
    }

    fn update_rates(&mut self, s: &mut Loop, now: Duration) {
        let generation = s.latest.map_or(0, |l| l.generation);
        s.gen_rate.update(now, generation, RATE_WINDOW);
        s.left_fps
            .update(now, self.inputs.left_ring.published(), RATE_WINDOW);
        s.right_fps
            .update(now, self.inputs.right_ring.published(), RATE_WINDOW);
    }

    /// Fault bits and state at `now`, with their transitions logged.
    fn supervise(&mut self, s: &mut Loop, now: Duration) {
        let i = &self.inputs;
        let observation = Observation {
            now,
            left_frame_at: i.left.last_frame_at(),
            right_frame_at: i.right.last_frame_at(),
            left_error: i.left.has_error(),
            right_error: i.right.has_error(),
            snapshot_at: s.latest_at,
            skew_fault: s.latest.is_some_and(|l| l.skew_fault),
            overrun: s.latest.is_some_and(|l| l.overrun),
            sensor: s.latest.map_or(SensorFaults::empty(), |l| l.sensor),
            can_failing: s.can_failing,
            mount_fault: s.latest.is_some_and(|l| l.mount_fault),
        };
        let faults = self.monitor.evaluate(&observation);
        let raised = faults & !s.faults;
        let cleared = s.faults & !faults;
        for name in raised.names() {
            let age_ms =
                |at: Option<Duration>| at.map(|t| now.saturating_sub(t).as_millis() as u64);
            tracing::warn!(
                fault = name,
                faults = %faults,
                left_frame_age_ms = age_ms(observation.left_frame_at),
                right_frame_age_ms = age_ms(observation.right_frame_at),
                snapshot_age_ms = age_ms(observation.snapshot_at),
                "fault raised"
            );
        }
        for name in cleared.names() {
            tracing::info!(fault = name, faults = %faults, "fault cleared");
        }
        s.report.faults_seen |= faults;
        s.faults = faults;
        s.sensor = observation.sensor;
        let state = self.monitor.state(faults);
        if state != s.state {
            tracing::info!(from = %s.state, to = %state, faults = %faults, "state changed");
            s.state = state;
            self.notifier
                .status(&format!("{state}: faults {faults}, command {}", s.command));
        }
    }

    /// What `snapshot` tells the decider, at the speed known now (faults are added when the
    /// command is decided).
    fn input_at(&self, snapshot: &Snapshot, now: Duration) -> DecisionInput {
        let age = now.saturating_sub(snapshot.capture_time());
        snapshot.tracked.credit(DecisionInput {
            global_warning: snapshot.global_warning,
            latency: (age + self.frame_period).as_secs_f64(),
            ..DecisionInput::at_speed(snapshot.confirmed_distance(), self.speed(now))
        })
    }

    /// Records a snapshot taken and what it told the decider (`input`, at `now`).
    fn record_snapshot(
        &self,
        s: &mut Loop,
        snapshot: &Snapshot,
        input: &DecisionInput,
        now: Duration,
    ) {
        if let Some(recorder) = &self.recorder {
            let observed = Observed {
                generation: snapshot.generation,
                warming_up: snapshot.warming_up,
                global_warning: snapshot.global_warning,
                matched: snapshot.matched,
                generation_time: snapshot.generation_time,
                road: &snapshot.road,
                tracked: &snapshot.tracked,
                path: snapshot.path,
                search_far: snapshot.search_far,
            };
            recorder.snapshot(next_seq(s), now, observed, input);
        }
    }

    /// Records a command decided at `now` from `input` (which came `from` there).
    fn record_decision(
        &self,
        s: &mut Loop,
        now: Duration,
        from: InputFrom,
        latest: Option<(u64, DecisionInput)>,
        input: &DecisionInput,
        decision: &flyd_core::decision::Decision,
    ) {
        if let Some(recorder) = &self.recorder {
            let seq = next_seq(s);
            recorder.command(seq, now, from, latest, s.faults, s.state, input, decision);
        }
    }

    fn stats(&mut self, s: &mut Loop) {
        let [p50, p99] = s
            .gen_times
            .percentiles([0.5, 0.99])
            .unwrap_or([Duration::ZERO; 2]);
        let i = &self.inputs;
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let latest = s.latest;
        tracing::info!(
            target: "flyd::stats",
            fps_left = s.left_fps.rate(),
            fps_right = s.right_fps.rate(),
            drops_left = i.left_ring.dropped(),
            drops_right = i.right_ring.dropped(),
            pair_rejects = i.evolution.pair_rejects.load(Ordering::Relaxed),
            pairs = i.evolution.pairs.load(Ordering::Relaxed),
            generations_per_sec = s.gen_rate.rate(),
            gen_p50_ms = ms(p50),
            gen_p99_ms = ms(p99),
            overruns = i.evolution.overruns.load(Ordering::Relaxed),
            snapshots_dropped = i.evolution.snapshots_dropped.load(Ordering::Relaxed),
            global_warning = latest.map_or(f64::NAN, |l| l.global_warning),
            matched = latest.map_or(f64::NAN, |l| l.matched),
            perception_age_ms = latest.map(|l| ms(self.clock.now().saturating_sub(l.capture_time()))),
            obstacle_m = latest
                .and_then(|l| l.tracked.obstacle)
                .map(|o| shown(o.distance, 2)),
            obstacle_confirmed = latest.is_some_and(|l| l.tracked.confirmed),
            obstacle_flies = latest.and_then(|l| l.tracked.obstacle).map(|o| o.flies),
            corridor_unique = latest.map(|l| l.corridor.unique),
            road = %latest.map_or(RoadSource::Prior, |l| l.road.source),
            road_height_m = latest.map(|l| shown(l.road.plane.height, 3)),
            road_pitch_deg = latest.map(|l| shown(l.road.plane.pitch_deg(), 2)),
            road_roll_deg = latest.map(|l| shown(l.road.plane.roll_deg(), 2)),
            speed_kmh = shown(self.speed(self.clock.now()) * 3.6, 2),
            motion = self.motion_label(s),
            motion_accepted = s.report.motion_accepted,
            motion_rejected = s.report.motion_rejected,
            decision = %s.command,
            state = %s.state,
            faults = %s.faults,
            can_errors = s.report.can_errors,
            "stats"
        );
        if let Some(recorder) = &self.recorder {
            recorder.stats(StatsEvent {
                t_ns: crate::record::nanos(self.clock.now()),
                fps_left: s.left_fps.rate(),
                fps_right: s.right_fps.rate(),
                generations_per_sec: s.gen_rate.rate(),
                gen_p50_ms: ms(p50),
                gen_p99_ms: ms(p99),
                generations: latest.map_or(0, |l| l.generation),
                pairs: i.evolution.pairs.load(Ordering::Relaxed),
                snapshots_dropped: i.evolution.snapshots_dropped.load(Ordering::Relaxed),
                record_dropped: recorder.counters().dropped(),
            });
        }
        let status = format!(
            "{}: {} | {:.0}/{:.0} fps | {:.0} gen/s | faults {}",
            s.state,
            s.command,
            s.left_fps.rate(),
            s.right_fps.rate(),
            s.gen_rate.rate(),
            s.faults
        );
        if self.notifier.is_ready() {
            self.notifier.status(&status);
        }
    }

    fn shut_down(&mut self, s: &mut Loop) {
        let now = self.clock.now();
        let decision = self.decision.shutdown();
        tracing::info!(command = %decision.command, "shutting down: last command and SHUTDOWN status");
        self.notifier.stopping("SHUTDOWN");
        let warning = s.latest.map_or(f64::NAN, |l| l.global_warning);
        let input = DecisionInput {
            global_warning: warning,
            ..DecisionInput::at_speed(None, f64::NAN)
        };
        self.record_decision(s, now, InputFrom::Shutdown, None, &input, &decision);
        let r = self.tx.send_command(&CommandMsg::of(&decision, warning));
        self.sent(s, r, "FLYD_Command");
        s.report.commands_sent += 1;
        s.report.last_command = Some(decision.command);
        let msg = self.status_msg(s, now, State::Shutdown);
        let r = self.tx.send_status(&msg);
        self.sent(s, r, "FLYD_Status");
        s.report.statuses_sent += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn periodic_is_fixed_rate_and_skips_missed_slots() {
        let mut p = Periodic::new(20 * MS, 100 * MS);
        assert!(!p.due(99 * MS));
        assert!(p.due(100 * MS));
        assert!(!p.due(119 * MS));
        assert!(
            p.due(125 * MS),
            "late but within the period: keeps the phase"
        );
        assert_eq!(p.next(), 140 * MS);
        assert!(p.due(200 * MS), "stalled for several periods");
        assert!(!p.due(201 * MS), "no burst of missed slots");
        assert_eq!(p.next(), 220 * MS);
    }
}
