//! `flyd replay`: run perception and the decision on recorded or synthetic frames and write
//! what they found.
//!
//! Frames come from one stereo pair (evaluated again and again, the paper's setting), a folder
//! of pairs (`--sequence`, in name order at `--fps`) or a hw-mock scenario ([`feed`]). Each
//! generation runs [`Perception::step`] (both engines, the road, the obstacle stage) and the
//! [`Decider`](flyd_core::decision::Decider) at the generation's time on the frames' clock, at the assumed speed; the
//! decider takes no input during the warm-up (it holds the safe command, as the daemon does).
//!
//! Outputs, in the output directory ([`output`]):
//! - `road_points.csv`: the road measurement's points on the last new frame (see
//!   [`flyd_core::perception::road_estimator`]): `x,y,z,fitness,ambiguity,u_left,v_left,used,residual`;
//! - `flies.csv`: one fly a row, `x,y,z,fitness,warning,u_left,v_left,u_right,v_right,
//!   raw_fitness,ambiguity` (metres, pixels; `fitness` is the value selection ranks by, after
//!   the region of interest and sharing; `raw_fitness` before sharing, what `warning` is
//!   computed from; `ambiguity` is the match's against nearby disparities on the last frame,
//!   see [`flyd_core::engine::Engine::ambiguity`]; flies outside an image have empty
//!   projections);
//! - `overlay.png`: the left image with the best 250 flies as crosses (the paper's figures 5, 7);
//! - `warnings.png`: each fly a spot as dark as its warning (figures 6, 8);
//! - `trace.csv`: one row a generation (frame, global warning, road, obstacle, command, time);
//! - `frames.csv`: the same columns, one row a frame (its last generation).
//!
//! It prints a JSON summary on stdout ([`Summary`]).
//!
//! This is a command at the edge: it reads files and the clock; perception does neither.

pub mod can_motion;
pub mod closed_loop;
pub mod command;
pub mod decided;
pub mod feed;
mod image_file;
pub mod output;
pub mod poses;
pub mod recorded;
pub mod request;
pub mod summary;

pub use image_file::{LoadedImage, load_image, load_rgb};

pub use feed::{FrameFeed, PairFeed, SEQUENCE_LAYOUTS, ScenarioFeed, SequenceFeed};
pub use output::{overlay, warning_map, write_flies_csv, write_outputs, write_trace_csv};
pub use request::{Prepared, Request, Source};
pub use summary::{Alarms, FrameReport, Reaction, Summary, Timing};

use crate::config::EvolutionConfig;
use crate::mock::MockError;
use flyd_core::calib::CalibError;
use flyd_core::decision::{
    Command, CommandReason, DecisionConfig, DecisionConfigError, DecisionInput,
};
use flyd_core::engine::{Engine, EngineError, EngineParams, GenerationStats};
use flyd_core::frame::{FrameError, PixelFormat, PreparedImage, StereoFrame};
use flyd_core::frame_step::{FrameStep, NewPair, StepConfig};
use flyd_core::kinematics::EgoTransform;
use flyd_core::perception::{
    CorridorCounts, Perception, PerceptionConfig, PerceptionError, RoadEstimate, Tracked,
};
use flyd_core::policy::DecisionStep;
use flyd_core::rectification::yaw::{ColumnCheck, ColumnReport};
use flyd_core::rectification::{RowCorrection, RowOffset, max_disparity, residual_row_offset};
use flyd_core::sensor::{ImageCheck, ImageHealth, SensorConfig, SensorVerdict};
use flyd_core::status::FaultBits;
use image::RgbImage;
use std::path::Path;
use std::time::{Duration, Instant};

/// Number of flies drawn on the overlay, as in the paper's figures.
pub const OVERLAY_FLIES: usize = 250;

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// A request that makes no sense (a negative speed, no frame rate).
    #[error("{0}")]
    Usage(String),
    #[error("{path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}")]
    Image {
        path: String,
        #[source]
        source: image::ImageError,
    },
    #[error("{path}: truncated or corrupt image: {what}")]
    Truncated { path: String, what: &'static str },
    #[error("calibration")]
    Calibration(#[from] CalibError),
    #[error(
        "{which} image {image} is {got_w}x{got_h} but {calibration} describes a {want_w}x{want_h} camera"
    )]
    ImageSize {
        which: &'static str,
        image: String,
        calibration: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("unknown scenario '{name}' (known: {known})")]
    UnknownScenario { name: String, known: String },
    #[error(
        "{dir} holds no stereo sequence: expected the folders left/ and right/, or KITTI's \
         image_02/data and image_03/data"
    )]
    SequenceLayout { dir: String },
    #[error("{file} has no image of the same name in {dir}")]
    SequenceUnpaired { file: String, dir: String },
    #[error("{dir} holds no PNG or JPEG image")]
    SequenceEmpty { dir: String },
    #[error("{path}: the vehicle's poses")]
    Poses {
        path: String,
        #[source]
        source: poses::PosesError,
    },
    #[error("{path}: {poses} poses for {frames} frames (one a frame, from the first)")]
    PosesCount {
        path: String,
        poses: usize,
        frames: usize,
    },
    #[error("hw-mock")]
    Mock(#[from] MockError),
    #[error("frame")]
    Frame(#[from] FrameError),
    #[error("engine")]
    Engine(#[from] EngineError),
    #[error("perception")]
    Perception(#[from] PerceptionError),
    #[error("decision")]
    Decision(#[from] DecisionConfigError),
    #[error("CAN configuration")]
    Can(#[from] flyd_core::can::CanConfigError),
    #[error("reading the recording")]
    Read(#[from] crate::record::read::ReadError),
    #[error(
        "{0}: no configuration attached (config.toml) and none given: pass --config with the \
         file the daemon ran with"
    )]
    NoConfig(String),
    #[error("the recording's configuration")]
    Config(#[from] crate::config::ConfigError),
    #[error("{0}: the recording has no images (record.images = false): nothing to replay")]
    NoImages(String),
    #[error("the replay's recording")]
    Record(#[from] crate::record::WriterError),
    #[error("the CAN input")]
    CanInput(#[source] Box<crate::bus::ReplayLogError>),
    #[error("a recorded JPEG frame")]
    Jpeg(#[source] Box<dyn std::error::Error + Send + Sync>),
}

/// How a replay runs.
#[derive(Debug, Clone)]
pub struct Settings {
    pub params: EngineParams,
    pub perception: PerceptionConfig,
    pub decision: DecisionConfig,
    /// The vehicle's speed the decision assumes where the feed does not know it, m/s.
    pub speed: f64,
    /// `speed` holds on every frame (`--speed` given), even where the feed knows its motion.
    pub fixed_speed: bool,
    /// Move the flies with the feed's motion between frames ([`Perception::predict`]).
    pub predict: bool,
    /// Generations to run.
    pub generations: u64,
    /// Generations per frame.
    pub per_frame: u64,
    /// Frames per second of the feed (the decider's clock).
    pub fps: f64,
    /// The sensor checks ([`flyd_core::sensor`]): a fault is CAMERA_ERROR for the decider.
    pub sensor: SensorConfig,
    /// Generations before the decider takes input.
    pub warmup_generations: u64,
    /// The blind-camera debounce ([`flyd_core::policy::BlindDebounce`], `evolution.blind_matched` and
    /// `evolution.blind_pairs`): the daemon's, BLIND being CAMERA_ERROR here too.
    pub blind_matched: f64,
    pub blind_pairs: u32,
    /// Write what the replay sees and decides to a recording (`flyd replay --record`).
    pub record: Option<crate::record::Recorder>,
    /// The calibration's row correction of the right image
    /// (`rectification.right_row_offset_px`).
    pub right_row_shift: f64,
    /// Measure the residual of a rectified pair's rows on the first frame and correct it
    /// (`rectification.measure`; a rig that is not rectified is not measured).
    pub measure_rows: bool,
    /// What was assumed of the cameras' mount, when the calibration gives none
    /// ([`flyd_core::calib::Calibration::mount_assumed`]).
    pub mount_assumed: Option<&'static str>,
    /// Check the right camera's yaw against the feed's motion
    /// ([`flyd_core::rectification::yaw`]; 0.1-0.2 s of CPU a metre driven).
    pub check_columns: bool,
}

/// Generations the daemon runs per frame of a video at `fps` that changes every frame (a
/// camera's noise is enough): a burst of `burst_generations` on the new frame, then one per
/// `generation_period` until the next (the generations' own time neglected).
pub fn daemon_generations_per_frame(evolution: &EvolutionConfig, fps: f64) -> u64 {
    let frame = if fps.is_finite() && fps > 0.0 {
        1.0 / fps
    } else {
        return u64::from(evolution.burst_generations.max(1));
    };
    let periods = evolution
        .generation_period
        .filter(|p| !p.is_zero())
        .map_or(0, |p| (frame / p.as_secs_f64()).floor() as u64);
    (u64::from(evolution.burst_generations.max(1)) + periods.saturating_sub(1)).max(1)
}

/// One row of `trace.csv`: a generation.
#[derive(Debug, Clone)]
pub struct TraceRow {
    pub frame: u64,
    pub frame_name: String,
    /// On the frames' clock.
    pub time: Duration,
    pub stats: GenerationStats,
    pub road: RoadEstimate,
    pub tracked: Tracked,
    /// Beside the corridor, left and right ([`flyd_core::perception::crossing`]).
    pub watched: [Tracked; 2],
    pub corridor: CorridorCounts,
    pub command: Command,
    pub reason: CommandReason,
    /// The speed the decision took, m/s.
    pub speed: f64,
    /// How far ahead the frame was searched, metres ([`Perception::search_far`]).
    pub search_far: f64,
    /// Wall time of the whole step (both engines and the perception stage).
    pub elapsed: Duration,
    /// Of which the road fit and the obstacle stage.
    pub stage: Duration,
    /// The sensor checks on this frame (left, right) and what they concluded.
    pub health: [ImageHealth; 2],
    pub sensor: SensorVerdict,
}

/// A finished replay: perception as it ended, and one trace row per generation.
pub struct Replay {
    pub perception: Perception,
    pub settings: Settings,
    /// Every fly's match ambiguity on the last frame ([`flyd_core::engine::Engine::ambiguity`]).
    pub ambiguity: Vec<f32>,
    pub trace: Vec<TraceRow>,
    /// The left image of the last frame.
    pub left: RgbImage,
    /// Frames shown.
    pub frames: u64,
    /// The feed knew its motion.
    pub moving_feed: bool,
    /// Where that motion came from (a scenario, a sequence's poses).
    pub motion_source: Option<String>,
    /// The right image's rows as measured on the last frame's fittest unique flies, after
    /// the calibration's correction ([`flyd_core::rectification`]).
    pub row_offset: Option<RowOffset>,
    /// The correction applied (the calibration's, or measured on the first frame).
    pub row_correction: Option<RowCorrection>,
    /// The frame the most severe alarm (the first STOP, else the first SLOW) was decided on.
    pub decided: Option<decided::Decided>,
    /// A closed loop's outcome ([`closed_loop`]).
    pub closed_loop: Option<closed_loop::ClosedLoopReport>,
    /// The right camera's yaw against the vehicle's motion, when checked
    /// ([`Settings::check_columns`], [`flyd_core::rectification::yaw`]).
    pub columns: Option<ColumnReport>,
}

impl Replay {
    /// The last row of each frame.
    pub fn frame_ends(&self) -> impl Iterator<Item = &TraceRow> {
        self.trace
            .iter()
            .enumerate()
            .filter(|(i, r)| self.trace.get(i + 1).is_none_or(|n| n.frame != r.frame))
            .map(|(_, r)| r)
    }
}

/// Runs `settings.generations` generations of perception and the decision on `feed`, a new
/// frame every `settings.per_frame` generations (the last frame stays once the feed has no
/// more).
pub fn run(feed: &mut dyn FrameFeed, mut settings: Settings) -> Result<Replay, ReplayError> {
    let perception = Perception::new(feed.rig(), settings.params.clone(), settings.perception)?
        .with_warmup(settings.warmup_generations)
        .with_reach(settings.decision);
    let mut step = FrameStep::new(
        perception,
        StepConfig {
            blind_matched: settings.blind_matched,
            blind_pairs: settings.blind_pairs,
            sensor: settings.sensor,
            predict_flies: settings.predict,
            assumed_speed: settings.speed,
        },
    );
    let mut decision_step = DecisionStep::new(settings.decision)?;
    let (w, h) = (feed.rig().left.width(), feed.rig().left.height());
    let (rw, rh) = (feed.rig().right.width(), feed.rig().right.height());
    // Taken out: the recording ends with this run (its writer waits for every handle).
    let recorder = settings.record.take();
    let retain = recorder.is_some();
    let image = move |w, h| PreparedImage::new(w, h).map(|i| i.retain_pixels_if(retain));
    let right = image(rw, rh)?.with_row_shift(settings.right_row_shift);
    let mut frame = StereoFrame::new(image(w, h)?, right, 0);
    let mut recording = recorder.map(ReplayRecording::new).transpose()?;
    let mut left = RgbImage::new(w, h);
    let per_frame = settings.per_frame.max(1);
    let fps = if settings.fps.is_finite() && settings.fps > 0.0 {
        settings.fps
    } else {
        10.0
    };
    let mut trace = Vec::with_capacity(usize::try_from(settings.generations).unwrap_or(0));
    let mut index = None;
    let mut row_correction = None;
    let mut checks = [ImageCheck::new(w, h), ImageCheck::new(rw, rh)];
    // The right camera's yaw against the motion: a pair and the distance driven since.
    let mut columns = ColumnCheck::new();
    let mut since: Option<(StereoFrame, f64, f64)> = None;
    let mut health = [ImageHealth::default(); 2];
    // A command each generation: the period's input is that generation's snapshot.
    let mut alarm: Option<decided::Decided> = None;
    for g in 0..settings.generations {
        if feed.finished() {
            break;
        }
        let wanted = (g / per_frame).min(feed.frames().saturating_sub(1));
        let mut predicted = None;
        let new_frame = index != Some(wanted);
        if new_frame {
            let mut moved = None;
            if let Some(previous) = index
                && let Some(motion) = feed.motion(previous)
            {
                let dt = (wanted - previous) as f64 / fps;
                // The corridor follows the motion's path either way, as the daemon's does.
                moved = Some((Some(motion), dt));
                predicted = Some((motion, dt));
            }
            feed.load(wanted, &mut frame, &mut left)?;
            if index.is_none() {
                // The first frame: the rows measured and corrected before any fly sees it.
                let rectified = feed.rig().is_rectified();
                let measured = (settings.measure_rows && rectified)
                    .then(|| {
                        residual_row_offset(
                            &frame,
                            max_disparity(feed.rig(), settings.params.min_depth),
                        )
                    })
                    .flatten();
                let decided = RowCorrection::decide(
                    settings.right_row_shift,
                    settings.measure_rows,
                    rectified,
                    measured,
                );
                if decided.applied_px != settings.right_row_shift {
                    frame.right = image(rw, rh)?.with_row_shift(decided.applied_px);
                    feed.load(wanted, &mut frame, &mut left)?;
                    settings.right_row_shift = decided.applied_px;
                }
                row_correction = Some(decided);
            }
            if settings.check_columns {
                since = compare_columns(&mut columns, since, &frame, moved, feed.rig());
            }
            frame.id = wanted;
            index = Some(wanted);
            health = [
                checks[0].observe(&frame.left),
                checks[1].observe(&frame.right),
            ];
            if feed.still() {
                // The same images shown again are a still scene, not a frozen camera.
                health.iter_mut().for_each(|h| h.unchanged = None);
            }
            step.pair(&NewPair {
                moved,
                health: Some(health),
            });
        }
        // On the frames' clock: the generations of a frame spread over its period.
        let time = Duration::from_secs_f64((g as f64 / per_frame as f64) / fps);
        let t = Instant::now();
        step.evolve(&frame)?;
        let observed = Instant::now();
        let outcome = step.observe(&frame)?;
        let (report, sensor) = (outcome.report, outcome.sensor);
        let (elapsed, stage) = (t.elapsed(), observed.elapsed());
        let speed = match feed.motion(wanted) {
            Some(m) if !settings.fixed_speed => m.speed.max(0.0),
            _ => settings.speed,
        };
        // The evidence's age on the frames' clock, and a frame until the next.
        let latency = (time.as_secs_f64() - wanted as f64 / fps).max(0.0) + 1.0 / fps;
        let input = outcome.decision_input(speed, latency);
        let (faults, snapshot) = (
            input.faults,
            DecisionInput {
                faults: FaultBits::empty(),
                ..input
            },
        );
        // As the daemon's control thread: a snapshot of a population still warming up is not
        // taken (the daemon's decider takes its fault path then: the safe command; the
        // replay's is not asked).
        if !outcome.warming_up {
            decision_step.observe(snapshot);
        }
        let decision = decision_step.decide_taken(time, faults).map(|d| d.decision);
        feed.tracked(time, &report.tracked);
        if let Some(d) = &decision {
            feed.obey(time, d);
        }
        // The first SLOW and the first STOP on the evidence (a SLOW may continue the start-up's
        // safe command: its reason changes, not the command).
        if let Some(d) = decision
            && d.command > Command::Clear
            && d.reason == CommandReason::Perception
            && alarm.as_ref().is_none_or(|a| d.command > a.command)
        {
            alarm = Some(decided::Decided::capture(
                d.command,
                wanted,
                feed.frame_name(wanted),
                time,
                speed,
                step.perception(),
                &report,
                &left,
                feed.rig(),
            ));
        }
        if let Some(rec) = recording.as_mut() {
            let frame_time = Duration::from_secs_f64(wanted as f64 / fps);
            if new_frame {
                rec.frames(&frame, frame_time, report.stats.generation, predicted);
            }
            rec.generation(
                step.perception(),
                &report,
                time,
                elapsed,
                &input,
                decision.as_ref(),
            );
        }
        trace.push(TraceRow {
            frame: wanted,
            frame_name: feed.frame_name(wanted),
            time,
            stats: report.stats,
            road: report.road,
            tracked: report.tracked,
            watched: report.watched,
            corridor: report.corridor,
            command: decision.map_or(decision_step.command(), |d| d.command),
            reason: decision.map_or(CommandReason::FaultFallback, |d| d.reason),
            speed,
            search_far: step.perception().search_far(),
            elapsed,
            stage,
            health,
            sensor,
        });
    }
    let mut perception = step.into_perception();
    let ambiguity = all_ambiguities(perception.engine_mut(), &frame)?;
    let row_offset =
        residual_row_offset(&frame, max_disparity(feed.rig(), settings.params.min_depth));
    drop(recording);
    let checked_columns = settings.check_columns.then(|| columns.report(feed.rig()));
    Ok(Replay {
        perception,
        settings,
        ambiguity,
        trace,
        left,
        frames: index.map_or(0, |i| i + 1),
        moving_feed: feed.motion_source().is_some(),
        motion_source: feed.motion_source(),
        row_offset,
        row_correction,
        decided: alarm,
        closed_loop: feed.closed_loop(),
        columns: checked_columns,
    })
}

/// Metres driven between the frames the yaw check compares.
const COLUMNS_TRAVEL: f64 = 1.0;

/// The yaw check's step on a new `frame`, reached by the motion `moved` (the motion of the
/// previous frame and the time since: none when the feed gives no motion): the distance and
/// turn since the pair `since` added up, and once [`COLUMNS_TRAVEL`] is driven the two compared
/// and `frame` the next to compare from. Returns what to compare from next.
fn compare_columns(
    columns: &mut ColumnCheck,
    since: Option<(StereoFrame, f64, f64)>,
    frame: &StereoFrame,
    moved: Option<(Option<flyd_core::kinematics::VehicleMotion>, f64)>,
    rig: &flyd_core::geometry::StereoRig,
) -> Option<(StereoFrame, f64, f64)> {
    let (Some((before, travelled, turned)), Some((Some(motion), dt))) = (since, moved) else {
        return Some((frame.clone(), 0.0, 0.0));
    };
    let (travelled, turned) = (travelled + motion.speed * dt, turned + motion.yaw_rate * dt);
    if travelled.abs() < COLUMNS_TRAVEL {
        return Some((before, travelled, turned));
    }
    columns.observe(
        &before,
        &frame.left,
        rig,
        &EgoTransform::new(travelled, turned),
        travelled,
    );
    Some((frame.clone(), 0.0, 0.0))
}

/// What a replay hands its recorder: the frames and pairs, the flies, one snapshot and one
/// command a generation (the replay's decider takes each generation's outcome), and each
/// command as the `FLYD_Command` frame it encodes to.
struct ReplayRecording {
    recorder: crate::record::Recorder,
    tx: flyd_core::can::Transmitter<crate::bus::MemoryBus>,
    bus: crate::bus::MemoryBus,
    seq: u64,
}

impl ReplayRecording {
    fn new(recorder: crate::record::Recorder) -> Result<Self, ReplayError> {
        let bus = crate::bus::MemoryBus::new(flyd_core::clock::ManualClock::new(Duration::ZERO));
        let tx =
            flyd_core::can::Transmitter::new(bus.clone(), flyd_core::can::CanConfig::default())?;
        Ok(Self {
            recorder,
            tx,
            bus,
            seq: 0,
        })
    }

    fn frames(
        &self,
        frame: &StereoFrame,
        at: Duration,
        generation: u64,
        predicted: Option<(flyd_core::kinematics::VehicleMotion, f64)>,
    ) {
        use crate::source::Side;
        for (side, image) in [(Side::Left, &frame.left), (Side::Right, &frame.right)] {
            if let Some(frame) = image.pixels() {
                let size = (image.width(), image.height());
                self.recorder.frame(side, at, size, frame);
            }
        }
        let ns = crate::record::nanos(at);
        self.recorder.pair(
            at,
            crate::record::topics::PairEvent {
                generation,
                pair_id: frame.id,
                left_ns: ns,
                right_ns: ns,
                predict: predicted.map(|(m, dt)| crate::record::topics::PredictEvent {
                    speed: m.speed,
                    yaw_rate: m.yaw_rate,
                    dt,
                }),
                right_row_shift_px: Some(frame.right.row_shift()),
                motion_unknown: false,
            },
        );
    }

    fn generation(
        &mut self,
        perception: &Perception,
        report: &flyd_core::perception::PerceptionReport,
        at: Duration,
        elapsed: Duration,
        input: &DecisionInput,
        decision: Option<&flyd_core::decision::Decision>,
    ) {
        let r = &self.recorder;
        let generation = report.stats.generation;
        r.flies(generation, at, perception.engine().population());
        self.seq += 1;
        let observed = crate::record::Observed {
            generation,
            warming_up: decision.is_none(),
            global_warning: report.stats.global_warning,
            matched: report.stats.matched,
            generation_time: elapsed,
            road: &report.road,
            tracked: &report.tracked,
            path: perception.path_estimate(),
            search_far: perception.search_far(),
        };
        r.snapshot(self.seq, at, observed, input);
        let Some(decision) = decision else {
            return;
        };
        self.seq += 1;
        let state = if input.faults.is_empty() {
            flyd_core::status::State::Running
        } else {
            flyd_core::status::State::Degraded
        };
        let from = crate::record::topics::InputFrom::Taken;
        r.command(
            self.seq,
            at,
            from,
            None,
            input.faults,
            state,
            input,
            decision,
        );
        let msg = flyd_core::can::messages::CommandMsg::of(decision, input.global_warning);
        if self.tx.send_command(&msg).is_ok() {
            for f in self.bus.take_frames() {
                r.can(true, self.seq, at, f.id, &f.data);
            }
        }
    }
}

/// A rendered pair (RGB8, the rig's size) into `frame` (prepared) and `left` (the left
/// image, for the overlay): what a hw-mock feed shows.
fn show_rendered(
    frame: &mut StereoFrame,
    left: &mut RgbImage,
    l: &[u8],
    r: &[u8],
) -> Result<(), ReplayError> {
    frame.left.prepare(PixelFormat::Rgb8, l)?;
    frame.right.prepare(PixelFormat::Rgb8, r)?;
    left.copy_from_slice(l);
    Ok(())
}

/// Every fly's ambiguity on `frame`, the engine's latest.
fn all_ambiguities(engine: &mut Engine, frame: &StereoFrame) -> Result<Vec<f32>, EngineError> {
    let mut ambiguity = vec![f32::INFINITY; engine.population().len()];
    let all: Vec<u32> = (0..ambiguity.len() as u32).collect();
    let chunk = engine.ambiguity_capacity().max(1);
    for (flies, out) in all.chunks(chunk).zip(ambiguity.chunks_mut(chunk)) {
        engine.ambiguity(frame, flies, out)?;
    }
    Ok(ambiguity)
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |source| ReplayError::Io {
        path: path.display().to_string(),
        source,
    }
}

#[cfg(test)]
mod tests;
