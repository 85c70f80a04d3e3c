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

/// Runs `flyd ARGS`, asserts that it succeeded, and returns the JSON summary it printed and
/// its stderr (what a replay warns of).
fn summary_and_stderr(args: &[&str]) -> (serde_json::Value, String) {
    let (ok, stdout, stderr) = flyd(args);
    assert!(ok, "{stderr}");
    let summary = serde_json::from_str(&stdout).expect("summary JSON");
    (summary, stderr)
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

/// The example rig of config/rig.toml (f B = 156 px m at 640x480) resolves 17.6 m within the
/// 2 m margin, short of the SLOW distance at 30 km/h (29.3 m): check-config passes with a
/// warning that states the rule; at 20 km/h (SLOW distance 15.1 m) it has nothing to say. The
/// demo's built-in mock rig resolves as little, and is a simulation: a note, not a warning.
#[test]
fn check_config_warns_when_the_rig_cannot_resolve_the_slow_distance() {
    let (ok, stdout, stderr) = flyd(&["check-config", &repo("config/flyd.toml")]);
    assert!(ok && stdout.contains("ok"), "{stdout} {stderr}");
    for needle in [
        "warning: the rig cannot resolve the SLOW distance",
        "29.3 m is 5.5 m of depth (Z^2 / (f B))",
        "decision.margin_m = 2",
        "resolves 17.6 m",
        // What would resolve it.
        "To resolve it: f B of at least 430 px m",
        "or decision.margin_m = 5.6",
    ] {
        assert!(stderr.contains(needle), "{needle:?} not in {stderr:?}");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(repo("config/rig.toml"), dir.path().join("rig.toml")).expect("copy rig");
    let text = std::fs::read_to_string(repo("config/flyd.toml")).expect("config");
    let file = dir.path().join("slow.toml");
    let slow = text.replacen("assumed_speed_kmh = 30", "assumed_speed_kmh = 20", 1);
    assert_ne!(slow, text, "flyd.toml sets the assumed speed");
    std::fs::write(&file, slow).expect("write");
    let (ok, stdout, stderr) = flyd(&["check-config", &file.display().to_string()]);
    assert!(ok && stdout.contains("ok"), "{stdout} {stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    // The demo: a note on what the mock rig resolves, no warning.
    let (ok, stdout, stderr) = flyd(&["check-config", &repo("config/demo.toml")]);
    assert!(ok && stdout.contains("ok"), "{stdout} {stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(
        stdout.contains("note: the built-in mock rig resolves 17.7 m"),
        "{stdout}"
    );
}

/// The demo logs no WARN about itself: its mock hardware is what it runs on.
#[test]
fn the_demo_runs_without_a_warning_about_itself() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args([
            "run",
            "--config",
            &repo("config/demo.toml"),
            "--duration",
            "2",
        ])
        .output()
        .expect("flyd run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("mock rig"),
        "the resolution is logged: {stderr}"
    );
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("WARN") || l.contains("ERROR"))
        .collect();
    assert!(warnings.is_empty(), "{warnings:#?}");
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
        "1..=30",
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
    signal_sends_the_shutdown_status(libc::SIGTERM);
}

#[test]
fn sigint_sends_the_shutdown_status_and_exits_zero() {
    signal_sends_the_shutdown_status(libc::SIGINT);
}

/// SIGHUP (a closed terminal, `kill -HUP`) used to end flyd at once (exit 129, no SHUTDOWN
/// frames); it ends it as SIGTERM does.
#[test]
fn sighup_ends_flyd_as_sigterm_does() {
    signal_sends_the_shutdown_status(libc::SIGHUP);
}

fn signal_sends_the_shutdown_status(signal: libc::c_int) {
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
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        assert!(t0.elapsed() < guard, "flyd did not exit on signal {signal}");
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(status.success(), "signal {signal}: {status:?}");
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

/// stdout to a full disk (`/dev/full`) made check-config, replay and bench panic (exit 101);
/// they exit 1 with a message.
#[test]
fn a_full_stdout_is_an_error_message_not_a_panic() {
    let out = tempfile::tempdir().expect("tempdir");
    let out_dir = out.path().display().to_string();
    let demo = repo("config/demo.toml");
    for args in [
        vec!["check-config", demo.as_str()],
        vec![
            "replay",
            "--scenario",
            "empty-road",
            "--width",
            "160",
            "--height",
            "120",
            "--generations",
            "3",
            "--out",
            out_dir.as_str(),
        ],
        vec!["bench", "--generations", "3"],
    ] {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .expect("/dev/full");
        let o = Command::new(env!("CARGO_BIN_EXE_flyd"))
            .args(&args)
            .stdout(full)
            .output()
            .expect("flyd runs");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(
            stderr.contains("writing to standard output"),
            "{args:?}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
}

/// A configuration path to /dev/zero or a 2 MB file never returned (3-4 GB of memory); both
/// are refused before parsing, naming the file and the limit.
#[test]
fn configuration_files_are_size_limited_before_parsing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let big = dir.path().join("big.toml");
    std::fs::write(&big, "#".repeat(2_000_000)).expect("write");
    let big = big.display().to_string();
    for (file, words) in [
        ("/dev/zero", "not a regular file"),
        (big.as_str(), "1048576-byte limit"),
    ] {
        let (ok, _, stderr) = flyd(&["check-config", file]);
        assert!(!ok);
        assert!(stderr.contains(file) && stderr.contains(words), "{stderr}");
        assert!(
            stderr.len() < 500,
            "the error echoes the file: {} bytes",
            stderr.len()
        );
    }
    // A calibration file too.
    let text = std::fs::read_to_string(repo("config/flyd.toml")).expect("flyd.toml");
    let config = dir.path().join("c.toml");
    std::fs::write(
        &config,
        text.replacen("file = \"rig.toml\"", "file = \"/dev/zero\"", 1),
    )
    .expect("write");
    let (ok, _, stderr) = flyd(&["check-config", &config.display().to_string()]);
    assert!(
        !ok && stderr.contains("/dev/zero") && stderr.contains("not a regular file"),
        "{stderr}"
    );
}

/// The values check-config accepted although they disable safety or cannot run (issue 17's
/// table): each is refused by check-config and by run, naming the key.
#[test]
fn values_that_disable_safety_are_refused() {
    for (from, to, key, words) in [
        (
            "stop_threshold = 1.5",
            "stop_threshold = 1e300",
            "decision.stop_threshold",
            "within",
        ),
        (
            "[engine]",
            "[engine]\nwarning_min_abs_x = 1e6",
            "engine.warning_min_abs_x",
            "within",
        ),
        (
            "[engine]",
            "[engine]\nwarning_min_z = 1e6",
            "engine.warning_min_z",
            "within",
        ),
        ("width = 640", "width = 16", "cameras.width", "160"),
        ("height = 480", "height = 16", "cameras.height", "120"),
        (
            "stale_frames = 3",
            "stale_frames = 4294967295",
            "cameras.stale_frames",
            "1..=30",
        ),
        (
            "[can]",
            "[control]\nsnapshot_timeout_ms = 999999999\n\n[can]",
            "control.snapshot_timeout_ms",
            "10..=1000",
        ),
        (
            "[can]",
            "[can.messages.command]\nid = 0x120\ndata_id = 0x0120\nperiod_ms = 4294967295\n\n[can]",
            "can.messages",
            "at most 100 ms",
        ),
        ("fps = 30", "fps = 3.9", "cameras.fps", "5..=120"),
        ("fps = 30", "fps = 1e-300", "cameras.fps", "5..=120"),
        (
            "[can]",
            "[perception.obstacle]\nmin_width = 1e6\n\n[can]",
            "perception.obstacle.min_width",
            "0..=0.5",
        ),
        (
            "[can]",
            "[perception.obstacle]\nmax_ambiguity = 1e-9\n\n[can]",
            "perception.obstacle.max_ambiguity",
            "0.1..=1",
        ),
        (
            "[can]",
            "[perception.track]\ntrigger_frames = 100\n\n[can]",
            "perception.track.trigger_frames",
            "1..=5",
        ),
        (
            "[engine]",
            "[engine]\nmax_depth = 20.0",
            "engine.max_depth",
            "SLOW distance",
        ),
        (
            "[decision]",
            "[decision]\nstop_decel = 0",
            "decision.stop_decel",
            "> 0",
        ),
        (
            "[decision]",
            "[decision]\nslow_decel = 9\nstop_decel = 9.5\nmax_decel = 10\nmargin_m = 1e9",
            "decision.margin_m",
            "0..=20",
        ),
        (
            "[decision]",
            "[decision]\nmax_decel = 3",
            "decision.max_decel",
            "at least stop_decel",
        ),
        (
            "[evolution]",
            "[evolution]\nblind_matched = 0",
            "evolution.blind_matched",
            "0.05",
        ),
        (
            "assumed_speed_kmh = 30",
            "assumed_speed_kmh = 0",
            "vehicle.assumed_speed_kmh",
            "10..=250",
        ),
        (
            "assumed_speed_kmh = 30",
            "assumed_speed_kmh = 30\nmotion_stale_periods = 0",
            "vehicle.motion_stale_periods",
            "1..=10",
        ),
        (
            "motion = \"none\"",
            "motion = \"wheels\"",
            "vehicle.motion",
            "unknown variant",
        ),
        (
            "[can]",
            "[can]\nmessages.motion = { id = 0x120, data_id = 0x0110, period_ms = 20 }",
            "can.messages",
            "share CAN ID",
        ),
        (
            "log_interface = \"vcan0\"",
            "log_interface = \"abcdefghijabcdefghijabcdefghij1234\"",
            "can.log_interface",
            "1 to 15",
        ),
        (
            "log_interface = \"vcan0\"",
            "log_interface = \"vcan0\\nINJECTED\"",
            "can.log_interface",
            "1 to 15",
        ),
    ] {
        eprintln!("case: {to}");
        check(from, to, key, words);
    }
}

/// The rig TOML's `[search]` was honoured by replay and ignored by the daemon: check-config
/// (what run starts with) takes its depth range.
#[test]
fn the_calibrations_search_range_is_honoured_by_the_daemon() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rig = std::fs::read_to_string(repo("tests/fixtures/calib/rig_explicit.toml")).expect("rig");
    assert!(rig.contains("min_depth = 1.0\nmax_depth = 25.0"));
    std::fs::write(
        dir.path().join("rig.toml"),
        rig.replace(
            "min_depth = 1.0\nmax_depth = 25.0",
            "min_depth = 2.0\nmax_depth = 30.0",
        ),
    )
    .expect("write");
    let text = std::fs::read_to_string(repo("config/flyd.toml")).expect("flyd.toml");
    let config = dir.path().join("flyd.toml");
    std::fs::write(&config, text).expect("write");
    let (ok, stdout, stderr) = flyd(&["check-config", &config.display().to_string()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("depths 2-30 m"), "{stdout}");
}

/// A truncated JPEG was decoded silently as another image (grey where the data stopped); it is
/// an error naming the file.
#[test]
fn a_truncated_jpeg_in_replay_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let img = image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 90])
    });
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
        .encode_image(&img)
        .expect("encode");
    let whole = dir.path().join("whole.jpg");
    let cut = dir.path().join("cut.jpg");
    std::fs::write(&whole, &jpeg).expect("write");
    std::fs::write(&cut, &jpeg[..jpeg.len() * 2 / 3]).expect("write");
    let pair = repo("tests/fixtures/kitti/kitti2015_train_000000");
    let out = dir.path().join("out").display().to_string();
    let replay = |left: &Path| {
        flyd(&[
            "replay",
            "--left",
            &left.display().to_string(),
            "--right",
            &format!("{pair}/im1.png"),
            "--calib",
            &format!("{pair}/rig.toml"),
            "--generations",
            "1",
            "--out",
            &out,
        ])
    };
    let (ok, _, stderr) = replay(&cut);
    assert!(!ok);
    assert!(
        stderr.contains(&cut.display().to_string()) && stderr.contains("truncated"),
        "{stderr}"
    );
    // The whole file decodes (and is then refused for its size, not its content).
    let (ok, _, stderr) = replay(&whole);
    assert!(
        !ok && !stderr.contains("truncated") && stderr.contains("64x48"),
        "{stderr}"
    );
}

/// Two flyds on one CAN interface would interleave contradicting commands: the second one is
/// refused, naming the interface (the lock is an abstract socket, as the first flyd holds it).
#[test]
fn a_second_flyd_on_the_same_interface_is_refused() {
    use std::os::linux::net::SocketAddrExt;
    let addr =
        std::os::unix::net::SocketAddr::from_abstract_name(b"flyd-can-flydtest0").expect("name");
    let _held = std::os::unix::net::UnixDatagram::bind_addr(&addr).expect("the lock is free");
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let config = dir.path().join("c.toml");
    let text = text.replace(
        "log = \"-\"\nlog_interface = \"vcan0\"",
        "interface = \"flydtest0\"",
    );
    assert!(text.contains("interface = \"flydtest0\""));
    std::fs::write(&config, text).expect("write");
    let (ok, _, stderr) = flyd(&[
        "run",
        "--config",
        &config.display().to_string(),
        "--duration",
        "1",
    ]);
    assert!(!ok);
    assert!(
        stderr.contains("flydtest0") && stderr.contains("another flyd"),
        "{stderr}"
    );
}

/// V4L2 cameras at an odd YUYV width or a fractional frame rate passed check-config and were
/// refused (or rounded silently) by run: check-config refuses them, naming the key.
#[test]
fn v4l2_settings_run_would_refuse_are_refused_by_check_config() {
    let text = std::fs::read_to_string(repo("config/flyd.toml")).expect("flyd.toml");
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(repo("config/rig.toml"), dir.path().join("rig.toml")).expect("rig");
    for (from, to, key, words) in [
        ("width = 640", "width = 641", "cameras.width", "even width"),
        ("fps = 30", "fps = 30.4", "cameras.fps", "whole number"),
    ] {
        let file = dir.path().join("c.toml");
        std::fs::write(&file, text.replacen(from, to, 1)).expect("write");
        let (ok, _, stderr) = flyd(&["check-config", &file.display().to_string()]);
        assert!(!ok, "{to}");
        assert!(
            stderr.contains(key) && stderr.contains(words),
            "{to}: {stderr}"
        );
    }
}

/// Runs the demo for 1 s with `[logging] format` set and stdout on a pipe, with
/// `$JOURNAL_STREAM` set to that pipe's device:inode (`matching`) or to another file's; returns
/// stdout.
fn demo_logs_with_journal_stream(format: &str, matching: bool) -> String {
    use std::io::Read;
    use std::os::fd::AsFd;
    use std::os::unix::fs::MetadataExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let config = dir.path().join("c.toml");
    let text = text.replacen("format = \"auto\"", &format!("format = \"{format}\""), 1);
    assert!(text.contains(&format!("format = \"{format}\"")));
    std::fs::write(&config, text).expect("write");
    let (mut reader, writer) = std::io::pipe().expect("pipe");
    let meta = std::fs::File::from(writer.as_fd().try_clone_to_owned().expect("dup"))
        .metadata()
        .expect("fstat");
    let stream = if matching {
        format!("{}:{}", meta.dev(), meta.ino())
    } else {
        format!("{}:{}", meta.dev(), meta.ino() + 1)
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(["run", "--config", &config.display().to_string()])
        .args(["--can-log", "/dev/null", "--duration", "1"])
        .env("JOURNAL_STREAM", stream)
        .stdout(writer)
        .stderr(Stdio::piped())
        .spawn()
        .expect("flyd runs");
    let mut out = String::new();
    reader.read_to_string(&mut out).expect("read");
    let mut err = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut err);
    }
    assert!(child.wait().expect("wait").success(), "{out}\n{err}");
    out
}

/// Under systemd flyd logs natively to the journal when its stdout is the stream systemd
/// named in `$JOURNAL_STREAM` (the VM suite's systemd scenario checks the entries with
/// journalctl). Here, where no journald listens, it finds its stream, then falls back to JSON
/// lines on stdout and says so once; with another stream named, it writes JSON lines as before.
#[test]
fn the_journal_stream_is_recognised_and_a_missing_journal_is_said_once() {
    let socket = Path::new("/run/systemd/journal/socket");
    if socket.exists() {
        println!(
            "note: {} exists: the fallback is not exercised here",
            socket.display()
        );
    }
    let json_lines = |out: &str| {
        out.lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).expect("a JSON line"))
            .collect::<Vec<_>>()
    };
    let unavailable = |lines: &[serde_json::Value]| {
        lines
            .iter()
            .filter(|v| {
                v["message"]
                    .as_str()
                    .is_some_and(|m| m.starts_with("journal socket unavailable"))
            })
            .count()
    };
    // Another stream named: JSON lines, no word of the journal.
    let other = json_lines(&demo_logs_with_journal_stream("auto", false));
    assert!(other.iter().any(|v| v["message"] == "flyd starting"));
    assert_eq!(unavailable(&other), 0);
    for format in ["auto", "journal"] {
        let out = demo_logs_with_journal_stream(format, true);
        if socket.exists() {
            // Entries went to the journal, not to stdout.
            assert!(!out.contains("flyd starting"), "{out}");
            continue;
        }
        let lines = json_lines(&out);
        assert_eq!(unavailable(&lines), 1, "said once ({format}):\n{out}");
        let said = lines
            .iter()
            .find(|v| {
                v["message"]
                    .as_str()
                    .is_some_and(|m| m.starts_with("journal socket"))
            })
            .expect("the notice");
        assert_eq!(said["level"], "WARN");
        assert_eq!(said["socket"], socket.display().to_string());
        assert!(lines.iter().any(|v| v["message"] == "flyd starting"));
    }
}

/// `flyd eval` without its data names the missing folder on the line a person reads, once,
/// with the option that fixes it (issue 47: it printed "seed 1: error"; issue 57: a line a run).
#[test]
fn eval_without_its_data_names_the_missing_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (ok, stdout, stderr) = flyd(&[
        "eval",
        &repo("eval/real.toml"),
        "--seeds",
        "1",
        "--only",
        "kitti2012_train_000000",
        "--data",
        &dir.path().join("missing").display().to_string(),
    ]);
    assert!(!ok);
    // Once, before any run: the folder, how many items miss theirs, and the option that
    // fixes it (issue 57: it named the missing calib.txt once a run, 14 times).
    let missing = dir.path().join("missing").display().to_string();
    assert!(
        stderr.contains("1 of the items' folders are not in")
            && stderr.contains("--data")
            && stderr.contains(&format!("{missing}/kitti2012_train_000000")),
        "{stdout}\n{stderr}"
    );
    assert_eq!(stderr.matches(&missing).count(), 2, "{stderr}");
    assert!(!stdout.contains("seed 1"), "no run started: {stdout}");
}

/// The markdown files whose references `every_path_and_command_the_docs_name_exists` checks
/// (those that exist), besides `docs/*.md`.
const DOCS: [&str; 6] = [
    "README.md",
    "ARCHITECTURE.md",
    "systemd/README.md",
    "tests/README.md",
    "tests/vm/README.md",
    "tests/fixtures/README.md",
];

/// A backticked word that starts with one of these (or with any other top-level folder of the
/// repository) names a path of the repository. Kept even where a folder is gone, so that a doc
/// still naming it is caught.
const REPO_FOLDERS: [&str; 13] = [
    ".ci/",
    "benches/",
    "config/",
    "crates/",
    "docs/",
    "eval/",
    "examples/",
    "hw-mock/",
    "packaging/",
    "scripts/",
    "src/",
    "systemd/",
    "tests/",
];

/// Upper-case words of real file names; any other (`FILE`, `DIR`, `seedN`, `poses_NN.txt`)
/// marks a placeholder.
const REAL_CAPS: [&str; 6] = [
    "README",
    "ARCHITECTURE",
    "LICENSE",
    "CHANGELOG",
    "CRATES",
    "STYLE",
];

/// Every path and command the docs name exists (issue 47). In README.md, ARCHITECTURE.md,
/// docs/*.md and the READMEs of systemd/, tests/, tests/vm/ and tests/fixtures/:
///
/// - every relative markdown link, `[text](path)` or `(path#anchor)`, names a file or folder
///   relative to the markdown file (web and mail links and `#anchor` alone are not checked);
/// - every word of inline code or a code block that starts with a top-level folder
///   (`src/`, `tests/`, `config/`...) names a file or folder relative to the repository's root
///   (or to the markdown file's own folder, for a README listing its neighbours), once a
///   trailing `:line`, `#anchor` or punctuation is stripped; placeholders (`*`, `{`, `<`,
///   `...`, upper-case words such as `FILE` or `seedN`) are skipped;
/// - every `flyd WORD` in inline code or a code block, WORD a lower-case word, is a
///   subcommand the real binary's `flyd --help` lists.
///
/// Fails with every dead reference, each with its file and line.
#[test]
fn every_path_and_command_the_docs_name_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (ok, help, stderr) = flyd(&["--help"]);
    assert!(ok, "flyd --help failed: {stderr}");
    let commands = subcommands(&help);
    assert!(
        ["run", "replay", "check-config"]
            .iter()
            .all(|c| commands.contains(*c)),
        "no command list in flyd --help: {commands:?}\n{help}"
    );
    let mut docs: Vec<String> = DOCS.iter().map(|d| d.to_string()).collect();
    let mut pages: Vec<String> = std::fs::read_dir(root.join("docs"))
        .expect("docs/")
        .map(|e| {
            e.expect("a docs/ entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|name| name.ends_with(".md"))
        .map(|name| format!("docs/{name}"))
        .collect();
    pages.sort();
    docs.extend(pages);
    let prefixes = repo_prefixes(root);
    let mut checked = Vec::new();
    let mut dead = Vec::new();
    for doc in docs.iter().filter(|d| root.join(d).is_file()) {
        dead.extend(dead_references(root, doc, &commands, &prefixes));
        checked.push(doc.as_str());
    }
    assert!(checked.contains(&"README.md"), "README.md not checked");
    assert!(
        dead.is_empty(),
        "{} dead reference(s) in the docs ({}):\n{}",
        dead.len(),
        checked.join(", "),
        dead.join("\n")
    );
}

/// The checker itself: a dead link, path and command are each found with their line, and
/// live ones, placeholders, web links and anchors are not.
#[test]
fn every_path_check_finds_each_kind_of_dead_reference() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path();
    std::fs::create_dir_all(root.join("docs")).expect("mkdir");
    std::fs::write(root.join("docs/a.md"), "# a\n").expect("write");
    let doc = "See [a](docs/a.md), [b](docs/gone.md#x), [web](https://example.com), [top](#top).\n\
               `docs/a.md:3`, `docs/missing.rs`, `src/<name>.rs`, `tests/FILE`, `docs/*.md`.\n\
               Run `flyd run --config FILE`, `flyd <command> --help` or `flyd\n\
               fly --fast`.\n\
               \n\
               ```sh\n\
               flyd replay --out DIR\n\
               target/release/flyd frobnicate   # not a command\n\
               cat \"docs/nope.txt\"\n\
               ```\n\
               \n    \
               flyd evaluate\n";
    std::fs::write(root.join("README.md"), doc).expect("write");
    let commands = subcommands("Usage: flyd <COMMAND>\n\nCommands:\n  run  R\n  replay  P\n\n");
    let dead = dead_references(root, "README.md", &commands, &repo_prefixes(root));
    let expected = [
        "README.md:1: link (docs/gone.md#x)",
        "README.md:2: path `docs/missing.rs`",
        "README.md:3: `flyd fly`",
        "README.md:8: `flyd frobnicate`",
        "README.md:9: path `docs/nope.txt`",
        "README.md:12: `flyd evaluate`",
    ];
    assert_eq!(dead.len(), expected.len(), "{dead:#?}");
    for (found, want) in dead.iter().zip(expected) {
        assert!(
            found.starts_with(want),
            "{found:?} is not {want:?}: {dead:#?}"
        );
    }
}

/// The subcommands `flyd --help` lists under "Commands:".
fn subcommands(help: &str) -> std::collections::BTreeSet<String> {
    help.lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_owned)
        .collect()
}

/// `REPO_FOLDERS` and every other top-level folder of `root` (not hidden, not `target`).
fn repo_prefixes(root: &Path) -> Vec<String> {
    let mut prefixes: Vec<String> = REPO_FOLDERS.iter().map(|p| p.to_string()).collect();
    for entry in std::fs::read_dir(root).expect("the repository") {
        let entry = entry.expect("an entry");
        let name = entry.file_name().to_string_lossy().into_owned();
        if entry.path().is_dir() && !name.starts_with('.') && name != "target" {
            let prefix = format!("{name}/");
            if !prefixes.contains(&prefix) {
                prefixes.push(prefix);
            }
        }
    }
    prefixes
}

/// The dead references of the markdown file `doc` (relative to `root`), one line each:
/// `doc:line: what`.
fn dead_references(
    root: &Path,
    doc: &str,
    commands: &std::collections::BTreeSet<String>,
    prefixes: &[String],
) -> Vec<String> {
    let text = std::fs::read_to_string(root.join(doc)).unwrap_or_else(|e| panic!("{doc}: {e}"));
    let dir = root.join(doc).parent().expect("a folder").to_path_buf();
    let (blocks, prose) = split_code_blocks(&text);
    let (spans, links_text) = code_spans(&prose);
    let mut dead = Vec::new();
    for (line, target) in links(&links_text) {
        if target.starts_with('#') || target.contains("://") || target.starts_with("mailto:") {
            continue;
        }
        let file = target.split(['#', '?']).next().unwrap_or_default();
        if !dir.join(file).exists() {
            dead.push(format!(
                "{doc}:{line}: link ({target}): no such file or folder"
            ));
        }
    }
    let mut code: Vec<(usize, String)> = blocks.into_iter().chain(spans).collect();
    code.sort_by_key(|(line, _)| *line);
    for (line, piece) in &code {
        for word in piece.split(|c: char| c.is_whitespace() || "\"'(),;=`".contains(c)) {
            let Some(path) = repo_path(word, prefixes) else {
                continue;
            };
            if !root.join(path).exists() && !dir.join(path).exists() {
                dead.push(format!(
                    "{doc}:{line}: path `{path}`: no such file or folder"
                ));
            }
        }
        for word in flyd_commands(piece) {
            if !commands.contains(word) {
                dead.push(format!(
                    "{doc}:{line}: `flyd {word}`: not a subcommand of flyd --help ({})",
                    commands.iter().cloned().collect::<Vec<_>>().join(", ")
                ));
            }
        }
    }
    dead
}

/// The lines of fenced and indented code blocks, each with its line number, and the rest of
/// the text with those lines left empty (so that line numbers stay).
fn split_code_blocks(text: &str) -> (Vec<(usize, String)>, String) {
    let mut code = Vec::new();
    let mut prose = String::with_capacity(text.len());
    let mut fence: Option<(char, usize)> = None;
    let mut previous_blank = true;
    let mut indented_block = false;
    // The last line of text was a list item or its continuation: an indented line after it is
    // the item's next paragraph, not code.
    let mut in_list = false;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let trimmed = line.trim_start();
        let marker = trimmed.chars().next().filter(|c| *c == '`' || *c == '~');
        let run = marker.map_or(0, |m| trimmed.chars().take_while(|c| *c == m).count());
        if let Some((m, len)) = fence {
            if marker == Some(m) && run >= len && trimmed[run..].trim().is_empty() {
                fence = None;
            } else {
                code.push((n, line.to_owned()));
            }
            prose.push('\n');
            continue;
        }
        if let (Some(m), true) = (marker, run >= 3) {
            fence = Some((m, run));
            prose.push('\n');
            previous_blank = false;
            indented_block = false;
            continue;
        }
        if line.trim().is_empty() {
            previous_blank = true;
            prose.push('\n');
            continue;
        }
        let indented = line.starts_with("    ") || line.starts_with('\t');
        if indented && (indented_block || (previous_blank && !in_list)) {
            indented_block = true;
            code.push((n, line.to_owned()));
            prose.push('\n');
            continue;
        }
        indented_block = false;
        let item = trimmed.starts_with("- ")
            || trimmed.starts_with("* ")
            || trimmed.starts_with("+ ")
            || trimmed.split_once(['.', ')']).is_some_and(|(num, rest)| {
                !num.is_empty() && num.chars().all(|c| c.is_ascii_digit()) && rest.starts_with(' ')
            });
        in_list = item || (in_list && line.starts_with(' '));
        previous_blank = false;
        prose.push_str(line);
        prose.push('\n');
    }
    (code, prose)
}

/// The inline code spans of `prose` (within a paragraph, over line breaks), each with the line
/// it starts on and its line breaks made spaces, and `prose` without them (line breaks kept).
fn code_spans(prose: &str) -> (Vec<(usize, String)>, String) {
    let line_of = |at: usize| prose[..at].matches('\n').count() + 1;
    let b = prose.as_bytes();
    let mut spans = Vec::new();
    let mut rest = String::with_capacity(prose.len());
    let (mut i, mut copied) = (0, 0);
    while i < b.len() {
        if b[i] != b'`' {
            i += 1;
            continue;
        }
        let open = i;
        while i < b.len() && b[i] == b'`' {
            i += 1;
        }
        let len = i - open;
        let mut j = i;
        let mut close = None;
        while j < b.len() {
            if b[j] == b'`' {
                let start = j;
                while j < b.len() && b[j] == b'`' {
                    j += 1;
                }
                if j - start == len {
                    close = Some(start);
                    break;
                }
            } else {
                j += 1;
            }
        }
        let Some(close) = close else {
            continue;
        };
        let content = &prose[i..close];
        let parts: Vec<&str> = content.split('\n').collect();
        if parts.len() > 2
            && parts[1..parts.len() - 1]
                .iter()
                .any(|p| p.trim().is_empty())
        {
            continue; // a blank line ends the paragraph: no span
        }
        spans.push((line_of(open), content.replace('\n', " ")));
        rest.push_str(&prose[copied..open]);
        rest.extend(content.chars().filter(|c| *c == '\n'));
        copied = close + len;
        i = copied;
    }
    rest.push_str(&prose[copied..]);
    (spans, rest)
}

/// The targets of the markdown links `[text](target)` of `text`, each with its line.
fn links(text: &str) -> Vec<(usize, String)> {
    text.match_indices("](")
        .filter_map(|(at, _)| {
            let target: String = text[at + 2..]
                .chars()
                .take_while(|c| *c != ')' && !c.is_whitespace())
                .collect();
            let target = target
                .trim_start_matches('<')
                .trim_end_matches('>')
                .to_owned();
            let line = text[..at].matches('\n').count() + 1;
            (!target.is_empty()).then_some((line, target))
        })
        .collect()
}

/// The repository path `word` names, if it starts with one of `prefixes` and is not a
/// placeholder: without a leading `./`, a trailing `#anchor`, `:line` or punctuation.
fn repo_path<'w>(word: &'w str, prefixes: &[String]) -> Option<&'w str> {
    let word = word.strip_prefix("./").unwrap_or(word);
    if !prefixes.iter().any(|p| word.starts_with(p.as_str())) {
        return None;
    }
    if word.contains(['*', '?', '{', '}', '<', '>', '[', ']', '$', '|', '~'])
        || word.contains("...")
    {
        return None;
    }
    let mut path = word.split('#').next().unwrap_or_default();
    loop {
        path = path.trim_end_matches(['.', ',', ':', ';', '!']);
        match path.rsplit_once(':') {
            Some((head, tail))
                if !tail.is_empty() && tail.chars().all(|c| c.is_ascii_digit() || c == '-') =>
            {
                path = head;
            }
            _ => break,
        }
    }
    let placeholder = path
        .char_indices()
        .filter(|(at, c)| {
            c.is_ascii_uppercase() && !path[..*at].ends_with(|p: char| p.is_ascii_uppercase())
        })
        .any(|(at, _)| {
            let caps: String = path[at..]
                .chars()
                .take_while(|c| c.is_ascii_uppercase())
                .collect();
            let next = path[at + caps.len()..].chars().next();
            !next.is_some_and(|c| c.is_ascii_lowercase()) && !REAL_CAPS.contains(&caps.as_str())
        });
    (!placeholder).then_some(path)
}

/// The words after `flyd ` in a piece of code: `flyd run` gives `run`; `flyd-rows`,
/// `flyd_core`, `flyd 2`, `flyd -p` and `flyd <command>` give nothing.
fn flyd_commands(piece: &str) -> Vec<&str> {
    piece
        .match_indices("flyd ")
        .filter_map(|(at, _)| {
            let before = piece[..at].chars().next_back();
            if before.is_some_and(|c| c.is_alphanumeric() || "_-.$".contains(c)) {
                return None;
            }
            let rest = &piece[at + "flyd ".len()..];
            let end = rest
                .find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-'))
                .unwrap_or(rest.len());
            let word = &rest[..end];
            let next = rest[end..].chars().next();
            let whole = !next.is_some_and(|c| c.is_alphanumeric() || c == '_');
            (word.starts_with(|c: char| c.is_ascii_lowercase()) && whole).then_some(word)
        })
        .collect()
}

/// A scenario filmed from a standing vehicle, decided at its own speed (0 km/h), brakes for
/// nothing it sees: the summary and stderr say why, and `--speed` decides as if it drove.
#[test]
fn a_replay_of_a_standing_vehicle_says_why_it_does_not_brake() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().display().to_string();
    let args = [
        "replay",
        "--scenario",
        "pedestrian-steps-in",
        "--width",
        "320",
        "--height",
        "240",
        "--flies",
        "1000",
        "--generations-per-frame",
        "1",
        "--out",
        &out,
    ];
    let (ok, stdout, stderr) = flyd(&args);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).expect("summary");
    assert_eq!(
        summary["decided_kmh"],
        serde_json::json!([0.0, 0.0]),
        "{stdout}"
    );
    assert!(
        summary["note"]
            .as_str()
            .is_some_and(|n| n.contains("stands still")),
        "{stdout}"
    );
    assert!(
        stderr.contains("note: the vehicle stands still"),
        "{stderr}"
    );
    let mut moving = args.to_vec();
    moving.extend(["--speed", "30"]);
    let (ok, stdout, stderr) = flyd(&moving);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).expect("summary");
    assert_eq!(
        summary["decided_kmh"],
        serde_json::json!([30.0, 30.0]),
        "{stdout}"
    );
    assert!(summary.get("note").is_none(), "{stdout}");
    assert!(!stderr.contains("note:"), "{stderr}");
}

/// A camera placed wrong on the vehicle hides what it exists to see (issue 57: the aanet pair
/// replayed with only its Middlebury-style calib.txt said CLEAR, nothing on stderr, with a car
/// 12.4 m ahead). The replay says what it assumed of the mount, and where the road measured
/// disagrees with a mount given wrong; given right, it says nothing of the mount.
#[test]
fn a_replay_says_what_it_assumed_of_the_mount_and_where_the_road_disagrees() {
    let pair = repo("tests/fixtures/kitti/kitti2015_000151_aanet_demo");
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out").display().to_string();
    let replay = |calib: &str| {
        summary_and_stderr(&[
            "replay",
            "--left",
            &format!("{pair}/im0.png"),
            "--right",
            &format!("{pair}/im1.png"),
            "--calib",
            calib,
            "--generations",
            "60",
            "--out",
            &out,
        ])
    };
    let (summary, stderr) = replay(&format!("{pair}/calib.txt"));
    assert!(
        stderr.contains("warning: a Middlebury calib.txt places no camera on the vehicle")
            && stderr.contains("[mount] position = [x, height, z]"),
        "{stderr}"
    );
    assert!(summary["mount_assumed"].is_string(), "{summary}");
    // The same calibration imported by rig files: the KITTI car's camera is 1.65 m up.
    let rig = |height: f64| {
        let path = dir.path().join(format!("rig-{height}.toml"));
        std::fs::write(
            &path,
            format!(
                "[import]\nfile = {:?}\n[mount]\nposition = [-0.06, {height:?}, 0.0]\n",
                format!("{pair}/calib.txt")
            ),
        )
        .expect("write");
        path.display().to_string()
    };
    let (summary, stderr) = replay(&rig(1.2));
    assert_eq!(summary["mount"]["verdict"], "DISAGREES", "{summary}");
    assert!(summary["mount"]["height_off"] == true, "{summary}");
    let h = summary["mount"]["road_height"].as_f64().expect("height");
    assert!((-0.6..=-0.3).contains(&h), "the road 0.45 m below: {h}");
    assert!(
        stderr.contains("warning: the mount disagrees with the road")
            && stderr.contains("not 1.20 m as declared ([mount] position"),
        "{stderr}"
    );
    let (summary, stderr) = replay(&rig(1.65));
    assert_eq!(summary["mount"]["verdict"], "AGREES", "{summary}");
    assert!(summary.get("mount_assumed").is_none(), "{summary}");
    assert!(!stderr.contains("mount"), "{stderr}");
}

/// The right camera's yaw checked against the motion (`rectification::yaw`): on the real
/// drive of the fixtures (KITTI odometry 06, its poses the motion) the calibration as given
/// is not said to disagree, and the same calibration with its right camera turned by 0.3
/// degrees is found,
/// said on stderr with the turn that undoes it; a pair that does not move measures nothing.
#[test]
fn a_right_camera_turned_in_the_calibration_is_found_by_the_motion() {
    let drive = repo("tests/fixtures/kitti/kitti_odom06_seq20_gray");
    let dir = tempfile::tempdir().expect("tempdir");
    let rig = dir.path().join("rig.toml");
    std::fs::write(
        &rig,
        format!(
            "[import]\nfile = {:?}\n[mount]\nposition = [0.0, 1.65, 0.0]\n",
            format!("{drive}/calib.txt")
        ),
    )
    .expect("write");
    let out = dir.path().join("out").display().to_string();
    let replay = |error: &str| {
        let (summary, stderr) = summary_and_stderr(&[
            "replay",
            "--sequence",
            &drive,
            "--calib",
            &rig.display().to_string(),
            "--right-yaw-error",
            error,
            "--generations-per-frame",
            "1",
            "--out",
            &out,
        ]);
        (summary["columns"].clone(), stderr)
    };
    // 19 pairs of this drive measure the calibration as given to +0.9 +- 0.3 px (its 50
    // pairs: +0.47 +- 0.09, AGREES): not enough to say it agrees, and nothing said against it.
    let (columns, stderr) = replay("0");
    assert_ne!(columns["verdict"], "DISAGREES", "{columns}");
    assert!(columns["pairs"].as_u64() >= Some(15), "{columns}");
    assert!(!stderr.contains("yaw"), "{stderr}");
    let (columns, stderr) = replay("0.3");
    assert_eq!(columns["verdict"], "DISAGREES", "{columns}");
    let turn = columns["right_yaw_deg"].as_f64().expect("turn");
    assert!(
        (-0.45..=-0.25).contains(&turn),
        "turned back by about 0.3 degrees: {columns}"
    );
    assert!(
        stderr.contains("warning: the right camera's yaw disagrees with the vehicle's motion")
            && stderr.contains("[right] yaw_deg"),
        "{stderr}"
    );
    // One pair, no motion: nothing measured, nothing said.
    let pair = repo("tests/fixtures/kitti/kitti2015_train_000000");
    let (summary, stderr) = summary_and_stderr(&[
        "replay",
        "--left",
        &format!("{pair}/im0.png"),
        "--right",
        &format!("{pair}/im1.png"),
        "--calib",
        &format!("{pair}/rig.toml"),
        "--right-yaw-error",
        "0.3",
        "--generations",
        "20",
        "--out",
        &out,
    ]);
    assert_eq!(summary["columns"]["verdict"], "UNMEASURED", "{summary}");
    assert_eq!(summary["columns"]["pairs"], 0, "{summary}");
    assert!(!stderr.contains("yaw"), "{stderr}");
}
