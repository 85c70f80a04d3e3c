//! What the obstacle stage looks for ([`ObstacleConfig`]: the corridor, the path, the
//! clustering and verification thresholds) and how a value out of its bounds is named
//! ([`PerceptionParamError`]).

use serde::{Deserialize, Serialize};

/// The name of a [`crate::path::PathModel`] in the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PathKind {
    Clothoid,
    ClothoidGated,
    Held,
}

/// What the obstacle stage looks for; the defaults are the vehicle's and the measurement's
/// (docs/perception.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObstacleConfig {
    /// Half-width of the corridor the vehicle sweeps: its half-width plus a margin, metres.
    pub corridor_half_width: f64,
    /// Beside the corridor, out to this far off the path either side, metres, obstacles are
    /// watched for one that walks or drives into it ([`crate::perception::crossing`]); 0 (the
    /// default): none. 4 m found the crossing pedestrians of hw-mock's Euro NCAP cases, but
    /// SLOWs for nothing on an empty road in the daemon's real-time run and on bends keep it
    /// off by default (docs/traffic.md).
    pub watch_half_width: f64,
    /// Lower bound of an obstacle's fly above the road, metres: below is road (and what a
    /// vehicle drives over: kerbs, cat's eyes).
    pub min_height: f64,
    /// Upper bound above the road, metres: the vehicle's height plus a margin (bridges, signs,
    /// branches above are no obstacle).
    pub max_height: f64,
    /// Flies farther ahead are not looked at, metres.
    pub max_distance: f64,
    /// The corridor follows the vehicle's predicted path (the arc of its trusted speed and
    /// yaw rate, [`crate::path::PredictedPath`], as `path_hold_s` says) instead of going straight ahead.
    /// Off: the straight box, whatever the yaw rate (on a bend it takes in the outside's
    /// roadside and leaves out what is on the path).
    pub follow_path: bool,
    /// The path bends only as much as the vehicle has turned, the same way, for this long,
    /// seconds (the smallest curvature over that time, [`crate::path::PathEstimator`]): a
    /// bend is followed once it has lasted this, a lane change's or a correction's brief yaw
    /// rate is not extrapolated over the SLOW distance. 0: the yaw rate of the moment.
    pub path_hold_s: f64,
    /// How the path is predicted from the motion: `clothoid` (the curvature of the moment
    /// and its change over `path_rate_window_s`, [`crate::path::PathModel::Clothoid`]) or
    /// `held` (the curvature held over `path_hold_s`, gated by the arc of the moment).
    pub path_model: PathKind,
    /// `clothoid`: over how many seconds the curvature's change is measured (0: the arc of
    /// the moment).
    pub path_rate_window_s: f64,
    /// With `follow_path`, while the vehicle's motion is configured but not trusted (a
    /// motion fault), the corridor covers every path the vehicle could take at this yaw rate
    /// either way, at the assumed speed (a fan of arcs up to `fault_yaw_rate / speed`,
    /// [`crate::path::nearest_in_fan`]; never less than the straight box), rad/s. 0: the
    /// straight box.
    pub fault_yaw_rate: f64,
    /// A cluster whose lowest fly is higher than this above the road is no obstacle, metres
    /// (see the module docs, step 4).
    pub max_bottom: f64,
    /// Corridor flies whose uniqueness is measured per estimate (4 evaluations each).
    pub candidates: usize,
    /// A fly's match is unique when its ambiguity (see the module docs) is at most this.
    pub max_ambiguity: f64,
    /// Unique flies a cluster needs to be an obstacle.
    pub min_flies: usize,
    /// Depth extent of a cluster, in pixels of disparity.
    pub cluster_disparity_px: f64,
    /// ... and at least this many metres.
    pub min_cluster_depth: f64,
    /// Distinct squares of the left image a cluster's flies must lie in.
    pub min_cells: usize,
    /// Lateral extent of a cluster, at least (4 median absolute deviations), metres.
    pub min_width: f64,
    /// ... and at most: its flies lie within this of one another laterally, metres. A car's
    /// width (2 m): the unique matches on a car ahead lie mostly on its two vertical edges,
    /// 1.8 m apart, and with 1 m each edge was a cluster of its own, one vertical edge
    /// rejected as such (`MIN_WIDTH_PX`): hw-mock's car followed 9.7 m ahead was found on
    /// one frame in three, or its cluster jumped 1.7 m from one edge to the other.
    pub cluster_width: f64,
    /// Flies of a cluster verified along the whole epipolar line (0: no verification).
    pub verify_flies: usize,
    /// Disparity step of that verification, pixels.
    pub line_step_px: f64,
    /// A fly holds up along the line when the best match elsewhere on it is at most this
    /// share of its own (libelas's support threshold: 0.85). Looser than `max_ambiguity`:
    /// the line offers hundreds of chances to the noise where the shifts offer four.
    pub max_line_ambiguity: f64,
    /// Side of those squares, pixels.
    pub cell_px: u32,
    /// The verified flies are also matched by an 11 x 11 window along the whole line
    /// ([`crate::perception::dense`]); unless half of those it judges agree, the cluster is dropped.
    pub dense_check: bool,
    /// How much more disparity than its near face an obstacle may have, pixels: the decision
    /// judges it at [`super::Obstacle::near`], `f B / (f B / distance + disparity_error_px)` (0: at
    /// its near face). On hw-mock's 40 km/h approach the near face of the pedestrian read
    /// 0.3-0.45 px long at 22-25 m (1-1.5 m, a pixel being 3.4 m there).
    pub disparity_error_px: f64,
}

impl ObstacleConfig {
    /// The path model `path_model` names, with its window or hold.
    pub fn path(&self) -> crate::path::PathModel {
        match self.path_model {
            PathKind::Clothoid => crate::path::PathModel::Clothoid {
                window: self.path_rate_window_s,
            },
            PathKind::ClothoidGated => crate::path::PathModel::ClothoidGated {
                window: self.path_rate_window_s,
            },
            PathKind::Held => crate::path::PathModel::Held {
                hold: self.path_hold_s,
            },
        }
    }
}

impl Default for ObstacleConfig {
    fn default() -> Self {
        Self {
            corridor_half_width: 1.2,
            watch_half_width: 0.0,
            follow_path: true,
            path_hold_s: 2.0,
            path_model: PathKind::ClothoidGated,
            path_rate_window_s: 0.3,
            fault_yaw_rate: 0.15,
            min_height: 0.3,
            max_height: 2.0,
            max_distance: 40.0,
            max_bottom: 1.2,
            candidates: 96,
            max_ambiguity: 0.5,
            min_flies: 8,
            cluster_disparity_px: 2.0,
            min_cluster_depth: 0.1,
            min_cells: 4,
            min_width: 0.1,
            cluster_width: 2.0,
            cell_px: 8,
            verify_flies: 6,
            line_step_px: 1.0,
            max_line_ambiguity: 0.85,
            dense_check: true,
            disparity_error_px: 0.5,
        }
    }
}

/// An [`ObstacleConfig`] that cannot work, named as in the configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("perception parameter '{key}': {reason}")]
pub struct PerceptionParamError {
    pub key: &'static str,
    pub reason: String,
}

impl PerceptionParamError {
    pub(in crate::perception) fn check(
        key: &'static str,
        ok: bool,
        reason: impl FnOnce() -> String,
    ) -> Result<(), Self> {
        if ok {
            Ok(())
        } else {
            Err(Self {
                key,
                reason: reason(),
            })
        }
    }
}

impl ObstacleConfig {
    /// Checks every parameter; the error names the offending key.
    pub fn validate(&self) -> Result<(), PerceptionParamError> {
        let positive = |key, v: f64| {
            PerceptionParamError::check(key, v.is_finite() && v > 0.0, || {
                format!("must be > 0, got {v}")
            })
        };
        positive("obstacle.corridor_half_width", self.corridor_half_width)?;
        positive("obstacle.max_distance", self.max_distance)?;
        positive("obstacle.cluster_disparity_px", self.cluster_disparity_px)?;
        positive("obstacle.min_cluster_depth", self.min_cluster_depth)?;
        positive("obstacle.cluster_width", self.cluster_width)?;
        PerceptionParamError::check(
            "obstacle.min_width",
            self.min_width.is_finite() && self.min_width >= 0.0,
            || format!("must be >= 0, got {}", self.min_width),
        )?;
        PerceptionParamError::check(
            "obstacle.max_height",
            self.min_height.is_finite()
                && self.max_height.is_finite()
                && self.max_height > self.min_height,
            || format!("must be greater than min_height ({})", self.min_height),
        )?;
        PerceptionParamError::check(
            "obstacle.max_ambiguity",
            self.max_ambiguity.is_finite() && self.max_ambiguity > 0.0,
            || format!("must be > 0, got {}", self.max_ambiguity),
        )?;
        PerceptionParamError::check(
            "obstacle.candidates",
            (16..=4096).contains(&self.candidates),
            || format!("must be within 16..=4096, got {}", self.candidates),
        )?;
        PerceptionParamError::check(
            "obstacle.min_flies",
            (1..=self.candidates).contains(&self.min_flies),
            || format!("must be within 1..=candidates, got {}", self.min_flies),
        )?;
        PerceptionParamError::check(
            "obstacle.min_cells",
            (1..=self.min_flies).contains(&self.min_cells),
            || format!("must be within 1..=min_flies, got {}", self.min_cells),
        )?;
        PerceptionParamError::check(
            "obstacle.cell_px",
            (1..=256).contains(&self.cell_px),
            || format!("must be within 1..=256, got {}", self.cell_px),
        )?;
        PerceptionParamError::check("obstacle.verify_flies", self.verify_flies <= 32, || {
            format!("must be within 0..=32, got {}", self.verify_flies)
        })?;
        PerceptionParamError::check(
            "obstacle.max_line_ambiguity",
            self.max_line_ambiguity.is_finite() && self.max_line_ambiguity > 0.0,
            || format!("must be > 0, got {}", self.max_line_ambiguity),
        )?;
        PerceptionParamError::check(
            "obstacle.line_step_px",
            self.line_step_px.is_finite() && (0.25..=8.0).contains(&self.line_step_px),
            || format!("must be within [0.25, 8], got {}", self.line_step_px),
        )?;
        self.within_what_sees_a_pedestrian()
    }

    /// Bounds that keep a pedestrian an obstacle: a corridor wider than a person, a height
    /// band a person crosses, uniqueness and cluster sizes a person's flies can meet. Outside
    /// them no obstacle is ever reported (a `min_width` of 1e6 m, a `max_ambiguity` of 1e-9).
    fn within_what_sees_a_pedestrian(&self) -> Result<(), PerceptionParamError> {
        let within = |key, v: f64, lo: f64, hi: f64| {
            PerceptionParamError::check(key, v.is_finite() && (lo..=hi).contains(&v), || {
                format!("must be within {lo}..={hi}, got {v}")
            })
        };
        within(
            "obstacle.corridor_half_width",
            self.corridor_half_width,
            0.5,
            3.0,
        )?;
        PerceptionParamError::check(
            "obstacle.watch_half_width",
            self.watch_half_width == 0.0
                || (self.watch_half_width.is_finite()
                    && self.watch_half_width >= self.corridor_half_width + 0.5
                    && self.watch_half_width <= 8.0),
            || {
                format!(
                    "must be 0 (no watch) or within corridor_half_width + 0.5 ({})..=8, got {}",
                    self.corridor_half_width + 0.5,
                    self.watch_half_width
                )
            },
        )?;
        within("obstacle.min_height", self.min_height, 0.0, 1.0)?;
        within("obstacle.max_height", self.max_height, 1.0, 5.0)?;
        within("obstacle.max_distance", self.max_distance, 5.0, 200.0)?;
        within("obstacle.max_bottom", self.max_bottom, 0.5, 5.0)?;
        within("obstacle.path_hold_s", self.path_hold_s, 0.0, 5.0)?;
        within(
            "obstacle.path_rate_window_s",
            self.path_rate_window_s,
            0.0,
            2.0,
        )?;
        // At most the largest plausible yaw rate a VCU_Motion frame may carry (1.5 rad/s).
        within("obstacle.fault_yaw_rate", self.fault_yaw_rate, 0.0, 1.5)?;
        within("obstacle.max_ambiguity", self.max_ambiguity, 0.1, 1.0)?;
        within(
            "obstacle.max_line_ambiguity",
            self.max_line_ambiguity,
            0.3,
            1.0,
        )?;
        within(
            "obstacle.cluster_disparity_px",
            self.cluster_disparity_px,
            0.5,
            16.0,
        )?;
        within(
            "obstacle.min_cluster_depth",
            self.min_cluster_depth,
            0.0,
            2.0,
        )?;
        within("obstacle.min_width", self.min_width, 0.0, 0.5)?;
        within("obstacle.cluster_width", self.cluster_width, 0.3, 5.0)?;
        within(
            "obstacle.disparity_error_px",
            self.disparity_error_px,
            0.0,
            2.0,
        )?;
        PerceptionParamError::check("obstacle.min_flies", self.min_flies <= 32, || {
            format!("must be within 1..=32, got {}", self.min_flies)
        })
    }
}
