//! What the evolution thread tells the control thread after each generation.
//!
//! A [`Snapshot`] is small and `Copy`: it goes through a bounded channel without allocating.
//! It carries the population's summary, the road and the debounced nearest obstacle
//! ([`flyd_core::perception`]), not the flies themselves (5000 flies x 10 floats per
//! generation would be 200 kB of copying for a control thread that needs a dozen numbers).

use std::time::Duration;

use crate::source::FrameMeta;
use flyd_core::can::messages::{ObstacleMsg, PathMsg};
use flyd_core::path::PathEstimate;
use flyd_core::perception::{CorridorCounts, RoadEstimate, Tracked};
use flyd_core::sensor::SensorFaults;

/// One generation's outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    /// Engine generation number.
    pub generation: u64,
    /// The paper's global warning (mean fly warning): what the decision thresholds compare.
    pub global_warning: f64,
    /// Where the evidence is, m^-3 (diagnostic, see the engine docs).
    pub danger: f64,
    /// Fraction of the flies evaluated in the generation whose windows match (see
    /// [`flyd_core::engine::GenerationStats`]): what `blind` is judged on, logged with the stats.
    pub matched: f64,
    /// The sensor faults of the newest pair ([`flyd_core::sensor`]), BLIND included (on the
    /// last `blind_pairs` new pairs, fewer than `blind_matched` of the flies matched: the
    /// images match nowhere, so a low warning proves nothing). Any of them is CAMERA_ERROR.
    pub sensor: SensorFaults,
    pub visible: usize,
    /// The generation saw a new pair (the population was re-evaluated).
    pub new_frame: bool,
    /// The road the heights are measured from.
    pub road: RoadEstimate,
    /// The declared mount against the road measured so far
    /// ([`flyd_core::perception::mount_check`]), and whether it is off by more than the road
    /// estimator absorbs (the INTERNAL fault).
    pub mount: flyd_core::perception::mount_check::MountReport,
    pub mount_fault: bool,
    /// The nearest obstacle in the corridor, debounced over frames.
    pub tracked: Tracked,
    /// What the latest obstacle estimate looked at.
    pub corridor: CorridorCounts,
    /// The paths the corridor follows (none: straight, no trusted motion).
    pub path: Option<PathEstimate>,
    /// How far ahead this frame was searched, metres (`Perception::search_far`).
    pub search_far: f64,
    /// Wall time of both engines' generation plus the perception stages.
    pub generation_time: Duration,
    /// `generation_time` over the configured maximum.
    pub overrun: bool,
    /// The pair evaluated, and its identity (`StereoFrame::id`).
    pub left: FrameMeta,
    pub right: FrameMeta,
    pub pair_id: u64,
    /// Pairing counters of the evolution thread.
    pub pairs: u64,
    pub pair_rejects: u64,
    /// Too many consecutive rejected candidates (STEREO_SKEW).
    pub skew_fault: bool,
    /// The population has not run `warmup_generations` yet: its danger is not trusted.
    pub warming_up: bool,
    /// When the generation finished (daemon clock).
    pub taken_at: Duration,
}

impl Snapshot {
    /// Capture time of the older frame of the pair.
    pub fn capture_time(&self) -> Duration {
        self.left.timestamp.min(self.right.timestamp)
    }

    /// Where the decision judges the confirmed obstacle, metres: its near bound
    /// ([`flyd_core::perception::Obstacle::near`]).
    pub fn confirmed_distance(&self) -> Option<f64> {
        self.tracked.decision_distance()
    }

    /// FLYD_Obstacle for this snapshot.
    pub fn obstacle_msg(&self) -> ObstacleMsg {
        ObstacleMsg::of(&self.tracked, &self.road)
    }

    /// FLYD_Path for this snapshot.
    pub fn path_msg(&self) -> PathMsg {
        PathMsg::of(self.path)
    }
}
