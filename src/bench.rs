//! `flyd bench`: timing of the engine on a synthetic scene, one thread.
//!
//! The scene is hw-mock's `pedestrian-4m` rendered through the mock rig (or, with
//! `--scenario`, a scenario's first frames played in order, the flies moved with its motion
//! between frames). Two frames with
//! different sensor noise alternate every `generations_per_frame` generations, so the figures
//! include the full re-evaluation a new frame costs, in the proportion the daemon sees it
//! (a pair every 3 generations at 30 fps and ~10 ms a generation). Frames are rendered and
//! prepared before timing starts. Each generation runs [`Perception::evolve`] (the engine's
//! generation: what `all`, `new_frame` and `same_frame` time), then the road measurement
//! (on a new frame: `road`) and the obstacle stage (`obstacle`), each timed apart.

use crate::mock::MockStereo;
use crate::replay::Timing;
use flyd_core::engine::{EngineParams, phase};
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::isa::Isa;
use flyd_core::perception::{Perception, PerceptionConfig};
use serde::Serialize;
use std::time::{Duration, Instant};

/// What to time.
#[derive(Debug, Clone)]
pub struct GenerationBench {
    pub flies: usize,
    pub width: u32,
    pub height: u32,
    pub generations: u64,
    pub generations_per_frame: u64,
    /// Instruction set of the hot loops; the best this CPU has when `None`.
    pub isa: Option<Isa>,
    /// The perception stages timed after each generation.
    pub perception: PerceptionConfig,
    /// The engine's parameters (`flies` replaces theirs).
    pub engine: EngineParams,
    /// A hw-mock scenario whose frames are played in order instead (its first
    /// [`SCENARIO_FRAMES`], looped), the flies moved with its own motion between frames
    /// when `predict`.
    pub scenario: Option<String>,
    pub predict: bool,
}

/// Frames of a scenario the benchmark renders (2 s at 30 fps).
pub const SCENARIO_FRAMES: u32 = 60;

/// Timing of generations, microseconds.
#[derive(Debug, Clone, Serialize)]
pub struct GenerationReport {
    /// The scene: `pedestrian-4m` (two noise draws alternating), or a scenario played in order.
    pub scene: String,
    /// The flies were moved with the scenario's motion between frames.
    pub predict: bool,
    pub flies: usize,
    pub width: u32,
    pub height: u32,
    pub generations: u64,
    pub generations_per_frame: u64,
    /// Instruction set the hot loops ran on.
    pub isa: &'static str,
    /// Every timed generation.
    pub all: Timing,
    /// Generations that re-evaluated the whole population on a new frame.
    pub new_frame: Timing,
    /// Generations on an unchanged frame (only offspring evaluated).
    pub same_frame: Timing,
    /// Flies evaluated per second over the run.
    pub flies_per_second: f64,
    /// Mean change evidence on the new frames (the engine's `change`: what draws guided
    /// immigrants; 0 on a still scene).
    pub change_mean: f64,
    /// The obstacle stage after each generation ([`Perception::find_obstacle`]).
    pub obstacle: Timing,
    /// Its total time over the generations' total: what it adds to a generation.
    pub obstacle_share: f64,
    /// The road measurement on each new frame's first generation
    /// ([`Perception::measure_road`]; nothing on the others).
    pub road: Timing,
    /// Its total time over the generations' total.
    pub road_share: f64,
    /// Median microseconds a generation in each step (built with `--features phase-timers`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub phases_us: Option<Vec<(&'static str, f64)>>,
}

impl std::fmt::Display for GenerationReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} ({}), {} flies, {}x{}, {} generations, a new frame every {}, {}",
            self.scene,
            if self.predict {
                "flies moved with the vehicle"
            } else {
                "flies not moved"
            },
            self.flies,
            self.width,
            self.height,
            self.generations,
            self.generations_per_frame,
            self.isa
        )?;
        for (name, t) in [
            ("all", &self.all),
            ("new frame", &self.new_frame),
            ("same frame", &self.same_frame),
        ] {
            writeln!(
                f,
                "  {name:<10} median {:8.1} us  min {:8.1} us  max {:8.1} us  p95 {:8.1} us",
                t.median_us, t.min_us, t.max_us, t.p95_us
            )?;
        }
        for (name, t, share) in [
            ("obstacle", &self.obstacle, self.obstacle_share),
            ("road/frame", &self.road, self.road_share),
        ] {
            writeln!(
                f,
                "  {name:<10} median {:8.1} us  p95 {:8.1} us  max {:8.1} us: {:.1} % of the generations' time",
                t.median_us,
                t.p95_us,
                t.max_us,
                100.0 * share
            )?;
        }
        write!(
            f,
            "  {:.3e} flies evaluated per second",
            self.flies_per_second
        )?;
        if let Some(phases) = &self.phases_us {
            write!(f, "\n  median us a generation:")?;
            for (name, us) in phases {
                write!(f, " {name} {us:.1}")?;
            }
        }
        Ok(())
    }
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("hw-mock has no {0} scenario")]
    NoScenario(String),
    #[error("the benchmark scene")]
    Mock(#[from] crate::mock::MockError),
    #[error("the benchmark frames")]
    Frame(#[from] flyd_core::frame::FrameError),
    #[error("the engine")]
    Engine(#[from] flyd_core::engine::EngineError),
    #[error("perception")]
    Perception(#[from] flyd_core::perception::PerceptionError),
}

/// The scene the benchmark renders.
const SCENE: &str = "pedestrian-4m";

/// Runs the benchmark (renders the scene first; that is not timed).
pub fn generations(cfg: &GenerationBench) -> Result<GenerationReport, BenchError> {
    let name = cfg.scenario.as_deref().unwrap_or(SCENE);
    let scenario =
        hw_mock::Scenario::by_name(name).ok_or_else(|| BenchError::NoScenario(name.into()))?;
    let played = cfg.scenario.is_some();
    let count = if played {
        SCENARIO_FRAMES.min(scenario.frame_count())
    } else {
        2
    };
    let fps = scenario.fps();
    let motions: Vec<_> = (0..count)
        .map(|f| flyd_core::kinematics::VehicleMotion {
            speed: scenario.speed_at(f),
            yaw_rate: scenario.yaw_rate_at(f),
        })
        .collect();
    let mut mock = MockStereo::new(scenario, cfg.width, cfg.height)?;
    let mut frames = Vec::new();
    for index in 0..count {
        let (l, r) = mock.frame(index)?;
        frames.push(StereoFrame::new(
            PreparedImage::from_pixels(cfg.width, cfg.height, PixelFormat::Rgb8, l)?,
            PreparedImage::from_pixels(cfg.width, cfg.height, PixelFormat::Rgb8, r)?,
            index as u64,
        ));
    }
    let params = EngineParams {
        flies: cfg.flies,
        ..cfg.engine.clone()
    };
    let warmup = 50;
    let mut perception = Perception::new(mock.rig(), params, cfg.perception)?.with_warmup(warmup);
    if let Some(isa) = cfg.isa {
        perception.engine_mut().set_isa(isa);
    }
    let k = cfg.generations_per_frame.max(1);
    let (mut all, mut new, mut same) = (Vec::new(), Vec::new(), Vec::new());
    let (mut obstacle, mut road) = (Vec::new(), Vec::new());
    let mut evaluated = 0usize;
    let mut change_sum = 0.0;
    let (mut total, mut obstacle_total, mut road_total) =
        (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let mut phases: Vec<Vec<Duration>> = vec![Vec::new(); phase::Phase::ALL.len()];
    for g in 0..warmup + cfg.generations {
        if g == warmup {
            phase::take();
        }
        let index = ((g / k) % u64::from(count)) as usize;
        let frame = &frames[index];
        if played && g % k == 0 && g > 0 && cfg.predict {
            // Looping back to the first frame is a jump no vehicle makes: not predicted.
            if index > 0 {
                perception.predict(motions[index - 1], 1.0 / fps);
            }
        }
        let t = Instant::now();
        let stats = perception.evolve(frame)?;
        let dt = t.elapsed();
        let t = Instant::now();
        perception.measure_road(frame)?;
        let dr = t.elapsed();
        let t = Instant::now();
        perception.find_obstacle(frame)?;
        let dob = t.elapsed();
        if g >= warmup {
            all.push(dt);
            obstacle.push(dob);
            total += dt;
            obstacle_total += dob;
            road_total += dr;
            if stats.new_frame {
                road.push(dr);
            }
            evaluated += stats.evaluated;
            if let Some(p) = phase::take() {
                for (k, &(_, ns)) in p.iter().enumerate() {
                    phases[k].push(Duration::from_nanos(ns));
                }
            }
            if stats.new_frame {
                change_sum += f64::from(stats.change);
                new.push(dt);
            } else {
                same.push(dt);
            }
        }
    }
    let phases_us = phase::take().map(|_| {
        phase::Phase::ALL
            .iter()
            .zip(&mut phases)
            .map(|(p, d)| (p.name(), Timing::of(d).median_us))
            .collect()
    });
    Ok(GenerationReport {
        scene: name.to_string(),
        predict: played && cfg.predict,
        flies: cfg.flies,
        width: cfg.width,
        height: cfg.height,
        generations: cfg.generations,
        isa: perception.engine().isa().name(),
        generations_per_frame: k,
        all: Timing::of(&mut all),
        new_frame: Timing::of(&mut new),
        same_frame: Timing::of(&mut same),
        flies_per_second: evaluated as f64 / total.as_secs_f64().max(1e-9),
        change_mean: change_sum / new.len().max(1) as f64,
        obstacle: Timing::of(&mut obstacle),
        obstacle_share: obstacle_total.as_secs_f64() / total.as_secs_f64().max(1e-9),
        road: Timing::of(&mut road),
        road_share: road_total.as_secs_f64() / total.as_secs_f64().max(1e-9),
        phases_us,
    })
}
