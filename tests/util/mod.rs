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
