//! `flyd run` with the vehicle's motion and no kernel CAN: the hw-mock vehicle on the mock
//! bus, and a recorded drive's bus replayed with `--can-input`. What flyd sent is decoded with
//! the project's DBC by can-dbc (tests/vm/can_log.rs), as a VCU built from it would read it.

#[path = "vm/can_log.rs"]
#[allow(dead_code)] // the VM suite's decoder; this file uses a part of it
mod can_log;
mod dbc_signals;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use can_log::{Decoder, Frame};
use flyd_core::can::candump::format_candump_line;
use flyd_core::can::messages::{AliveCounter, MotionMsg};

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// The demo at 320x240 with 1000 flies on `scenario`, the vehicle's motion from CAN.
fn config(dir: &Path, scenario: &str) -> PathBuf {
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let text = text
        .replace(
            "mock = \"pedestrian-steps-in\"",
            &format!("mock = \"{scenario}\""),
        )
        .replace("width = 640", "width = 320")
        .replace("height = 480", "height = 240")
        .replace("flies = 5000", "flies = 1000")
        .replace("motion = \"none\"", "motion = \"can\"");
    // The drives replayed here run over scenes filmed standing: moving the flies with a
    // speed the images do not show would test prediction against a contradiction (what a
    // car ahead at the vehicle's speed is; docs/perception.md), not the motion input.
    let text = text.replace("[vehicle]", "[vehicle]\npredict_flies = false");
    assert!(
        text.contains("motion = \"can\""),
        "demo.toml has a [vehicle] motion key"
    );
    let path = dir.join("flyd.toml");
    std::fs::write(&path, text).expect("write config");
    path
}

/// Runs flyd for `seconds` and decodes what it sent.
fn run(config: &Path, input: Option<&Path>, seconds: f64) -> Vec<Frame> {
    run_logged(config, input, seconds).0
}

/// [`run`], and flyd's log (stderr: the CAN log is the file).
fn run_logged(config: &Path, input: Option<&Path>, seconds: f64) -> (Vec<Frame>, String) {
    let dir = config.parent().expect("dir");
    let log = dir.join("sent.log");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_flyd"));
    cmd.args(["run", "--config"])
        .arg(config)
        .arg("--can-log")
        .arg(&log)
        .args(["--duration", &seconds.to_string()]);
    if let Some(input) = input {
        cmd.arg("--can-input").arg(input);
    }
    let out = cmd.output().expect("flyd runs");
    assert!(
        out.status.success(),
        "flyd run: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&log).expect("CAN log");
    let frames = Decoder::new().decode_log(&text);
    assert!(frames.iter().all(|f| f.crc_ok), "every frame's CRC holds");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (frames, log)
}

/// (seconds since the first frame, value).
type Timeline<T> = Vec<(f64, T)>;

/// (seconds since the first frame, command) of every FLYD_Command but the last one (the
/// shutdown's safe command), and the same for the
/// MotionFault of every FLYD_Status.
fn timeline(frames: &[Frame]) -> (Timeline<String>, Timeline<f64>) {
    let t0 = frames.first().map_or(0.0, |f| f.time);
    let commands = frames
        .iter()
        .filter(|f| f.message == "FLYD_Command" && f.label("CommandReason") != "SHUTDOWN")
        .map(|f| (f.time - t0, f.label("Command").to_string()))
        .collect();
    let faults = frames
        .iter()
        .filter(|f| f.message == "FLYD_Status")
        .map(|f| (f.time - t0, f.value("MotionFault")))
        .collect();
    (commands, faults)
}

#[test]
fn the_parked_mock_vehicle_reports_standstill_and_flyd_does_not_brake_for_what_is_4m_ahead() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = config(dir.path(), "pedestrian-4m");
    let frames = run(&config, None, 3.0);
    let (commands, faults) = timeline(&frames);
    // After the start (SLOW, the start-up fallback, then its hold), the motion is known.
    let late: Vec<_> = faults.iter().filter(|(t, _)| *t > 1.0).collect();
    assert!(
        !late.is_empty() && late.iter().all(|(_, f)| *f == 0.0),
        "{faults:?}"
    );
    // At 0 km/h the stopping distance is the 2 m margin: the pedestrian 4 m ahead is CLEAR.
    let after: Vec<_> = commands.iter().filter(|(t, _)| *t > 2.0).collect();
    assert!(!after.is_empty(), "commands after 2 s");
    assert!(
        after.iter().all(|(_, c)| c == "CLEAR"),
        "at a standstill: {after:?}"
    );
    assert!(commands.iter().all(|(_, c)| c != "STOP"), "{commands:?}");
}

/// A drive's bus as candump recorded it: `VCU_Motion` at 20 ms, 30 km/h for `seconds`, then
/// nothing (the VCU went silent); a few bad frames among the good ones.
fn recorded_drive(path: &Path, seconds: f64) {
    recorded_drive_at(path, seconds, 30.0 / 3.6);
}

fn recorded_drive_at(path: &Path, seconds: f64, speed: f64) {
    let mut text = String::new();
    let mut counter = AliveCounter::ZERO;
    let t0 = Duration::from_secs(1_764_000_000);
    let ms = Duration::from_millis;
    let periods = (seconds / 0.02).round() as u32;
    for k in 0..periods {
        let t = t0 + ms(20 * u64::from(k));
        let msg = MotionMsg {
            valid: true,
            speed,
            yaw_rate: 0.0,
        };
        let data = msg.encode(counter.advance());
        text.push_str(&format_candump_line(t, "vcan0", 0x110, &data));
        text.push('\n');
        if k % 10 == 5 {
            // Corrupted, and a speed no vehicle has: ignored.
            let mut bad = data;
            bad[2] ^= 0xFF;
            text.push_str(&format_candump_line(t + ms(1), "vcan0", 0x110, &bad));
            text.push('\n');
            let fast = MotionMsg {
                speed: 300.0,
                ..msg
            };
            let data = fast.encode(counter.advance());
            text.push_str(&format_candump_line(t + ms(2), "vcan0", 0x110, &data));
            text.push('\n');
        }
        // Another node's frame on the same bus: not flyd's business.
        text.push_str(&format_candump_line(t + ms(5), "vcan0", 0x3A0, &[1, 2, 3]));
        text.push('\n');
    }
    std::fs::write(path, text).expect("write log");
}

#[test]
fn a_recorded_drive_at_30_kmh_stops_for_the_pedestrian_and_its_silence_is_a_motion_fault() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = config(dir.path(), "pedestrian-4m");
    let input = dir.path().join("drive.log");
    recorded_drive(&input, 2.0);
    let frames = run(&config, Some(&input), 3.5);
    let (commands, faults) = timeline(&frames);
    // Known from the start (the second frame) to the end of the log at 2 s, unknown 3
    // periods later. The log starts when flyd opens its input, a few tens of ms after the
    // first frame flyd sends: tolerances of 200 ms.
    let known: Vec<_> = faults
        .iter()
        .filter(|(t, _)| (0.2..1.8).contains(t))
        .collect();
    assert!(
        !known.is_empty() && known.iter().all(|(_, f)| *f == 0.0),
        "motion known while the VCU sends: {faults:?}"
    );
    let lost: Vec<_> = faults.iter().filter(|(t, _)| *t > 2.3).collect();
    assert!(
        !lost.is_empty() && lost.iter().all(|(_, f)| *f == 1.0),
        "MotionFault once it is silent: {faults:?}"
    );
    // At 30 km/h measured, then assumed: STOP 4 m before the pedestrian, throughout.
    let stops: Vec<_> = commands.iter().filter(|(t, _)| *t > 1.0).collect();
    assert!(
        !stops.is_empty() && stops.iter().all(|(_, c)| c == "STOP"),
        "{commands:?}"
    );
}

/// At 80 km/h the SLOW distance (2 m + 11.1 m + 164.6 m) lies far beyond the 40 m flyd
/// searches: said in the log, and the decision still at the measured speed (STOP 4 m before
/// the pedestrian). At 30 km/h (29.3 m) nothing is said.
#[test]
fn a_speed_beyond_what_flyd_sees_in_time_is_logged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = config(dir.path(), "pedestrian-4m");
    let warning = "speed beyond what flyd sees in time";
    let input = dir.path().join("fast.log");
    recorded_drive_at(&input, 2.0, 80.0 / 3.6);
    let (_, log) = run_logged(&config, Some(&input), 1.5);
    assert!(log.contains(warning), "{log}");
    recorded_drive_at(&input, 2.0, 30.0 / 3.6);
    let (_, log) = run_logged(&config, Some(&input), 1.5);
    assert!(!log.contains(warning), "{log}");
}

/// The speed (m/s) and yaw rate (rad/s, left positive) between consecutive KITTI poses
/// (3x4 camera-to-world, camera x right, y down, z ahead) at `fps`.
fn motion_of_poses(text: &str, fps: f64) -> Vec<(f64, f64)> {
    let poses: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            l.split_whitespace()
                .map(|v| v.parse().expect("number"))
                .collect()
        })
        .collect();
    poses
        .windows(2)
        .map(|w| {
            let (a, b) = (&w[0], &w[1]);
            let travelled = ((b[3] - a[3]).powi(2) + (b[11] - a[11]).powi(2)).sqrt();
            let heading = |p: &Vec<f64>| p[2].atan2(p[10]);
            (travelled * fps, -(heading(b) - heading(a)) * fps)
        })
        .collect()
}

/// `flyd replay` of the drive's images in `drive`, calibrated by `rig`, the vehicle's motion
/// from the candump log `bus`, into `out`: its output, whether it succeeded or not.
fn replay_drive(drive: &Path, rig: &Path, bus: &Path, out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(["replay", "--sequence"])
        .arg(drive)
        .arg("--calib")
        .arg(rig)
        .arg("--can-input")
        .arg(bus)
        .arg("--out")
        .arg(out)
        .output()
        .expect("flyd replay")
}

#[test]
fn a_real_drive_replayed_with_its_bus_is_decided_at_the_speed_vcu_motion_says() {
    let dir = tempfile::tempdir().expect("tempdir");
    let drive = repo("tests/fixtures/kitti/kitti_odom06_seq20_gray");
    let poses = std::fs::read_to_string(drive.join("poses.txt")).expect("poses");
    let motion = motion_of_poses(&poses, 10.0);
    // The drive's bus: VCU_Motion every 20 ms with the poses' motion for 1.2 s (12 frames),
    // every 7th frame corrupted; then the VCU falls silent.
    let mut text = String::new();
    let mut counter = AliveCounter::ZERO;
    let t0 = Duration::from_secs(1_764_000_000);
    for k in 0..60u64 {
        let (speed, yaw_rate) = motion[(k / 5) as usize];
        let msg = MotionMsg {
            valid: true,
            speed,
            yaw_rate,
        };
        let mut data = msg.encode(counter.advance());
        if k % 7 == 3 {
            data[2] ^= 0x5A;
        }
        let t = t0 + Duration::from_millis(20 * k);
        text.push_str(&format_candump_line(t, "can0", 0x110, &data));
        text.push('\n');
    }
    let log = dir.path().join("bus.log");
    std::fs::write(&log, text).expect("log");
    let out_dir = dir.path().join("out");
    let rig = dir.path().join("rig.toml");
    std::fs::write(
        &rig,
        format!(
            "[import]\nfile = {:?}\n\n[mount]\nposition = [0.0, 1.65, 0.0]\n",
            drive.join("calib.txt").display().to_string()
        ),
    )
    .expect("rig");
    let out = replay_drive(&drive, &rig, &log, &out_dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("summary");
    let source = summary["motion_source"].as_str().expect("motion source");
    // 60 sent, 9 corrupted; the first frame comes with the first message (not yet trusted),
    // and the frames after the silence (stale after 3 periods) have none.
    assert!(
        source.starts_with("candump ")
            && source.contains("51 VCU_Motion accepted, 9 rejected")
            && source.contains("no trusted motion on 8 of 20 frames"),
        "{source}"
    );
    assert_eq!(summary["speed_source"], "feed");
    assert_eq!(summary["predict_flies"], true);
    // Each frame's speed is what the bus said while it was trusted, else the assumed 30 km/h.
    let frames = std::fs::read_to_string(out_dir.join("frames.csv")).expect("frames.csv");
    let mut lines = frames.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (frame_col, speed_col) = (col("frame"), col("speed_kmh"));
    for line in lines {
        let row: Vec<&str> = line.split(',').collect();
        let frame: usize = row[frame_col].parse().expect("frame");
        let speed: f64 = row[speed_col].parse().expect("speed");
        // The newest message at the frame's time that was not corrupted.
        let newest = (0..=5 * frame as u64).rev().find(|k| k % 7 != 3);
        let want = match newest {
            Some(k) if (1..=12).contains(&frame) => motion[(k / 5) as usize].0 * 3.6,
            _ => 30.0,
        };
        assert!(
            (speed - want).abs() < 0.2,
            "frame {frame}: {speed} km/h, the bus said {want}"
        );
    }
    // A log that is not candump is an error naming the file and line.
    std::fs::write(&log, "not a candump line\n").expect("log");
    let out = replay_drive(&drive, &rig, &log, &out_dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("bus.log:1: not a candump line"),
        "{stderr}"
    );
}
