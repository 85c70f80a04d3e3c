//! Test hardware for the threaded daemon: a stereo rig, cameras that render an analytic scene
//! (a textured "pedestrian" panel on a textured road) and can be told to show the
//! obstacle, stall, or end, and helpers to run `flyd::daemon::run` in the background and decode
//! what it sent.
#![allow(dead_code)] // each test binary uses a part of it

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use flyd::bus::{MemoryBus, MemoryRx, RecordedFrame};
use flyd::config::DaemonConfig;
use flyd::daemon::{self, MonotonicClock, RunReport, SharedClock, Shutdown};
use flyd::source::{FrameMeta, FrameSource, SourceError};
use flyd_core::can::messages::{
    AliveCounter, CanMessage, CommandMsg, ObstacleMotionMsg, ObstacleMsg, PathMsg, StatusMsg,
};
use flyd_core::decision::DecisionConfig;
use flyd_core::decision::{Command, CommandReason};
use flyd_core::engine::EngineParams;
use flyd_core::frame::{PixelFormat, PreparedImage};
use flyd_core::geometry::{Camera, Distortion, StereoRig};
use flyd_core::status::State;

pub const W: u32 = 160;
pub const H: u32 = 120;
/// Depth of the obstacle panel, metres.
pub const OBSTACLE_Z: f64 = 3.0;

pub fn rig() -> StereoRig {
    flyd_core::test_support::small_rig(Distortion::default())
}

fn hash(ix: i64, iy: i64) -> f64 {
    let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Depth of the textured backdrop behind everything, metres: beyond the corridor's reach, so
/// flies that find it see no obstacle.
pub const BACKDROP_Z: f64 = 80.0;

/// Grey image of `cam`: a textured panel (|x| <= 0.6 m, 0 <= y <= 1.8 m) at z = OBSTACLE_Z
/// when `obstacle`, on a textured road (the plane y = 0) before a textured backdrop at
/// BACKDROP_Z (a real camera never sees a uniform world: the sensor checks take that for a
/// covered lens).
fn render(cam: &Camera, obstacle: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity((W * H) as usize);
    for v in 0..H {
        for u in 0..W {
            let (o, d) = cam.ray_from_pixel(u as f64, v as f64).expect("ray");
            let p = o + d * ((OBSTACLE_Z - o.z) / d.z);
            let on_panel = obstacle && p.x.abs() <= 0.6 && (0.0..=1.8).contains(&p.y);
            let value = if on_panel {
                let cell = 0.04;
                40.0 + 180.0 * hash((p.x / cell).floor() as i64, (p.y / cell).floor() as i64)
            } else if d.y < 0.0 && (o + d * (-o.y / d.y)).z < BACKDROP_Z {
                // The road: a textured ground plane (height 0, no obstacle).
                let g = o + d * (-o.y / d.y);
                let cell = 0.3;
                60.0 + 120.0
                    * hash(
                        2_000 + (g.x / cell).floor() as i64,
                        (g.z / cell).floor() as i64,
                    )
            } else {
                let b = o + d * ((BACKDROP_Z - o.z) / d.z);
                let cell = 1.5;
                70.0 + 110.0
                    * hash(
                        1_000 + (b.x / cell).floor() as i64,
                        (b.y / cell).floor() as i64,
                    )
            };
            out.push(value as u8);
        }
    }
    out
}

/// What the test tells the cameras; shared by both.
#[derive(Debug, Default)]
pub struct SceneControl {
    pub obstacle: AtomicBool,
    pub stall_left: AtomicBool,
    pub stall_right: AtomicBool,
    /// End the stream after this many frames (0 = never).
    pub end_after: AtomicU64,
    /// Added to the right camera's timestamps, microseconds (stereo skew).
    pub right_offset_us: AtomicI64,
    /// Capture timestamp of the first frame that showed the obstacle (ns; 0 = none yet).
    pub first_obstacle_frame_ns: AtomicU64,
}

/// One camera of the scene, paced at `fps` on the shared clock. Both cameras stamp frame `k`
/// with `start + k / fps`, so they pair exactly unless told otherwise.
pub struct SceneCamera {
    name: String,
    right: bool,
    images: [Vec<u8>; 2],
    control: Arc<SceneControl>,
    clock: SharedClock,
    start: Duration,
    period: Duration,
    next: u64,
    /// The frame delivered: the image with this frame's sensor noise.
    noisy: Vec<u8>,
}

/// Sensor noise of the scene cameras, grey levels either side (a live sensor's frames never
/// repeat exactly: the sensor checks take a repeated one for a frozen camera).
pub const NOISE: u64 = 2;

impl SceneCamera {
    pub fn pair(
        control: &Arc<SceneControl>,
        clock: &SharedClock,
        fps: f64,
    ) -> (Box<dyn FrameSource>, Box<dyn FrameSource>) {
        let rig = rig();
        let start = clock.now();
        let make = |cam: &Camera, right: bool| -> Box<dyn FrameSource> {
            Box::new(SceneCamera {
                name: if right { "scene:right" } else { "scene:left" }.into(),
                right,
                images: [render(cam, false), render(cam, true)],
                control: control.clone(),
                clock: clock.clone(),
                start,
                period: Duration::from_secs_f64(1.0 / fps),
                next: 0,
                noisy: vec![0; (W * H) as usize],
            })
        };
        (make(&rig.left, false), make(&rig.right, true))
    }
}

impl FrameSource for SceneCamera {
    fn name(&self) -> &str {
        &self.name
    }
    fn size(&self) -> (u32, u32) {
        (W, H)
    }
    fn next_frame(
        &mut self,
        out: &mut PreparedImage,
        timeout: Duration,
    ) -> Result<FrameMeta, SourceError> {
        let c = &self.control;
        let end = c.end_after.load(Ordering::Relaxed);
        if end > 0 && self.next >= end {
            return Err(SourceError::EndOfStream);
        }
        let stalled = if self.right {
            &c.stall_right
        } else {
            &c.stall_left
        };
        if stalled.load(Ordering::Relaxed) {
            std::thread::sleep(timeout);
            return Err(SourceError::Timeout(timeout));
        }
        // The frame due next on this camera's schedule; frames missed (stall, late thread)
        // are skipped as a real camera's would be.
        let now = self.clock.now();
        let elapsed = now.saturating_sub(self.start).as_nanos() as u64;
        let period = self.period.as_nanos() as u64;
        let k = self.next.max(elapsed.div_ceil(period));
        let due = self.start + Duration::from_nanos(k * period);
        if due > now {
            std::thread::sleep(due - now);
        }
        self.next = k + 1;
        let obstacle = c.obstacle.load(Ordering::Relaxed);
        let seed = (k as i64) << 1 | self.right as i64;
        for (i, (n, &v)) in self
            .noisy
            .iter_mut()
            .zip(&self.images[obstacle as usize])
            .enumerate()
        {
            let e = (hash(seed, i as i64) * (2 * NOISE + 1) as f64) as i64 - NOISE as i64;
            *n = (i64::from(v) + e).clamp(0, 255) as u8;
        }
        out.prepare(PixelFormat::Grey8, &self.noisy)
            .map_err(|e| SourceError::Format {
                device: self.name.clone(),
                reason: "preparing a frame".into(),
                cause: Some(e.into()),
            })?;
        let mut timestamp = due;
        if self.right {
            let offset = c.right_offset_us.load(Ordering::Relaxed);
            timestamp = if offset >= 0 {
                timestamp + Duration::from_micros(offset as u64)
            } else {
                timestamp.saturating_sub(Duration::from_micros(offset.unsigned_abs()))
            };
        } else if obstacle {
            let _ = c.first_obstacle_frame_ns.compare_exchange(
                0,
                timestamp.as_nanos() as u64,
                Ordering::Relaxed,
                Ordering::Relaxed,
            );
        }
        Ok(FrameMeta {
            timestamp,
            sequence: k,
        })
    }
}

/// A daemon configuration for the scene: small population, short holds and periods.
pub fn config() -> DaemonConfig {
    let mut c = DaemonConfig::with_rig(rig());
    c.cameras.stale_frames = 6;
    c.engine = EngineParams {
        flies: 600,
        min_depth: 1.0,
        max_depth: 20.0,
        ..EngineParams::default()
    };
    c.decision = DecisionConfig {
        slow_hold: Duration::from_millis(200),
        stop_hold: Duration::from_millis(300),
        ..DecisionConfig::default()
    };
    c.evolution.generation_period = Some(Duration::from_millis(5));
    // Debug builds on a shared machine: only a stuck evolution is an overrun here.
    c.evolution.max_generation_time = Duration::from_secs(1);
    c.control.snapshot_timeout = Duration::from_secs(1);
    c.logging.stats_interval = Duration::from_millis(500);
    c
}

/// A daemon running in the background on scene cameras and a memory bus.
pub struct Running {
    pub control: Arc<SceneControl>,
    pub bus: MemoryBus,
    pub shutdown: Shutdown,
    pub clock: SharedClock,
    handle: Option<JoinHandle<Result<RunReport, daemon::DaemonError>>>,
}

/// Deadlock guard for every wait: generous, never a timing assertion.
pub const GUARD: Duration = Duration::from_secs(60);

pub fn start(config: DaemonConfig) -> Running {
    start_with(config, Arc::new(SceneControl::default()))
}

pub fn start_with(config: DaemonConfig, control: Arc<SceneControl>) -> Running {
    start_receiving(config, control, None)
}

/// As [`start_with`], with `rx` as the frames the daemon receives (the vehicle's motion).
pub fn start_receiving(
    config: DaemonConfig,
    control: Arc<SceneControl>,
    rx: Option<MemoryRx>,
) -> Running {
    launch(config, control, rx, daemon::ServiceNotifier::none())
}

/// As [`start`], notifying systemd through `notifier` (a socket the test binds).
pub fn start_notifying(config: DaemonConfig, notifier: daemon::ServiceNotifier) -> Running {
    launch(config, Arc::new(SceneControl::default()), None, notifier)
}

fn launch(
    config: DaemonConfig,
    control: Arc<SceneControl>,
    rx: Option<MemoryRx>,
    notifier: daemon::ServiceNotifier,
) -> Running {
    let _ = tracing_subscriber::fmt()
        .with_test_writer()
        .with_max_level(tracing::Level::INFO)
        .try_init();
    let clock = MonotonicClock::shared();
    let bus_clock = clock.clone();
    let bus = MemoryBus::new(move || bus_clock.now());
    let cameras = SceneCamera::pair(&control, &clock, config.cameras.fps);
    let shutdown = Shutdown::new();
    let (b, c, s) = (bus.clone(), clock.clone(), shutdown.clone());
    let handle = daemon::spawn_named("test-daemon", move || {
        let port = daemon::CanPort {
            tx: Box::new(b),
            rx: rx.map(|rx| Box::new(rx) as Box<dyn flyd_core::can::bus::CanReceiver>),
        };
        daemon::run(cameras, port, c, &config, s, notifier)
    })
    .expect("spawn");
    Running {
        control,
        bus,
        shutdown,
        clock,
        handle: Some(handle),
    }
}

impl Running {
    /// Waits (deadlock guard [`GUARD`]) until `pred` holds for the decoded frames so far.
    pub fn wait_for(&self, what: &str, pred: impl Fn(&[Frame]) -> bool) -> Vec<Frame> {
        let t0 = Instant::now();
        loop {
            let frames = decode_all(&self.bus.frames());
            if pred(&frames) {
                return frames;
            }
            let finished = self.handle.as_ref().is_none_or(|h| h.is_finished());
            assert!(
                !finished && t0.elapsed() < GUARD,
                "gave up waiting for {what} (daemon finished: {finished}); frames: {}",
                summary(&frames)
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Requests shutdown and joins the daemon.
    pub fn stop(mut self) -> (RunReport, Vec<Frame>) {
        self.shutdown.request();
        self.join()
    }

    /// Joins a daemon that ends by itself (end of stream), within the guard.
    pub fn join(&mut self) -> (RunReport, Vec<Frame>) {
        let handle = self.handle.take().expect("joined once");
        let t0 = Instant::now();
        while !handle.is_finished() {
            assert!(t0.elapsed() < GUARD, "daemon did not stop");
            std::thread::sleep(Duration::from_millis(5));
        }
        let report = handle.join().expect("no panic").expect("run succeeds");
        (report, decode_all(&self.bus.frames()))
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.shutdown.request();
    }
}

/// A decoded frame: every frame must pass the CRC and counter checks.
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    Command(CommandMsg, AliveCounter),
    Status(StatusMsg, AliveCounter),
    Obstacle(ObstacleMsg, AliveCounter),
    Path(PathMsg, AliveCounter),
    ObstacleMotion(ObstacleMotionMsg, AliveCounter),
}

pub fn decode(f: &RecordedFrame) -> Frame {
    fn ctx<T>(f: &RecordedFrame) -> impl Fn(flyd_core::can::messages::DecodeError) -> T + '_ {
        move |e| panic!("frame {:#x} {:02x?} does not decode: {e}", f.id, f.data)
    }
    match f.id {
        0x120 => {
            let (m, c) = CommandMsg::decode_with(&f.data, CommandMsg::DEFAULT_DATA_ID)
                .unwrap_or_else(ctx(f));
            Frame::Command(m, c)
        }
        0x121 => {
            let (m, c) =
                StatusMsg::decode_with(&f.data, StatusMsg::DEFAULT_DATA_ID).unwrap_or_else(ctx(f));
            Frame::Status(m, c)
        }
        0x122 => {
            let (m, c) = ObstacleMsg::decode_with(&f.data, ObstacleMsg::DEFAULT_DATA_ID)
                .unwrap_or_else(ctx(f));
            Frame::Obstacle(m, c)
        }
        0x123 => {
            let (m, c) =
                PathMsg::decode_with(&f.data, PathMsg::DEFAULT_DATA_ID).unwrap_or_else(ctx(f));
            Frame::Path(m, c)
        }
        0x124 => {
            let (m, c) =
                ObstacleMotionMsg::decode_with(&f.data, ObstacleMotionMsg::DEFAULT_DATA_ID)
                    .unwrap_or_else(ctx(f));
            Frame::ObstacleMotion(m, c)
        }
        id => panic!("unexpected CAN id {id:#x}"),
    }
}

pub fn decode_all(frames: &[RecordedFrame]) -> Vec<Frame> {
    frames.iter().map(decode).collect()
}

/// The messages of variant `$kind` of `Frame` among `$frames`.
macro_rules! messages {
    ($frames:expr, $kind:path) => {
        $frames
            .iter()
            .filter_map(|f| if let $kind(m, _) = f { Some(*m) } else { None })
            .collect()
    };
}

pub fn obstacle_motions(frames: &[Frame]) -> Vec<ObstacleMotionMsg> {
    messages!(frames, Frame::ObstacleMotion)
}

pub fn paths(frames: &[Frame]) -> Vec<PathMsg> {
    messages!(frames, Frame::Path)
}

pub fn commands(frames: &[Frame]) -> Vec<CommandMsg> {
    messages!(frames, Frame::Command)
}

pub fn statuses(frames: &[Frame]) -> Vec<StatusMsg> {
    messages!(frames, Frame::Status)
}

/// The alive counters of one message kind, in order.
pub fn counters(frames: &[Frame], kind: fn(&Frame) -> Option<AliveCounter>) -> Vec<AliveCounter> {
    frames.iter().filter_map(kind).collect()
}

pub fn command_counter(f: &Frame) -> Option<AliveCounter> {
    match f {
        Frame::Command(_, c) => Some(*c),
        _ => None,
    }
}
pub fn status_counter(f: &Frame) -> Option<AliveCounter> {
    match f {
        Frame::Status(_, c) => Some(*c),
        _ => None,
    }
}
pub fn obstacle_counter(f: &Frame) -> Option<AliveCounter> {
    match f {
        Frame::Obstacle(_, c) => Some(*c),
        _ => None,
    }
}
pub fn obstacle_motion_counter(f: &Frame) -> Option<AliveCounter> {
    match f {
        Frame::ObstacleMotion(_, c) => Some(*c),
        _ => None,
    }
}
pub fn path_counter(f: &Frame) -> Option<AliveCounter> {
    match f {
        Frame::Path(_, c) => Some(*c),
        _ => None,
    }
}

/// Each counter is the previous one + 1 (mod 15): no frame lost or repeated.
pub fn assert_consecutive(counters: &[AliveCounter], what: &str) {
    for pair in counters.windows(2) {
        assert_eq!(
            pair[0].delta(pair[1]),
            1,
            "{what}: counter {:?} then {:?}",
            pair[0],
            pair[1]
        );
    }
}

pub fn is_running_clear(frames: &[Frame]) -> bool {
    statuses(frames).iter().any(|s| s.state == State::Running)
        && commands(frames)
            .iter()
            .any(|c| c.command == Command::Clear && c.reason == CommandReason::Perception)
}

/// A short account of the frames for failure messages.
pub fn summary(frames: &[Frame]) -> String {
    let mut out = String::new();
    let mut last = String::new();
    let mut n = 0;
    for f in frames {
        let s = match f {
            Frame::Command(m, _) => format!("cmd {} {}", m.command, m.reason),
            Frame::Status(m, _) => format!("status {} {}", m.state, m.faults),
            Frame::Obstacle(..) | Frame::Path(..) | Frame::ObstacleMotion(..) => continue,
        };
        if s == last {
            n += 1;
        } else {
            if n > 0 {
                out.push_str(&format!("{last} x{n}; "));
            }
            last = s;
            n = 1;
        }
    }
    out.push_str(&format!("{last} x{n}"));
    out
}
