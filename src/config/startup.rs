//! What start-up checks before opening any device ([`check`], which `flyd check-config` and
//! `flyd run` both call): the configuration, the calibration, an engine built on them, the
//! ranges against the SLOW distance, and how well the rig resolves it.

use std::path::Path;

use super::{ConfigError, DaemonConfig};
use flyd_core::decision::{Command, DecisionMode};
use flyd_core::engine::{Engine, EngineError};
use flyd_core::geometry::StereoRig;
use flyd_core::perception::Resolution;

impl DaemonConfig {
    /// In the obstacle mode, how well `rig` resolves the SLOW distance at
    /// `vehicle.assumed_speed_kmh`, the highest speed the configuration is checked for
    /// ([`flyd_core::perception::range`]: one pixel of disparity at `Z` is `Z^2 / (f B)` metres,
    /// against `decision.margin_m`). Start-up logs it and `check-config` warns when it is not
    /// enough.
    pub fn resolution(&self, rig: &StereoRig) -> Option<Resolution> {
        (self.decision.mode == DecisionMode::Obstacle).then(|| {
            let fb = rig.right.intrinsics().fx * rig.baseline();
            Resolution::at(&self.decision, fb, self.vehicle.assumed_speed)
        })
    }
}

/// Everything start-up checks before opening any device: the config, the calibration, and an
/// engine built once on them (common field of view over the depth range).
///
/// A calibration file's `[search]` is honoured as replay honours it: its depth range replaces
/// `engine.min_depth`/`max_depth`, and `road = false` turns the road region of interest off.
pub fn check(path: &Path) -> Result<DaemonConfig, ConfigError> {
    let mut config = DaemonConfig::load(path)?;
    let cal = config.load_calibration()?;
    cal.apply_to(&mut config.engine);
    check_reach(&config, path, cal.depth_range.is_some())?;
    let rig = cal.rig;
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

/// In the obstacle mode, the flies must be searched, and obstacles seen, as far as the SLOW
/// distance at the assumed speed: a shorter range would see a pedestrian only once braking
/// can no longer stop in time.
fn check_reach(
    config: &DaemonConfig,
    path: &Path,
    from_calibration: bool,
) -> Result<(), ConfigError> {
    if config.decision.mode != DecisionMode::Obstacle {
        return Ok(());
    }
    let speed = config.vehicle.assumed_speed;
    let reach = config.decision.reach(Command::Slow, speed);
    let depth_key = if from_calibration {
        "calibration (its [search] max_depth)"
    } else {
        "engine.max_depth"
    };
    let ranges = [
        (depth_key, config.engine.max_depth),
        (
            "engine.roi.max_ahead",
            config.engine.roi.map_or(f64::INFINITY, |r| r.max_ahead),
        ),
        (
            "perception.obstacle.max_distance",
            config.perception.obstacle.max_distance,
        ),
    ];
    for (key, range) in ranges {
        if range < reach {
            return Err(ConfigError::Invalid {
                file: path.to_path_buf(),
                key: key.into(),
                reason: format!(
                    "reaches {range} m, less than the SLOW distance at vehicle.assumed_speed_kmh \
                     = {:.0} ({reach:.1} m): an obstacle would be seen only once braking is too \
                     late",
                    speed * 3.6
                ),
            });
        }
    }
    Ok(())
}
