//! Running the real `flyd` binary from integration tests.
#![allow(dead_code)] // each test binary uses a part of it

use std::ffi::OsStr;
use std::process::Command;

/// Runs `flyd ARGS`, asserts that it succeeded (printing its stderr if not), and returns the
/// JSON document it printed on stdout (replay's summary, bench's report).
pub fn flyd_json<I, S>(args: I) -> serde_json::Value
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    let args: Vec<_> = args.into_iter().map(|a| a.as_ref().to_owned()).collect();
    let output = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .args(&args)
        .output()
        .expect("run flyd");
    assert!(
        output.status.success(),
        "flyd {args:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("a JSON document on stdout")
}
