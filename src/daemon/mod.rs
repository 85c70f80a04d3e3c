//! The real-time daemon: cameras in, CAN frames out.
//!
//! ```text
//!  [flyd-cap-left ]--FrameRing--\                                    
//!                                >--[flyd-evolution]--snapshots-->[flyd-control]--> CAN bus
//!  [flyd-cap-right]--FrameRing--/     pairer, engine   (bounded,     decider, faults,  systemd
//!                                                       try_send)    periods, logs
//! ```
//!
//! - [`capture`]: one thread per camera, `FrameSource::next_frame` straight into a ring slot;
//!   never blocks on a consumer, polls with a timeout, reopens a failing device with backoff.
//! - [`ring`]: lock-free newest-frame slots (triple buffer), drops counted.
//! - [`flyd_core::pairing`]: left/right matching by capture timestamp (pure, in the core).
//! - [`evolution`]: one generation per period on the newest pair, [`Snapshot`]s out with
//!   `try_send` (never blocks).
//! - [`control`]: decisions ([`flyd_core::decision::Decider`]), fault detection
//!   ([`flyd_core::faults`]), CAN frames at fixed periods, logs, systemd notifications
//!   ([`notify`]).
//!
//! # Invariants
//! - Only the control thread writes to the CAN bus and to the systemd socket.
//! - No thread waits on another one's progress: capture and evolution hand over through
//!   lock-free slots and `try_send`; the control thread runs on its own periods and reads
//!   counters. A stalled thread shows up as a fault, never as a stalled pipeline.
//! - The engine never reads a clock; all time comes from the injected
//!   [`crate::os_clock::Clock`], and frame timestamps must be on its timebase (CLOCK_MONOTONIC in
//!   production).
//! - Shutdown (the [`Shutdown`] flag, or a mock scenario's end of stream): the control thread
//!   sends its last command (reason SHUTDOWN) and a status with state SHUTDOWN, then every
//!   thread stops and is joined; this takes at most one capture poll timeout (<= 250 ms).
//! - Nothing on the real-time path returns an error for a runtime fault: faults become fault
//!   bits and the safe command. [`run`] fails only on start-up errors.

pub mod capture;
pub mod control;
pub mod end_to_end_bench;
pub mod evolution;
pub mod hardware;
pub mod notify;
mod recording;
use recording::start_recording;
pub mod ring;
pub mod rows;
pub mod shared_motion;
pub mod snapshot;
pub mod stats;

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use thiserror::Error;

pub use crate::os_clock::{MonotonicClock, SharedClock};
pub use crate::thread::{Shutdown, spawn_named};
pub use control::ControlReport;
pub use end_to_end_bench::{BenchReport, bench_end_to_end, bench_end_to_end_with};
pub use hardware::{Cameras, InterfaceLock, lock_interface};
pub use snapshot::Snapshot;

use crate::config::{ConfigError, DaemonConfig};
use crate::record::recording_bus::RecordingBus;
use crate::source::Side;
use capture::{CameraHealth, CaptureThread};
use control::{ControlThread, Inputs, MotionInputs};
use evolution::{EvolutionCounters, EvolutionThread};
use flyd_core::can::bus::{CanBus, CanReceiver};
use flyd_core::can::motion_monitor::MotionMonitor;
use flyd_core::can::{CanConfigError, Transmitter};
use flyd_core::decision::DecisionConfigError;
use flyd_core::engine::EngineError;
use flyd_core::faults::{FaultConfig, FaultMonitor};
use flyd_core::frame::{FrameError, PreparedImage, StereoFrame};
use flyd_core::frame_step::FrameStep;
use flyd_core::pairing::Pairer;
use flyd_core::perception::{Perception, PerceptionError};
pub use notify::ServiceNotifier;
use ring::frame_ring_of;

/// Why the daemon could not start (runtime faults are not errors: see the module docs).
#[derive(Debug, Error)]
pub enum DaemonError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(
        "CAN interface {iface} is taken: another flyd drives it (lock @{name}); stop it first \
         (systemctl stop flyd)"
    )]
    Lock {
        iface: String,
        name: String,
        #[source]
        error: std::io::Error,
    },
    #[error("engine")]
    Engine(#[from] EngineError),
    #[error("perception")]
    Perception(#[from] PerceptionError),
    #[error(
        "camera {camera} delivers {got_w}x{got_h} but the configuration says {want_w}x{want_h}"
    )]
    CameraSize {
        camera: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("frame buffers")]
    Frame(#[from] FrameError),
    #[error("rectification monitor")]
    Rows(#[from] rows::RowsError),
    #[error("CAN configuration")]
    Can(#[from] CanConfigError),
    #[error("decision configuration")]
    Decision(#[from] DecisionConfigError),
    #[error("CAN bus {target}")]
    Bus {
        target: String,
        #[source]
        error: flyd_core::can::bus::BusError,
    },
    #[error("CAN log {path}")]
    CanLog {
        path: String,
        #[source]
        error: std::io::Error,
    },
    #[error("CAN input")]
    CanInput(#[from] crate::bus::ReplayLogError),
    #[error("mock cameras")]
    MockCameras(#[from] crate::mock::camera::MockCameraError),
    #[error("camera {device}")]
    CameraConfig {
        device: String,
        #[source]
        error: crate::capture::v4l2::V4l2ConfigError,
    },
    #[error("the end-to-end benchmark needs mock cameras with an obstacle: {0}")]
    BenchScenario(String),
    #[error("cannot start thread {thread}")]
    Spawn {
        thread: &'static str,
        #[source]
        error: std::io::Error,
    },
    #[error("thread {thread} panicked")]
    Panicked { thread: &'static str },
    #[error("recorder")]
    Record(#[from] crate::record::WriterError),
}

/// Why the run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    /// The shutdown flag (signal, `--duration`, test).
    Shutdown,
    /// A camera reached its end of stream (a finished mock scenario).
    EndOfStream,
}

/// One camera's figures at the end of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CameraReport {
    pub frames: u64,
    /// Overwritten in the ring before the evolution thread took them.
    pub dropped: u64,
    pub timeouts: u64,
    pub errors: u64,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RunReport {
    pub ended_by: EndReason,
    pub control: ControlReport,
    pub left: CameraReport,
    pub right: CameraReport,
    pub generations: u64,
    pub pairs: u64,
    pub pair_rejects: u64,
    pub snapshots_dropped: u64,
    pub overruns: u64,
    /// The evolution thread stopped on an engine error (already logged; the daemon ran on in
    /// FAULT with the safe command).
    pub evolution_error: Option<EngineError>,
    /// What the recorder wrote (`None`: no `[record]` path and no `[live]` view).
    pub recording: Option<RecordingReport>,
}

/// The recorder's figures at the end of a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingReport {
    pub writer: crate::record::writer::WriterReport,
    /// Records dropped on the real-time side (a full queue, no free buffer).
    pub dropped: u64,
    /// The live view's address, if it listened.
    pub live: Option<std::net::SocketAddr>,
}

const EVOLUTION: &str = "flyd-evolution";
const CONTROL: &str = "flyd-control";
const CAPTURE: [&str; 2] = ["flyd-cap-left", "flyd-cap-right"];

/// The CAN interface as the daemon uses it: frames out, and the vehicle's frames in.
pub struct CanPort {
    pub tx: Box<dyn CanBus>,
    /// `None`: nothing is received (a configured vehicle motion is then MotionFault).
    pub rx: Option<Box<dyn CanReceiver>>,
}

impl<B: CanBus + 'static> From<B> for CanPort {
    /// A bus that only sends.
    fn from(bus: B) -> Self {
        Self {
            tx: Box::new(bus),
            rx: None,
        }
    }
}

/// Runs the daemon on the given hardware until `shutdown` is requested or a camera ends its
/// stream. See the module docs for the threads and their promises.
///
/// `clock` must be the timebase of the cameras' frame timestamps. `notifier` is where the
/// systemd notifications go: [`ServiceNotifier::from_env`] under systemd,
/// [`ServiceNotifier::none`] elsewhere.
pub fn run(
    cameras: Cameras,
    can: impl Into<CanPort>,
    clock: SharedClock,
    config: &DaemonConfig,
    shutdown: Shutdown,
    notifier: ServiceNotifier,
) -> Result<RunReport, DaemonError> {
    let can = can.into();
    let (width, height) = (config.cameras.width, config.cameras.height);
    let flyd_core::calib::Calibration {
        rig,
        right_row_offset_px,
        measure_rows,
        ..
    } = config.load_calibration()?;
    for source in [&cameras.0, &cameras.1] {
        let (w, h) = source.size();
        if (w, h) != (width, height) {
            return Err(DaemonError::CameraSize {
                camera: source.name().to_string(),
                got_w: w,
                got_h: h,
                want_w: width,
                want_h: height,
            });
        }
    }
    let perception = Perception::new(&rig, config.engine.clone(), config.perception)?
        .with_warmup(config.evolution.warmup_generations)
        .with_reach(config.decision);
    tracing::info!(
        judgeable_m = crate::logging::shown(perception.judgeable_distance(), 2),
        "perception: both cameras see the whole corridor from this distance on; a nearer \
         obstacle is confirmed only when seen coming from beyond it"
    );
    // How far the search can reach: as configured, extended with the speed up to what the
    // rig searches (the control thread logs a speed whose SLOW distance is beyond it).
    let search_limit = perception
        .search_far()
        .max(perception.reach().map_or(0.0, |r| r.cap()));
    log_resolution(config, &rig);
    let decision = flyd_core::policy::DecisionStep::new(config.decision)?;
    let recording = start_recording(config, &rig)?;
    let recorder = recording.as_ref().map(|r| r.recorder.clone());
    let tx = Transmitter::new(
        RecordingBus::new(can.tx, recorder.clone(), clock.clone()),
        config.can.messages,
    )?;
    // A recorder keeps the frames as captured: every image that goes round the rings (they
    // are swapped with the engine's) then keeps its packed pixels.
    let image =
        || PreparedImage::new(width, height).map(|i| i.retain_pixels_if(recorder.is_some()));
    // The right camera's images carry the row correction (they stay on their side: the
    // evolution thread swaps left with left, right with right): the calibration's, until the
    // `flyd-rows` worker measures another (the right capture thread sets it on each frame).
    let row_shift = rows::SharedRowShift::new(right_row_offset_px);
    let right_image = || image().map(|i| i.with_row_shift(right_row_offset_px));
    let (left_writer, left_reader) = frame_ring_of(image()?);
    let (right_writer, right_reader) = frame_ring_of(right_image()?);
    let stereo = StereoFrame::new(image()?, right_image()?, 0);
    let (snapshot_tx, snapshot_rx) = crossbeam_channel::bounded(config.evolution.snapshot_queue);

    let stop = Shutdown::new();
    let finish = Shutdown::new();
    let health = [
        Arc::new(CameraHealth::default()),
        Arc::new(CameraHealth::default()),
    ];
    let rings = [
        left_writer.counters().clone(),
        right_writer.counters().clone(),
    ];
    let evolution_counters = Arc::new(EvolutionCounters::default());
    let motion = shared_motion::SharedMotion::default();
    // At least a frame period, at most 250 ms (a stop request is seen within that).
    let max_poll = Duration::from_millis(250);
    let poll_timeout = config
        .cameras
        .stale_timeout()
        .max(config.cameras.frame_period().min(max_poll))
        .min(max_poll);

    let mut threads = Threads {
        captures: Vec::new(),
        evolution: None,
        rows: None,
        stop: stop.clone(),
    };
    let (left_source, right_source) = cameras;
    for ((side, source), writer) in [(Side::Left, left_source), (Side::Right, right_source)]
        .into_iter()
        .zip([left_writer, right_writer])
    {
        let index = side as usize;
        let thread = CaptureThread {
            side,
            source,
            writer,
            health: health[index].clone(),
            clock: clock.clone(),
            poll_timeout,
            stop: stop.clone(),
            finish: finish.clone(),
            recorder: recorder.clone(),
            row_shift: (side == Side::Right).then(|| row_shift.clone()),
        };
        let name = CAPTURE[index];
        let handle =
            spawn_named(name, move || thread.run()).map_err(|error| DaemonError::Spawn {
                thread: name,
                error,
            })?;
        threads.captures.push((name, handle));
    }

    // The right image's rows, measured now and then (corners up to the nearest depth's
    // disparity).
    let (rows_monitor, rows_worker) = rows::RowsMonitor::start(
        width,
        height,
        flyd_core::rectification::max_disparity(&rig, config.engine.min_depth),
        rows::RowsPolicy {
            measure: measure_rows,
            rectified: rig.is_rectified(),
            shift: row_shift,
        },
    )?;
    threads.rows = Some(rows_worker);
    let evolution = EvolutionThread {
        step: FrameStep::new(perception, config.step_config()),
        left: left_reader,
        right: right_reader,
        pairer: Pairer::new(config.cameras.timestamp_tolerance),
        stereo,
        snapshots: snapshot_tx,
        counters: evolution_counters.clone(),
        clock: clock.clone(),
        config: config.evolution,
        stop: stop.clone(),
        road_source: None,
        motion: config.motion().map(|_| motion.clone()),
        recorder: recorder.clone(),
        rows: Some(rows_monitor),
        mount: flyd_core::perception::mount_check::MountCheck::default(),
        declared_height: rig.left.centre().y,
        max_height_change: config.perception.road.max_height_change,
        mount_report: flyd_core::perception::mount_check::MountCheck::default().report(),
    };
    threads.evolution = Some(
        spawn_named(EVOLUTION, move || evolution.run()).map_err(|error| DaemonError::Spawn {
            thread: EVOLUTION,
            error,
        })?,
    );

    let start = clock.now();
    let control = ControlThread {
        tx,
        decision,
        monitor: FaultMonitor::new(
            FaultConfig {
                stale_timeout: config.cameras.stale_timeout(),
                snapshot_timeout: config.control.snapshot_timeout,
                startup_timeout: config.control.startup_timeout,
            },
            start,
        ),
        notifier,
        inputs: Inputs {
            snapshots: snapshot_rx,
            left: health[0].clone(),
            right: health[1].clone(),
            left_ring: rings[0].clone(),
            right_ring: rings[1].clone(),
            evolution: evolution_counters.clone(),
        },
        clock: clock.clone(),
        can_silence: config.control.can_silence,
        assumed_speed: config.vehicle.assumed_speed,
        frame_period: config.cameras.frame_period(),
        range: search_limit,
        motion: config.motion().map(|m| MotionInputs {
            monitor: MotionMonitor::new(m),
            id: config.can.messages.motion.id,
            rx: can.rx,
            shared: motion.clone(),
        }),
        can: config.can.messages,
        stats_interval: config.logging.stats_interval,
        shutdown: shutdown.clone(),
        finish: finish.clone(),
        recorder: recorder.clone(),
    };
    drop(recorder);
    let control_report = spawn_named(CONTROL, move || control.run())
        .map_err(|error| DaemonError::Spawn {
            thread: CONTROL,
            error,
        })?
        .join()
        .map_err(|_| DaemonError::Panicked { thread: CONTROL })?;

    let evolution_error = threads.join()?;
    // Every thread has dropped its recorder handle: the writer drains the queue and closes.
    let recording = match recording {
        Some(r) => Some(r.finish()?),
        None => None,
    };
    let camera = |i: usize| CameraReport {
        frames: rings[i].published(),
        dropped: rings[i].dropped(),
        timeouts: health[i].timeouts(),
        errors: health[i].errors(),
    };
    let c = &evolution_counters;
    use std::sync::atomic::Ordering::Relaxed;
    Ok(RunReport {
        ended_by: if shutdown.is_requested() {
            EndReason::Shutdown
        } else {
            EndReason::EndOfStream
        },
        control: control_report,
        left: camera(0),
        right: camera(1),
        generations: c.generations.load(Relaxed),
        pairs: c.pairs.load(Relaxed),
        pair_rejects: c.pair_rejects.load(Relaxed),
        snapshots_dropped: c.snapshots_dropped.load(Relaxed),
        overruns: c.overruns.load(Relaxed),
        evolution_error,
        recording,
    })
}

/// Logs how well the rig resolves the SLOW distance at the assumed speed: a warning when one
/// pixel of disparity there is more than the decision's margin.
fn log_resolution(config: &DaemonConfig, rig: &flyd_core::geometry::StereoRig) {
    let Some(r) = config.resolution(rig) else {
        return;
    };
    // One event, its level and message by case (tracing's levels are constants).
    macro_rules! resolution {
        ($level:ident, $message:expr) => {
            tracing::$level!(
                speed_kmh = crate::logging::shown(r.speed * 3.6, 1),
                slow_distance_m = crate::logging::shown(r.slow_distance, 2),
                depth_error_per_px_m = crate::logging::shown(r.error_per_pixel, 2),
                margin_m = crate::logging::shown(r.margin, 2),
                resolved_m = crate::logging::shown(r.resolved, 2),
                $message
            )
        };
    }
    let mock = config.calibration == crate::config::CalibrationSource::BuiltinMock;
    if r.enough() {
        resolution!(
            info,
            "the rig resolves the SLOW distance at the assumed speed within the margin"
        );
    } else if mock {
        // hw-mock's simulated pair: what it resolves is a fact of the demo, not a fault of
        // the configuration.
        resolution!(
            info,
            "the built-in mock rig resolves less than the SLOW distance at the assumed speed \
             within the margin (a real rig is warned about)"
        );
    } else {
        resolution!(
            warn,
            "the rig cannot resolve the SLOW distance at the assumed speed: one pixel of \
             disparity there (Z^2 / (f B)) is more depth than the decision's margin \
             (`flyd check-config` says what would)"
        );
    }
}

/// The worker threads; dropping it (an early return) stops and joins them.
struct Threads {
    captures: Vec<(&'static str, JoinHandle<()>)>,
    evolution: Option<JoinHandle<Result<(), EngineError>>>,
    /// The rows worker: ends once the evolution thread (its only sender) has.
    rows: Option<JoinHandle<()>>,
    stop: Shutdown,
}

impl Threads {
    /// Stops and joins every thread; returns the evolution thread's error, if any.
    fn join(&mut self) -> Result<Option<EngineError>, DaemonError> {
        self.stop.request();
        let mut panicked = None;
        let mut evolution_error = None;
        if let Some(handle) = self.evolution.take() {
            match handle.join() {
                Ok(result) => evolution_error = result.err(),
                Err(_) => panicked = Some(EVOLUTION),
            }
        }
        for (name, handle) in self.captures.drain(..) {
            if handle.join().is_err() {
                panicked = Some(name);
            }
        }
        if let Some(handle) = self.rows.take()
            && handle.join().is_err()
        {
            panicked = Some(rows::THREAD);
        }
        match panicked {
            Some(thread) => Err(DaemonError::Panicked { thread }),
            None => Ok(evolution_error),
        }
    }
}

impl Drop for Threads {
    fn drop(&mut self) {
        // Errors were reported by `join` already, or the caller is returning another error.
        let _ = self.join();
    }
}
