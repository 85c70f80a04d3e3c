//! Random configurations through `config::check` (what `check-config` and `run` both run) and
//! the threaded daemon: whatever the check accepts starts, sends CAN frames and stops cleanly;
//! whatever it refuses names a key. Deterministic (xorshift, fixed seeds), so a failure
//! reproduces: the case's file is printed.

use std::collections::BTreeMap;
use std::time::Duration;

use flyd::bus::MemoryBus;
use flyd::config::{self, CanTarget};
use flyd::daemon::{self, MonotonicClock, Shutdown, hardware};
use flyd_core::can::messages::{CanMessage, StatusMsg};

/// Keys and a typical value of each (the shipped defaults' scale).
const KEYS: &[(&str, &str, f64)] = &[
    ("cameras", "fps", 30.0),
    ("cameras", "stale_frames", 3.0),
    ("cameras", "timestamp_tolerance_ms", 10.0),
    ("engine", "flies", 500.0),
    ("engine", "min_depth", 1.0),
    ("engine", "max_depth", 40.0),
    ("engine", "warning_min_abs_x", 0.5),
    ("engine", "warning_min_z", 1.0),
    ("engine", "survival_rate", 0.4),
    ("engine", "mutation_rate", 0.4),
    ("engine", "immigration_rate", 0.05),
    ("decision", "slow_threshold", 0.5),
    ("decision", "stop_threshold", 1.5),
    ("decision", "release_ratio", 0.8),
    ("decision", "slow_hold_ms", 500.0),
    ("decision", "stop_hold_ms", 1000.0),
    ("decision", "slow_decel", 1.5),
    ("decision", "stop_decel", 4.0),
    ("decision", "max_decel", 9.0),
    ("decision", "reaction_time_ms", 500.0),
    ("decision", "margin_m", 2.0),
    ("decision", "lead_decel", 3.0),
    ("vehicle", "assumed_speed_kmh", 30.0),
    ("evolution", "generation_period_ms", 10.0),
    ("evolution", "burst_generations", 12.0),
    ("evolution", "max_generation_ms", 50.0),
    ("evolution", "warmup_generations", 30.0),
    ("evolution", "blind_matched", 0.25),
    ("evolution", "blind_pairs", 3.0),
    ("evolution", "skew_fault_rejects", 3.0),
    ("evolution", "snapshot_queue", 64.0),
    ("control", "snapshot_timeout_ms", 100.0),
    ("control", "startup_timeout_ms", 5000.0),
    ("control", "can_silence_ms", 500.0),
    ("sensor", "min_contrast", 6.0),
    ("sensor", "min_textured", 0.01),
    ("sensor", "frozen_unchanged", 0.95),
    ("sensor", "frozen_frames", 3.0),
    ("sensor", "raise_frames", 2.0),
    ("sensor", "clear_frames", 3.0),
    ("logging", "stats_interval_s", 10.0),
    ("perception.obstacle", "min_width", 0.1),
    ("perception.obstacle", "max_ambiguity", 0.5),
    ("perception.obstacle", "corridor_half_width", 1.2),
    ("perception.obstacle", "watch_half_width", 4.0),
    ("perception.track", "trigger_frames", 2.0),
    ("perception.road", "max_slope", 0.08),
];

/// Integer keys (a fractional value there is a type error, which is fine too).
const INTEGERS: &[&str] = &[
    "stale_frames",
    "flies",
    "slow_hold_ms",
    "stop_hold_ms",
    "burst_generations",
    "warmup_generations",
    "blind_pairs",
    "skew_fault_rejects",
    "snapshot_queue",
    "frozen_frames",
    "raise_frames",
    "clear_frames",
    "trigger_frames",
];

fn xorshift(mut x: u64) -> impl FnMut() -> u64 {
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    }
}

/// The base configuration: the demo on 160x120 mock cameras, CAN to a log.
fn base() -> BTreeMap<&'static str, BTreeMap<&'static str, String>> {
    let mut t: BTreeMap<&'static str, BTreeMap<&'static str, String>> = BTreeMap::new();
    let mut put = |table, key, value: &str| {
        t.entry(table).or_default().insert(key, value.to_string());
    };
    put("cameras", "mock", "\"pedestrian-steps-in\"");
    put("cameras", "width", "160");
    put("cameras", "height", "120");
    put("cameras", "fps", "30");
    put("calibration", "builtin", "\"mock\"");
    put("engine", "flies", "500");
    put("can", "log", "\"/dev/null\"");
    put("logging", "level", "\"warn\"");
    t
}

fn render(t: &BTreeMap<&'static str, BTreeMap<&'static str, String>>) -> String {
    let mut out = String::new();
    for (table, keys) in t {
        out.push_str(&format!("[{table}]\n"));
        for (k, v) in keys {
            out.push_str(&format!("{k} = {v}\n"));
        }
        out.push('\n');
    }
    out
}

/// A value for a key of typical value `typical`: in range, at its edges, or hostile.
fn value(next: &mut impl FnMut() -> u64, key: &str, typical: f64) -> String {
    const FACTORS: [f64; 9] = [0.0, -1.0, 0.001, 0.3, 0.9, 1.1, 3.0, 30.0, 1e6];
    const SPECIAL: [&str; 6] = ["nan", "inf", "-inf", "1e300", "1e-300", "4294967295"];
    let v = match next() % 4 {
        0 => return SPECIAL[(next() % SPECIAL.len() as u64) as usize].to_string(),
        _ => typical * FACTORS[(next() % FACTORS.len() as u64) as usize],
    };
    if INTEGERS.contains(&key) {
        format!("{}", v.round() as i64)
    } else {
        format!("{v:?}")
    }
}

/// Runs the accepted `config` for a moment on its mock cameras and a memory bus.
fn starts(config: &flyd::config::DaemonConfig, what: &str) {
    let clock = MonotonicClock::shared();
    let bus_clock = clock.clone();
    let bus = MemoryBus::new(move || bus_clock.now());
    let cameras = hardware::open_cameras(config, &clock)
        .unwrap_or_else(|e| panic!("{what}: accepted, but the cameras do not open: {e}"));
    let shutdown = Shutdown::new();
    let stop = shutdown.clone();
    let timer = daemon::spawn_named("test-stop", move || {
        std::thread::sleep(Duration::from_millis(400));
        stop.request();
    })
    .expect("spawn");
    let b = bus.clone();
    let result = daemon::run(
        cameras,
        Box::new(b),
        clock,
        config,
        shutdown,
        daemon::ServiceNotifier::none(),
    );
    timer.join().expect("timer");
    let report = result.unwrap_or_else(|e| panic!("{what}: accepted, but run failed: {e}"));
    let frames = bus.frames();
    assert!(
        !frames.is_empty(),
        "{what}: accepted, started, sent nothing"
    );
    let last = frames.last().expect("frames");
    assert_eq!(
        last.id, config.can.messages.status.id,
        "{what}: last frame not the status"
    );
    StatusMsg::decode_with(&last.data, config.can.messages.status.data_id)
        .unwrap_or_else(|e| panic!("{what}: undecodable status: {e:?}"));
    let _ = report;
}

#[test]
fn whatever_check_config_accepts_starts_and_whatever_it_refuses_names_a_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("flyd.toml");
    let (mut accepted, mut refused) = (0, 0);
    for case in 0..96u64 {
        let mut next = xorshift(0x9E37_79B9_7F4A_7C15 ^ (case + 1).wrapping_mul(0xBF58_476D));
        let mut t = base();
        let changes = 1 + next() % 3;
        for _ in 0..changes {
            let (table, key, typical) = KEYS[(next() % KEYS.len() as u64) as usize];
            let v = value(&mut next, key, typical);
            t.entry(table).or_default().insert(key, v);
        }
        let text = render(&t);
        std::fs::write(&path, &text).expect("write");
        let what = format!("case {case}:\n{text}");
        match config::check(&path) {
            Ok(config) => {
                assert!(matches!(config.can.target, CanTarget::Log { .. }));
                starts(&config, &what);
                accepted += 1;
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(&path.display().to_string()) && msg.contains("key"),
                    "{what}: the refusal names no key: {msg}"
                );
                refused += 1;
            }
        }
    }
    println!("{accepted} configurations accepted and started, {refused} refused naming a key");
    assert!(
        accepted >= 5 && refused >= 5,
        "{accepted} accepted, {refused} refused"
    );
}
