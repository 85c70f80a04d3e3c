//! The closed loop through the real binary: hw-mock's vehicle obeys `flyd replay --case`'s
//! commands (it stops short of a stopped car, the run written as CSV and SVG), and `flyd eval`
//! judges cases by outcome (a steel plate on the lane is no reason to brake; brakes too weak
//! to stop end in contact, and the label says so).

mod flyd_cli;

use flyd_cli::flyd_json;
use std::path::Path;
use std::process::Command;

#[test]
fn a_vehicle_that_obeys_stops_short_of_a_stopped_car() {
    let out = tempfile::tempdir().expect("tempdir");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let case = repo.join("eval/closed-loop/stationary.toml");
    let summary = flyd_json([
        "replay".as_ref(),
        "--case".as_ref(),
        case.as_os_str(),
        "--case-name".as_ref(),
        "car-stationary-100-20kmh".as_ref(),
        "--seed".as_ref(),
        "1".as_ref(),
        "--out".as_ref(),
        out.path().as_os_str(),
    ]);
    let run = &summary["closed_loop"];
    eprintln!("{run:#}");
    assert_eq!(run["contact"], false, "{run}");
    let gap = run["stopped_gap_m"].as_f64().expect("stopped");
    assert!((0.0..6.0).contains(&gap), "stopped {gap} m short");
    assert!(run["first_stop_s"].as_f64().is_some(), "{run}");
    let peak = run["peak_decel"].as_f64().expect("braked");
    assert!(peak > 1.0 && peak <= 9.5, "{peak}");
    assert_eq!(run["end_kmh"], 0.0);
    assert_eq!(summary["speed_source"], "feed");
    // The tracked car's measured motion is held to the truth: it stands still.
    let checks = run["motion_by_sightings"]
        .as_array()
        .expect("motion checked");
    assert!(checks.len() >= 8, "{checks:?}");
    assert!(checks.iter().all(|c| c["truth"] == 0.0), "{checks:?}");
    // The run over time: a row a command, ending at a standstill ...
    let csv = std::fs::read_to_string(out.path().join("closed_loop.csv")).expect("csv");
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(
        rows[0],
        [
            "t",
            "speed_kmh",
            "gap_m",
            "requested_decel",
            "decel",
            "command"
        ]
    );
    assert!(rows.len() > 30 && rows.iter().all(|r| r.len() == 6));
    let last = rows.last().expect("rows");
    assert_eq!(last[1].parse::<f64>().ok(), Some(0.0), "{last:?}");
    assert!(rows.iter().any(|r| r[5] == "STOP"));
    // ... and as a picture that an XML reader takes.
    let svg = out.path().join("closed_loop.svg");
    let parsed = Command::new("python3")
        .args(["-c", "import sys, xml.etree.ElementTree as E; r = E.parse(sys.argv[1]).getroot(); print(r.tag)"])
        .arg(&svg)
        .output()
        .expect("python3");
    assert!(
        parsed.status.success(),
        "{}",
        String::from_utf8_lossy(&parsed.stderr)
    );
    assert!(
        String::from_utf8_lossy(&parsed.stdout)
            .trim()
            .ends_with("svg")
    );
}

#[test]
fn eval_judges_cases_by_outcome() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = r#"
[[case]]
name = "plate"
road = "straight"
speed_kmh = 30
expect = "no-activation"
[[case.actor]]
kind = "plate"
at = 25.0

[[case]]
name = "weak-brakes"
description = "Brakes that give 0.5 m/s^2: no command can stop in time."
road = "straight"
speed_kmh = 30
expect = "no-contact"
[case.vehicle]
max_decel = 0.5
[[case.actor]]
kind = "car"
at = 25.0
"#;
    std::fs::write(dir.path().join("cases.toml"), cases).expect("write");
    std::fs::write(dir.path().join("m.toml"), "cases = [\"cases.toml\"]\n").expect("write");
    let json = dir.path().join("report.json");
    let output = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .arg("eval")
        .arg(dir.path().join("m.toml"))
        .args(["--seeds", "1", "--jobs", "2", "--json"])
        .arg(&json)
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .expect("runs");
    let text = String::from_utf8_lossy(&output.stdout);
    eprintln!("{text}");
    assert_eq!(output.status.code(), Some(1), "a label is not met");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parses");
    let item = |name: &str| {
        report["items"]
            .as_array()
            .and_then(|items| items.iter().find(|i| i["name"] == name))
            .cloned()
            .unwrap_or_else(|| panic!("no item {name}"))
    };
    let plate = item("plate");
    assert_eq!(plate["ok"], 1, "{plate}");
    assert_eq!(
        plate["runs"][0]["closed_loop"]["first_slow_s"],
        serde_json::Value::Null
    );
    let weak = item("weak-brakes");
    assert_eq!(weak["ok"], 0);
    let run = &weak["runs"][0]["closed_loop"];
    assert_eq!(run["contact"], true, "{run}");
    let impact = run["impact_kmh"].as_f64().expect("impact");
    assert!(impact > 5.0 && impact <= 30.0 + 1e-9, "{impact}");
    assert!(text.contains("weak-brakes: seed 1: contact at"), "{text}");
    // The index of why runs braked shows each closed loop's run over time.
    let index = std::fs::read_to_string(dir.path().join("out/index.html")).expect("index");
    assert!(
        index.contains("<img src=\"weak-brakes/seed1/closed_loop.svg\""),
        "{index}"
    );
    assert!(dir.path().join("out/plate/seed1/closed_loop.svg").is_file());
}

/// The shipped configuration with the zones beside the corridor watched 4 m out
/// (`config/flyd.toml`'s comment says how), written with its rig into `dir`.
fn watching_config(dir: &Path) -> std::path::PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let shipped = std::fs::read_to_string(repo.join("config/flyd.toml")).expect("config");
    let key = "# watch_half_width = 0.0";
    assert_eq!(
        shipped.matches(key).count(),
        1,
        "the shipped config names it once"
    );
    std::fs::copy(repo.join("config/rig.toml"), dir.join("rig.toml")).expect("rig");
    let path = dir.join("flyd.toml");
    std::fs::write(&path, shipped.replace(key, "watch_half_width = 4.0")).expect("write");
    path
}

/// One closed-loop run of `name` from `eval/closed-loop/traffic.toml` with the watch on.
fn watched_run(name: &str) -> serde_json::Value {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = watching_config(dir.path());
    let case = Path::new(env!("CARGO_MANIFEST_DIR")).join("eval/closed-loop/traffic.toml");
    let summary = flyd_json([
        "replay".as_ref(),
        "--case".as_ref(),
        case.as_os_str(),
        "--case-name".as_ref(),
        name.as_ref(),
        "--seed".as_ref(),
        "1".as_ref(),
        "--config".as_ref(),
        config.as_os_str(),
        "--out".as_ref(),
        dir.path().join("out").as_os_str(),
    ]);
    let run = summary["closed_loop"].clone();
    eprintln!("{name}: {run:#}");
    run
}

#[test]
fn with_the_zones_beside_the_corridor_watched_a_pedestrian_who_crosses_is_stopped_for() {
    // Euro NCAP's CPFA-50 at 40 km/h: from the far side at 8 km/h; seen in the corridor only
    // 0.5 s before the impact, where nothing stops the vehicle (the default's contact).
    let run = watched_run("pedestrian-crossing-far-50-40kmh");
    assert_eq!(run["contact"], false, "{run}");
    assert!(run["first_stop_s"].as_f64().is_some(), "{run}");
}

#[test]
fn with_the_zones_beside_the_corridor_watched_one_who_stops_at_the_kerb_is_not_stopped_for() {
    // The same walk as CPNA-25 at 30 km/h, stopping 1.2 m short of the corridor: a SLOW is
    // allowed, a STOP is not (it is asked at the latest moment, and they stop before it).
    let run = watched_run("pedestrian-stops-at-kerb-30kmh");
    assert_eq!(run["contact"], false, "{run}");
    assert_eq!(run["first_stop_s"], serde_json::Value::Null, "{run}");
    let peak = run["peak_decel"].as_f64().unwrap_or(0.0);
    assert!(peak < 2.0, "{peak}");
}
