use super::*;
use flyd_core::decision::DecisionMode;

const MINIMAL: &str = r#"
[cameras]
left = "/dev/video0"
right = "/dev/video1"
width = 640
height = 480
fps = 30

[calibration]
file = "rig.toml"

[can]
interface = "can0"
"#;

fn parse(text: &str) -> Result<DaemonConfig, ConfigError> {
    DaemonConfig::from_toml(text, Path::new("/etc/flyd/flyd.toml"))
}

/// `text` must be rejected with an error naming `key` and containing `words`.
fn check_err(text: &str, key: &str, words: &str) {
    let e = parse(text).expect_err("must be rejected");
    let msg = e.to_string();
    assert_eq!(e.key(), Some(key), "{msg}");
    assert!(msg.contains("/etc/flyd/flyd.toml"), "{msg}");
    assert!(msg.contains(key), "{msg}");
    assert!(msg.contains(words), "{msg}");
}

/// MINIMAL with `extra` appended to the end of the `[table]` it names (or the file).
fn with(table: &str, extra: &str) -> String {
    let header = format!("[{table}]\n");
    match MINIMAL.find(&header) {
        Some(i) => {
            let at = i + header.len();
            format!("{}{extra}\n{}", &MINIMAL[..at], &MINIMAL[at..])
        }
        None => format!("{MINIMAL}\n{header}{extra}\n"),
    }
}

#[test]
fn minimal_config_resolves_with_defaults() {
    let c = parse(MINIMAL).expect("valid");
    assert_eq!(
        c.cameras.source,
        CameraSource::Devices {
            left: "/dev/video0".into(),
            right: "/dev/video1".into()
        }
    );
    assert_eq!(
        c.calibration,
        CalibrationSource::File("/etc/flyd/rig.toml".into()),
        "relative to the config file"
    );
    assert_eq!(c.can.target, CanTarget::Interface("can0".into()));
    assert_eq!(c.engine, EngineParams::default());
    assert_eq!(c.decision, DecisionConfig::default());
    assert_eq!(c.cameras.stale_timeout(), Duration::from_millis(100));
}

#[test]
fn unknown_keys_are_named() {
    check_err(
        &with("cameras", "exposure = 3"),
        "cameras.exposure",
        "unknown field",
    );
    check_err(&with("engine", "flys = 3"), "engine.flys", "unknown field");
    check_err(
        &with("engine.roi", "max_heigth = 3.0"),
        "engine.roi.max_heigth",
        "unknown",
    );
    check_err(
        &with("can.messages.command", "id = 0x200\nperiod = 3"),
        "can.messages.command.period",
        "unknown",
    );
    check_err(
        &format!("verbose = true\n{MINIMAL}"),
        "verbose",
        "unknown field",
    );
}

#[test]
fn the_flies_compare_luma_unless_colour_is_asked_of_a_colour_camera() {
    let c = parse(MINIMAL).expect("valid");
    assert_eq!(c.cameras.channels, Channels::Luma);
    assert_eq!(c.cameras.device_output(), PixelFormat::Grey8);
    let c = parse(&with("cameras", "channels = \"colour\"")).expect("valid");
    assert_eq!(c.cameras.device_output(), PixelFormat::Rgb8);
    let c = parse(&with(
        "cameras",
        "channels = \"colour\"\npixel_format = \"MJPG\"",
    ))
    .expect("valid");
    assert_eq!(c.cameras.device_output(), PixelFormat::Rgb8);
    check_err(
        &with("cameras", "channels = \"colour\"\npixel_format = \"GREY\""),
        "cameras.channels",
        "luma only",
    );
    check_err(
        &with("cameras", "channels = \"rgb\""),
        "cameras.channels",
        "unknown variant",
    );
}

#[test]
fn wrong_types_are_named() {
    check_err(
        &with("decision", "stop_threshold = \"high\""),
        "decision.stop_threshold",
        "invalid type",
    );
    check_err(
        &with("cameras", "pixel_format = \"RGB3\""),
        "cameras.pixel_format",
        "unknown variant",
    );
}

#[test]
fn the_decision_mode_and_speed_resolve() {
    let c = parse(&with(
        "decision",
        "mode = \"global-warning\"\nreaction_time_ms = 800\nmargin_m = 3.5",
    ))
    .expect("valid");
    assert_eq!(c.decision.mode, DecisionMode::GlobalWarning);
    assert_eq!(c.decision.reaction_time, Duration::from_millis(800));
    assert_eq!(c.decision.margin, 3.5);
    let c = parse(&with("vehicle", "assumed_speed_kmh = 50")).expect("valid");
    assert!((c.vehicle.assumed_speed - 50.0 / 3.6).abs() < 1e-12);
    let c = parse(MINIMAL).expect("valid");
    assert_eq!(c.decision.mode, DecisionMode::Obstacle);
    assert_eq!(c.perception, PerceptionConfig::default());
}

#[test]
fn impossible_values_are_named() {
    check_err(
        &with("engine", "min_depth = 50.0"),
        "engine.max_depth",
        "greater than min_depth",
    );
    check_err(
        &with("decision", "slow_threshold = 0.8\nstop_threshold = 0.4"),
        "decision.stop_threshold",
        "slow",
    );
    check_err(
        &with("decision", "safe_command = \"CLEAR\""),
        "decision.safe_command",
        "SLOW or STOP",
    );
    check_err(
        &with("decision", "stop_hold_ms = 0"),
        "decision.stop_hold_ms",
        "> 0",
    );
    check_err(
        &with("decision", "mode = \"paper\""),
        "decision.mode",
        "unknown variant",
    );
    check_err(
        &with("decision", "margin_m = -1.0"),
        "decision.margin_m",
        ">= 0",
    );
    check_err(
        &with("decision", "slow_decel = 5.0"),
        "decision.slow_decel",
        "<=",
    );
    check_err(
        &with("vehicle", "assumed_speed_kmh = 400"),
        "vehicle.assumed_speed_kmh",
        "10..=250",
    );
    check_err(
        &with("perception.obstacle", "min_height = 2.5"),
        "perception.obstacle.max_height",
        "greater than min_height",
    );
    check_err(
        &with("perception.track", "trigger_frames = 0"),
        "perception.track.trigger_frames",
        "1..=5",
    );
    check_err(
        &with("perception.road", "gain = 2.0"),
        "perception.road.gain",
        "(0, 1]",
    );
    check_err(
        &with("perception.road", "flies = 1000"),
        "perception.road.flies",
        "unknown field",
    );
    check_err(
        &with("cameras", "timestamp_tolerance_ms = 0"),
        "cameras.timestamp_tolerance_ms",
        "positive",
    );
    check_err(
        &with("cameras", "stale_frames = 0"),
        "cameras.stale_frames",
        "1..=30",
    );
    check_err(
        &with("evolution", "blind_pairs = 0"),
        "evolution.blind_pairs",
        "1..=30",
    );
    check_err(
        &with("evolution", "burst_generations = 0"),
        "evolution.burst_generations",
        "1..=1000",
    );
    check_err(
        &with("evolution", "max_generation_ms = -1"),
        "evolution.max_generation_ms",
        "positive",
    );
    check_err(
        &with("logging", "level = \"loud\""),
        "logging.level",
        "loud",
    );
    check_err(
        &with(
            "can.messages.status",
            "id = 0x120\ndata_id = 0x121\nperiod_ms = 20",
        ),
        "can.messages",
        "share CAN ID",
    );
    check_err(
        &MINIMAL.replace("left = \"/dev/video0\"", "mock = \"empty-road\""),
        "cameras.mock",
        "not both",
    );
    let driving = MINIMAL
        .replace("left = \"/dev/video0\"\n", "mock = \"driving\"\n")
        .replace("right = \"/dev/video1\"\n", "");
    check_err(&driving, "cameras.mock", "flyd replay");
    check_err(
        &MINIMAL.replace("file = \"rig.toml\"", "builtin = \"mock\""),
        "calibration.builtin",
        "mock cameras",
    );
}

#[test]
fn key_at_finds_table_and_key() {
    let text = "a = 1\n[t.u]\nb = 2\n  c=3\n";
    assert_eq!(key_at(text, 0).as_deref(), Some("a"));
    assert_eq!(
        key_at(text, text.find("b =").unwrap()).as_deref(),
        Some("t.u.b")
    );
    assert_eq!(
        key_at(text, text.find("c=").unwrap() + 2).as_deref(),
        Some("t.u.c")
    );
    assert_eq!(
        key_at(text, text.find("[t").unwrap()).as_deref(),
        Some("t.u")
    );
}

#[test]
fn damaged_config_files_are_errors_naming_the_file_never_a_panic() {
    use flyd_core::test_support::damage_each;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    let (mut loaded, mut refused) = (0, 0);
    for name in ["flyd.toml", "demo.toml"] {
        let file = path.join(name);
        let text = std::fs::read_to_string(&file).expect("shipped config");
        let parse = |t: &str| DaemonConfig::from_toml(t, &file);
        let (l, r) = damage_each(&text, 0..1_500, name, parse, |_, _| {});
        (loaded, refused) = (loaded + l, refused + r);
    }
    println!("damaged configs: {loaded} loaded, {refused} refused");
    assert!(
        loaded > 100 && refused > 1000,
        "{loaded} loaded, {refused} refused"
    );
}

/// The `[sensor]` keys config/flyd.toml documents (commented out) are the defaults, and each
/// bound it states is enforced.
#[test]
fn sensor_table_documents_its_defaults_and_bounds() {
    let doc = include_str!("../../config/flyd.toml");
    let section = doc
        .split("\n[sensor]\n")
        .nth(1)
        .and_then(|s| s.split("\n[").next())
        .expect("a [sensor] table in config/flyd.toml");
    // `# key = number` lines: the documented defaults.
    let keys: Vec<&str> = section
        .lines()
        .filter_map(|l| l.strip_prefix("# "))
        .filter(|l| {
            l.split_once(" = ").is_some_and(|(k, v)| {
                k.chars().all(|c| c.is_ascii_lowercase() || c == '_') && v.parse::<f64>().is_ok()
            })
        })
        .collect();
    assert_eq!(keys.len(), 8, "{keys:?}");
    let c = parse(&with("sensor", &keys.join("\n"))).expect("the documented values parse");
    assert_eq!(c.sensor, SensorConfig::default());
    for (key, bad) in [
        ("min_contrast", "0.1"),
        ("min_textured", "0.9"),
        ("frozen_unchanged", "1.5"),
        ("frozen_frames", "0"),
        ("mismatch_mean", "1e300"),
        ("mismatch_contrast", "1"),
        ("raise_frames", "31"),
        ("clear_frames", "0"),
    ] {
        check_err(
            &with("sensor", &format!("{key} = {bad}")),
            &format!("sensor.{key}"),
            "must be within",
        );
    }
}

/// `flyd run` (and `check-config`) refuse a calibration that does not say where the cameras
/// are on the vehicle: a camera's height decides every obstacle's (issue 57). With the mount
/// given, the same calibration loads.
#[test]
fn a_calibration_without_a_mount_is_refused_naming_what_to_add() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/kitti/kitti2015_000151_aanet_demo/calib.txt");
    let load = |rig_text: Option<String>| {
        let file = match rig_text {
            Some(text) => {
                let rig = dir.path().join("rig.toml");
                std::fs::write(&rig, text).expect("write");
                rig
            }
            None => calib.clone(),
        };
        let config = MINIMAL
            .replace(
                "file = \"rig.toml\"",
                &format!("file = {:?}", file.display().to_string()),
            )
            .replace("width = 640", "width = 1242")
            .replace("height = 480", "height = 375");
        parse(&config).expect("config").load_calibration()
    };
    let import = format!("[import]\nfile = {:?}\n", calib.display().to_string());
    let e = load(None).expect_err("no mount: refused");
    let msg = flyd_core::chain::Chain(&e).to_string();
    assert!(
        msg.contains("Middlebury calib.txt places no camera on the vehicle")
            && msg.contains("[mount] position = [x, height, z]"),
        "{msg}"
    );
    // Imported by a rig file without a mount: refused by the rig file's own check.
    let e = load(Some(import.clone())).expect_err("no mount: refused");
    let msg = flyd_core::chain::Chain(&e).to_string();
    assert!(msg.contains("mount.position"), "{msg}");
    let mounted = load(Some(format!(
        "{import}[mount]\nposition = [-0.06, 1.65, 0.0]\n"
    )))
    .expect("with its mount");
    assert_eq!(mounted.mount_assumed, None);
    assert!((mounted.rig.left.centre().y - 1.65).abs() < 1e-9);
}
