//! Holds `systemd/flyd.service` to `systemd-analyze`: `verify` is clean and the offline
//! `security` exposure is at most 2.0.
//!
//! `systemd-analyze` missing is a failure, not a skip: CI installs systemd
//! (`apt-get install systemd`), and a unit nobody checks rots silently.
//!
//! `verify` checks that `ExecStart=`'s binary exists. The unit names the installed path,
//! `/usr/bin/flyd`, which a build machine does not have, so `verify` runs on a copy whose
//! `ExecStart=` points at the binary cargo just built (the only line changed); the pristine unit
//! is also verified, and its only complaint may be that `/usr/bin/flyd` is missing.

use std::path::Path;
use std::process::{Command, Output};

const UNIT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/systemd/flyd.service");
const INSTALLED_BINARY: &str = "/usr/bin/flyd";
const MAX_EXPOSURE: f64 = 2.0;

fn systemd_analyze(args: &[&str]) -> Output {
    Command::new("systemd-analyze")
        .args(args)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "FAIL (not a skip): cannot run systemd-analyze ({e}); install systemd \
                 (apt-get install systemd) to check systemd/flyd.service"
            )
        })
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The unit with `ExecStart=` running `binary` instead of the installed path.
fn with_binary(unit: &str, binary: &str) -> String {
    let prefix = format!("ExecStart={INSTALLED_BINARY} ");
    let rewritten: Vec<String> = unit
        .lines()
        .map(|line| match line.strip_prefix(&prefix) {
            Some(args) => format!("ExecStart={binary} {args}"),
            None => line.to_owned(),
        })
        .collect();
    let changed = unit.lines().zip(&rewritten).filter(|(a, b)| a != b).count();
    assert_eq!(
        changed, 1,
        "expected exactly one `{prefix}...` line in {UNIT}"
    );
    rewritten.join("\n") + "\n"
}

#[test]
fn unit_verifies_cleanly() {
    let unit = std::fs::read_to_string(UNIT).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("flyd.service");
    std::fs::write(&copy, with_binary(&unit, env!("CARGO_BIN_EXE_flyd"))).unwrap();

    let out = systemd_analyze(&["verify", copy.to_str().unwrap()]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(
        out.status.success() && stderr.trim().is_empty() && stdout.trim().is_empty(),
        "systemd-analyze verify is not clean ({}):\n{stdout}{stderr}",
        out.status
    );

    // The pristine unit: nothing but the missing installed binary may be reported.
    let out = systemd_analyze(&["verify", UNIT]);
    let stderr = text(&out.stderr);
    let others: Vec<&str> = stderr
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.contains(INSTALLED_BINARY))
        .collect();
    assert!(
        others.is_empty(),
        "systemd-analyze verify {UNIT}:\n{stderr}"
    );
    if Path::new(INSTALLED_BINARY).exists() {
        assert!(out.status.success(), "{stderr}");
    }
}

/// The number on the "Overall exposure level for flyd.service: 1.4 OK" line.
fn overall_exposure(report: &str) -> Option<f64> {
    let line = report
        .lines()
        .find(|l| l.contains("Overall exposure level"))?;
    line.rsplit_once(": ")?
        .1
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[test]
fn exposure_parser_reads_the_summary_line() {
    assert_eq!(
        overall_exposure("x\n→ Overall exposure level for flyd.service: 1.4 OK 🙂\n"),
        Some(1.4)
    );
    assert_eq!(
        overall_exposure("→ Overall exposure level for a.service: 9.6 UNSAFE 😨"),
        Some(9.6)
    );
    assert_eq!(overall_exposure("no summary"), None);
}

#[test]
fn unit_exposure_is_at_most_2() {
    let out = systemd_analyze(&["security", "--offline=true", UNIT]);
    let report = text(&out.stdout);
    assert!(
        out.status.success(),
        "systemd-analyze security failed ({}):\n{report}{}",
        out.status,
        text(&out.stderr)
    );
    let exposure = overall_exposure(&report)
        .unwrap_or_else(|| panic!("no \"Overall exposure level\" line in:\n{report}"));
    let open: Vec<&str> = report.lines().filter(|l| l.starts_with('✗')).collect();
    println!("exposure {exposure}; open items:\n{}", open.join("\n"));
    assert!(
        exposure <= MAX_EXPOSURE,
        "exposure {exposure} > {MAX_EXPOSURE}:\n{report}"
    );
}

/// What the daemon's design relies on, beyond what the security score measures.
#[test]
fn unit_keeps_the_daemon_contract() {
    let unit = std::fs::read_to_string(UNIT).unwrap();
    let directives: Vec<&str> = unit
        .lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#') && l.contains('='))
        .collect();
    for needed in [
        "Type=notify",
        "WatchdogSec=2s",
        "Restart=on-failure",
        "ExecStart=/usr/bin/flyd run --config /etc/flyd/flyd.toml",
        "SupplementaryGroups=video",
        "DevicePolicy=closed",
        "DeviceAllow=char-video4linux rw",
        "RestrictAddressFamilies=AF_UNIX AF_CAN AF_NETLINK",
        "CapabilityBoundingSet=",
        "AmbientCapabilities=",
        "NoNewPrivileges=yes",
        "MemoryMax=512M",
        "MemorySwapMax=0",
    ] {
        assert!(directives.contains(&needed), "{UNIT} lacks `{needed}`");
    }
    // These would hide can0 or the cameras.
    for forbidden in ["PrivateNetwork=", "PrivateDevices="] {
        assert!(
            !directives.iter().any(|d| d.starts_with(forbidden)),
            "{UNIT} sets {forbidden}"
        );
    }
}
