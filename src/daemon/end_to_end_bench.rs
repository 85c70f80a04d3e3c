//! End-to-end reaction benchmark (`flyd bench --end-to-end`): the whole threaded daemon on
//! hw-mock cameras and the in-memory bus, repeated.
//!
//! Reaction of one run = time of the first STOP command frame the control thread hands to the
//! bus at or after the capture timestamp of the first frame showing the obstacle in the lane,
//! minus that capture timestamp; both on the daemon clock. A run ends at that STOP (or at the
//! end of the scenario: a miss). STOPs before the obstacle appears are counted as false stops.
//! Each run uses another engine seed, so the runs are samples, not repeats.
//!
//! Each reaction is split at the snapshot the control thread held when it decided the first
//! STOP: `pipeline_ms` is from the capture of that snapshot's frames to the STOP frame (ring,
//! pairing, one generation, channel, control period: what the daemon adds), the rest is the
//! evolution converging on the obstacle over the frames before it.

use std::path::Path;
use std::time::{Duration, Instant};

use serde::Serialize;

use super::{DaemonError, Shutdown, run, spawn_named};
use crate::bus::MemoryBus;
use crate::config::{CameraSource, DaemonConfig};
use crate::mock::camera::mock_cameras;
use crate::os_clock::{MonotonicClock, SharedClock};
use flyd_core::can::messages::{CanMessage, CommandMsg};
use flyd_core::decision::Command;

/// The demo configuration (config/demo.toml), which the benchmark runs by default.
pub const DEMO_CONFIG: &str = include_str!("../../config/demo.toml");

/// Results over all runs (milliseconds).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    pub scenario: String,
    pub runs: usize,
    pub width: u32,
    pub height: u32,
    pub flies: usize,
    /// Reaction of each run that stopped, in run order.
    pub reactions_ms: Vec<f64>,
    pub median_ms: Option<f64>,
    pub p95_ms: Option<f64>,
    /// Per run that stopped: capture of the frames behind the STOP decision -> STOP frame.
    pub pipeline_ms: Vec<f64>,
    pub pipeline_median_ms: Option<f64>,
    /// Runs without a STOP after the obstacle appeared.
    pub misses: usize,
    /// Runs with a STOP before the obstacle appeared.
    pub false_stops: usize,
}

/// [`bench_end_to_end_with`] on the demo configuration.
pub fn bench_end_to_end(runs: usize) -> Result<BenchReport, DaemonError> {
    let config = DaemonConfig::from_toml(DEMO_CONFIG, Path::new("config/demo.toml"))?;
    bench_end_to_end_with(&config, runs)
}

/// `runs` runs of the daemon on `config`'s mock scenario (which must have an obstacle).
pub fn bench_end_to_end_with(
    config: &DaemonConfig,
    runs: usize,
) -> Result<BenchReport, DaemonError> {
    let CameraSource::Mock { scenario, .. } = &config.cameras.source else {
        return Err(DaemonError::BenchScenario(
            "the configuration has real cameras (set cameras.mock)".into(),
        ));
    };
    let mut reactions = Vec::with_capacity(runs);
    let mut pipeline = Vec::with_capacity(runs);
    let (mut misses, mut false_stops) = (0, 0);
    for i in 0..runs {
        let mut config = config.clone();
        config.engine.seed = config.engine.seed.wrapping_add(i as u64);
        let outcome = one_run(&config, scenario)?;
        false_stops += usize::from(outcome.false_stop);
        match outcome.reaction {
            Some(r) => reactions.push(r.as_secs_f64() * 1e3),
            None => misses += 1,
        }
        if let Some(p) = outcome.pipeline {
            pipeline.push(p.as_secs_f64() * 1e3);
        }
        tracing::info!(run = i, reaction_ms = ?outcome.reaction.map(|r| r.as_secs_f64() * 1e3), "bench run");
    }
    let pct = |values: &[f64], q: f64| {
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        (!sorted.is_empty()).then(|| {
            let rank = (q * sorted.len() as f64).ceil() as usize;
            sorted[rank.clamp(1, sorted.len()) - 1]
        })
    };
    Ok(BenchReport {
        scenario: scenario.clone(),
        runs,
        width: config.cameras.width,
        height: config.cameras.height,
        flies: config.engine.flies,
        median_ms: pct(&reactions, 0.5),
        p95_ms: pct(&reactions, 0.95),
        reactions_ms: reactions,
        pipeline_median_ms: pct(&pipeline, 0.5),
        pipeline_ms: pipeline,
        misses,
        false_stops,
    })
}

struct Outcome {
    reaction: Option<Duration>,
    pipeline: Option<Duration>,
    false_stop: bool,
}

/// Longest a run may take beyond its scenario (deadlock guard).
const GUARD: Duration = Duration::from_secs(60);

fn one_run(config: &DaemonConfig, scenario: &str) -> Result<Outcome, DaemonError> {
    let clock: SharedClock = MonotonicClock::shared();
    let (w, h) = (config.cameras.width, config.cameras.height);
    let (left, right, truth) = mock_cameras(scenario, w, h, &clock, &[])?;
    if truth.first_obstacle_frame().is_none() {
        return Err(DaemonError::BenchScenario(format!(
            "scenario {scenario} has none"
        )));
    }
    let bus_clock = clock.clone();
    let bus = MemoryBus::new(move || bus_clock.now());
    let shutdown = Shutdown::new();
    let daemon = {
        let (bus, clock, shutdown, config) =
            (bus.clone(), clock.clone(), shutdown.clone(), config.clone());
        spawn_named("flyd-bench-run", move || {
            run(
                (Box::new(left), Box::new(right)),
                Box::new(bus),
                clock,
                &config,
                shutdown,
                super::ServiceNotifier::none(),
            )
        })
        .map_err(|error| DaemonError::Spawn {
            thread: "flyd-bench-run",
            error,
        })?
    };
    let command_id = config.can.messages.command.id;
    let data_id = config.can.messages.command.data_id;
    let (mut seen, mut outcome) = (0, None);
    let mut false_stop = false;
    let started = Instant::now();
    while !daemon.is_finished() && started.elapsed() < GUARD {
        std::thread::sleep(Duration::from_millis(2));
        let frames = bus.frames();
        let obstacle_at = truth.first_obstacle_at();
        for f in &frames[seen..] {
            let stop = f.id == command_id
                && CommandMsg::decode_with(&f.data, data_id)
                    .is_ok_and(|(m, _)| m.command == Command::Stop);
            if !stop {
                continue;
            }
            match obstacle_at {
                Some(t) if f.timestamp >= t => {
                    outcome = Some(f.timestamp - t);
                    break;
                }
                _ => false_stop = true,
            }
        }
        seen = frames.len();
        if outcome.is_some() {
            break;
        }
    }
    shutdown.request();
    let report = daemon.join().map_err(|_| DaemonError::Panicked {
        thread: "flyd-bench-run",
    })??;
    let c = &report.control;
    // The control report's first STOP is the one measured unless a false stop came first.
    let pipeline = match (outcome, c.first_stop_at, c.first_stop_frame_at) {
        (Some(_), Some(sent), Some(captured)) if !false_stop => Some(sent.saturating_sub(captured)),
        _ => None,
    };
    Ok(Outcome {
        reaction: outcome,
        pipeline,
        false_stop,
    })
}
