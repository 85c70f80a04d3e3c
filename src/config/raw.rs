//! The configuration file's shape (`deny_unknown_fields` everywhere) and its resolution into
//! the [`DaemonConfig`] types: each check names the key it refuses.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use super::{
    CalibrationSource, CameraSource, CanSection, CanTarget, ControlConfig, DaemonConfig,
    EvolutionConfig, LogFormat, LoggingConfig, MotionInput, VehicleConfig,
};
use flyd_core::can::CanConfig;
use flyd_core::decision::Command;
use flyd_core::decision::{DecisionConfig, DecisionConfigError, DecisionMode};
use flyd_core::engine::EngineParams;
use flyd_core::perception::PerceptionConfig;
use flyd_core::sensor::SensorConfig;
use flyd_core::status::FaultBits;

mod cameras;
mod record;

use cameras::RawCameras;
use record::{RawLive, RawRecord};

type Invalid = (String, String);

fn bad<T>(key: &str, reason: impl Into<String>) -> Result<T, Invalid> {
    Err((key.to_string(), reason.into()))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    cameras: RawCameras,
    calibration: RawCalibration,
    #[serde(default)]
    engine: EngineParams,
    #[serde(default)]
    decision: RawDecision,
    #[serde(default)]
    perception: PerceptionConfig,
    #[serde(default)]
    vehicle: RawVehicle,
    #[serde(default)]
    sensor: SensorConfig,
    #[serde(default)]
    evolution: RawEvolution,
    #[serde(default)]
    control: RawControl,
    can: RawCan,
    #[serde(default)]
    logging: RawLogging,
    #[serde(default)]
    record: RawRecord,
    #[serde(default)]
    live: RawLive,
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
    mode: RawMode,
    slow_threshold: f64,
    stop_threshold: f64,
    release_ratio: f64,
    slow_hold_ms: u64,
    stop_hold_ms: u64,
    safe_command: SafeCommand,
    slow_decel: f64,
    stop_decel: f64,
    max_decel: f64,
    reaction_time_ms: f64,
    margin_m: f64,
    lead_decel: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
enum RawMode {
    #[serde(rename = "obstacle")]
    Obstacle,
    #[serde(rename = "global-warning")]
    GlobalWarning,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawVehicle {
    assumed_speed_kmh: f64,
    motion: MotionInput,
    motion_stale_periods: u32,
    predict_flies: bool,
}

impl Default for RawVehicle {
    fn default() -> Self {
        let d = VehicleConfig::default();
        Self {
            assumed_speed_kmh: d.assumed_speed * 3.6,
            motion: d.motion,
            motion_stale_periods: d.motion_stale_periods,
            predict_flies: d.predict_flies,
        }
    }
}

impl RawVehicle {
    fn resolve(self) -> Result<VehicleConfig, Invalid> {
        let v = self.assumed_speed_kmh;
        // A low assumed speed shortens every stopping distance: 0 would stop for nothing.
        if !(v.is_finite() && (10.0..=250.0).contains(&v)) {
            return bad(
                "vehicle.assumed_speed_kmh",
                format!("must be within 10..=250 km/h, got {v}"),
            );
        }
        // 1 period: one late frame is a fault; more than 10 (200 ms at 20 ms): a vehicle that
        // brakes hard is 2 m/s slower than the speed still trusted.
        let n = self.motion_stale_periods;
        if !(1..=10).contains(&n) {
            return bad(
                "vehicle.motion_stale_periods",
                format!("must be within 1..=10, got {n}"),
            );
        }
        Ok(VehicleConfig {
            assumed_speed: v / 3.6,
            motion: self.motion,
            motion_stale_periods: n,
            predict_flies: self.predict_flies,
        })
    }
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
            mode: match d.mode {
                DecisionMode::Obstacle => RawMode::Obstacle,
                DecisionMode::GlobalWarning => RawMode::GlobalWarning,
            },
            slow_threshold: d.slow_threshold,
            stop_threshold: d.stop_threshold,
            release_ratio: d.release_ratio,
            slow_hold_ms: d.slow_hold.as_millis() as u64,
            stop_hold_ms: d.stop_hold.as_millis() as u64,
            safe_command: SafeCommand::Slow,
            slow_decel: d.slow_decel,
            stop_decel: d.stop_decel,
            max_decel: d.max_decel,
            reaction_time_ms: d.reaction_time.as_secs_f64() * 1e3,
            margin_m: d.margin,
            lead_decel: d.lead_decel,
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
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawControl {
    snapshot_timeout_ms: f64,
    startup_timeout_ms: f64,
    can_silence_ms: f64,
}

impl Default for RawControl {
    fn default() -> Self {
        let d = ControlConfig::default();
        Self {
            snapshot_timeout_ms: d.snapshot_timeout.as_secs_f64() * 1e3,
            startup_timeout_ms: d.startup_timeout.as_secs_f64() * 1e3,
            can_silence_ms: d.can_silence.as_secs_f64() * 1e3,
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

/// A Linux network interface name (IFNAMSIZ: at most 15 bytes) of letters, digits, `-`, `_`
/// and `.`: what `ip link` accepts and what a candump line can carry unquoted.
fn check_iface(key: &str, name: &str) -> Result<(), Invalid> {
    let ok_char = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if name.is_empty()
        || name.len() > 15
        || !name.chars().all(ok_char)
        || name == "."
        || name == ".."
    {
        let shown: String = name.escape_debug().take(40).collect();
        return bad(
            key,
            format!(
                "must be an interface name of 1 to 15 letters, digits, '-', '_' or '.', got \"{shown}\""
            ),
        );
    }
    Ok(())
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
    pub(super) fn resolve(self, path: &Path) -> Result<DaemonConfig, Invalid> {
        let base = path.parent().unwrap_or(Path::new("."));
        let cameras = self.cameras.resolve()?;
        let calibration = self.calibration.resolve(base)?;
        if let Err(e) = self.engine.validate() {
            return bad(&format!("engine.{}", e.key), e.reason);
        }
        let decision = self.decision.resolve()?;
        let evolution = self.evolution.resolve()?;
        if let Err(e) = self.perception.validate() {
            return bad(&format!("perception.{}", e.key), e.reason);
        }
        let vehicle = self.vehicle.resolve()?;
        if let Err(e) = self.sensor.validate() {
            return bad(
                &format!("sensor.{}", e.key),
                format!("must be within {}", e.range),
            );
        }
        let control = self.control.resolve()?;
        let can = self.can.resolve(base)?;
        let logging = self.logging.resolve()?;
        let record = self.record.resolve(base)?;
        let live = self.live.resolve()?;
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
            perception: self.perception,
            vehicle,
            sensor: self.sensor,
            evolution,
            control,
            can,
            logging,
            record,
            live,
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
        let reaction_time = if self.reaction_time_ms == 0.0 {
            Duration::ZERO
        } else {
            millis("decision.reaction_time_ms", self.reaction_time_ms)?
        };
        let config = DecisionConfig {
            mode: match self.mode {
                RawMode::Obstacle => DecisionMode::Obstacle,
                RawMode::GlobalWarning => DecisionMode::GlobalWarning,
            },
            reaction_time,
            margin: self.margin_m,
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
            max_decel: self.max_decel,
            lead_decel: self.lead_decel,
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
                    DecisionConfigError::DecelOrder { .. } => "decision.slow_decel",
                    DecisionConfigError::Margin(_) => "decision.margin_m",
                    DecisionConfigError::MaxDecel { .. } => "decision.max_decel",
                    DecisionConfigError::OutOfRange { key, .. } => {
                        return bad(&format!("decision.{key}"), e.to_string());
                    }
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
    fn resolve(self) -> Result<EvolutionConfig, Invalid> {
        let generation_period = if self.generation_period_ms == 0.0 {
            None
        } else {
            Some(millis(
                "evolution.generation_period_ms",
                self.generation_period_ms,
            )?)
        };
        if generation_period.is_some_and(|p| p > Duration::from_millis(100)) {
            return bad(
                "evolution.generation_period_ms",
                format!(
                    "must be 0 or within (0, 100] ms, got {}",
                    self.generation_period_ms
                ),
            );
        }
        let max_generation_time = millis("evolution.max_generation_ms", self.max_generation_ms)?;
        if max_generation_time > Duration::from_secs(1) {
            return bad(
                "evolution.max_generation_ms",
                format!(
                    "must be within (0, 1000] ms, got {}",
                    self.max_generation_ms
                ),
            );
        }
        if self.warmup_generations > 10_000 {
            return bad(
                "evolution.warmup_generations",
                format!("must be within 0..=10000, got {}", self.warmup_generations),
            );
        }
        if !(1..=1000).contains(&self.burst_generations) {
            return bad("evolution.burst_generations", "must be within 1..=1000");
        }
        if !(1..=65_536).contains(&self.snapshot_queue) {
            return bad("evolution.snapshot_queue", "must be within 1..=65536");
        }
        if !(1..=30).contains(&self.skew_fault_rejects) {
            return bad("evolution.skew_fault_rejects", "must be within 1..=30");
        }
        // 0 would disable the check; healthy images give 0.73-0.97 (docs/tuning.md).
        if !(0.05..=0.6).contains(&self.blind_matched) {
            return bad("evolution.blind_matched", "must be within [0.05, 0.6]");
        }
        if !(1..=30).contains(&self.blind_pairs) {
            return bad("evolution.blind_pairs", "must be within 1..=30");
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
        })
    }
}

impl RawControl {
    fn resolve(self) -> Result<ControlConfig, Invalid> {
        let within = |key: &str, ms: f64, lo: f64, hi: f64| {
            if ms.is_finite() && (lo..=hi).contains(&ms) {
                Ok(Duration::from_secs_f64(ms / 1e3))
            } else {
                bad(key, format!("must be within {lo}..={hi} ms, got {ms}"))
            }
        };
        Ok(ControlConfig {
            // A frozen evolution thread must be a fault well within the watchdog.
            snapshot_timeout: within(
                "control.snapshot_timeout_ms",
                self.snapshot_timeout_ms,
                10.0,
                1000.0,
            )?,
            startup_timeout: within(
                "control.startup_timeout_ms",
                self.startup_timeout_ms,
                100.0,
                60_000.0,
            )?,
            // Under WatchdogSec=2s, so a daemon that cannot send is restarted.
            can_silence: within("control.can_silence_ms", self.can_silence_ms, 50.0, 1500.0)?,
        })
    }
}

impl RawCan {
    fn resolve(self, base: &Path) -> Result<CanSection, Invalid> {
        check_iface("can.log_interface", &self.log_interface)?;
        let target = match (self.interface, self.log) {
            (Some(iface), None) => {
                check_iface("can.interface", &iface)?;
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
