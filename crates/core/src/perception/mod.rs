//! From a fly population to what the decision needs, in metres: the road and the nearest
//! obstacle in the corridor.
//!
//! [`Perception`] owns the engine (the paper's population, whose region of interest is
//! measured from the road), the road estimator ([`road_estimator`]), the obstacle stage ([`obstacle`])
//! and its debounce ([`track`]). One [`Perception::step`] is one generation; on the first
//! generation of each new frame the road is measured and the engine takes it; on every
//! `estimate_every`-th generation (and each new frame's first) the obstacle stage looks at the
//! corridor and the tracker takes its verdict.
//!
//! Pure, like the engine: frames in, values out; no allocation per step.

pub mod crossing;
pub mod dense;
pub mod motion;
pub mod mount_check;
pub mod obstacle;
pub mod range;
pub mod road_estimator;
pub mod track;

use serde::{Deserialize, Serialize};

pub use obstacle::{
    CorridorCounts, Obstacle, ObstacleConfig, ObstacleFinder, PathKind, PerceptionParamError,
};
pub use range::{Resolution, SearchReach};
pub use road_estimator::{RoadConfig, RoadEstimate, RoadEstimator, RoadSource};
pub use track::{TrackConfig, Tracked, Tracker};

use crate::decision::{DecisionConfig, DecisionMode};
use crate::engine::{Corridor, Engine, EngineError, EngineParams, GenerationStats};
use crate::frame::StereoFrame;
use crate::geometry::StereoRig;
use crate::path::{PathEstimate, PathEstimator};
use crate::road_plane::RoadPlane;

/// The `[perception]` settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionConfig {
    /// Obstacle estimates every this many generations besides each new frame's first (1:
    /// every generation).
    pub estimate_every: u32,
    pub obstacle: ObstacleConfig,
    pub track: TrackConfig,
    pub road: RoadConfig,
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self {
            estimate_every: 1,
            obstacle: ObstacleConfig::default(),
            track: TrackConfig::default(),
            road: RoadConfig::default(),
        }
    }
}

impl PerceptionConfig {
    /// Checks every parameter; the error names the offending key.
    pub fn validate(&self) -> Result<(), PerceptionParamError> {
        self.obstacle.validate()?;
        self.track.validate()?;
        PerceptionParamError::check(
            "estimate_every",
            (1..=1000).contains(&self.estimate_every),
            || format!("must be within 1..=1000, got {}", self.estimate_every),
        )?;
        self.road.validate()
    }
}

/// The nearest distance ahead, metres, from which on both cameras see the whole cross-section
/// of the corridor (`corridor_half_width` either side, `min_height` to `max_height` above the
/// calibration's road) and its disparity is within what the flies search (`min_depth` on):
/// nearer, an obstacle in the corridor is seen by one camera only, or in part, and the few
/// pixels both share match anything. 4.8 m on KITTI's rig (the corridor's foot, 1.35 m
/// below cameras 1.65 m up that see 0.28 rad down), 2.2 m on hw-mock's (its sides).
/// [`Tracker::new`] says what an obstacle nearer must show.
pub fn judgeable_distance(rig: &StereoRig, obstacle: &ObstacleConfig, min_depth: f64) -> f64 {
    let (half, lo, hi) = (
        obstacle.corridor_half_width,
        obstacle.min_height,
        obstacle.max_height,
    );
    let seen = |z: f64| {
        [(-half, lo), (half, lo), (-half, hi), (half, hi)]
            .iter()
            .all(|&(x, y)| {
                let p = nalgebra::Point3::new(x, y, z);
                [&rig.left, &rig.right].iter().all(|cam| {
                    cam.pixel_from_vehicle(&p)
                        .is_some_and(|px| cam.contains(&px))
                })
            })
    };
    // From the farthest obstacle looked at inwards, in steps of 5 cm: the nearest distance
    // from which on the whole cross-section is seen.
    let far = obstacle.max_distance.max(min_depth);
    let mut z = far;
    while z - 0.05 >= min_depth && seen(z - 0.05) {
        z -= 0.05;
    }
    z.max(min_depth)
}

/// How far ahead `params` and `obstacle` search: the least of the depth range, the region
/// of interest and the obstacle range, metres.
fn search_far(params: &EngineParams, obstacle: &ObstacleConfig) -> f64 {
    params
        .max_depth
        .min(params.roi.map_or(f64::INFINITY, |r| r.max_ahead))
        .min(obstacle.max_distance)
}

/// Why perception cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PerceptionError {
    #[error(transparent)]
    Param(#[from] PerceptionParamError),
    #[error("the engine")]
    Engine(#[source] EngineError),
}

/// What one step found.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PerceptionReport {
    /// The engine's generation.
    pub stats: GenerationStats,
    /// The road the heights are measured from.
    pub road: RoadEstimate,
    /// The debounced obstacle (see [`Tracker`]): the corridor's, or one beside it predicted
    /// to enter it ([`crossing`]).
    pub tracked: Tracked,
    /// The nearest obstacle watched beside the corridor, left and right ([`crossing`];
    /// nothing without watch zones).
    pub watched: [Tracked; 2],
    /// What the latest obstacle estimate looked at.
    pub corridor: CorridorCounts,
    /// Whether this step ran the obstacle stage.
    pub estimated: bool,
}

/// The engines, the road and the obstacle stage (see the module docs).
pub struct Perception {
    engine: Engine,
    road: RoadEstimator,
    finder: ObstacleFinder,
    tracker: Tracker,
    config: PerceptionConfig,
    /// Generations before the obstacle stage runs (the population is not trusted before).
    warmup: u64,
    report: PerceptionReport,
    /// The paths of the motion given for the next new frame ([`Perception::predict`] or
    /// [`Perception::follow`]); none: that frame's corridor is straight.
    predicted_path: Option<PathEstimate>,
    /// The curvature the vehicle has held (`obstacle.path_hold_s`).
    path_estimator: PathEstimator,
    /// The paths the current frame's corridor follows; none: straight, no trusted motion.
    followed: Option<PathEstimate>,
    /// With [`Perception::with_reach`]: the search reaches the SLOW distance at the speed of
    /// the motion given for the next new frame (`pending_reach`), from that frame on.
    reach: Option<SearchReach>,
    pending_reach: Option<f64>,
    /// The next new frame's corridor is the fan of this curvature either way, 1/m
    /// ([`Perception::motion_unknown`]).
    pending_fan: Option<f64>,
    /// How far the current frame is searched, metres (see [`Perception::search_far`]).
    search_far: f64,
    /// The rig's f B, pixel metres.
    fb: f64,
    /// The corridor the corridor immigrants scan (none without a road); it bends with the
    /// held path.
    corridor: Option<Corridor>,
    /// The zones beside the corridor, left and right ([`crossing`]); none with
    /// `obstacle.watch_half_width = 0`.
    watch: Vec<Watch>,
    /// The vehicle's speed over the current frame, and over the next, m/s, as its trusted
    /// motion gave it (none: not known).
    speed: Option<f64>,
    pending_speed: Option<f64>,
}

/// A zone beside the corridor: its finder, its tracker and their latest verdict.
struct Watch {
    finder: ObstacleFinder,
    tracker: Tracker,
    tracked: Tracked,
}

impl Perception {
    /// The engine over `rig`, the road prior being the calibration's (y = 0).
    pub fn new(
        rig: &StereoRig,
        params: EngineParams,
        config: PerceptionConfig,
    ) -> Result<Self, PerceptionError> {
        config.validate()?;
        let flies = params.flies;
        let params_min_depth = params.min_depth;
        let scan = params.roi.map(|_| params.corridor_scan_distance);
        let mut engine = Engine::new(rig, params).map_err(PerceptionError::Engine)?;
        // Some immigrants scan the corridor the obstacle stage looks in; a scene without a
        // road (a dataset) has none.
        let corridor = scan.map(|scan| {
            let o = &config.obstacle;
            Corridor {
                half_width: o.corridor_half_width as f32,
                min_height: o.min_height as f32,
                max_height: o.max_height as f32,
                max_distance: o.max_distance.min(scan) as f32,
                curvature: 0.0,
                watch_half_width: o.watch_half_width as f32,
            }
        });
        engine.set_corridor(corridor);
        let prior = RoadPlane::FLAT;
        let fb = rig.right.intrinsics().fx * rig.baseline();
        let far = search_far(engine.params(), &config.obstacle);
        let judgeable = judgeable_distance(rig, &config.obstacle, params_min_depth);
        let image = (rig.left.width(), rig.left.height());
        let (inner, outer) = (
            config.obstacle.corridor_half_width,
            config.obstacle.watch_half_width,
        );
        let watch = if outer > inner {
            [(-outer, -inner), (inner, outer)]
                .into_iter()
                .map(|(lo, hi)| Watch {
                    finder: ObstacleFinder::new(config.obstacle, flies, fb, image).watching(lo, hi),
                    tracker: Tracker::new(config.track, judgeable, fb),
                    tracked: Tracked::NONE,
                })
                .collect()
        } else {
            Vec::new()
        };
        Ok(Self {
            engine,
            road: RoadEstimator::new(config.road, prior),
            finder: ObstacleFinder::new(config.obstacle, flies, fb, image),
            tracker: Tracker::new(config.track, judgeable, fb),
            report: PerceptionReport {
                stats: GenerationStats::default(),
                road: RoadEstimate::prior(prior),
                tracked: Tracked::NONE,
                watched: [Tracked::NONE; 2],
                corridor: CorridorCounts::default(),
                estimated: false,
            },
            path_estimator: PathEstimator::with_model(config.obstacle.path()),
            followed: None,
            reach: None,
            pending_reach: None,
            pending_fan: None,
            search_far: far,
            fb,
            corridor,
            watch,
            speed: None,
            pending_speed: None,
            config,
            warmup: 0,
            predicted_path: None,
        })
    }

    /// No obstacle estimate in the first `generations` generations: a population not yet
    /// converged on the scene holds chance matches, and a debounce fed with them would carry
    /// them past the warm-up.
    pub fn with_warmup(self, generations: u64) -> Self {
        Self {
            warmup: generations,
            ..self
        }
    }

    /// Generations before the population is trusted ([`Perception::with_warmup`]).
    pub fn warmup(&self) -> u64 {
        self.warmup
    }

    /// The search follows the speed: on each new frame after a [`Perception::predict`] or
    /// [`Perception::follow`], the flies and the obstacle stage reach the SLOW distance of
    /// `decision` at that motion's speed, never less than configured and at most what the
    /// rig searches ([`SearchReach`]); a frame without a trusted motion is searched as
    /// configured (which start-up checked against the assumed speed). Only in the obstacle
    /// mode: the global warning has no distance to reach.
    pub fn with_reach(self, decision: DecisionConfig) -> Self {
        if decision.mode != DecisionMode::Obstacle {
            return self;
        }
        Self {
            reach: Some(SearchReach::new(decision, self.fb)),
            ..self
        }
    }

    /// The speed-dependent search, if [`Perception::with_reach`] set one.
    pub fn reach(&self) -> Option<&SearchReach> {
        self.reach.as_ref()
    }

    /// How far ahead the current frame is searched, metres: the least of the depth range,
    /// the region of interest and the obstacle stage's range, as the speed extended them.
    pub fn search_far(&self) -> f64 {
        self.search_far
    }

    /// The engine.
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// The engine, e.g. to set its instruction set or to measure ambiguities.
    pub fn engine_mut(&mut self) -> &mut Engine {
        &mut self.engine
    }

    /// The road estimator (its latest points: [`RoadEstimator::swept`]).
    pub fn road(&self) -> &RoadEstimator {
        &self.road
    }

    pub fn config(&self) -> &PerceptionConfig {
        &self.config
    }

    /// The latest step's report.
    pub fn report(&self) -> &PerceptionReport {
        &self.report
    }

    /// Moves the flies with the vehicle's motion over `dt` seconds, between two frames
    /// ([`Engine::predict`]); with `obstacle.follow_path`, on the next frame the obstacle
    /// stage's corridor follows the path the vehicle has held over `obstacle.path_hold_s`,
    /// and what it finds must also be on the arc of the moment ([`PathEstimator`],
    /// [`PathEstimate`]). A frame not preceded by a prediction (no trusted motion) has a
    /// straight corridor, and the hold starts again after it.
    pub fn predict(&mut self, motion: crate::kinematics::VehicleMotion, dt: f64) {
        let moving = moving_region(&self.report.tracked, dt);
        self.engine.predict_around(motion, dt, moving);
        self.tracker.moved(motion.speed * dt, dt);
        for w in &mut self.watch {
            w.tracker.moved(motion.speed * dt, dt);
        }
        self.follow(motion, dt);
    }

    /// The vehicle's motion over the `dt` seconds before the next frame, for its path only
    /// (the flies stay where they are: `vehicle.predict_flies = false`); [`Perception::predict`]
    /// does this too.
    pub fn follow(&mut self, motion: crate::kinematics::VehicleMotion, dt: f64) {
        if self.config.obstacle.follow_path {
            self.predicted_path = Some(self.path_estimator.update(motion, dt));
        }
        self.pending_reach = self.reach.map(|r| r.at(motion.speed));
        self.pending_fan = None;
        self.pending_speed = Some(motion.speed);
    }

    /// The vehicle's motion is configured but not trusted before the next frame (a motion
    /// fault): with `obstacle.follow_path`, that frame's corridor covers every path the
    /// vehicle could take at `obstacle.fault_yaw_rate` either way at `speed` m/s (the speed
    /// the decision assumes then), never less than the straight box; the flies stay.
    pub fn motion_unknown(&mut self, speed: f64) {
        let o = &self.config.obstacle;
        self.pending_fan = o.follow_path.then(|| {
            crate::path::PredictedPath::of_motion(crate::kinematics::VehicleMotion {
                speed: speed.abs(),
                yaw_rate: o.fault_yaw_rate,
            })
            .curvature
        });
        self.predicted_path = None;
        self.pending_reach = None;
        self.pending_speed = None;
    }

    /// The vehicle's motion over the `dt` seconds before the next frame, as the daemon and
    /// every replay hand it over: trusted (`Some`), the flies moved with it when
    /// `predict_flies` ([`Perception::predict`]) or its path only ([`Perception::follow`]);
    /// configured but not trusted (`None`): [`Perception::motion_unknown`] at
    /// `assumed_speed`.
    pub fn vehicle_moved(
        &mut self,
        motion: Option<crate::kinematics::VehicleMotion>,
        dt: f64,
        predict_flies: bool,
        assumed_speed: f64,
    ) {
        match motion {
            Some(m) if predict_flies => self.predict(m, dt),
            Some(m) => self.follow(m, dt),
            None => self.motion_unknown(assumed_speed),
        }
    }

    /// The fan the current frame's corridor covers (its largest curvature either way, 1/m):
    /// the vehicle's motion was not trusted ([`Perception::motion_unknown`]).
    pub fn fan(&self) -> Option<f64> {
        self.finder.fan()
    }

    /// The path the obstacle stage's corridor follows on the current frame.
    pub fn path(&self) -> crate::path::PredictedPath {
        self.finder.path()
    }

    /// The paths of the current frame's corridor, as the vehicle's motion gave them
    /// (`FLYD_Path`); `None`: straight ahead, for want of a trusted motion (or with
    /// `obstacle.follow_path` off).
    pub fn path_estimate(&self) -> Option<PathEstimate> {
        self.followed
    }

    /// The left-image pixels and depths of the latest estimate's unique corridor flies
    /// ([`ObstacleFinder::unique_pixels`]).
    pub fn corridor_pixels(&self) -> impl Iterator<Item = (f32, f32, f32)> + '_ {
        self.finder.unique_pixels()
    }

    /// The nearest distance an obstacle is judged from one sighting, metres
    /// ([`judgeable_distance`]).
    pub fn judgeable_distance(&self) -> f64 {
        self.tracker.judgeable()
    }

    /// One generation on `frame`, then the road and obstacle stages
    /// ([`Perception::evolve`] then [`Perception::observe`]; see the module docs).
    pub fn step(&mut self, frame: &StereoFrame) -> Result<&PerceptionReport, EngineError> {
        self.evolve(frame)?;
        self.observe(frame)
    }

    /// One generation on `frame`.
    pub fn evolve(&mut self, frame: &StereoFrame) -> Result<GenerationStats, EngineError> {
        let stats = self.engine.step(frame)?;
        if stats.new_frame {
            self.followed = self.predicted_path.take();
            if self.followed.is_none() {
                self.path_estimator.reset();
            }
            let path = self.followed.unwrap_or(PathEstimate::STRAIGHT);
            self.finder.set_paths(path.held, path.now);
            for w in &mut self.watch {
                w.finder.set_paths(path.held, path.now);
            }
            self.speed = self.pending_speed.take();
            // The corridor immigrants scan along the held path (the straight box on a fan,
            // which the fan holds).
            if let Some(c) = self.corridor.as_mut() {
                // A clothoid: the arc of its displacement halfway along the scan.
                let k = path
                    .held
                    .effective_curvature(0.5 * f64::from(c.max_distance))
                    as f32;
                if c.curvature != k {
                    c.curvature = k;
                    self.engine.set_corridor(Some(*c));
                }
            }
            if let Some(k) = self.pending_fan.take() {
                self.finder.set_fan(k);
                for w in &mut self.watch {
                    w.finder.set_fan(k);
                }
            }
            if self.reach.is_some() {
                let far = self.pending_reach.take().unwrap_or(0.0);
                self.engine.set_reach(far);
                let o = &self.config.obstacle;
                self.finder.set_max_distance(o.max_distance.max(far));
                for w in &mut self.watch {
                    w.finder.set_max_distance(o.max_distance.max(far));
                }
                self.search_far = search_far(self.engine.params(), self.finder.config());
            }
        }
        self.report.stats = stats;
        self.report.estimated = false;
        Ok(stats)
    }

    /// After [`Perception::evolve`] on `frame`: on a new frame, measures the road (both engines
    /// take it for their next generation); when due, looks for the obstacle
    /// ([`Perception::measure_road`] then [`Perception::find_obstacle`]).
    pub fn observe(&mut self, frame: &StereoFrame) -> Result<&PerceptionReport, EngineError> {
        self.measure_road(frame)?;
        self.find_obstacle(frame)
    }

    /// After [`Perception::evolve`] on `frame`: the road, measured on a new frame's first
    /// generation (the engine takes it for its next generation); kept otherwise.
    pub fn measure_road(&mut self, frame: &StereoFrame) -> Result<&RoadEstimate, EngineError> {
        if self.config.road.enabled && self.report.stats.new_frame {
            let road = self.road.update(&mut self.engine, frame)?;
            self.engine.set_road(road.plane);
            self.report.road = road;
        }
        Ok(&self.report.road)
    }

    /// After [`Perception::measure_road`]: when due (each new frame's first generation and
    /// every `estimate_every`-th, after the warm-up), the obstacle stage and its debounce.
    pub fn find_obstacle(&mut self, frame: &StereoFrame) -> Result<&PerceptionReport, EngineError> {
        let stats = self.report.stats;
        let every = u64::from(self.config.estimate_every.max(1));
        let due = stats.new_frame || stats.generation.is_multiple_of(every);
        if due && stats.generation > self.warmup {
            let road = self.report.road.plane;
            let seen = self.finder.find(&mut self.engine, frame, &road)?;
            // The flies look around what was seen in the corridor; a scene without a road
            // (a dataset) has no corridor to look at.
            if self.engine.params().roi.is_some() {
                if self.watch.is_empty() {
                    self.engine.set_focus(self.finder.unique_pixels());
                } else {
                    // Half the focus around what the corridor saw, the rest around what
                    // each band watched beside it saw on its latest frame: the flies find a
                    // parked car's inner side and a pedestrian sooner (docs/traffic.md).
                    let share = crate::engine::MAX_FOCUS / (2 * self.watch.len());
                    let beside = self
                        .watch
                        .iter()
                        .flat_map(|w| w.finder.unique_pixels().take(share));
                    self.engine.set_focus(
                        self.finder
                            .unique_pixels()
                            .take(crate::engine::MAX_FOCUS / 2)
                            .chain(beside),
                    );
                }
            }
            let tracked = self.tracker.update(frame.id, seen);
            // Beside the corridor, once a frame: who may step into it.
            if stats.new_frame {
                for (w, shown) in self.watch.iter_mut().zip(&mut self.report.watched) {
                    let seen = w.finder.find(&mut self.engine, frame, &road)?;
                    w.tracked = w.tracker.update(frame.id, seen);
                    *shown = w.tracked;
                }
            }
            self.report.tracked = crossing::nearest_in_path(
                tracked,
                self.watch.iter().map(|w| w.tracked),
                self.config.obstacle.corridor_half_width,
                self.speed,
            );
            self.report.corridor = self.finder.counts();
            self.report.estimated = true;
        }
        Ok(&self.report)
    }
}

/// The tracked obstacle's region and travel over `dt` seconds, for the flies on it
/// ([`Engine::predict_around`]): once its track's motion is established, the flies
/// within 2 m of it across (a car's width either way of where its flies' median is) and from
/// a metre before its near end to 3 m behind its middle move with it. Its speed is bounded by
/// what an obstacle may drive ([`motion::MAX_SPEED`]); a wrong one
/// costs the flies moved with it, a quarter of them stay where they were whatever moves.
fn moving_region(tracked: &Tracked, dt: f64) -> Option<crate::engine::MovingRegion> {
    let (o, m) = (tracked.obstacle?, tracked.motion.filter(|m| m.established)?);
    let speed = m.speed.clamp(-motion::MAX_SPEED, motion::MAX_SPEED);
    if !(speed.is_finite() && dt.is_finite() && dt > 0.0) {
        return None;
    }
    let (lateral, near, distance) = (o.lateral as f32, o.near as f32, o.distance as f32);
    Some(crate::engine::MovingRegion {
        x: (lateral - 2.0, lateral + 2.0),
        z: (near - 1.0, distance.max(near) + 3.0),
        travelled: speed * dt,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// KITTI's colour pair, 1.65 m up and level, sees 0.28 rad below its axis: the corridor's
    /// foot (0.3 m above the road) enters both images 4.8 m ahead. Nearer, the "obstacles"
    /// of the odometry 06 drive (1.0-1.9 m) were matches of pixels the cameras barely share.
    #[test]
    fn kitti_judges_obstacles_from_the_corridors_foot() {
        let rig = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
            .join("tests/fixtures/kitti/kitti2012_train_000000/rig.toml");
        let cal = crate::calib::load(&rig).expect("rig");
        let o = ObstacleConfig::default();
        let d = judgeable_distance(&cal.rig, &o, 1.0);
        assert!((4.5..5.2).contains(&d), "{d}");
        // The foot: (1.65 - 0.3) m below the cameras, at the bottom row's angle.
        let k = cal.rig.left.intrinsics();
        let below = (f64::from(cal.rig.left.height()) - 0.5 - k.cy) / k.fy;
        let foot = (1.65 - o.min_height) / below;
        assert!((d - foot).abs() < 0.2, "{d} vs {foot}");
        // Never nearer than the search range.
        assert!(judgeable_distance(&cal.rig, &o, 6.0) >= 6.0);
    }
}
