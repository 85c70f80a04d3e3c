//! Running the real `flyd` binary from integration tests.
#![allow(dead_code)] // each test binary uses a part of it

use std::ffi::OsStr;
use std::process::{Command, Output};

/// Runs `cmd` (`what` names it in messages), asserts that it succeeded, printing its stderr if
/// not, and returns its output.
pub fn output_ok(cmd: &mut Command, what: &str) -> Output {
    let output = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
    assert!(
        output.status.success(),
        "{what} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// Runs `flyd ARGS`, asserts that it succeeded (printing its stderr if not), and returns the
/// JSON document it printed on stdout (replay's summary, bench's report).
pub fn flyd_json<I, S>(args: I) -> serde_json::Value
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    let args: Vec<_> = args.into_iter().map(|a| a.as_ref().to_owned()).collect();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_flyd"));
    let output = output_ok(cmd.args(&args), &format!("flyd {args:?}"));
    serde_json::from_slice(&output.stdout).expect("a JSON document on stdout")
}

/// The VM suite's 320x240 mock rig (`tests/vm/config/mock-rig-320x240.toml`) with `extra` TOML
/// appended, written into `dir` as `rig.toml`: its path.
pub fn mock_rig_320x240(dir: &std::path::Path, extra: &str) -> std::path::PathBuf {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let rig = std::fs::read_to_string(repo.join("tests/vm/config/mock-rig-320x240.toml"))
        .expect("the mock rig file");
    let path = dir.join("rig.toml");
    std::fs::write(&path, format!("{rig}\n{extra}")).expect("write rig");
    path
}

/// `demo` (the text of config/demo.toml) at 320x240 with 1000 flies, calibrated by the rig
/// file `rig` instead of the built-in mock rig.
pub fn demo_320x240_on(demo: &str, rig: &std::path::Path) -> String {
    let config = demo
        .replace("width = 640", "width = 320")
        .replace("height = 480", "height = 240")
        .replace("flies = 5000", "flies = 1000")
        .replace(
            "builtin = \"mock\"",
            &format!("file = {:?}", rig.display().to_string()),
        );
    assert!(
        config.contains("file = "),
        "the demo config changed: {config}"
    );
    config
}
