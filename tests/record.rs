//! Recording (`flyd run --record`) and its replay (`flyd replay --mcap`), end to end through
//! the real binary on the mock demo:
//! - the recording is read back by third-party readers (Python `mcap` with
//!   `mcap-protobuf-support`, tests/record/check_recording.py): channels, schemas, message
//!   counts against the frames, pairs, generations, snapshots and commands the daemon
//!   reported, monotonic log times, and the CAN frames equal to the `--can-log` of the run;
//! - the replay reproduces every recorded command frame byte for byte, and another seed does
//!   not (the comparison can fail).
//!
//! Needs target/py (scripts/prereqs installs it); without it the reader check fails with
//! a message, unless FLYD_ALLOW_NO_PY is set, in which case it prints SKIP.

mod flyd_cli;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn python() -> Option<PathBuf> {
    let py = std::env::var_os("FLYD_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo("target/py/bin/python3"));
    let ok = Command::new(&py)
        .args(["-c", "import mcap, mcap_protobuf"])
        .status()
        .is_ok_and(|s| s.success());
    ok.then_some(py)
}

/// The value of `key` in the last JSON log line whose message is `message`.
fn logged(stderr: &str, message: &str) -> serde_json::Value {
    stderr
        .lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|v| v["message"] == message)
        .unwrap_or_else(|| panic!("no {message:?} log line in {stderr}"))
}

/// `flyd replay --mcap MCAP ARGS...`: whether it succeeded, its JSON summary (null when it
/// printed none) and its stderr.
fn replay(mcap: &Path, args: &[&OsStr]) -> (bool, serde_json::Value, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args([OsStr::new("replay"), OsStr::new("--mcap"), mcap.as_os_str()])
        .args(args)
        .output()
        .expect("flyd replay runs");
    let summary = serde_json::from_slice(&out.stdout).unwrap_or(serde_json::Value::Null);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.success(), summary, stderr)
}

/// [`replay`], which must succeed: its summary.
fn replay_ok(mcap: &Path, args: &[&OsStr]) -> serde_json::Value {
    let (ok, summary, stderr) = replay(mcap, args);
    assert!(
        ok,
        "flyd replay --mcap {}: {summary}\n{stderr}",
        mcap.display()
    );
    summary
}

struct Recorded {
    _dir: tempfile::TempDir,
    mcap: PathBuf,
    log: PathBuf,
    stopped: serde_json::Value,
    closed: serde_json::Value,
}

/// `flyd run` on the demo configuration with `--record` and `--can-log`.
fn record_demo(extra_toml: &str) -> Recorded {
    record_with(|demo| format!("{demo}\n{extra_toml}"), None)
}

/// `flyd run --record --can-log` on the demo configuration as `edit` makes it.
/// With `can_input`, the frames flyd receives come from that candump log.
fn record_with(edit: impl FnOnce(&str) -> String, can_input: Option<&Path>) -> Recorded {
    let dir = tempfile::tempdir().expect("tempdir");
    let demo = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let text = edit(&demo);
    let config = dir.path().join("demo.toml");
    std::fs::write(&config, text).expect("write config");
    let mcap = dir.path().join("demo.mcap");
    let log = dir.path().join("demo.log");
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .arg("run")
        .arg("--config")
        .arg(&config)
        .arg("--record")
        .arg(&mcap)
        .arg("--can-log")
        .arg(&log)
        .args(can_input.iter().flat_map(|p| [Path::new("--can-input"), p]))
        .output()
        .expect("flyd runs");
    // With the CAN log in a file, the logs go to stdout (JSON lines off a terminal).
    let logs =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "flyd run failed: {logs}");
    Recorded {
        stopped: logged(&logs, "flyd stopped"),
        closed: logged(&logs, "recording closed"),
        _dir: dir,
        mcap,
        log,
    }
}

#[test]
fn the_recorded_demo_reads_back_with_third_party_readers_and_replays_bit_for_bit() {
    let r = record_demo("");
    let stopped = &r.stopped;
    assert_eq!(r.closed["failed"], false, "{}", r.closed);
    assert_eq!(stopped["ended_by"], "EndOfStream", "{stopped}");
    assert!(
        stopped["generations"].as_u64().unwrap_or(0) > 200,
        "{stopped}"
    );

    // The third-party readers.
    match python() {
        Some(py) => {
            let expected = serde_json::json!({
                "frames_left": stopped["frames_left"],
                "frames_right": stopped["frames_right"],
                "pairs": stopped["pairs"],
                "generations": stopped["generations"],
                "snapshots": stopped["snapshots"],
                "commands": stopped["commands"],
                "record_dropped": stopped["record_dropped"],
                "flies_skipped": r.closed["flies_skipped"],
                "flies_every": 10,
                "flies": 5000,
                "width": 640,
                "height": 480,
            });
            let expected_file = r.mcap.with_extension("expected.json");
            std::fs::write(&expected_file, expected.to_string()).expect("write");
            let out = Command::new(py)
                .arg(repo("tests/record/check_recording.py"))
                .arg(&r.mcap)
                .arg(&r.log)
                .arg(&expected_file)
                .output()
                .expect("python runs");
            let stdout = String::from_utf8_lossy(&out.stdout);
            let stderr = String::from_utf8_lossy(&out.stderr);
            println!("readers: {stdout}");
            assert!(out.status.success(), "{stdout}\n{stderr}");
        }
        None if std::env::var_os("FLYD_ALLOW_NO_PY").is_some() => {
            println!("SKIP: Python mcap readers not installed (scripts/prereqs makes target/py)");
        }
        None => panic!(
            "Python with mcap and mcap-protobuf-support not found in target/py: run \
             scripts/prereqs (or set FLYD_ALLOW_NO_PY=1 to skip the reader check)"
        ),
    }

    // The replay: the same command frames, byte for byte.
    let summary = replay_ok(&r.mcap, &[]);
    println!("replay: {summary}");
    let commands = std::fs::read_to_string(&r.log)
        .expect("can log")
        .lines()
        .filter(|l| {
            l.split_whitespace()
                .nth(2)
                .is_some_and(|f| f.starts_with("120#"))
        })
        .count();
    // FLYD_Command is 0x120 (config/flyd.dbc).
    assert!(commands > 100, "{commands} FLYD_Command frames in the log");
    assert_eq!(summary["commands_recorded"].as_u64(), Some(commands as u64));
    assert_eq!(
        summary["commands_identical"].as_u64(),
        Some(commands as u64)
    );
    assert_eq!(summary["snapshots"], summary["snapshots_identical"]);
    assert_eq!(summary["divergence"], serde_json::Value::Null);
    assert_eq!(summary["complete"], true);
    assert!(
        summary["changes"].as_array().is_some_and(|c| c
            .iter()
            .any(|s| s.as_str().is_some_and(|s| s.ends_with(":STOP")))),
        "the demo's STOP is replayed: {summary}"
    );

    // The replay can record itself; that recording replays bit for bit again.
    let again = r.mcap.with_file_name("replayed.mcap");
    replay_ok(&r.mcap, &[OsStr::new("--record"), again.as_os_str()]);
    let twice = replay_ok(&again, &[]);
    assert_eq!(
        twice["commands_identical"].as_u64(),
        Some(commands as u64),
        "{twice}"
    );
    assert_eq!(twice["changes"], summary["changes"]);

    // Another seed is another population: the replay says where it parts.
    let (ok, _, stderr) = replay(&r.mcap, &[OsStr::new("--seed"), OsStr::new("7")]);
    assert!(!ok, "another seed must diverge");
    assert!(
        stderr.contains("diverges from the recording (perception)"),
        "{stderr}"
    );
}

#[test]
fn a_recording_without_images_still_holds_the_decisions_and_cannot_be_replayed() {
    let r = record_demo("[record]\nimages = false\nflies_every = 50\n");
    assert_eq!(r.closed["frames_left"], 0, "{}", r.closed);
    let (ok, _, stderr) = replay(&r.mcap, &[]);
    assert!(!ok);
    assert!(stderr.contains("has no images"), "{stderr}");
    let size = std::fs::metadata(&r.mcap).expect("file").len();
    println!("5 s of the demo without images: {size} bytes");
    assert!(size < 5_000_000, "{size} bytes");
}

#[test]
fn an_unwritable_recording_path_fails_at_start_naming_it() {
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(["run", "--config"])
        .arg(repo("config/demo.toml"))
        .args([
            "--record",
            "/nonexistent/dir/x.mcap",
            "--can-log",
            "/dev/null",
        ])
        .output()
        .expect("flyd runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("/nonexistent/dir/x.mcap"), "{stderr}");
}

#[test]
fn a_full_disk_stops_the_recording_not_the_perception() {
    // /dev/full: every write fails with ENOSPC, as on a full disk.
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("full.log");
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(["run", "--config"])
        .arg(repo("config/demo.toml"))
        .args(["--record", "/dev/full", "--duration", "2", "--can-log"])
        .arg(&log)
        .output()
        .expect("flyd runs");
    let logs =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "flyd drives on: {logs}");
    assert!(logs.contains("recording stopped: cannot write"), "{logs}");
    assert!(logs.contains("No space left on device"), "{logs}");
    let stopped = logged(&logs, "flyd stopped");
    assert_eq!(
        stopped["faults_seen"], "none",
        "not a fault of the perception: {stopped}"
    );
    // FLYD_Command every 20 ms for the 2 s (100): at least half of them on a loaded machine.
    let commands = std::fs::read_to_string(&log)
        .expect("can log")
        .lines()
        .filter(|l| l.contains(" 120#"))
        .count();
    assert!(commands >= 50, "{commands} commands in 2 s");
}

#[test]
fn rotation_splits_the_recording_into_files_that_each_stand_alone() {
    let r = record_demo("[record]\nrotate_mb = 16\n");
    let files: Vec<PathBuf> = r.closed["files"]
        .as_str()
        .and_then(|s| serde_json::from_str::<Vec<String>>(s).ok())
        .unwrap_or_default()
        .into_iter()
        .map(PathBuf::from)
        .collect();
    assert!(files.len() >= 5, "{}", r.closed);
    assert_eq!(files[0], r.mcap);
    assert_eq!(files[1], r.mcap.with_file_name("demo.1.mcap"));
    let mut images = 0;
    for file in &files {
        let data = std::fs::read(file).expect("part");
        let summary = mcap::Summary::read(&data)
            .expect("a complete MCAP file")
            .expect("with a summary");
        assert_eq!(summary.channels.len(), 15, "{}", file.display());
        assert!(
            summary
                .attachment_indexes
                .iter()
                .any(|a| a.name == "config.toml"),
            "{}",
            file.display()
        );
        let mut calibrations = 0;
        for m in mcap::MessageStream::new(&data).expect("messages") {
            let m = m.expect("message");
            match m.channel.topic.as_str() {
                "/camera/left/image" | "/camera/right/image" => images += 1,
                "/camera/left/calibration" | "/camera/right/calibration" => calibrations += 1,
                _ => {}
            }
        }
        assert_eq!(
            calibrations,
            2,
            "each part carries both calibrations: {}",
            file.display()
        );
    }
    let frames = r.stopped["frames_left"].as_u64().unwrap_or(0)
        + r.stopped["frames_right"].as_u64().unwrap_or(0);
    assert_eq!(images, frames, "no frame lost between parts");
}

/// Messages per topic of an MCAP file, read with the `mcap` crate.
fn topic_counts(path: &Path) -> std::collections::BTreeMap<String, usize> {
    let data = std::fs::read(path).expect("recording");
    let mut counts = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&data).expect("mcap") {
        *counts
            .entry(m.expect("message").channel.topic.clone())
            .or_insert(0) += 1;
    }
    counts
}

#[test]
fn a_kitti_sequence_becomes_a_recording() {
    let seq = repo("tests/fixtures/kitti/kitti_raw_2011_09_26_seq12");
    let dir = tempfile::tempdir().expect("tempdir");
    let mcap = dir.path().join("seq12.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .arg("replay")
        .arg("--sequence")
        .arg(&seq)
        .arg("--calib")
        .arg(seq.join("rig.toml"))
        .args(["--speed", "30", "--out"])
        .arg(dir.path())
        .arg("--record")
        .arg(&mcap)
        .output()
        .expect("flyd replay runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("summary");
    let generations = summary["generations"].as_u64().expect("generations") as usize;
    let counts = topic_counts(&mcap);
    println!("{counts:?}");
    assert_eq!(counts.get("/camera/left/image"), Some(&12));
    assert_eq!(counts.get("/camera/right/image"), Some(&12));
    assert_eq!(counts.get("/flyd/pair"), Some(&12));
    assert_eq!(counts.get("/flyd/perception"), Some(&generations));
    // One command a generation after the warm-up, each with its FLYD_Command frame.
    let decisions = counts.get("/flyd/decision").copied().unwrap_or(0);
    assert!(decisions > 0 && decisions < generations, "{decisions}");
    assert_eq!(counts.get("/can/tx"), Some(&decisions));
    assert_eq!(counts.get("/flyd/flies"), Some(&(generations / 10)));
}

#[test]
fn the_shipped_foxglove_layout_only_names_topics_and_fields_flyd_records() {
    let text = std::fs::read_to_string(repo("config/foxglove-layout.json")).expect("layout");
    let layout: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let mut named = Vec::new();
    fn walk(v: &serde_json::Value, out: &mut Vec<String>) {
        match v {
            serde_json::Value::String(s) if s.starts_with('/') => out.push(s.clone()),
            serde_json::Value::Array(a) => a.iter().for_each(|v| walk(v, out)),
            serde_json::Value::Object(o) => o.iter().for_each(|(k, v)| {
                if k.starts_with('/') {
                    out.push(k.clone());
                }
                walk(v, out);
            }),
            _ => {}
        }
    }
    walk(&layout["configById"], &mut named);
    assert!(named.len() >= 10, "{named:?}");
    for path in named {
        let (topic, field) = path.split_once('.').unwrap_or((&path, ""));
        let known = flyd::record::topics::Topic::from_name(topic)
            .unwrap_or_else(|| panic!("the layout names {topic}, which flyd does not record"));
        if !field.is_empty() {
            let (_, schema) = known.json_schema().expect("a JSON topic");
            let schema: serde_json::Value = serde_json::from_str(&schema).expect("schema");
            assert!(
                schema["properties"][field].is_object(),
                "the layout plots {path}: {topic} has no field {field}"
            );
        }
    }
    // Every panel the layout arranges is configured.
    for id in ["Image!flydleft", "3D!flydscene", "Plot!flydwarning"] {
        assert!(
            layout["configById"][id].is_object() && text.matches(id).count() >= 2,
            "{id}"
        );
    }
}

#[test]
fn a_file_size_limit_hit_mid_run_stops_the_recording_not_the_perception() {
    // RLIMIT_FSIZE at 20-40 MB (under a second of the demo's frames): the write that crosses it
    // fails with EFBIG (flyd ignores SIGXFSZ, which would kill it), as a disk filling up does.
    let dir = tempfile::tempdir().expect("tempdir");
    let (mcap, log) = (dir.path().join("r.mcap"), dir.path().join("can.log"));
    let script = format!(
        "ulimit -f 40000; exec '{}' run --config '{}' --record '{}' --can-log '{}' --duration 3",
        env!("CARGO_BIN_EXE_flyd"),
        repo("config/demo.toml").display(),
        mcap.display(),
        log.display()
    );
    let out = Command::new("sh")
        .args(["-c", &script])
        .output()
        .expect("sh runs");
    let logs =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "flyd drives on: {logs}");
    assert!(logs.contains("recording stopped: cannot write"), "{logs}");
    assert!(logs.contains("File too large"), "{logs}");
    let stopped = logged(&logs, "flyd stopped");
    assert_eq!(stopped["faults_seen"], "none", "{stopped}");
    assert!(
        stopped["generations"].as_u64().unwrap_or(0) > 100,
        "{stopped}"
    );
    let commands = std::fs::read_to_string(&log)
        .expect("can log")
        .lines()
        .filter(|l| l.contains(" 120#"))
        .count();
    assert!(
        commands >= 75,
        "{commands} commands in 3 s (150 sent every 20 ms)"
    );
    // What was written before the limit replays, as far as it goes.
    let s = replay_ok(&mcap, &[]);
    assert_eq!(s["complete"], false, "{s}");
    assert!(s["commands_recorded"].as_u64() > Some(5), "{s}");
    assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
    // `ulimit -f` counts 512- or 1024-byte blocks, as the shell decides.
    let size = std::fs::metadata(&mcap).expect("file").len();
    assert!((20_000 * 512..=40_000 * 1024).contains(&size), "{size}");
}

/// A candump log of `VCU_Motion` at `speed` m/s every 20 ms for `seconds`, with a frame of
/// bad CRC every 200 ms (rejected).
fn motion_log(path: &Path, seconds: f64, speed: f64) {
    use flyd_core::can::candump::format_candump_line;
    use flyd_core::can::messages::{AliveCounter, MotionMsg};
    let (mut text, mut counter) = (String::new(), AliveCounter::ZERO);
    let t0 = std::time::Duration::from_secs(1_764_000_000);
    for k in 0..(seconds / 0.02).round() as u64 {
        let t = t0 + std::time::Duration::from_millis(20 * k);
        let msg = MotionMsg {
            valid: true,
            speed,
            yaw_rate: 0.0,
        };
        let mut data = msg.encode(counter.advance());
        text += &format_candump_line(t, "vcan0", 0x110, &data);
        text.push('\n');
        if k % 10 == 5 {
            data[0] ^= 0xFF;
            text += &format_candump_line(
                t + std::time::Duration::from_millis(1),
                "vcan0",
                0x110,
                &data,
            );
            text.push('\n');
        }
    }
    std::fs::write(path, text).expect("write the motion log");
}

#[test]
fn a_drive_with_the_vehicles_motion_replays_with_its_received_frames_and_moved_flies() {
    // A recorded 30 km/h drive's bus (--can-input) under the demo: the flies are moved with
    // it between frames. The replay runs the received frames through the motion monitor
    // again (its speed is checked against the recorded one) and moves the flies with the
    // recorded motion.
    let inputs = tempfile::tempdir().expect("tempdir");
    let input = inputs.path().join("motion.log");
    motion_log(&input, 6.0, 30.0 / 3.6);
    let r = record_with(
        |demo| {
            demo.replace("width = 640", "width = 320")
                .replace("height = 480", "height = 240")
                .replace("flies = 5000", "flies = 1000")
                .replace("motion = \"none\"", "motion = \"can\"")
        },
        Some(&input),
    );
    let counts = topic_counts(&r.mcap);
    let received = counts.get("/can/rx").copied().unwrap_or(0);
    assert!(
        received > 100,
        "{received} VCU_Motion frames recorded: {counts:?}"
    );
    // Every frame flyd read is in the recording, the rejected ones too.
    let read = r.stopped["motion_accepted"].as_u64().unwrap_or(0)
        + r.stopped["motion_rejected"].as_u64().unwrap_or(0);
    assert_eq!(received as u64, read, "{}", r.stopped);
    assert!(
        r.stopped["motion_rejected"].as_u64() > Some(10),
        "{}",
        r.stopped
    );
    let data = std::fs::read(&r.mcap).expect("recording");
    let predicted = mcap::MessageStream::new(&data)
        .expect("mcap")
        .filter_map(Result::ok)
        .filter(|m| m.channel.topic == "/flyd/pair")
        .filter(|m| {
            serde_json::from_slice::<serde_json::Value>(&m.data)
                .is_ok_and(|v| v["predict"]["speed"].as_f64().is_some_and(|s| s > 8.0))
        })
        .count();
    assert!(
        predicted > 50,
        "{predicted} pairs with the flies moved at 30 km/h"
    );
    let s = replay_ok(&r.mcap, &[]);
    println!("replay: {s}");
    assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
    assert!(s["commands_recorded"].as_u64() > Some(100), "{s}");
}

#[test]
fn generations_on_the_last_pair_after_the_cameras_stop_replay_too() {
    // Both cameras deliver nothing from 3 s (a dropped stream): the evolution goes on on the
    // last pair, the decision falls back (stale cameras) on those snapshots; the replay runs
    // those generations too and reproduces every command.
    let r = record_with(
        |demo| {
            demo.replacen(
                "stale_frames = 3\n",
                "stale_frames = 3\n\n[[cameras.mock_faults]]\nkind = \"drop\"\ncamera = \"both\"\nfrom_s = 3.0\nto_s = 6.0\n",
                1,
            )
        },
        None,
    );
    assert!(
        r.stopped["faults_seen"]
            .as_str()
            .is_some_and(|f| f.contains("CAMERA_STALE")),
        "{}",
        r.stopped
    );
    let s = replay_ok(&r.mcap, &[]);
    // Up to the last generation the decision took: the daemon's last, but for the few its
    // evolution ran while the control thread was already shutting down.
    let (replayed, ran) = (
        s["generations"].as_u64().unwrap_or(0),
        r.stopped["generations"].as_u64().unwrap_or(0),
    );
    assert!(
        replayed <= ran && replayed + 20 >= ran,
        "{replayed} of {ran}: {s}"
    );
    assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
}

#[test]
fn a_rig_with_a_row_correction_records_and_replays_bit_for_bit() {
    // The daemon's right frames are read 0.3 rows down (rectification.right_row_offset_px):
    // the replay must correct the recorded pixels the same way, or the flies part.
    let rigs = tempfile::tempdir().expect("tempdir");
    let rig_file =
        flyd_cli::mock_rig_320x240(rigs.path(), "[rectification]\nright_row_offset_px = 0.3\n");
    let r = record_with(|demo| flyd_cli::demo_320x240_on(demo, &rig_file), None);
    let s = replay_ok(&r.mcap, &[]);
    assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
    assert_eq!(s["commands_recorded"], r.stopped["commands"], "{s}");
    assert_eq!(s["snapshots"], s["snapshots_identical"], "{s}");
}

#[test]
fn commands_decided_on_the_newest_snapshot_again_replay_and_record_again() {
    // A generation every 50 ms and on each new frame (33 ms) against a command every 20 ms:
    // many commands find no new snapshot and are decided on the newest one again, at their
    // own time (what a loaded machine makes of the shipped settings).
    let r = record_with(
        |demo| {
            demo.replace(
                "generation_period_ms = 10",
                "generation_period_ms = 50\nburst_generations = 1",
            )
            .replace("width = 640", "width = 320")
            .replace("height = 480", "height = 240")
            .replace("flies = 5000", "flies = 1000")
        },
        None,
    );
    let data = std::fs::read(&r.mcap).expect("recording");
    let latest = mcap::MessageStream::new(&data)
        .expect("mcap")
        .filter_map(Result::ok)
        .filter(|m| m.channel.topic == "/flyd/decision")
        .filter(|m| {
            serde_json::from_slice::<serde_json::Value>(&m.data)
                .is_ok_and(|v| v["from"] == "latest")
        })
        .count();
    assert!(
        latest > 20,
        "{latest} commands on the newest snapshot again"
    );
    let again = r.mcap.with_file_name("again.mcap");
    let first = replay_ok(&r.mcap, &[OsStr::new("--record"), again.as_os_str()]);
    let second = replay_ok(&again, &[]);
    for s in [&first, &second] {
        assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
        assert_eq!(s["commands_recorded"], r.stopped["commands"], "{s}");
    }
}

#[test]
fn an_mjpeg_camera_is_recorded_as_its_jpeg_and_replays_bit_for_bit() {
    // Mock cameras delivering MJPEG (`pixel_format = "MJPG"`): each frame JPEG-encoded, then
    // decoded by the V4L2 MJPEG converter. The recording keeps the JPEG, a tenth of the
    // pixels, and the replay decodes it to the very same pixels.
    let r = record_with(
        |demo| {
            demo.replace(
                "stale_frames = 3\n",
                "stale_frames = 3\npixel_format = \"MJPG\"\n",
            )
        },
        None,
    );
    let counts = topic_counts(&r.mcap);
    assert_eq!(counts.get("/camera/left/image"), None, "{counts:?}");
    assert_eq!(
        counts
            .get("/camera/left/image/compressed")
            .map(|&n| n as u64),
        r.stopped["frames_left"].as_u64(),
        "{counts:?}"
    );
    let size = std::fs::metadata(&r.mcap).expect("file").len();
    println!("5 s of the demo from MJPEG cameras: {size} bytes");
    assert!(size < 40_000_000, "{size} bytes");
    // A third-party decoder reads the frames.
    let data = std::fs::read(&r.mcap).expect("recording");
    let jpeg = mcap::MessageStream::new(&data)
        .expect("mcap")
        .filter_map(Result::ok)
        .find(|m| m.channel.topic == "/camera/right/image/compressed")
        .expect("a right frame");
    let decoded = <foxglove::schemas::CompressedImage as foxglove::Decode>::decode(&jpeg.data[..])
        .expect("CompressedImage");
    assert_eq!(decoded.format, "jpeg");
    let picture = image::load_from_memory(&decoded.data).expect("a JPEG");
    assert_eq!((picture.width(), picture.height()), (640, 480));
    let s = replay_ok(&r.mcap, &[]);
    assert_eq!(s["commands_identical"], s["commands_recorded"], "{s}");
    assert_eq!(s["commands_recorded"], r.stopped["commands"], "{s}");
    assert!(
        s["changes"].as_array().is_some_and(|c| c
            .iter()
            .any(|x| x.as_str().is_some_and(|x| x.ends_with(":STOP")))),
        "the demo's STOP through the MJPEG path: {s}"
    );
}

/// A camera that goes blind mid-run (hw-mock's left camera delivers noise from 2 to 3.5 s):
/// the daemon debounces it into the BLIND sensor fault and CAMERA_ERROR, and the replay of
/// the recording (which runs the same `BlindDebounce`, `flyd_core::policy`) reproduces every
/// command frame byte for byte.
#[test]
fn a_recording_where_a_camera_goes_blind_replays_its_commands_bit_for_bit() {
    use flyd_core::can::candump::parse_candump_line;
    use flyd_core::can::messages::{CanMessage, StatusMsg};
    use flyd_core::sensor::SensorFaults;
    use flyd_core::status::FaultBits;

    let fault = "[[cameras.mock_faults]]\nkind = \"noise\"\ncamera = \"left\"\nfrom_s = 2.0\n\
                 to_s = 3.5\n\n[calibration]";
    let r = record_with(|demo| demo.replacen("[calibration]", fault, 1), None);
    let log = std::fs::read_to_string(&r.log).expect("can log");
    let frames: Vec<(u32, Vec<u8>)> = log
        .lines()
        .filter_map(|l| parse_candump_line(l).ok())
        .map(|(_, _, id, data)| (id, data))
        .collect();
    let blind = frames
        .iter()
        .filter(|(id, _)| *id == StatusMsg::DEFAULT_ID)
        .filter_map(|(_, data)| StatusMsg::decode(data).ok())
        .filter(|s| {
            s.sensor.contains(SensorFaults::BLIND) && s.faults.contains(FaultBits::CAMERA_ERROR)
        })
        .count();
    assert!(blind > 5, "{blind} FLYD_Status frames say BLIND");
    let commands = frames
        .iter()
        .filter(|(id, _)| *id == flyd_core::can::messages::CommandMsg::DEFAULT_ID)
        .count();
    let summary = replay_ok(&r.mcap, &[]);
    assert_eq!(summary["commands_recorded"].as_u64(), Some(commands as u64));
    assert_eq!(
        summary["commands_identical"].as_u64(),
        Some(commands as u64),
        "{summary}"
    );
    assert_eq!(summary["divergence"], serde_json::Value::Null, "{summary}");
}
