//! What a replay is asked to run, turned into a feed and its [`Settings`]: the one place
//! `flyd replay` and `flyd eval` set a replay up, so both run the same thing.

use std::path::PathBuf;

use super::can_motion;
use super::{
    FrameFeed, PairFeed, Replay, ReplayError, ScenarioFeed, SequenceFeed, Settings,
    daemon_generations_per_frame, summary::Reaction,
};
use crate::config::DaemonConfig;

/// The frame rate a still pair is replayed at (a camera filming it).
pub const PAIR_FPS: f64 = 30.0;

/// Where a replay's frames come from.
#[derive(Debug, Clone)]
pub enum Source {
    /// One stereo pair, filmed by a still camera at [`PAIR_FPS`].
    Pair {
        left: PathBuf,
        right: PathBuf,
        calib: PathBuf,
    },
    /// A folder of pairs at `fps`, the vehicle's motion from `can_input` (a candump log of
    /// its bus, [`super::can_motion`]) or else the folder's `poses.txt`, if any.
    Sequence {
        dir: PathBuf,
        calib: PathBuf,
        fps: f64,
        can_input: Option<PathBuf>,
    },
    /// A hw-mock scenario rendered at `width` x `height`.
    Scenario {
        name: String,
        width: u32,
        height: u32,
    },
    /// A closed-loop case ([`super::closed_loop`]): hw-mock's vehicle obeys the replay's
    /// commands, its cameras rendered at `width` x `height` (the mock rig's).
    ClosedLoop {
        case: Box<hw_mock::closed_loop::Case>,
        width: u32,
        height: u32,
    },
}

/// A replay as asked for: the source and what the command line overrides of the
/// configuration.
#[derive(Debug, Clone)]
pub struct Request {
    pub source: Source,
    /// Population size (default: the configuration's).
    pub flies: Option<usize>,
    /// Seed (default: the configuration's).
    pub seed: Option<u64>,
    /// The speed the decision assumes on every frame, km/h (default: a scenario's or
    /// sequence's own motion, else `vehicle.assumed_speed`).
    pub speed_kmh: Option<f64>,
    /// Generations to run (default: see [`Request::prepare`]).
    pub generations: Option<u64>,
    /// Generations per frame (default: see [`Request::prepare`]).
    pub generations_per_frame: Option<u64>,
    /// Turn the calibration's right camera by this many degrees, the images unchanged
    /// ([`super::feed::Miscalibrated`]).
    pub right_yaw_error_deg: Option<f64>,
}

/// A feed and the settings to replay it with.
pub struct Prepared {
    pub feed: Box<dyn FrameFeed>,
    pub settings: Settings,
}

impl Request {
    /// A request for `source` with the configuration's values.
    pub fn new(source: Source) -> Self {
        Self {
            source,
            flies: None,
            seed: None,
            speed_kmh: None,
            generations: None,
            generations_per_frame: None,
            right_yaw_error_deg: None,
        }
    }

    /// The feed and settings of this request under `config`. Defaults: a scenario runs 3
    /// generations a frame (30 fps at ~10 ms a generation) over all its frames; a sequence
    /// what the daemon runs at its frame rate ([`daemon_generations_per_frame`]) over all its
    /// frames; a still pair 3 a frame until the decision has settled
    /// ([`settled_pair_generations`]).
    pub fn prepare(&self, config: &DaemonConfig) -> Result<Prepared, ReplayError> {
        let mut params = config.engine.clone();
        if let Some(flies) = self.flies {
            params.flies = flies;
        }
        if let Some(seed) = self.seed {
            params.seed = seed;
        }
        let speed_kmh = self.speed_kmh.unwrap_or(config.vehicle.assumed_speed * 3.6);
        if !(speed_kmh.is_finite() && (0.0..=250.0).contains(&speed_kmh)) {
            return Err(ReplayError::Usage(format!(
                "speed {speed_kmh} km/h: must be within 0..=250 km/h"
            )));
        }
        // The calibration's row correction of the right image (a scenario's rig needs none).
        let mut right_row_shift = 0.0;
        // A scenario's rig is hw-mock's, not rectified: the replay says so and measures nothing.
        let mut measure_rows = true;
        // What was assumed of a calibration's mount (hw-mock's rigs are placed).
        let mut mount_assumed = None;
        let (feed, generations, per_frame, fps): (Box<dyn FrameFeed>, u64, u64, f64) =
            match &self.source {
                Source::Scenario {
                    name,
                    width,
                    height,
                } => {
                    let feed = ScenarioFeed::new(name, *width, *height)?;
                    let per_frame = self.generations_per_frame.unwrap_or(3).max(1);
                    let generations = self.generations.unwrap_or(feed.frames() * per_frame);
                    let fps = feed.fps();
                    (Box::new(feed), generations, per_frame, fps)
                }
                Source::ClosedLoop {
                    case,
                    width,
                    height,
                } => {
                    let feed = super::closed_loop::ClosedLoopFeed::new(
                        (**case).clone(),
                        *width,
                        *height,
                        params.seed,
                    )?;
                    let per_frame = self.generations_per_frame.unwrap_or(3).max(1);
                    let generations = self.generations.unwrap_or(feed.frames() * per_frame);
                    // No row correction for the mock's rigs (neither is rectified but
                    // the vehicle rig, whose rows are exact).
                    measure_rows = false;
                    (
                        Box::new(feed),
                        generations,
                        per_frame,
                        super::closed_loop::FPS,
                    )
                }
                Source::Sequence {
                    dir,
                    calib,
                    fps,
                    can_input,
                } => {
                    if !(fps.is_finite() && *fps > 0.0) {
                        return Err(ReplayError::Usage(format!(
                            "fps {fps}: must be a positive number of frames per second"
                        )));
                    }
                    let (mut feed, cal) = SequenceFeed::open(dir, calib, *fps)?;
                    if let Some(log) = can_input {
                        let id = config.can.messages.motion.id;
                        let monitor = config.motion_monitor();
                        let frames = usize::try_from(feed.frames()).unwrap_or(usize::MAX);
                        let m = can_motion::from_candump(log, frames, *fps, id, monitor)?;
                        let c = m.counters;
                        let source = format!(
                            "candump {} ({} VCU_Motion accepted, {} rejected, {} lost; \
                             no trusted motion on {} of {} frames{})",
                            log.display(),
                            c.accepted,
                            c.rejected(),
                            c.lost,
                            m.untrusted_frames(),
                            frames,
                            if m.unused > 0 {
                                format!("; {} after the last frame", m.unused)
                            } else {
                                String::new()
                            }
                        );
                        feed = feed.with_motion(source, m.per_frame);
                    }
                    cal.apply_to(&mut params);
                    right_row_shift = cal.right_row_offset_px;
                    measure_rows = cal.measure_rows;
                    mount_assumed = cal.mount_assumed;
                    let per_frame = self
                        .generations_per_frame
                        .unwrap_or_else(|| daemon_generations_per_frame(&config.evolution, *fps))
                        .max(1);
                    let generations = self.generations.unwrap_or(feed.frames() * per_frame);
                    (Box::new(feed), generations, per_frame, *fps)
                }
                Source::Pair { left, right, calib } => {
                    let (feed, cal) = PairFeed::load(left, right, calib)?;
                    cal.apply_to(&mut params);
                    right_row_shift = cal.right_row_offset_px;
                    measure_rows = cal.measure_rows;
                    mount_assumed = cal.mount_assumed;
                    // A still camera filming the pair at 30 fps, 3 generations a frame (no
                    // change, so no burst): what the daemon sees standing in front of that scene.
                    let per_frame = self.generations_per_frame.unwrap_or(3).max(1);
                    let generations = self
                        .generations
                        .unwrap_or_else(|| settled_pair_generations(config, per_frame, PAIR_FPS));
                    let feed = feed.repeated(generations.div_ceil(per_frame));
                    (Box::new(feed), generations, per_frame, PAIR_FPS)
                }
            };
        let feed: Box<dyn FrameFeed> = match self.right_yaw_error_deg {
            Some(deg) => Box::new(super::feed::Miscalibrated::new(feed, deg)?),
            None => feed,
        };
        let settings = Settings {
            record: None,
            params,
            perception: config.perception,
            decision: config.decision,
            speed: speed_kmh / 3.6,
            fixed_speed: self.speed_kmh.is_some(),
            predict: config.vehicle.predict_flies,
            generations,
            per_frame,
            fps,
            sensor: config.sensor,
            warmup_generations: config.evolution.warmup_generations,
            blind_matched: config.evolution.blind_matched,
            blind_pairs: config.evolution.blind_pairs,
            right_row_shift,
            measure_rows,
            mount_assumed,
            // The yaw check on real drives, and wherever a yaw error is put in; hw-mock's rigs
            // are the truth, and the check costs a tenth of a second a metre driven.
            check_columns: self.right_yaw_error_deg.is_some()
                || matches!(self.source, Source::Sequence { .. }),
        };
        Ok(Prepared { feed, settings })
    }
}

impl Prepared {
    /// Runs the replay; with how the decision reacted where the feed knows when its first
    /// obstacle appears.
    pub fn run(mut self, config: &DaemonConfig) -> Result<(Replay, Option<Reaction>), ReplayError> {
        let run = super::run(self.feed.as_mut(), self.settings)?;
        let reaction = self.feed.first_obstacle().and_then(|f| {
            Reaction::of(
                &run.trace,
                f,
                config.decision.slow_threshold,
                config.decision.stop_threshold,
            )
        });
        Ok((run, reaction))
    }
}

/// Generations a still pair needs for its replay to end on a settled decision: the warm-up
/// (untrusted: the safe command), the hold that releases the safe command once the
/// perception is trusted (the longer of the two holds with a STOP safe command), the frames
/// that confirm an obstacle, and two frames more; at least 50. At the defaults (warm-up 30,
/// SLOW held 500 ms, confirmed on 2 frames, 3 generations a 30 fps frame): 87. With 50, the
/// replay of a clear road ended on the start-up's SLOW (FAULT_FALLBACK) before the hold ran
/// out.
pub fn settled_pair_generations(config: &DaemonConfig, per_frame: u64, fps: f64) -> u64 {
    let d = &config.decision;
    let hold = match d.safe_command {
        flyd_core::decision::Command::Stop => d.slow_hold.max(d.stop_hold),
        _ => d.slow_hold,
    };
    let hold_frames = (hold.as_secs_f64() * fps).ceil() as u64;
    let confirm_frames = u64::from(config.perception.track.trigger_frames) + 2;
    let needed = config.evolution.warmup_generations + per_frame * (hold_frames + confirm_frames);
    needed.max(50)
}
