//! Runs the real `flyd replay` binary on hw-mock scenarios and checks what a user of the daemon
//! relies on, with bounds loose enough for any seed and tight enough to catch a regression:
//! - a pedestrian stepping into the lane is a STOP within a few generations;
//! - driving down an empty road (the whole image flowing) never reaches STOP;
//! - driving towards a pedestrian ends in a STOP.
//!
//! The figures themselves (over many seeds) are in docs/perception.md; these are guards.

mod util;

use std::path::Path;

/// Runs `flyd replay --scenario NAME ...` into a temporary directory; returns the JSON summary
/// and the global warning of every generation (trace.csv).
fn replay(scenario: &str, size: (u32, u32), seed: u64) -> (serde_json::Value, Vec<f64>) {
    let out = std::env::temp_dir().join(format!(
        "flyd-scenario-{scenario}-{seed}-{}",
        std::process::id()
    ));
    let (w, h) = (size.0.to_string(), size.1.to_string());
    let seed = seed.to_string();
    let out_dir = out.display().to_string();
    let summary = util::flyd_json([
        "replay",
        "--scenario",
        scenario,
        "--seed",
        &seed,
        "--width",
        &w,
        "--height",
        &h,
        "--out",
        &out_dir,
    ]);
    let warnings = read_warnings(&out.join("trace.csv"));
    std::fs::remove_dir_all(&out).ok();
    (summary, warnings)
}

fn read_warnings(trace: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(trace).expect("trace.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = header
        .iter()
        .position(|&c| c == "global_warning")
        .expect("global_warning column");
    lines
        .map(|l| {
            l.split(',')
                .nth(col)
                .and_then(|v| v.parse().ok())
                .expect("a number")
        })
        .collect()
}

/// The STOP threshold of config/flyd.toml.
const STOP: f64 = 1.5;

#[test]
fn a_pedestrian_stepping_in_is_a_stop_within_a_few_generations() {
    let (summary, _) = replay("pedestrian-steps-in", (640, 480), 1);
    let reaction = &summary["reaction"];
    let after = |key: &str| reaction[key].as_u64().unwrap_or(u64::MAX);
    // Measured over seeds 1-80: STOP after 3-5 generations, half-settled after 3-8 (median
    // 4); before this work 6-8 and 11. A guard, not the figure.
    assert!(after("stop_threshold_after") <= 8, "{reaction}");
    assert!(after("half_settled_after") <= 8, "{reaction}");
}

#[test]
fn driving_an_empty_road_is_never_a_stop() {
    // 320x240 keeps each replay at a few seconds (every frame of a moving vehicle is a full
    // render). Measured: max 0.35-0.75 after the first 60 generations (seeds 1-3): the
    // horizon-line false matches docs/perception.md describes.
    for seed in [1, 2] {
        let (_, w) = replay("driving", (320, 240), seed);
        let max = w[60..].iter().cloned().fold(0.0, f64::max);
        assert!(
            max < STOP,
            "seed {seed}: global warning up to {max} on an empty road"
        );
    }
}

#[test]
fn driving_towards_a_pedestrian_ends_in_a_stop() {
    let (summary, _) = replay("driving-to-pedestrian", (320, 240), 1);
    let reaction = &summary["reaction"];
    let slow = reaction["slow_threshold_after"].as_u64();
    let stop = reaction["stop_threshold_after"].as_u64();
    // Measured: SLOW after 184, STOP after 274 generations (the pedestrian ~15 m ahead); it is
    // 5.2 m ahead at the last of the 450.
    assert!(
        matches!((slow, stop), (Some(s), Some(t)) if s <= t && t < 450),
        "{reaction}"
    );
}
