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
use crate::mock::camera::MockFault;
use flyd_core::calib::{self, CalibError, Calibration};
use flyd_core::can::CanConfig;
use flyd_core::can::motion_monitor::MotionConfig;
use flyd_core::decision::DecisionConfig;
use flyd_core::engine::EngineParams;
use flyd_core::frame::PixelFormat;
use flyd_core::geometry::StereoRig;
use flyd_core::perception::PerceptionConfig;
use flyd_core::sensor::SensorConfig;

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
#[derive(Debug, Clone, PartialEq)]
pub enum CameraSource {
    /// Two V4L2 devices.
    Devices { left: PathBuf, right: PathBuf },
    /// A hw-mock scenario rendered for both cameras (`mock = "pedestrian-steps-in"`), with
    /// the faults to inject (`[[cameras.mock_faults]]`).
    Mock {
        scenario: String,
        faults: Vec<MockFault>,
        /// The scenario plays again from its first frame when it ends (`cameras.mock_loop`).
        looped: bool,
    },
}

/// What the flies compare of a camera's pixels (`cameras.channels`).
///
/// YUYV carries one chroma sample for two pixels and MJPEG usually one for four: at an edge the
/// pair's mean colour is a fringe that falls differently in the two cameras (their pairs start
/// at different scene points at any odd disparity), so a fly on the edge matches worse in
/// colour than in luma. Measured on hw-mock pedestrian-4m at 320x240, 1000 flies, seeds 1-10:
/// the pedestrian's supporting flies median 41-87 (a frame without the obstacle on 0.8 % of
/// the estimates) through YUYV in colour, 95-108 (0.0 %) in luma, 94-107 on the rendered RGB.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channels {
    /// The luma at full resolution (the default).
    #[default]
    Luma,
    /// RGB from the camera's chroma, as it is subsampled.
    Colour,
}

#[derive(Debug, Clone, PartialEq)]
pub struct CamerasConfig {
    pub source: CameraSource,
    pub width: u32,
    pub height: u32,
    /// Nominal frame rate, frames per second (a whole number for V4L2 devices).
    pub fps: f64,
    pub pixel_format: CaptureFormat,
    /// What the flies compare of a V4L2 camera's frames (mock cameras render colour).
    pub channels: Channels,
    /// Left and right frames further apart than this (capture timestamps) are not a pair.
    pub timestamp_tolerance: Duration,
    /// A camera with no frame for this many frame periods is stale (fault).
    pub stale_frames: u32,
}

impl CamerasConfig {
    pub fn frame_period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.fps)
    }

    /// What a V4L2 camera's frames are prepared as for the flies (see [`Channels`]).
    pub fn device_output(&self) -> PixelFormat {
        match self.channels {
            Channels::Luma => PixelFormat::Grey8,
            Channels::Colour => self.pixel_format.natural_output(),
        }
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
        }
    }
}

/// Where flyd learns the vehicle's motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum MotionInput {
    /// `VCU_Motion` on the CAN interface flyd sends on (`can.messages.motion`); missing or
    /// untrusted motion is `FLYD_Status.MotionFault` and the assumed speed.
    #[serde(rename = "can")]
    Can,
    /// No motion message: the decision always assumes `assumed_speed`, MotionFault stays 0.
    #[serde(rename = "none")]
    None,
}

/// What flyd knows of the vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleConfig {
    /// The speed the decision assumes while the measured one is not known (or not
    /// configured), m/s: the highest the vehicle drives at while flyd is in charge.
    pub assumed_speed: f64,
    /// Where the measured speed comes from.
    pub motion: MotionInput,
    /// No accepted `VCU_Motion` for this many of its periods: MotionFault.
    pub motion_stale_periods: u32,
    /// Move the flies with the trusted motion between two frames ([`flyd_core::engine::Engine::predict`]).
    pub predict_flies: bool,
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self {
            assumed_speed: 30.0 / 3.6,
            motion: MotionInput::Can,
            motion_stale_periods: 3,
            predict_flies: true,
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
    /// No CAN frame sent successfully for this long: the systemd watchdog is no longer pinged
    /// (a daemon that cannot send is restarted).
    pub can_silence: Duration,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            snapshot_timeout: Duration::from_millis(100),
            startup_timeout: Duration::from_secs(5),
            can_silence: Duration::from_millis(500),
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
    /// Native journal entries on the stream systemd connected to the journal
    /// (`$JOURNAL_STREAM`), human-readable on a terminal, JSON lines anywhere else.
    Auto,
    Json,
    Human,
    /// Native journal entries over journald's socket (JSON lines if it is not there).
    Journal,
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

/// `[record]`: what `flyd run --record` (or `record.path`) writes; see [`crate::record`].
#[derive(Debug, Clone, PartialEq)]
pub struct RecordConfig {
    /// Record to this MCAP file from the start (`--record` overrides it); `None`: off.
    pub path: Option<PathBuf>,
    /// Start a new file after this many bytes of payload (`rotate_mb`; `None`: never).
    pub rotate_bytes: Option<u64>,
    /// ... or after this long (`rotate_s`).
    pub rotate_after: Option<Duration>,
    /// Record the camera frames (needed to replay; without them a recording shows what flyd
    /// decided and found, not what it saw).
    pub images: bool,
    /// Record the population every this many generations.
    pub flies_every: u64,
    /// Records waiting for the writer at most (a full queue drops).
    pub queue: usize,
    /// zstd-compressed chunks.
    pub compression: bool,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            path: None,
            rotate_bytes: None,
            rotate_after: None,
            images: true,
            flies_every: 10,
            queue: 1024,
            compression: true,
        }
    }
}

/// `[live]`: the Foxglove WebSocket live view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveConfig {
    /// `None`: off (the default).
    pub listen: Option<std::net::SocketAddr>,
    /// Images per camera, and populations, sent per second at most.
    pub image_hz: f64,
    pub flies_hz: f64,
}

impl Default for LiveConfig {
    fn default() -> Self {
        Self {
            listen: None,
            image_hz: 5.0,
            flies_hz: 5.0,
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
    pub perception: PerceptionConfig,
    pub vehicle: VehicleConfig,
    /// The sensor checks' thresholds (`[sensor]`).
    pub sensor: SensorConfig,
    pub evolution: EvolutionConfig,
    pub control: ControlConfig,
    pub can: CanSection,
    pub logging: LoggingConfig,
    pub record: RecordConfig,
    pub live: LiveConfig,
}

impl DaemonConfig {
    /// What the perception's step is set up with besides the perception
    /// ([`flyd_core::frame_step`]): `[evolution]`'s blindness, `[sensor]`,
    /// `vehicle.predict_flies` and the assumed speed.
    pub fn step_config(&self) -> flyd_core::frame_step::StepConfig {
        flyd_core::frame_step::StepConfig {
            blind_matched: self.evolution.blind_matched,
            blind_pairs: self.evolution.blind_pairs,
            sensor: self.sensor,
            predict_flies: self.vehicle.predict_flies,
            assumed_speed: self.vehicle.assumed_speed,
        }
    }

    /// The motion monitor's settings: `VCU_Motion`'s Data ID and period from
    /// `can.messages.motion`, staleness from `vehicle.motion_stale_periods`; `None` when
    /// `vehicle.motion = "none"`.
    pub fn motion(&self) -> Option<MotionConfig> {
        (self.vehicle.motion != MotionInput::None).then(|| self.motion_monitor())
    }

    /// [`DaemonConfig::motion`] whatever `vehicle.motion` says (a replay given a candump log).
    pub fn motion_monitor(&self) -> MotionConfig {
        let m = self.can.messages.motion;
        MotionConfig {
            data_id: m.data_id,
            period: m.period(),
            stale: m.period() * self.vehicle.motion_stale_periods,
        }
    }

    /// A configuration for a rig given in code: 30 fps cameras of the rig's size, default
    /// everything else, CAN to a candump log on stdout (tests replace the bus anyway).
    pub fn with_rig(rig: StereoRig) -> Self {
        let (width, height) = (rig.left.width(), rig.left.height());
        Self {
            file: None,
            cameras: CamerasConfig {
                source: CameraSource::Mock {
                    scenario: "in-code".into(),
                    faults: Vec::new(),
                    looped: false,
                },
                width,
                height,
                fps: 30.0,
                pixel_format: CaptureFormat::Yuyv,
                channels: Channels::Luma,
                timestamp_tolerance: Duration::from_millis(10),
                stale_frames: 3,
            },
            calibration: CalibrationSource::Rig(Box::new(rig)),
            engine: EngineParams::default(),
            decision: DecisionConfig::default(),
            perception: PerceptionConfig::default(),
            vehicle: VehicleConfig::default(),
            sensor: SensorConfig::default(),
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
            record: RecordConfig::default(),
            live: LiveConfig::default(),
        }
    }

    /// Reads and checks a config file (syntax, types, values; not the calibration file).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = flyd_core::textfile::read(path).map_err(|error| ConfigError::Io {
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
        self.load_calibration().map(|c| c.rig)
    }

    /// The calibration (the rig at the cameras' size, and a file's `[search]`: depth range and
    /// whether there is a road).
    pub fn load_calibration(&self) -> Result<Calibration, ConfigError> {
        let file = self.file_for_messages();
        let invalid = |reason: String| ConfigError::Invalid {
            file: file.clone(),
            key: "calibration".into(),
            reason,
        };
        let built = |rig: StereoRig| Calibration {
            rig,
            depth_range: None,
            has_road: true,
            right_row_offset_px: 0.0,
            measure_rows: true,
            mount_assumed: None,
        };
        let cal = match &self.calibration {
            CalibrationSource::Rig(rig) => built((**rig).clone()),
            CalibrationSource::File(path) => {
                calib::load(path).map_err(|error| ConfigError::Calibration {
                    file: file.clone(),
                    error,
                })?
            }
            CalibrationSource::BuiltinMock => built(
                crate::mock::mock_rig(self.cameras.width, self.cameras.height)
                    .map_err(|e| invalid(format!("built-in mock rig: {e}")))?,
            ),
        };
        let rig = &cal.rig;
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
        // A camera's height decides every obstacle's: flyd does not guess it on a vehicle
        // (replay and eval say what they assumed instead).
        if let Some(assumed) = cal.mount_assumed {
            return Err(invalid(format!(
                "{assumed}; flyd does not guess where the cameras are on a vehicle: write a rig \
                 file with [import] file = \"...\" and [mount] position = [x, height, z] \
                 (metres: the left camera's place, its height above the road), pitch_deg and \
                 roll_deg (the format: crates/core/src/calib/rig.rs)"
            )));
        }
        Ok(cal)
    }
}

/// The dotted key at byte `offset` of a TOML text (for the span toml gives with an error);
/// `None` before any key.
fn key_at(text: &str, offset: usize) -> Option<String> {
    Some(flyd_core::toml_key::key_at(text, offset)).filter(|k| !k.is_empty())
}

mod raw;
mod startup;
#[cfg(test)]
mod tests;

use raw::RawConfig;
pub use startup::check;
