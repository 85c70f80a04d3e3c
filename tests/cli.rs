//! The real binary: `flyd check-config` and `flyd run` on bad files exit non-zero with a
//! message naming the key and the file; `flyd run` on SIGTERM sends the SHUTDOWN status and
//! exits 0.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use flyd_core::can::candump::parse_candump_line;
use flyd_core::can::messages::StatusMsg;
use flyd_core::status::State;

fn flyd(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(args)
        .output()
        .expect("flyd runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(path)
        .display()
        .to_string()
}

#[test]
fn shipped_configs_pass_check_config() {
    for file in ["config/flyd.toml", "config/demo.toml"] {
        let (ok, stdout, stderr) = flyd(&["check-config", &repo(file)]);
        assert!(ok, "{file}: {stderr}");
        assert!(stdout.contains("ok"), "{stdout}");
    }
}

/// The demo config with `from` replaced by `to`: check-config and run must both fail, naming
/// `key` and the file.
fn check(from: &str, to: &str, key: &str, words: &str) {
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    assert!(text.contains(from), "demo.toml has no {from:?}");
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, text.replacen(from, to, 1)).expect("write");
    let file = file.display().to_string();
    for args in [
        vec!["check-config", file.as_str()],
        vec!["run", "--config", file.as_str(), "--duration", "1"],
    ] {
        let (ok, _, stderr) = flyd(&args);
        assert!(!ok, "{args:?} must fail");
        for needle in [file.as_str(), key, words] {
            assert!(
                stderr.contains(needle),
                "{args:?}: {needle:?} not in {stderr:?}"
            );
        }
    }
}

#[test]
fn bad_configs_name_the_key_and_the_file() {
    check(
        "fps = 30",
        "fps = 30\nexposure = 2",
        "cameras.exposure",
        "unknown field",
    );
    check(
        "flies = 5000",
        "flies = \"many\"",
        "engine.flies",
        "invalid type",
    );
    check(
        "flies = 5000",
        "flies = 5000\nmin_depth = 50.0",
        "engine.max_depth",
        "min_depth",
    );
    check(
        "stop_threshold = 1.5",
        "stop_threshold = 0.1",
        "decision.stop_threshold",
        "slow",
    );
    check(
        "safe_command = \"SLOW\"",
        "safe_command = \"CLEAR\"",
        "decision.safe_command",
        "SLOW or STOP",
    );
    check(
        "stale_frames = 3",
        "stale_frames = 0",
        "cameras.stale_frames",
        "at least 1",
    );
    check(
        "mock = \"pedestrian-steps-in\"",
        "mock = \"pedestrian-steps-in\"\nleft = \"/dev/video0\"",
        "cameras.mock",
        "not both",
    );
    check(
        "builtin = \"mock\"",
        "file = \"missing-rig.toml\"",
        "calibration",
        "missing-rig.toml",
    );
}

#[test]
fn unknown_scenario_is_named_with_the_known_ones() {
    check(
        "mock = \"pedestrian-steps-in\"",
        "mock = \"moose-crossing\"",
        "cameras.mock",
        "pedestrian-steps-in",
    );
}

/// `flyd run` on the demo scenario (small images, to keep a debug build fast), CAN to a
/// candump log; SIGTERM once frames flow: exit 0, and the log's last frame is the SHUTDOWN
/// status.
#[test]
fn sigterm_sends_the_shutdown_status_and_exits_zero() {
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let text = text
        .replace("width = 640", "width = 160")
        .replace("height = 480", "height = 120")
        .replace("flies = 5000", "flies = 500");
    let dir = tempfile::tempdir().expect("tempdir");
    let config = dir.path().join("demo.toml");
    std::fs::write(&config, text).expect("write");
    let log = dir.path().join("can.log");
    let mut child = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(["run", "--config"])
        .arg(&config)
        .arg("--can-log")
        .arg(&log)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("flyd starts");
    let statuses = || -> Vec<StatusMsg> {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| parse_candump_line(l).ok())
            .filter(|(_, _, id, _)| *id == 0x121)
            .map(|(_, _, _, data)| StatusMsg::decode(&data).expect("valid status frame"))
            .collect()
    };
    let guard = Duration::from_secs(60);
    let t0 = Instant::now();
    while statuses().len() < 10 {
        assert!(t0.elapsed() < guard, "no status frames");
        assert!(
            child.try_wait().expect("wait").is_none(),
            "flyd exited early"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: plain kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        assert!(t0.elapsed() < guard, "flyd did not exit on SIGTERM");
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(status.success(), "{status:?}");
    let text = std::fs::read_to_string(&log).expect("log");
    let last = text.lines().last().expect("lines");
    let (_, iface, id, data) = parse_candump_line(last).expect("parses");
    assert_eq!((iface.as_str(), id), ("vcan0", 0x121));
    assert_eq!(
        StatusMsg::decode(&data).map(|s| s.state),
        Ok(State::Shutdown)
    );
}

#[test]
fn missing_file_is_named() {
    let (ok, _, stderr) = flyd(&["check-config", "/nonexistent/flyd.toml"]);
    assert!(!ok);
    assert!(stderr.contains("/nonexistent/flyd.toml"), "{stderr}");
}

#[test]
fn errors_name_their_cause_once() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli-errors");
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let bad = dir.join("bad.png");
    std::fs::write(&bad, b"not a png").expect("write");
    let (bad, out) = (
        bad.display().to_string(),
        dir.join("out").display().to_string(),
    );
    let calib = repo("tests/fixtures/middlebury-motorcycle/calib.txt");
    let png = [
        "replay", "--left", &bad, "--right", &bad, "--calib", &calib, "--out", &out,
    ];
    let size = [
        "replay",
        "--scenario",
        "pedestrian-4m",
        "--width",
        "5",
        "--height",
        "5",
        "--out",
        &out,
    ];
    for (args, names, cause) in [
        (&png[..], "bad.png", "Invalid PNG signature"),
        (&size[..], "mock camera", "at least 16x16"),
    ] {
        let (ok, _, stderr) = flyd(args);
        assert!(!ok, "{args:?} succeeded");
        assert!(stderr.contains(names), "{args:?}: {stderr}");
        // Errors that put their cause in their own message used to print it twice.
        assert_eq!(stderr.matches(cause).count(), 1, "{args:?}: {stderr}");
    }
}

#[test]
fn bench_runs_on_the_instruction_set_asked_for_and_refuses_a_missing_one() {
    let (ok, stdout, stderr) = flyd(&[
        "bench",
        "--isa",
        "baseline",
        "--flies",
        "500",
        "--width",
        "160",
        "--height",
        "120",
        "--generations",
        "6",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("\"isa\": \"baseline\""), "{stdout}");
    let (ok, _, stderr) = flyd(&["bench", "--isa", "sse9"]);
    assert!(!ok);
    assert!(stderr.contains("this CPU has baseline"), "{stderr}");
}
