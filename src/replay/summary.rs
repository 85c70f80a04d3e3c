//! The JSON summary `flyd replay` prints, and the reaction figures of a scenario.

use std::path::Path;
use std::time::Duration;

use flyd_core::decision::{Command, CommandReason};
use flyd_core::perception::mount_check::{MountCheck, MountReport};
use flyd_core::perception::{Obstacle, RoadEstimate};
use flyd_core::rectification::yaw::{ColumnReport, ColumnVerdict};
use serde::Serialize;

use super::{Replay, TraceRow};

/// Per-generation timing figures, microseconds.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Timing {
    pub median_us: f64,
    pub p95_us: f64,
    pub min_us: f64,
    pub max_us: f64,
}

impl Timing {
    /// Figures of a set of durations (sorted in place).
    pub fn of(samples: &mut [Duration]) -> Self {
        if samples.is_empty() {
            return Self::default();
        }
        samples.sort_unstable();
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        let at = |q: f64| us(samples[((samples.len() - 1) as f64 * q).round() as usize]);
        Self {
            median_us: at(0.5),
            p95_us: at(0.95),
            min_us: us(samples[0]),
            max_us: us(samples[samples.len() - 1]),
        }
    }
}

/// The obstacle as the summary reports it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ObstacleReport {
    #[serde(flatten)]
    pub obstacle: Obstacle,
    /// Seen on `trigger_frames` consecutive frames: what the decision acts on.
    pub confirmed: bool,
    /// Consecutive frames it was seen on.
    pub seen_frames: u32,
}

/// The state after one generation, as reported.
#[derive(Debug, Clone, Serialize)]
pub struct FrameReport {
    pub frame: u64,
    /// Its left file, for a sequence.
    pub name: String,
    pub generation: u64,
    pub global_warning: f64,
    pub road: RoadEstimate,
    pub obstacle: Option<ObstacleReport>,
    pub command: String,
    pub reason: String,
    /// The sensor faults on this frame ("none" when healthy).
    pub sensor_faults: String,
}

impl FrameReport {
    pub fn of(r: &TraceRow) -> Self {
        Self {
            frame: r.frame,
            name: r.frame_name.clone(),
            generation: r.stats.generation,
            global_warning: r.stats.global_warning,
            road: r.road,
            obstacle: r.tracked.obstacle.map(|obstacle| ObstacleReport {
                obstacle,
                confirmed: r.tracked.confirmed,
                seen_frames: r.tracked.seen_frames,
            }),
            command: r.command.to_string(),
            reason: r.reason.to_string(),
            sensor_faults: r.sensor.faults.to_string(),
        }
    }
}

/// Commands the perception alone asked for after the warm-up (reason PERCEPTION): on a
/// scene without obstacle, each is a false alarm.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Alarms {
    /// Generations whose command was SLOW, and STOP.
    pub slow_generations: u64,
    pub stop_generations: u64,
    /// The first such generation.
    pub first_generation: Option<u64>,
    /// The nearest confirmed obstacle after the warm-up, metres.
    pub nearest_confirmed: Option<f64>,
}

impl Alarms {
    pub fn of(trace: &[TraceRow], warmup: u64) -> Self {
        let mut a = Self::default();
        for r in trace.iter().filter(|r| r.stats.generation > warmup) {
            if r.reason == CommandReason::Perception && r.command > Command::Clear {
                match r.command {
                    Command::Stop => a.stop_generations += 1,
                    _ => a.slow_generations += 1,
                }
                a.first_generation.get_or_insert(r.stats.generation);
            }
            if let Some(o) = r.tracked.confirmed() {
                a.nearest_confirmed = Some(
                    a.nearest_confirmed
                        .map_or(o.distance, |d: f64| d.min(o.distance)),
                );
            }
        }
        a
    }
}

/// The JSON summary printed on stdout.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// (The mean warning of the final population, the paper's global warning, is `last`'s
    /// `global_warning`.)
    /// Contrast-independent danger of the final population, m^-3 (see the engine docs).
    pub danger: f64,
    pub generations: u64,
    pub frames: u64,
    pub flies: usize,
    pub seed: u64,
    pub time_per_generation: Timing,
    /// What the road estimate and the obstacle stage cost per generation (both engines'
    /// time is in `time_per_generation`; this is the road fit and the obstacle stage alone).
    pub perception_stage: Timing,
    pub out_dir: String,
    /// The decision: its mode and the speed it assumed.
    pub decision_mode: String,
    /// The speed decided at where the feed does not give one (`--speed`, else the assumed);
    /// null when the feed gives every frame's (`speed_source` "feed": `decided_kmh` says it).
    pub speed_kmh: Option<f64>,
    /// "fixed" (`--speed`: on every frame), "feed" (a scenario's own speed; `speed_kmh`
    /// unused) or "assumed".
    pub speed_source: &'static str,
    /// The slowest and fastest speed the decision was made at over the generations, km/h.
    pub decided_kmh: [f64; 2],
    /// What a reader of the commands should know: a vehicle standing still has no stopping
    /// distance, so nothing it sees is a reason to brake.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The flies were moved with the feed's motion between frames.
    pub predict_flies: bool,
    /// Where the feed's motion came from: "scenario NAME", "poses FILE" (a sequence's KITTI
    /// poses), or null (none: the decision's speed is `speed_kmh`, the flies stay).
    pub motion_source: Option<String>,
    /// The nearest distance an obstacle is judged from one sighting, metres (nearer: only one
    /// seen coming; `flyd_core::perception::judgeable_distance`).
    pub judgeable_distance: f64,
    /// The state after the last generation.
    #[serde(flatten)]
    pub last: FrameReport,
    /// Commands after the warm-up (`warmup_generations`).
    pub warmup_generations: u64,
    pub alarms: Alarms,
    /// Frames on which a sensor check failed (uniform, frozen or mismatched images: see
    /// `flyd_core::sensor`); the decider then held the safe command.
    pub sensor_fault_frames: u64,
    /// On a scenario where an obstacle appears: how fast the warning and the command reacted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reaction: Option<Reaction>,
    /// The right image's row correction, and what is left of the rows' misalignment.
    pub row_offset: RowOffsetReport,
    /// How that correction was chosen: the rig's, or measured on the first frame.
    pub row_correction: Option<flyd_core::rectification::RowCorrection>,
    /// The declared mount against the road measured on every frame
    /// ([`flyd_core::perception::mount_check`]).
    pub mount: MountReport,
    /// What was assumed of the mount, when the calibration gives none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mount_assumed: Option<&'static str>,
    /// The right camera's yaw against the motion, when checked (a sequence, or a yaw error
    /// put in: [`flyd_core::rectification::yaw`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub columns: Option<ColumnReport>,
    /// A closed loop's outcome: contact, gap, braking ([`super::closed_loop`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<super::closed_loop::ClosedLoopReport>,
    /// The state at the last generation of each frame, when there is more than one frame.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub per_frame: Vec<FrameReport>,
}

/// The summary's `row_offset`: the calibration's correction of the right image's rows, and
/// the residual measured on the last frame (`residual_px`, `flies`, `at_range_edge`; absent
/// when too few flies matched). A residual beyond ~0.2 px is worth adding to
/// `rectification.right_row_offset_px`.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RowOffsetReport {
    pub applied_px: f64,
    #[serde(flatten)]
    pub measured: Option<flyd_core::rectification::RowOffset>,
}

impl Summary {
    /// What a person must be told of the mount on stderr: what was assumed of it, and where
    /// the road disagrees with it ([`MountReport::advice`]).
    pub fn mount_warnings(&self, declared_height: f64) -> Vec<String> {
        let m = &self.mount;
        match self.mount_assumed {
            // What the road said is measured from the assumed mount: said as it is.
            Some(assumed) => {
                let road = if m.frames > 0 {
                    format!(
                        "; the road measured lies {:.2} m from where that mount puts it, rising \
                         {:.1} degrees ahead",
                        m.road_height, m.road_pitch_deg
                    )
                } else {
                    String::new()
                };
                vec![format!(
                    "{assumed}{road}. Where the cameras are on a vehicle, a rig file must say: \
                     [import] file = \"...\" and [mount] position = [x, height, z] (the format: \
                     crates/core/src/calib/rig.rs)"
                )]
            }
            None => m.advice(declared_height).into_iter().collect(),
        }
    }

    /// What a person must be told of the right camera's yaw on stderr, when the motion says
    /// the calibration is off ([`ColumnReport`]), for a rig of focal length `focal_px` and
    /// `baseline` metres.
    pub fn columns_warning(&self, focal_px: f64, baseline: f64) -> Option<String> {
        let c = self.columns.as_ref()?;
        (c.verdict == ColumnVerdict::Disagrees).then(|| {
            // A disparity offset of -offset: a point at z seen at z f B / (f B - z offset).
            let (z, fb) = (20.0, focal_px * baseline);
            let seen = z * fb / (fb - z * c.offset_px);
            format!(
                "the right camera's yaw disagrees with the vehicle's motion over {} pairs of \
                 frames: the right image shows points {:+.2} px (+/- {:.2}) from where the \
                 calibration puts them, so a point 20 m ahead is measured at {:.1} m; turn the \
                 right camera by {:+.3} degrees in the calibration (a rig file's [right] yaw_deg)",
                c.pairs, c.offset_px, c.offset_sigma_px, seen, c.right_yaw_deg
            )
        })
    }

    /// The summary of `replay`, written to `out`.
    pub fn of(replay: &Replay, out: &Path, reaction: Option<Reaction>) -> Self {
        let engine = replay.perception.engine();
        let stats = engine.stats();
        let mut times: Vec<Duration> = replay.trace.iter().map(|r| r.elapsed).collect();
        let mut stage: Vec<Duration> = replay.trace.iter().map(|r| r.stage).collect();
        let per_frame = if replay.frames > 1 {
            replay.frame_ends().map(FrameReport::of).collect()
        } else {
            Vec::new()
        };
        let last = replay.trace.last().map_or_else(
            || FrameReport {
                frame: 0,
                name: String::new(),
                generation: 0,
                global_warning: f64::NAN,
                road: replay.perception.report().road,
                obstacle: None,
                command: replay.settings.decision.safe_command.to_string(),
                reason: CommandReason::FaultFallback.to_string(),
                sensor_faults: "none".into(),
            },
            FrameReport::of,
        );
        let decided_kmh = replay
            .trace
            .iter()
            .map(|r| r.speed * 3.6)
            .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], v| {
                [lo.min(v), hi.max(v)]
            });
        let decided_kmh = if replay.trace.is_empty() {
            [0.0; 2]
        } else {
            decided_kmh.map(|v| (v * 1000.0).round() / 1000.0)
        };
        let note = (decided_kmh[1] == 0.0 && !replay.trace.is_empty()).then(|| {
            "the vehicle stands still (0 km/h) on every frame: no stopping distance, so no \
             obstacle is a reason to brake; `--speed KMH` decides as if it drove"
                .to_string()
        });
        Self {
            danger: stats.danger,
            generations: stats.generation,
            frames: replay.frames,
            flies: engine.params().flies,
            seed: engine.params().seed,
            time_per_generation: Timing::of(&mut times),
            perception_stage: Timing::of(&mut stage),
            out_dir: out.display().to_string(),
            decision_mode: replay.settings.decision.mode.to_string(),
            speed_kmh: (replay.settings.fixed_speed || !replay.moving_feed)
                .then(|| (replay.settings.speed * 3.6 * 1000.0).round() / 1000.0),
            speed_source: if replay.settings.fixed_speed {
                "fixed"
            } else if replay.moving_feed {
                "feed"
            } else {
                "assumed"
            },
            decided_kmh,
            note,
            predict_flies: replay.settings.predict && replay.moving_feed,
            motion_source: replay.motion_source.clone(),
            judgeable_distance: replay.perception.judgeable_distance(),
            closed_loop: replay.closed_loop.clone(),
            last,
            warmup_generations: replay.settings.warmup_generations,
            alarms: Alarms::of(&replay.trace, replay.settings.warmup_generations),
            sensor_fault_frames: replay
                .frame_ends()
                .filter(|r| !r.sensor.faults.is_empty())
                .count() as u64,
            reaction,
            row_offset: RowOffsetReport {
                applied_px: replay.settings.right_row_shift,
                measured: replay.row_offset,
            },
            row_correction: replay.row_correction,
            mount: {
                let mut check = MountCheck::default();
                replay
                    .frame_ends()
                    .filter(|r| r.sensor.faults.is_empty())
                    .for_each(|r| check.add(&r.road));
                check.report()
            },
            mount_assumed: replay.settings.mount_assumed,
            columns: replay.columns,
            per_frame,
        }
    }
}

/// How the global warning and the command reacted to an obstacle appearing at frame
/// `appears_at_frame`. Counts are generations from the first one that saw that frame (1 = that
/// generation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Reaction {
    pub appears_at_frame: u64,
    /// The first generation that saw it.
    pub appears_at_generation: u64,
    /// Global warning of the generation before.
    pub before: f64,
    /// Global warning `SETTLE_GENERATIONS` after the first generation that saw the obstacle.
    pub settled: f64,
    /// Generations to reach half of `settled`.
    pub half_settled_after: Option<u64>,
    /// Generations for the global warning to reach the `global-warning` mode's thresholds.
    pub slow_threshold_after: Option<u64>,
    pub stop_threshold_after: Option<u64>,
    /// Generations to the first SLOW (or STOP) and the first STOP command.
    pub slow_command_after: Option<u64>,
    pub stop_command_after: Option<u64>,
}

/// "Settled" = the global warning this many generations after the obstacle appeared (issue 2).
pub const SETTLE_GENERATIONS: usize = 50;

impl Reaction {
    /// The reaction in `trace` to an obstacle first shown by frame `frame`; `None` when the
    /// trace does not run `SETTLE_GENERATIONS` past it.
    pub fn of(trace: &[TraceRow], frame: u64, slow: f64, stop: f64) -> Option<Self> {
        let first = trace.iter().position(|r| r.frame >= frame)?;
        let settled = trace.get(first + SETTLE_GENERATIONS)?.stats.global_warning;
        let after = |hit: &dyn Fn(&TraceRow) -> bool| {
            trace[first..].iter().position(hit).map(|k| k as u64 + 1)
        };
        let warning = |level: f64| after(&|r: &TraceRow| r.stats.global_warning >= level);
        Some(Self {
            appears_at_frame: frame,
            appears_at_generation: trace[first].stats.generation,
            before: first
                .checked_sub(1)
                .map_or(f64::NAN, |b| trace[b].stats.global_warning),
            settled,
            half_settled_after: warning(settled / 2.0),
            slow_threshold_after: warning(slow),
            stop_threshold_after: warning(stop),
            slow_command_after: after(&|r: &TraceRow| {
                r.command >= Command::Slow && r.reason == CommandReason::Perception
            }),
            stop_command_after: after(&|r: &TraceRow| r.command == Command::Stop),
        })
    }
}
