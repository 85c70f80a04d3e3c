//! The daemon's configuration file (`flyd run --config FILE`, `flyd check-config FILE`).
//!
//! TOML, every table `deny_unknown_fields`: a misspelt key is an error, not a silently ignored
//! setting. Every error names the file and the key (dotted, as written in the file), e.g.
//! `config file /etc/flyd/flyd.toml: key 'engine.max_depth': must be greater than min_depth`.
//! `config/flyd.toml` documents every key; `config/demo.toml` is the mock demo.
//!
//! Loading ([`DaemonConfig::load`]) checks syntax, types and impossible values (depth range,
//! thresholds out of order, zero periods, ...). [`check`] additionally loads the calibration and
//! builds an engine once, which is what `flyd check-config` and start-up run.
//!
//! Tests build a [`DaemonConfig`] in code ([`DaemonConfig::with_rig`]) rather than from text.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use thiserror::Error;

use crate::capture::CaptureFormat;
use flyd_core::calib::{self, CalibError};
use flyd_core::can::CanConfig;
use flyd_core::decision::Command;
use flyd_core::decision::{DecisionConfig, DecisionConfigError};
use flyd_core::engine::{Engine, EngineError, EngineParams};
use flyd_core::geometry::StereoRig;
use flyd_core::status::FaultBits;

/// Why a configuration cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("config file {}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        error: std::io::Error,
    },
    /// Syntax, an unknown key, a wrong type or a missing key.
    #[error("config file {}: {}{message}", file.display(), key_prefix(key))]
    Parse {
        file: PathBuf,
        key: Option<String>,
        message: String,
    },
    /// A well-formed value that cannot work.
    #[error("config file {}: key '{key}': {reason}", file.display())]
    Invalid {
        file: PathBuf,
        key: String,
        reason: String,
    },
    /// The calibration the config points to cannot be loaded.
    #[error("config file {}: key 'calibration'", file.display())]
    Calibration {
        file: PathBuf,
        #[source]
        error: CalibError,
    },
}

fn key_prefix(key: &Option<String>) -> String {
    key.as_ref()
        .map(|k| format!("key '{k}': "))
        .unwrap_or_default()
}

impl ConfigError {
    /// The offending key, dotted (`engine.max_depth`), when the error is about one.
    pub fn key(&self) -> Option<&str> {
        match self {
            Self::Io { .. } => None,
            Self::Parse { key, .. } => key.as_deref(),
            Self::Invalid { key, .. } => Some(key),
            Self::Calibration { .. } => Some("calibration"),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The resolved configuration

/// Where the frames come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraSource {
    /// Two V4L2 devices.
    Devices { left: PathBuf, right: PathBuf },
    /// A hw-mock scenario rendered for both cameras (`mock = "pedestrian-steps-in"`).
    Mock { scenario: String },
}

#[derive(Debug, Clone, PartialEq)]
pub struct CamerasConfig {
    pub source: CameraSource,
    pub width: u32,
    pub height: u32,
    /// Nominal frame rate, frames per second (a whole number for V4L2 devices).
    pub fps: f64,
    pub pixel_format: CaptureFormat,
    /// Left and right frames further apart than this (capture timestamps) are not a pair.
    pub timestamp_tolerance: Duration,
    /// A camera with no frame for this many frame periods is stale (fault).
    pub stale_frames: u32,
}

impl CamerasConfig {
    pub fn frame_period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.fps)
    }

    /// No frame for this long: the camera is stale.
    pub fn stale_timeout(&self) -> Duration {
        Duration::from_secs_f64(f64::from(self.stale_frames) / self.fps)
    }
}

/// Where the stereo rig comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum CalibrationSource {
    /// A calibration file (absolute, or resolved against the config file's directory).
    File(PathBuf),
    /// The rig hw-mock renders with (`builtin = "mock"`), at the cameras' size.
    BuiltinMock,
    /// A rig given in code (tests).
    Rig(Box<StereoRig>),
}

/// The evolution thread's timing and its nearest-obstacle estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvolutionConfig {
    /// One generation per period; `None` runs generations back to back.
    pub generation_period: Option<Duration>,
    /// Generations run back to back, without waiting for the period, when a new pair shows
    /// a change (the engine's change map is not empty): the population converges on what
    /// appeared within the frame that showed it instead of over several periods. 1 = none.
    pub burst_generations: u32,
    /// A generation longer than this is an overrun (fault EVOLUTION_OVERRUN).
    pub max_generation_time: Duration,
    /// Generations before the danger is trusted: the initial random population gives chance
    /// matches a large weight until it has converged on the scene (the paper: 10 to 30).
    /// Until then the state stays INIT and the command the safe one.
    pub warmup_generations: u64,
    /// Capacity of the snapshot channel to the control thread.
    pub snapshot_queue: usize,
    /// Consecutive rejected left/right candidates before STEREO_SKEW is raised.
    pub skew_fault_rejects: u32,
    /// Fraction of matching flies (the engine's `matched`) under which a new pair counts as
    /// matching nowhere (measured on hw-mock: 0.97-0.98 converged, 0.77 for the random initial
    /// flies, 0.03-0.04 with a camera delivering noise). 0 disables the check.
    pub blind_matched: f64,
    /// Consecutive new pairs matching nowhere before CAMERA_ERROR (perception blind).
    pub blind_pairs: u32,
    /// Half-width of the vehicle's lane, metres (vehicle x): flies outside it are not obstacles.
    pub lane_half_width: f64,
    /// How many of the fittest in-lane flies the nearest-obstacle estimate looks at.
    pub obstacle_best_flies: usize,
    /// Fewer fit in-lane flies than this: no obstacle is reported.
    pub obstacle_min_flies: usize,
}

impl Default for EvolutionConfig {
    fn default() -> Self {
        Self {
            generation_period: Some(Duration::from_millis(10)),
            burst_generations: 12,
            max_generation_time: Duration::from_millis(50),
            warmup_generations: 30,
            snapshot_queue: 64,
            skew_fault_rejects: 3,
            blind_matched: 0.25,
            blind_pairs: 3,
            lane_half_width: 1.0,
            obstacle_best_flies: 50,
            obstacle_min_flies: 5,
        }
    }
}

/// The control thread's supervision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlConfig {
    /// No snapshot for this long: SNAPSHOT_STALE.
    pub snapshot_timeout: Duration,
    /// Not running (both cameras delivering, a generation done) this long after start: the
    /// stale faults are raised instead of waiting in INIT.
    pub startup_timeout: Duration,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            snapshot_timeout: Duration::from_millis(100),
            startup_timeout: Duration::from_secs(5),
        }
    }
}

/// Where the CAN frames go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CanTarget {
    /// A SocketCAN interface (`can0`, `vcan0`).
    Interface(String),
    /// candump log lines to a file (`-` = stdout), written as if on `iface`.
    Log { path: PathBuf, iface: String },
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CanSection {
    pub target: CanTarget,
    pub messages: CanConfig,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// JSON lines when stdout is not a terminal (journald), human-readable on a terminal.
    Auto,
    Json,
    Human,
}

#[derive(Debug, Clone, PartialEq)]
pub struct LoggingConfig {
    pub format: LogFormat,
    /// Maximum level: error, warn, info, debug, trace.
    pub level: tracing::Level,
    /// Period of the stats event.
    pub stats_interval: Duration,
}

impl Default for LoggingConfig {
    fn default() -> Self {
        Self {
            format: LogFormat::Auto,
            level: tracing::Level::INFO,
            stats_interval: Duration::from_secs(10),
        }
    }
}

/// Everything `flyd run` needs besides the hardware handles.
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonConfig {
    /// The file this came from (for messages); `None` when built in code.
    pub file: Option<PathBuf>,
    pub cameras: CamerasConfig,
    pub calibration: CalibrationSource,
    pub engine: EngineParams,
    pub decision: DecisionConfig,
    pub evolution: EvolutionConfig,
    pub control: ControlConfig,
    pub can: CanSection,
    pub logging: LoggingConfig,
}

impl DaemonConfig {
    /// A configuration for a rig given in code: 30 fps cameras of the rig's size, default
    /// everything else, CAN to a candump log on stdout (tests replace the bus anyway).
    pub fn with_rig(rig: StereoRig) -> Self {
        let (width, height) = (rig.left.width(), rig.left.height());
        Self {
            file: None,
            cameras: CamerasConfig {
                source: CameraSource::Mock {
                    scenario: "in-code".into(),
                },
                width,
                height,
                fps: 30.0,
                pixel_format: CaptureFormat::Yuyv,
                timestamp_tolerance: Duration::from_millis(10),
                stale_frames: 3,
            },
            calibration: CalibrationSource::Rig(Box::new(rig)),
            engine: EngineParams::default(),
            decision: DecisionConfig::default(),
            evolution: EvolutionConfig::default(),
            control: ControlConfig::default(),
            can: CanSection {
                target: CanTarget::Log {
                    path: "-".into(),
                    iface: "vcan0".into(),
                },
                messages: CanConfig::default(),
            },
            logging: LoggingConfig::default(),
        }
    }

    /// Reads and checks a config file (syntax, types, values; not the calibration file).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Io {
            file: path.to_path_buf(),
            error,
        })?;
        Self::from_toml(&text, path)
    }

    /// Parses config text; `path` is where it came from (for messages and relative paths).
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            file: path.to_path_buf(),
            key: e.span().and_then(|span| key_at(text, span.start)),
            message: e.message().trim_end().to_string(),
        })?;
        raw.resolve(path)
            .map_err(|(key, reason)| ConfigError::Invalid {
                file: path.to_path_buf(),
                key,
                reason,
            })
    }

    fn file_for_messages(&self) -> PathBuf {
        self.file
            .clone()
            .unwrap_or_else(|| PathBuf::from("<built-in>"))
    }

    /// The rig at the cameras' size, as the engine will use it.
    pub fn load_rig(&self) -> Result<StereoRig, ConfigError> {
        let file = self.file_for_messages();
        let invalid = |reason: String| ConfigError::Invalid {
            file: file.clone(),
            key: "calibration".into(),
            reason,
        };
        let rig = match &self.calibration {
            CalibrationSource::Rig(rig) => (**rig).clone(),
            CalibrationSource::File(path) => {
                calib::load(path)
                    .map_err(|error| ConfigError::Calibration {
                        file: file.clone(),
                        error,
                    })?
                    .rig
            }
            CalibrationSource::BuiltinMock => {
                crate::mock::mock_rig(self.cameras.width, self.cameras.height)
                    .map_err(|e| invalid(format!("built-in mock rig: {e}")))?
            }
        };
        for (side, cam) in [("left", &rig.left), ("right", &rig.right)] {
            if (cam.width(), cam.height()) != (self.cameras.width, self.cameras.height) {
                return Err(invalid(format!(
                    "the {side} camera is calibrated at {}x{} but cameras.width x cameras.height \
                     is {}x{}",
                    cam.width(),
                    cam.height(),
                    self.cameras.width,
                    self.cameras.height
                )));
            }
        }
        Ok(rig)
    }
}

/// Everything start-up checks before opening any device: the config, the calibration, and an
/// engine built once on them (common field of view over the depth range).
pub fn check(path: &Path) -> Result<DaemonConfig, ConfigError> {
    let config = DaemonConfig::load(path)?;
    let rig = config.load_rig()?;
    Engine::new(&rig, config.engine.clone()).map_err(|e| {
        let key = match &e {
            EngineError::Param(p) => format!("engine.{}", p.key),
            EngineError::NoCommonView { .. } => "engine.max_depth".into(),
            EngineError::NotInvertible | EngineError::FrameSize { .. } => "calibration".into(),
        };
        ConfigError::Invalid {
            file: path.to_path_buf(),
            key,
            reason: e.to_string(),
        }
    })?;
    Ok(config)
}

/// The dotted key at byte `offset` of a TOML text: the `[table]` header above it and the key
/// of its line (for the span toml gives with an error).
fn key_at(text: &str, offset: usize) -> Option<String> {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    let line = text[line_start..line_end].trim();
    let header = |l: &str| {
        l.strip_prefix('[').map(|l| {
            l.trim_start_matches('[')
                .trim_end_matches(']')
                .trim()
                .to_string()
        })
    };
    if line.starts_with('[') {
        return header(line);
    }
    let key = line.split('=').next()?.trim().trim_matches('"');
    if key.is_empty() || key.starts_with('#') {
        return None;
    }
    let table = text[..line_start]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .and_then(header);
    Some(match table {
        Some(t) => format!("{t}.{key}"),
        None => key.to_string(),
    })
}

// ---------------------------------------------------------------------------------------------
// The file's shape

type Invalid = (String, String);

fn bad<T>(key: &str, reason: impl Into<String>) -> Result<T, Invalid> {
    Err((key.to_string(), reason.into()))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    cameras: RawCameras,
    calibration: RawCalibration,
    #[serde(default)]
    engine: EngineParams,
    #[serde(default)]
    decision: RawDecision,
    #[serde(default)]
    evolution: RawEvolution,
    #[serde(default)]
    control: RawControl,
    can: RawCan,
    #[serde(default)]
    logging: RawLogging,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCameras {
    left: Option<PathBuf>,
    right: Option<PathBuf>,
    mock: Option<String>,
    width: u32,
    height: u32,
    fps: f64,
    #[serde(default = "default_pixel_format")]
    pixel_format: CaptureFormat,
    #[serde(default = "default_tolerance_ms")]
    timestamp_tolerance_ms: f64,
    #[serde(default = "default_stale_frames")]
    stale_frames: u32,
}

fn default_pixel_format() -> CaptureFormat {
    CaptureFormat::Yuyv
}
fn default_tolerance_ms() -> f64 {
    10.0
}
fn default_stale_frames() -> u32 {
    3
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCalibration {
    file: Option<PathBuf>,
    builtin: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawDecision {
    slow_threshold: f64,
    stop_threshold: f64,
    release_ratio: f64,
    slow_hold_ms: u64,
    stop_hold_ms: u64,
    safe_command: SafeCommand,
    slow_decel: f64,
    stop_decel: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
enum SafeCommand {
    #[serde(rename = "SLOW")]
    Slow,
    #[serde(rename = "STOP")]
    Stop,
    #[serde(rename = "CLEAR")]
    Clear,
}

impl Default for RawDecision {
    fn default() -> Self {
        let d = DecisionConfig::default();
        Self {
            slow_threshold: d.slow_threshold,
            stop_threshold: d.stop_threshold,
            release_ratio: d.release_ratio,
            slow_hold_ms: d.slow_hold.as_millis() as u64,
            stop_hold_ms: d.stop_hold.as_millis() as u64,
            safe_command: SafeCommand::Slow,
            slow_decel: d.slow_decel,
            stop_decel: d.stop_decel,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawEvolution {
    /// 0 = as fast as possible.
    generation_period_ms: f64,
    burst_generations: u32,
    max_generation_ms: f64,
    warmup_generations: u64,
    snapshot_queue: usize,
    skew_fault_rejects: u32,
    blind_matched: f64,
    blind_pairs: u32,
    lane_half_width: f64,
    obstacle_best_flies: usize,
    obstacle_min_flies: usize,
}

impl Default for RawEvolution {
    fn default() -> Self {
        let d = EvolutionConfig::default();
        Self {
            generation_period_ms: d.generation_period.map_or(0.0, |p| p.as_secs_f64() * 1e3),
            burst_generations: d.burst_generations,
            max_generation_ms: d.max_generation_time.as_secs_f64() * 1e3,
            warmup_generations: d.warmup_generations,
            snapshot_queue: d.snapshot_queue,
            skew_fault_rejects: d.skew_fault_rejects,
            blind_matched: d.blind_matched,
            blind_pairs: d.blind_pairs,
            lane_half_width: d.lane_half_width,
            obstacle_best_flies: d.obstacle_best_flies,
            obstacle_min_flies: d.obstacle_min_flies,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawControl {
    snapshot_timeout_ms: f64,
    startup_timeout_ms: f64,
}

impl Default for RawControl {
    fn default() -> Self {
        let d = ControlConfig::default();
        Self {
            snapshot_timeout_ms: d.snapshot_timeout.as_secs_f64() * 1e3,
            startup_timeout_ms: d.startup_timeout.as_secs_f64() * 1e3,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCan {
    interface: Option<String>,
    log: Option<PathBuf>,
    #[serde(default = "default_log_iface")]
    log_interface: String,
    #[serde(default)]
    messages: CanConfig,
}

fn default_log_iface() -> String {
    "can0".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawLogging {
    format: LogFormat,
    level: String,
    stats_interval_s: f64,
}

impl Default for RawLogging {
    fn default() -> Self {
        Self {
            format: LogFormat::Auto,
            level: "info".into(),
            stats_interval_s: 10.0,
        }
    }
}

/// A positive, finite number of milliseconds.
fn millis(key: &str, ms: f64) -> Result<Duration, Invalid> {
    if ms.is_finite() && ms > 0.0 && ms < 1e9 {
        Ok(Duration::from_secs_f64(ms / 1e3))
    } else {
        bad(
            key,
            format!("must be a positive number of milliseconds, got {ms}"),
        )
    }
}

impl RawConfig {
    fn resolve(self, path: &Path) -> Result<DaemonConfig, Invalid> {
        let base = path.parent().unwrap_or(Path::new("."));
        let cameras = self.cameras.resolve()?;
        let calibration = self.calibration.resolve(base)?;
        if let Err(e) = self.engine.validate() {
            return bad(&format!("engine.{}", e.key), e.reason);
        }
        let decision = self.decision.resolve()?;
        let evolution = self.evolution.resolve(&self.engine)?;
        let control = self.control.resolve()?;
        let can = self.can.resolve(base)?;
        let logging = self.logging.resolve()?;
        if matches!(cameras.source, CameraSource::Devices { .. })
            && calibration == CalibrationSource::BuiltinMock
        {
            return bad(
                "calibration.builtin",
                "the built-in mock rig only fits mock cameras (cameras.mock)",
            );
        }
        Ok(DaemonConfig {
            file: Some(path.to_path_buf()),
            cameras,
            calibration,
            engine: self.engine,
            decision,
            evolution,
            control,
            can,
            logging,
        })
    }
}

impl RawCameras {
    fn resolve(self) -> Result<CamerasConfig, Invalid> {
        let source = match (self.left, self.right, self.mock) {
            (None, None, Some(scenario)) => {
                match hw_mock::Scenario::by_name(&scenario) {
                    None => {
                        return bad(
                            "cameras.mock",
                            format!(
                                "unknown scenario '{scenario}' (known: {})",
                                hw_mock::Scenario::names().join(", ")
                            ),
                        );
                    }
                    Some(s) if !s.live() => {
                        return bad(
                            "cameras.mock",
                            format!(
                                "scenario '{scenario}' renders every frame in full, a few a \
                                 second: use it with `flyd replay --scenario`, not as a live \
                                 camera"
                            ),
                        );
                    }
                    Some(_) => {}
                }
                CameraSource::Mock { scenario }
            }
            (Some(left), Some(right), None) => {
                if left == right {
                    return bad("cameras.right", "must be another device than cameras.left");
                }
                CameraSource::Devices { left, right }
            }
            (_, _, Some(_)) => {
                return bad(
                    "cameras.mock",
                    "give either mock = \"scenario\" or left and right devices, not both",
                );
            }
            (None, _, None) => return bad("cameras.left", "missing (or give cameras.mock)"),
            (_, None, None) => return bad("cameras.right", "missing (or give cameras.mock)"),
        };
        if !(16..=8192).contains(&self.width) {
            return bad(
                "cameras.width",
                format!("must be within 16..=8192, got {}", self.width),
            );
        }
        if !(16..=8192).contains(&self.height) {
            return bad(
                "cameras.height",
                format!("must be within 16..=8192, got {}", self.height),
            );
        }
        if !(self.fps.is_finite() && self.fps > 0.0 && self.fps <= 1000.0) {
            return bad(
                "cameras.fps",
                format!("must be within (0, 1000], got {}", self.fps),
            );
        }
        let tolerance = millis(
            "cameras.timestamp_tolerance_ms",
            self.timestamp_tolerance_ms,
        )?;
        if self.stale_frames == 0 {
            return bad("cameras.stale_frames", "must be at least 1");
        }
        Ok(CamerasConfig {
            source,
            width: self.width,
            height: self.height,
            fps: self.fps,
            pixel_format: self.pixel_format,
            timestamp_tolerance: tolerance,
            stale_frames: self.stale_frames,
        })
    }
}

impl RawCalibration {
    fn resolve(self, base: &Path) -> Result<CalibrationSource, Invalid> {
        match (self.file, self.builtin) {
            (Some(file), None) => Ok(CalibrationSource::File(base.join(file))),
            (None, Some(name)) if name == "mock" => Ok(CalibrationSource::BuiltinMock),
            (None, Some(name)) => bad(
                "calibration.builtin",
                format!("unknown built-in rig '{name}' (the only one is \"mock\")"),
            ),
            (Some(_), Some(_)) => bad("calibration", "give either file or builtin, not both"),
            (None, None) => bad("calibration", "give file = \"PATH\" or builtin = \"mock\""),
        }
    }
}

impl RawDecision {
    fn resolve(self) -> Result<DecisionConfig, Invalid> {
        let config = DecisionConfig {
            slow_threshold: self.slow_threshold,
            stop_threshold: self.stop_threshold,
            release_ratio: self.release_ratio,
            slow_hold: Duration::from_millis(self.slow_hold_ms),
            stop_hold: Duration::from_millis(self.stop_hold_ms),
            safe_command: match self.safe_command {
                SafeCommand::Slow => Command::Slow,
                SafeCommand::Stop => Command::Stop,
                SafeCommand::Clear => Command::Clear,
            },
            fault_mask: FaultBits::all(),
            slow_decel: self.slow_decel,
            stop_decel: self.stop_decel,
        };
        match config.validate() {
            Ok(()) => Ok(config),
            Err(e) => {
                let key = match e {
                    DecisionConfigError::Thresholds { slow, .. } => {
                        if slow.is_finite() && slow > 0.0 {
                            "decision.stop_threshold"
                        } else {
                            "decision.slow_threshold"
                        }
                    }
                    DecisionConfigError::ReleaseRatio(_) => "decision.release_ratio",
                    DecisionConfigError::ZeroHold => {
                        if self.slow_hold_ms == 0 {
                            "decision.slow_hold_ms"
                        } else {
                            "decision.stop_hold_ms"
                        }
                    }
                    DecisionConfigError::UnsafeFallback => "decision.safe_command",
                    DecisionConfigError::Decel { command, .. } => {
                        if command == Command::Slow {
                            "decision.slow_decel"
                        } else {
                            "decision.stop_decel"
                        }
                    }
                };
                bad(key, e.to_string())
            }
        }
    }
}

impl RawEvolution {
    fn resolve(self, engine: &EngineParams) -> Result<EvolutionConfig, Invalid> {
        let generation_period = if self.generation_period_ms == 0.0 {
            None
        } else {
            Some(millis(
                "evolution.generation_period_ms",
                self.generation_period_ms,
            )?)
        };
        let max_generation_time = millis("evolution.max_generation_ms", self.max_generation_ms)?;
        if !(1..=1000).contains(&self.burst_generations) {
            return bad("evolution.burst_generations", "must be within 1..=1000");
        }
        if !(1..=65_536).contains(&self.snapshot_queue) {
            return bad("evolution.snapshot_queue", "must be within 1..=65536");
        }
        if self.skew_fault_rejects == 0 {
            return bad("evolution.skew_fault_rejects", "must be at least 1");
        }
        if !(0.0..=1.0).contains(&self.blind_matched) {
            return bad(
                "evolution.blind_matched",
                "must be within [0, 1] (0 disables the check)",
            );
        }
        if self.blind_pairs == 0 {
            return bad("evolution.blind_pairs", "must be at least 1");
        }
        if !(self.lane_half_width.is_finite() && self.lane_half_width > 0.0) {
            return bad("evolution.lane_half_width", "must be > 0 metres");
        }
        if !(1..=engine.flies).contains(&self.obstacle_best_flies) {
            return bad(
                "evolution.obstacle_best_flies",
                format!("must be within 1..=engine.flies ({})", engine.flies),
            );
        }
        if !(1..=self.obstacle_best_flies).contains(&self.obstacle_min_flies) {
            return bad(
                "evolution.obstacle_min_flies",
                "must be within 1..=evolution.obstacle_best_flies",
            );
        }
        Ok(EvolutionConfig {
            generation_period,
            burst_generations: self.burst_generations,
            max_generation_time,
            warmup_generations: self.warmup_generations,
            snapshot_queue: self.snapshot_queue,
            skew_fault_rejects: self.skew_fault_rejects,
            blind_matched: self.blind_matched,
            blind_pairs: self.blind_pairs,
            lane_half_width: self.lane_half_width,
            obstacle_best_flies: self.obstacle_best_flies,
            obstacle_min_flies: self.obstacle_min_flies,
        })
    }
}

impl RawControl {
    fn resolve(self) -> Result<ControlConfig, Invalid> {
        Ok(ControlConfig {
            snapshot_timeout: millis("control.snapshot_timeout_ms", self.snapshot_timeout_ms)?,
            startup_timeout: millis("control.startup_timeout_ms", self.startup_timeout_ms)?,
        })
    }
}

impl RawCan {
    fn resolve(self, base: &Path) -> Result<CanSection, Invalid> {
        let target = match (self.interface, self.log) {
            (Some(iface), None) => {
                if iface.is_empty() || iface.len() > 15 {
                    return bad(
                        "can.interface",
                        "must be an interface name of 1 to 15 bytes",
                    );
                }
                CanTarget::Interface(iface)
            }
            (None, Some(log)) => CanTarget::Log {
                path: if log.as_os_str() == "-" {
                    log
                } else {
                    base.join(log)
                },
                iface: self.log_interface,
            },
            (Some(_), Some(_)) => return bad("can", "give either interface or log, not both"),
            (None, None) => return bad("can", "give interface = \"can0\" or log = \"PATH\""),
        };
        if let Err(e) = self.messages.validate() {
            return bad("can.messages", e.to_string());
        }
        Ok(CanSection {
            target,
            messages: self.messages,
        })
    }
}

impl RawLogging {
    fn resolve(self) -> Result<LoggingConfig, Invalid> {
        let level = self.level.parse::<tracing::Level>().or_else(|_| {
            bad(
                "logging.level",
                format!(
                    "'{}' is not one of error, warn, info, debug, trace",
                    self.level
                ),
            )
        })?;
        let stats = self.stats_interval_s;
        if !(stats.is_finite() && stats > 0.0 && stats < 1e6) {
            return bad(
                "logging.stats_interval_s",
                format!("must be > 0 seconds, got {stats}"),
            );
        }
        Ok(LoggingConfig {
            format: self.format,
            level,
            stats_interval: Duration::from_secs_f64(stats),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[cameras]
left = "/dev/video0"
right = "/dev/video1"
width = 640
height = 480
fps = 30

[calibration]
file = "rig.toml"

[can]
interface = "can0"
"#;

    fn parse(text: &str) -> Result<DaemonConfig, ConfigError> {
        DaemonConfig::from_toml(text, Path::new("/etc/flyd/flyd.toml"))
    }

    /// `text` must be rejected with an error naming `key` and containing `words`.
    fn check_err(text: &str, key: &str, words: &str) {
        let e = parse(text).expect_err("must be rejected");
        let msg = e.to_string();
        assert_eq!(e.key(), Some(key), "{msg}");
        assert!(msg.contains("/etc/flyd/flyd.toml"), "{msg}");
        assert!(msg.contains(key), "{msg}");
        assert!(msg.contains(words), "{msg}");
    }

    /// MINIMAL with `extra` appended to the end of the `[table]` it names (or the file).
    fn with(table: &str, extra: &str) -> String {
        let header = format!("[{table}]\n");
        match MINIMAL.find(&header) {
            Some(i) => {
                let at = i + header.len();
                format!("{}{extra}\n{}", &MINIMAL[..at], &MINIMAL[at..])
            }
            None => format!("{MINIMAL}\n{header}{extra}\n"),
        }
    }

    #[test]
    fn minimal_config_resolves_with_defaults() {
        let c = parse(MINIMAL).expect("valid");
        assert_eq!(
            c.cameras.source,
            CameraSource::Devices {
                left: "/dev/video0".into(),
                right: "/dev/video1".into()
            }
        );
        assert_eq!(
            c.calibration,
            CalibrationSource::File("/etc/flyd/rig.toml".into()),
            "relative to the config file"
        );
        assert_eq!(c.can.target, CanTarget::Interface("can0".into()));
        assert_eq!(c.engine, EngineParams::default());
        assert_eq!(c.decision, DecisionConfig::default());
        assert_eq!(c.cameras.stale_timeout(), Duration::from_millis(100));
    }

    #[test]
    fn unknown_keys_are_named() {
        check_err(
            &with("cameras", "exposure = 3"),
            "cameras.exposure",
            "unknown field",
        );
        check_err(&with("engine", "flys = 3"), "engine.flys", "unknown field");
        check_err(
            &with("engine.roi", "max_heigth = 3.0"),
            "engine.roi.max_heigth",
            "unknown",
        );
        check_err(
            &with("can.messages.command", "id = 0x200\nperiod = 3"),
            "can.messages.command.period",
            "unknown",
        );
        check_err(
            &format!("verbose = true\n{MINIMAL}"),
            "verbose",
            "unknown field",
        );
    }

    #[test]
    fn wrong_types_are_named() {
        check_err(
            &with("decision", "stop_threshold = \"high\""),
            "decision.stop_threshold",
            "invalid type",
        );
        check_err(
            &with("cameras", "pixel_format = \"RGB3\""),
            "cameras.pixel_format",
            "unknown variant",
        );
    }

    #[test]
    fn impossible_values_are_named() {
        check_err(
            &with("engine", "min_depth = 30.0"),
            "engine.max_depth",
            "greater than min_depth",
        );
        check_err(
            &with("decision", "slow_threshold = 0.8\nstop_threshold = 0.4"),
            "decision.stop_threshold",
            "slow",
        );
        check_err(
            &with("decision", "safe_command = \"CLEAR\""),
            "decision.safe_command",
            "SLOW or STOP",
        );
        check_err(
            &with("decision", "stop_hold_ms = 0"),
            "decision.stop_hold_ms",
            "> 0",
        );
        check_err(
            &with("cameras", "timestamp_tolerance_ms = 0"),
            "cameras.timestamp_tolerance_ms",
            "positive",
        );
        check_err(
            &with("cameras", "stale_frames = 0"),
            "cameras.stale_frames",
            "at least 1",
        );
        check_err(
            &with("evolution", "blind_pairs = 0"),
            "evolution.blind_pairs",
            "at least 1",
        );
        check_err(
            &with("evolution", "burst_generations = 0"),
            "evolution.burst_generations",
            "1..=1000",
        );
        check_err(
            &with("evolution", "max_generation_ms = -1"),
            "evolution.max_generation_ms",
            "positive",
        );
        check_err(
            &with("logging", "level = \"loud\""),
            "logging.level",
            "loud",
        );
        check_err(
            &with(
                "can.messages.status",
                "id = 0x120\ndata_id = 0x121\nperiod_ms = 20",
            ),
            "can.messages",
            "share CAN ID",
        );
        check_err(
            &MINIMAL.replace("left = \"/dev/video0\"", "mock = \"empty-road\""),
            "cameras.mock",
            "not both",
        );
        let driving = MINIMAL
            .replace("left = \"/dev/video0\"\n", "mock = \"driving\"\n")
            .replace("right = \"/dev/video1\"\n", "");
        check_err(&driving, "cameras.mock", "flyd replay");
        check_err(
            &MINIMAL.replace("file = \"rig.toml\"", "builtin = \"mock\""),
            "calibration.builtin",
            "mock cameras",
        );
    }

    #[test]
    fn key_at_finds_table_and_key() {
        let text = "a = 1\n[t.u]\nb = 2\n  c=3\n";
        assert_eq!(key_at(text, 0).as_deref(), Some("a"));
        assert_eq!(
            key_at(text, text.find("b =").unwrap()).as_deref(),
            Some("t.u.b")
        );
        assert_eq!(
            key_at(text, text.find("c=").unwrap() + 2).as_deref(),
            Some("t.u.c")
        );
        assert_eq!(
            key_at(text, text.find("[t").unwrap()).as_deref(),
            Some("t.u")
        );
    }

    #[test]
    fn damaged_config_files_are_errors_naming_the_file_never_a_panic() {
        use flyd_core::test_support::damage_each;
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
        let (mut loaded, mut refused) = (0, 0);
        for name in ["flyd.toml", "demo.toml"] {
            let file = path.join(name);
            let text = std::fs::read_to_string(&file).expect("shipped config");
            let parse = |t: &str| DaemonConfig::from_toml(t, &file);
            let (l, r) = damage_each(&text, 0..1_500, name, parse, |_, _| {});
            (loaded, refused) = (loaded + l, refused + r);
        }
        println!("damaged configs: {loaded} loaded, {refused} refused");
        assert!(
            loaded > 100 && refused > 1000,
            "{loaded} loaded, {refused} refused"
        );
    }
}
