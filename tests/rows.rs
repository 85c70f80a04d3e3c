//! The running daemon measures the right image's rows (`flyd::daemon::rows`) and says when
//! the rig file's correction does not fit: `flyd run` on mock cameras (320x240, the built-in
//! mock rig as a rig file), once as calibrated and once with a wrong correction of 0.5 px.

mod util;

use std::path::Path;
use std::process::Command;

fn repo(path: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// `flyd run` for 3 s with the mock rig plus `rectification` (TOML appended to the rig file):
/// the first rectification event it logged.
fn measured(rectification: &str) -> serde_json::Value {
    let dir = tempfile::tempdir().expect("tempdir");
    let rig_file = util::mock_rig_320x240(dir.path(), rectification);
    let demo = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let config = util::demo_320x240_on(&demo, &rig_file)
        .replace("mock = \"pedestrian-steps-in\"", "mock = \"pedestrian-4m\"");
    let config_file = dir.path().join("flyd.toml");
    std::fs::write(&config_file, config).expect("write config");
    let out = util::output_ok(
        Command::new(env!("CARGO_BIN_EXE_flyd"))
            .args(["run", "--duration", "3", "--config"])
            .arg(&config_file)
            .arg("--can-log")
            .arg(dir.path().join("can.log")),
        "flyd run",
    );
    // With the CAN log in a file, the JSON logs go to stdout.
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|e| {
            e["message"]
                .as_str()
                .is_some_and(|m| m.starts_with("rectification:"))
        })
        .expect("a rectification event in the log")
}

#[test]
fn the_daemon_measures_the_right_rows_and_warns_when_the_correction_is_wrong() {
    let fitting = measured("");
    println!("as calibrated: {fitting}");
    assert_eq!(fitting["level"], "INFO", "{fitting}");
    assert_eq!(fitting["threadName"], "flyd-rows", "{fitting}");
    let r = fitting["residual_px"].as_f64().expect("residual_px");
    // Measured 0.006 px (hw-mock renders through the rig's own model).
    assert!(r.abs() <= 0.15, "{fitting}");

    // A correction of 0.5 px the images do not need: the rows are then 0.5 px off the other
    // way (measured -0.45), and the warning names the value to set.
    let wrong = measured("[rectification]\nright_row_offset_px = 0.5\n");
    println!("with 0.5 px: {wrong}");
    assert_eq!(wrong["level"], "WARN", "{wrong}");
    let r = wrong["residual_px"].as_f64().expect("residual_px");
    assert!((r + 0.5).abs() <= 0.15, "{wrong}");
    let suggested = wrong["suggested_px"].as_f64().expect("suggested_px");
    assert!(suggested.abs() <= 0.15, "{wrong}");
    assert_eq!(wrong["applied_px"], 0.5, "{wrong}");
}
