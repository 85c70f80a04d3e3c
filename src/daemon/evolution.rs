//! The evolution thread: pairs frames, runs generations, publishes [`Snapshot`]s.
//!
//! Each turn: fetch each camera's newest frame from its ring and offer it to the [`Pairer`];
//! on a pair, swap both images into the engine's [`StereoFrame`] (zero copy) under a new id, so
//! the engine re-evaluates the whole population; run one generation (on the newest pair, new or
//! not: the population keeps converging between frames, as in the paper) of both engines,
//! then the perception stages (on a new pair the road is measured; the obstacle stage runs every
//! `perception.estimate_every` generations and on each new pair; see
//! [`flyd_core::perception`]); `try_send` the snapshot (a full channel drops it and counts it: this thread never
//! blocks on the control thread). Then wait for the next period (`generation_period`), or go on
//! at once when it is unset, or when a camera publishes a frame meanwhile (checked every
//! millisecond: one atomic load per ring), or while a burst lasts: a new pair that shows a change (the
//! engine's change map) starts `burst_generations` generations back to back, so what appeared
//! is found within that frame's first milliseconds rather than over several periods (the
//! paper's 10-30 generations would otherwise be 100-300 ms). A static scene costs no burst.
//! A turn longer than `max_generation_time` is flagged as an overrun.
//!
//! Allocation happens only at start: the engines, the two images of the stereo frame, the
//! perception stages' buffers.

use flyd_core::chain::Chain;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use crossbeam_channel::{Sender, TrySendError};

use super::ring::FrameReader;
use super::shared_motion::SharedMotion;
use super::snapshot::Snapshot;
use crate::config::EvolutionConfig;
use crate::os_clock::SharedClock;
use crate::record::topics::{PairEvent, PredictEvent};
use crate::source::FrameMeta;
use crate::source::Side;
use crate::thread::Shutdown;
use flyd_core::engine::EngineError;
use flyd_core::frame::StereoFrame;
use flyd_core::frame_step::{FrameStep, NewPair};
use flyd_core::pairing::{PairOutcome, Pairer};
use flyd_core::perception::mount_check::{MountCheck, MountReport};
use flyd_core::perception::{RoadEstimate, RoadSource};
use flyd_core::policy::Blindness;
use flyd_core::sensor::{ImageHealth, SensorFaults, SensorVerdict};

/// Counters the control thread reads (statistics, `Relaxed`).
#[derive(Debug, Default)]
pub struct EvolutionCounters {
    pub generations: AtomicU64,
    pub snapshots_dropped: AtomicU64,
    pub overruns: AtomicU64,
    pub pairs: AtomicU64,
    pub pair_rejects: AtomicU64,
}

pub struct EvolutionThread {
    /// The perception of the pairs: motion, sensor checks, engine, stages, blindness.
    pub step: FrameStep,
    pub left: FrameReader,
    pub right: FrameReader,
    pub pairer: Pairer,
    /// The engine's input; its images are swapped with the rings' slots.
    pub stereo: StereoFrame,
    pub snapshots: Sender<Snapshot>,
    pub counters: Arc<EvolutionCounters>,
    pub clock: SharedClock,
    pub config: EvolutionConfig,
    pub stop: Shutdown,
    /// The road estimate's source at the last new pair (its changes are logged).
    pub road_source: Option<RoadSource>,
    /// The vehicle's trusted motion (`None`: no motion configured): each new pair's
    /// corridor follows its path, and its flies are first moved with it over the time since
    /// the previous pair (with `vehicle.predict_flies`; a motion fault's corridor is the fan
    /// at `vehicle.assumed_speed_kmh`).
    pub motion: Option<SharedMotion>,
    /// Gets each new pair (with the motion its flies were moved with) and the flies every
    /// `record.flies_every` generations.
    pub recorder: Option<crate::record::Recorder>,
    /// Hands a pair now and then to the worker that measures the right image's rows.
    pub rows: Option<super::rows::RowsMonitor>,
    /// The declared mount against each new pair's road, the left camera's declared height
    /// (metres, for the log) and the road estimator's `max_height_change` (the fault's bound).
    pub mount: MountCheck,
    pub declared_height: f64,
    pub max_height_change: f64,
    /// Its report after the latest pair it took (what the snapshots carry; its verdict is
    /// the one last logged).
    pub mount_report: MountReport,
}

/// Granularity of the wait for a new frame between generations.
const FRAME_POLL: Duration = Duration::from_millis(1);

/// How long to wait for the first pair before looking again.
const IDLE_WAIT: Duration = Duration::from_millis(1);

impl EvolutionThread {
    pub fn run(mut self) -> Result<(), EngineError> {
        let mut pair: Option<(FrameMeta, FrameMeta)> = None;
        let mut next_turn: Option<Duration> = None;
        // Generations of the current burst still to run back to back.
        let mut burst: u32 = 0;
        while !self.stop.is_requested() {
            let mut predicted = None;
            let mut motion_unknown = false;
            if let Some((l, r, health)) = self.take_pair() {
                let mut moved = None;
                if let (Some((previous, _)), Some(shared)) = (pair, self.motion.as_ref()) {
                    let dt = l.timestamp.saturating_sub(previous.timestamp).as_secs_f64();
                    let motion = shared.get();
                    moved = Some((motion, dt));
                    motion_unknown = motion.is_none();
                    predicted = motion.map(|m| PredictEvent {
                        speed: m.speed,
                        yaw_rate: m.yaw_rate,
                        dt,
                    });
                }
                pair = Some((l, r));
                let new_pair = NewPair {
                    moved,
                    health: Some(health),
                };
                let (was, now) = self.step.pair(&new_pair);
                log_sensor(&was, &now, &health);
            }
            let Some((left, right)) = pair else {
                self.stop.sleep(IDLE_WAIT);
                continue;
            };
            let started = self.clock.now();
            let outcome = self.step.generation(&self.stereo).inspect_err(|e| {
                tracing::error!(error = %Chain(e), "generation failed: evolution stops (SNAPSHOT_STALE)");
            })?;
            let (report, stats) = (outcome.report, outcome.report.stats);
            if stats.new_frame {
                self.log_road(&report.road);
                // A camera at fault shows no road to check the mount against.
                if outcome.sensor.faults.is_empty() {
                    self.mount.add(&report.road);
                    let now = self.mount.report();
                    self.log_mount(&now);
                    self.mount_report = now;
                }
            }
            let mount = self.mount_report;
            let finished = self.clock.now();
            if stats.new_frame
                && stats.generation >= self.config.warmup_generations
                && let Some(rows) = self.rows.as_mut()
            {
                rows.offer(finished, &self.stereo);
            }
            if let Some(recorder) = &self.recorder {
                if stats.new_frame {
                    recorder.pair(
                        finished,
                        PairEvent {
                            generation: stats.generation,
                            pair_id: self.stereo.id,
                            left_ns: crate::record::nanos(left.timestamp),
                            right_ns: crate::record::nanos(right.timestamp),
                            predict: predicted,
                            right_row_shift_px: Some(self.stereo.right.row_shift()),
                            motion_unknown,
                        },
                    );
                }
                recorder.flies(
                    stats.generation,
                    finished,
                    self.step.perception().engine().population(),
                );
            }
            let generation_time = finished.saturating_sub(started);
            let overrun = generation_time > self.config.max_generation_time;
            let pc = self.pairer.counts();
            let c = &self.counters;
            c.generations.store(stats.generation, Ordering::Relaxed);
            c.pairs.store(pc.paired, Ordering::Relaxed);
            c.pair_rejects.store(pc.rejected, Ordering::Relaxed);
            if overrun {
                c.overruns.fetch_add(1, Ordering::Relaxed);
            }
            let warming_up = outcome.warming_up;
            let Blindness {
                blind,
                changed,
                pairs,
            } = outcome.blindness;
            if changed {
                if blind {
                    tracing::warn!(
                        matched = stats.matched,
                        blind_matched = self.config.blind_matched,
                        pairs,
                        "perception blind: the stereo pair matches nowhere (a camera delivers \
                         noise or is covered, or the calibration no longer fits): CAMERA_ERROR"
                    );
                } else {
                    tracing::info!(matched = stats.matched, "perception matches again");
                }
            }
            let sensor = outcome.sensor.faults;
            let snapshot = Snapshot {
                generation: stats.generation,
                global_warning: stats.global_warning,
                danger: stats.danger,
                matched: stats.matched,
                sensor,
                visible: stats.visible,
                new_frame: stats.new_frame,
                road: report.road,
                mount,
                mount_fault: mount.hides(self.max_height_change),
                tracked: report.tracked,
                corridor: report.corridor,
                path: self.step.perception().path_estimate(),
                search_far: self.step.perception().search_far(),
                generation_time,
                overrun,
                left,
                right,
                pair_id: self.stereo.id,
                pairs: pc.paired,
                pair_rejects: pc.rejected,
                skew_fault: pc.consecutive_rejects >= u64::from(self.config.skew_fault_rejects),
                warming_up,
                taken_at: finished,
            };
            match self.snapshots.try_send(snapshot) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) => {
                    c.snapshots_dropped.fetch_add(1, Ordering::Relaxed);
                }
                Err(TrySendError::Disconnected(_)) => break,
            }
            if stats.new_frame && stats.change > 0.0 {
                burst = self.config.burst_generations.saturating_sub(1);
            }
            if burst > 0 {
                burst -= 1;
                next_turn = None;
                continue;
            }
            if let Some(period) = self.config.generation_period {
                // Fixed rate from the first generation; after an overrun, restart from now
                // rather than bursting to catch up.
                let deadline = next_turn.unwrap_or(started) + period;
                let now = self.clock.now();
                next_turn = Some(deadline.max(now));
                if deadline > now && self.wait_for_frame(deadline - now) {
                    // A new frame cuts the wait short: the period restarts from it.
                    next_turn = None;
                }
            }
        }
        Ok(())
    }

    /// Logs the road estimate when its source changes (a fallback to the prior, a return to
    /// measurement) and, at debug level, on every new pair.
    fn log_road(&mut self, road: &RoadEstimate) {
        let p = road.plane;
        // One event, its level and message by case (tracing's levels are constants).
        macro_rules! road {
            ($level:ident, $message:expr) => {
                tracing::$level!(
                    source = %road.source,
                    height_m = p.height,
                    pitch_deg = p.pitch_deg(),
                    roll_deg = p.roll_deg(),
                    inliers = road.inliers,
                    rms_m = road.rms,
                    $message
                )
            };
        }
        if self.road_source != Some(road.source) {
            if road.measured() {
                road!(info, "road measured");
            } else {
                tracing::warn!(
                    source = %road.source,
                    inliers = road.inliers,
                    "road not measured: heights are taken from the calibration's mount (the prior)"
                );
            }
            self.road_source = Some(road.source);
        }
        road!(debug, "road");
    }

    /// Logs the mount check when its verdict changes: a WARN naming what disagrees (the
    /// measured and declared values and the key to fix), an INFO when it agrees.
    fn log_mount(&self, r: &MountReport) {
        if r.verdict == self.mount_report.verdict {
            return;
        }
        let fault = r.hides(self.max_height_change);
        match r.advice(self.declared_height) {
            Some(advice) => tracing::warn!(
                road_height_m = crate::logging::shown(r.road_height, 3),
                road_pitch_deg = crate::logging::shown(r.road_pitch_deg, 2),
                road_roll_deg = crate::logging::shown(r.road_roll_deg, 2),
                declared_height_m = crate::logging::shown(self.declared_height, 3),
                frames = r.frames,
                fault,
                "{advice}"
            ),
            None => tracing::info!(
                road_height_m = crate::logging::shown(r.road_height, 3),
                road_pitch_deg = crate::logging::shown(r.road_pitch_deg, 2),
                road_roll_deg = crate::logging::shown(r.road_roll_deg, 2),
                frames = r.frames,
                verdict = %r.verdict,
                "the mount agrees with the road measured"
            ),
        }
    }

    /// Sleeps up to `wait`, in slices of at most [`FRAME_POLL`], until either camera publishes
    /// a frame (returns true) or the wait or the daemon ends (false). A new frame is worked on
    /// at once instead of at the next period: that is up to a period off every reaction.
    fn wait_for_frame(&self, wait: Duration) -> bool {
        let until = self.clock.now() + wait;
        loop {
            if self.left.pending() || self.right.pending() {
                return true;
            }
            let now = self.clock.now();
            if now >= until || self.stop.sleep((until - now).min(FRAME_POLL)) {
                return false;
            }
        }
    }

    /// Offers newly fetched frames to the pairer; on a pair, moves both images into the
    /// stereo frame under a new id.
    fn take_pair(&mut self) -> Option<(FrameMeta, FrameMeta, [ImageHealth; 2])> {
        for (side, reader) in [(Side::Left, &mut self.left), (Side::Right, &mut self.right)] {
            if reader.fetch()
                && let Some(slot) = reader.slot()
            {
                self.pairer.offer(side, slot.meta);
            }
        }
        match self.pairer.try_pair() {
            PairOutcome::Paired { left, right, .. } => {
                let (Some(l), Some(r)) = (self.left.slot_mut(), self.right.slot_mut()) else {
                    return None;
                };
                std::mem::swap(&mut self.stereo.left, &mut l.image);
                std::mem::swap(&mut self.stereo.right, &mut r.image);
                self.stereo.id = self.stereo.id.wrapping_add(1);
                Some((left, right, [l.health, r.health]))
            }
            PairOutcome::Rejected { side, skew } => {
                tracing::debug!(
                    side = side.name(),
                    skew_ms = skew.as_secs_f64() * 1e3,
                    "pair rejected"
                );
                None
            }
            PairOutcome::Waiting => None,
        }
    }
}

/// Logs the sensor faults that a pair raised or cleared, naming the camera and what was
/// measured on it.
fn log_sensor(was: &SensorVerdict, now: &SensorVerdict, health: &[ImageHealth; 2]) {
    let [l, r] = health;
    let changes = [
        (
            SensorFaults::UNIFORM,
            now.uniform.name(),
            "image uniform or without texture (dark, saturated, covered, defocused): CAMERA_ERROR",
        ),
        (
            SensorFaults::FROZEN,
            now.frozen.name(),
            "image frozen: the camera repeats the same frame: CAMERA_ERROR",
        ),
        (
            SensorFaults::MISMATCH,
            "both",
            "left and right exposures far apart: CAMERA_ERROR",
        ),
    ];
    for (bit, camera, what) in changes {
        let (before, after) = (was.faults.contains(bit), now.faults.contains(bit));
        if before == after {
            continue;
        }
        if after {
            tracing::warn!(
                fault = %bit, camera,
                left_contrast = l.contrast, right_contrast = r.contrast,
                left_textured = l.textured, right_textured = r.textured,
                left_mean = l.mean, right_mean = r.mean,
                left_unchanged = l.unchanged.unwrap_or(f32::NAN),
                right_unchanged = r.unchanged.unwrap_or(f32::NAN),
                "{what}"
            );
        } else {
            tracing::info!(fault = %bit, "sensor fault cleared: the images are healthy again");
        }
    }
}
