//! `flyd replay --mcap`: a recording's frames through the same engine and decider, and
//! whether they reproduce the recorded decisions bit for bit.
//!
//! The daemon is asynchronous, so a recording keeps what its threads' timing decided (see
//! [`crate::record`]): which frames were paired, the first generation run on each pair and
//! the motion its flies were moved with, which snapshots the decider was fed with the speed
//! and latency then, and when each command was decided with which faults. The replay takes
//! those as given and recomputes everything else:
//!
//! 1. the perception: the recorded frames prepared again, [`FrameStep`] generation
//!    by generation (each pair from its first generation to the next pair's), the flies
//!    predicted with the recorded motion; each recorded snapshot's global warning and
//!    obstacle are compared with the replayed generation's (the first difference is where
//!    the perception diverges);
//! 2. the decision: the [`Decider`] fed the replayed snapshots, merged as the control thread
//!    merged them, at the recorded times and faults; `VCU_Motion` frames received go through
//!    the [`MotionMonitor`] again, and its speed is checked against the recorded one;
//! 3. the commands: each `FLYD_Command` frame encoded again (same E2E counter and CRC) and
//!    compared byte for byte with the frame the daemon sent.
//!
//! Sensor faults and the other fault bits are inputs here (recorded per command), as the
//! clock is; they are not re-derived.
//!
//! [`Decider`]: flyd_core::decision::Decider
//! [`MotionMonitor`]: flyd_core::can::motion_monitor::MotionMonitor

use std::collections::VecDeque;
use std::path::Path;
use std::time::Duration;

use crate::capture::{CaptureFormat, FrameConverter};
use crate::config::DaemonConfig;
use crate::record::read::{ControlEvent, Frame, Recording};
use crate::record::topics::{PairEvent, PredictEvent};
use crate::replay::ReplayError;
use crate::source::Side;
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::frame_step::{FrameStep, NewPair};
use flyd_core::kinematics::VehicleMotion;
use flyd_core::perception::Perception;

mod decisions;

use decisions::{replay_decisions, secs_after};

/// Where a replay first differs from its recording.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Divergence {
    /// `perception`, `speed`, `command`, `recording`.
    pub what: &'static str,
    /// Seconds after the recording's first pair.
    pub t: f64,
    pub generation: Option<u64>,
    pub detail: String,
}

/// What `flyd replay --mcap` prints.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordedSummary {
    pub recording: String,
    /// `false`: the file was cut short (no footer: a full disk, a killed daemon) and is
    /// replayed as far as it goes.
    pub complete: bool,
    pub seed: u64,
    pub frames: [u64; 2],
    pub pairs: usize,
    pub generations: u64,
    /// Snapshots the decider was fed, compared.
    pub snapshots: usize,
    pub snapshots_identical: usize,
    pub commands_recorded: usize,
    pub commands_replayed: usize,
    /// `FLYD_Command` frames equal byte for byte, in order.
    pub commands_identical: usize,
    /// Seconds after the first pair (as every time here).
    pub first_stop_s: Option<f64>,
    /// Commands as `t_s:COMMAND` where the command changed.
    pub changes: Vec<String>,
    /// The right image's row correction over the recording: (seconds, pixels) at the first
    /// pair and wherever the daemon changed it (`flyd::daemon::rows`).
    pub row_corrections: Vec<(f64, f64)>,
    /// `None`: reproduced bit for bit.
    pub divergence: Option<Divergence>,
}

impl RecordedSummary {
    pub fn reproduced(&self) -> bool {
        self.divergence.is_none()
    }

    /// Keeps the first divergence found.
    fn diverge(&mut self, what: &'static str, t: f64, generation: Option<u64>, detail: String) {
        if self.divergence.is_none() {
            self.divergence = Some(Divergence {
                what,
                t,
                generation,
                detail,
            });
        }
    }
}

/// What one replayed generation produced that the decision reads.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Outcome {
    global_warning: f64,
    obstacle: Option<f64>,
    /// For a new recording of the replay.
    matched: f64,
    road: flyd_core::perception::RoadEstimate,
    tracked: flyd_core::perception::Tracked,
    path: Option<flyd_core::path::PathEstimate>,
    search_far: f64,
}

/// What the replay needs to write a recording of itself (`flyd replay --mcap --record`).
pub type StartRecording<'a> =
    &'a mut dyn FnMut(
        &flyd_core::geometry::StereoRig,
        &DaemonConfig,
    ) -> Result<crate::record::Recorder, crate::record::WriterError>;

/// Replays `path`; `config` overrides the attached configuration, `seed` its seed; `record`
/// starts a recording of the replay (its frames, flies, snapshots and commands as replayed).
pub fn replay(
    path: &Path,
    config: Option<&Path>,
    seed: Option<u64>,
    record: Option<StartRecording<'_>>,
) -> Result<RecordedSummary, ReplayError> {
    let recording = Recording::open(path)?;
    let shown = path.display().to_string();
    let mut config = match config {
        Some(file) => crate::config::check(file)?,
        None => {
            let text = recording
                .config_text()?
                .ok_or_else(|| ReplayError::NoConfig(shown.clone()))?;
            let meta = recording.metadata()?;
            let origin = meta
                .get("config_path")
                .map_or_else(|| path.to_path_buf(), std::path::PathBuf::from);
            DaemonConfig::from_toml(&text, &origin)?
        }
    };
    if let Some(seed) = seed {
        config.engine.seed = seed;
    }
    let events = recording.events()?;
    if events.images == [0, 0] {
        return Err(ReplayError::NoImages(shown));
    }
    let mut summary = RecordedSummary {
        complete: recording.complete(),
        recording: shown,
        seed: config.engine.seed,
        frames: events.images,
        pairs: events.pairs.len(),
        generations: 0,
        snapshots: 0,
        snapshots_identical: 0,
        commands_recorded: 0,
        commands_replayed: 0,
        commands_identical: 0,
        first_stop_s: None,
        changes: Vec::new(),
        row_corrections: Vec::new(),
        divergence: None,
    };
    let start = events
        .pairs
        .first()
        .map_or(0, |p| p.left_ns.min(p.right_ns));
    let recorder = match record {
        Some(start_recording) => Some(start_recording(&config.load_rig()?, &config)?),
        None => None,
    };
    let last_generation = events
        .control
        .iter()
        .filter_map(|e| match e {
            ControlEvent::Perception(p) => Some(p.generation),
            ControlEvent::Decision(d) => d.latest_generation,
            ControlEvent::Received(_) => None,
        })
        .max()
        .unwrap_or(0);
    let outcomes = replay_perception(
        &recording,
        &config,
        &events.pairs,
        last_generation,
        start,
        recorder.as_ref(),
        &mut summary,
    )?;
    replay_decisions(
        &config,
        &events,
        &outcomes,
        start,
        recorder.as_ref(),
        &mut summary,
    )?;
    Ok(summary)
}

/// Runs the perception over the recorded pairs, and on the last one up to `last_generation`
/// (the last the decision took); the outcome of every generation, by number (index 0
/// unused).
fn replay_perception(
    recording: &Recording,
    config: &DaemonConfig,
    pairs: &[PairEvent],
    last_generation: u64,
    start: u64,
    recorder: Option<&crate::record::Recorder>,
    summary: &mut RecordedSummary,
) -> Result<Vec<Option<Outcome>>, ReplayError> {
    let flyd_core::calib::Calibration {
        rig,
        right_row_offset_px,
        ..
    } = config.load_calibration()?;
    let (w, h) = (config.cameras.width, config.cameras.height);
    let perception = Perception::new(&rig, config.engine.clone(), config.perception)?
        .with_warmup(config.evolution.warmup_generations)
        .with_reach(config.decision);
    // The recorded decisions carry the sensor faults: the images' health is not checked again.
    let mut step = FrameStep::new(perception, config.step_config());
    let image = || PreparedImage::new(w, h).map(|i| i.retain_pixels_if(recorder.is_some()));
    let right = image()?.with_row_shift(right_row_offset_px);
    let mut stereo = StereoFrame::new(image()?, right, 0);
    let mut mjpeg = None;
    let mut outcomes: Vec<Option<Outcome>> = vec![None];
    let mut pending: [VecDeque<Frame>; 2] = [VecDeque::new(), VecDeque::new()];
    let mut next = 0;
    let mut generation = 0;
    let mut frames = recording.frames()?;
    let mut exhausted = false;
    // The newest pair's time: when the replayed flies are recorded.
    let mut last_at = Duration::ZERO;
    let mut last_shift = None;
    while next < pairs.len() {
        let pair = pairs[next];
        let wanted = [pair.left_ns, pair.right_ns];
        // Read frames until both of this pair's are there (or the recording ends).
        let found = loop {
            for (side, queue) in pending.iter_mut().enumerate() {
                while queue.front().is_some_and(|f| f.timestamp_ns < wanted[side]) {
                    queue.pop_front();
                }
            }
            let have = |side: usize| {
                pending[side]
                    .front()
                    .is_some_and(|f| f.timestamp_ns == wanted[side])
            };
            if have(0) && have(1) {
                break true;
            }
            let passed = |side: usize| pending[side].front().is_some();
            if exhausted || (!have(0) && passed(0)) || (!have(1) && passed(1)) {
                break false;
            }
            match frames.next() {
                Some(frame) => {
                    let frame = frame?;
                    pending[frame.side as usize].push_back(frame);
                }
                None => exhausted = true,
            }
        };
        if !found {
            summary.diverge(
                "recording",
                secs_after(pair.left_ns, start),
                Some(pair.generation),
                format!(
                    "the frames of pair {} (left {} ns, right {} ns) are not in the recording \
                     (the recorder dropped them): the replay stops there",
                    pair.pair_id, pair.left_ns, pair.right_ns
                ),
            );
            break;
        }
        // The generations the daemon ran on the previous pair before this one came.
        while generation + 1 < pair.generation && next > 0 {
            generation = run_generation(&mut step, &stereo, &mut outcomes, recorder, last_at)?;
        }
        for side in [Side::Left, Side::Right] {
            if let Some(frame) = pending[side as usize].pop_front() {
                let image = match side {
                    Side::Left => &mut stereo.left,
                    Side::Right => {
                        // The row correction the daemon prepared this pair's right image with.
                        let px = pair.right_row_shift_px.unwrap_or(right_row_offset_px);
                        if last_shift != Some(px) {
                            last_shift = Some(px);
                            summary
                                .row_corrections
                                .push((secs_after(pair.left_ns, start), px));
                        }
                        stereo.right.set_row_shift(px);
                        &mut stereo.right
                    }
                };
                match frame.format {
                    Some(format) => image.prepare(format, &frame.pixels)?,
                    // An MJPEG camera's frame: decoded and prepared as the capture thread did.
                    None => jpeg(&mut mjpeg, w, h)?
                        .prepare(&frame.pixels, image)
                        .map_err(|e| ReplayError::Jpeg(Box::new(e)))?,
                }
                if let (Some(r), Some(retained)) = (recorder, image.pixels()) {
                    let at = Duration::from_nanos(frame.timestamp_ns);
                    r.frame(side, at, (w, h), retained);
                }
            }
        }
        if let Some(r) = recorder {
            r.pair(Duration::from_nanos(pair.left_ns.max(pair.right_ns)), pair);
        }
        last_at = Duration::from_nanos(pair.left_ns.max(pair.right_ns));
        stereo.id = pair.pair_id;
        // As the daemon did: the flies moved only with vehicle.predict_flies; a motion fault's
        // fan at the assumed speed.
        let motion = |p: PredictEvent| VehicleMotion {
            speed: p.speed,
            yaw_rate: p.yaw_rate,
        };
        let moved = match pair.predict {
            Some(p) => Some((Some(motion(p)), p.dt)),
            None => pair.motion_unknown.then_some((None, 0.0)),
        };
        step.pair(&NewPair {
            moved,
            health: None,
        });
        generation = run_generation(&mut step, &stereo, &mut outcomes, recorder, last_at)?;
        if generation != pair.generation {
            summary.diverge(
                "recording",
                secs_after(pair.left_ns, start),
                Some(pair.generation),
                format!(
                    "pair {} was first evolved at generation {} in the recording, {} here",
                    pair.pair_id, pair.generation, generation
                ),
            );
            break;
        }
        next += 1;
    }
    // The generations the daemon ran on the last pair, up to the last one the decision took.
    if summary.divergence.is_none() && next > 0 {
        while generation < last_generation {
            generation = run_generation(&mut step, &stereo, &mut outcomes, recorder, last_at)?;
        }
    }
    summary.generations = generation;
    Ok(outcomes)
}

/// The MJPEG converter the capture thread uses (RGB out), made on the first JPEG frame.
fn jpeg(
    slot: &mut Option<FrameConverter>,
    w: u32,
    h: u32,
) -> Result<&mut FrameConverter, ReplayError> {
    if slot.is_none() {
        let max = w as usize * h as usize * 3;
        let c = FrameConverter::new(CaptureFormat::Mjpg, w, h, 0, PixelFormat::Rgb8, max)
            .map_err(|e| ReplayError::Jpeg(Box::new(e)))?;
        *slot = Some(c);
    }
    slot.as_mut()
        .ok_or_else(|| ReplayError::Jpeg(Box::new(std::io::Error::other("no MJPEG converter"))))
}

fn run_generation(
    step: &mut FrameStep,
    stereo: &StereoFrame,
    outcomes: &mut Vec<Option<Outcome>>,
    recorder: Option<&crate::record::Recorder>,
    at: Duration,
) -> Result<u64, ReplayError> {
    let report = step.generation(stereo)?.report;
    let g = report.stats.generation;
    if let Some(r) = recorder {
        r.flies(g, at, step.perception().engine().population());
    }
    let outcome = Outcome {
        global_warning: report.stats.global_warning,
        obstacle: report.tracked.decision_distance(),
        matched: report.stats.matched,
        road: report.road,
        tracked: report.tracked,
        path: step.perception().path_estimate(),
        search_far: step.perception().search_far(),
    };
    // Generations count up by one from 1: this is the next slot.
    if usize::try_from(g).is_ok_and(|i| i == outcomes.len()) {
        outcomes.push(Some(outcome));
    }
    Ok(g)
}

#[cfg(test)]
mod tests {
    use super::decisions::{same, same_opt, unhex};

    #[test]
    fn hex_round_trips() {
        assert_eq!(
            unhex(&crate::record::topics::hex(&[0, 0x7f, 0xff])),
            vec![0, 0x7f, 0xff]
        );
    }

    #[test]
    fn same_compares_bits_and_nan_equals_nan() {
        assert!(same(f64::NAN, f64::NAN));
        assert!(!same(0.1 + 0.2, 0.3));
        assert!(same_opt(None, None));
        assert!(!same_opt(Some(1.0), None));
    }
}
