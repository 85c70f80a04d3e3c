//! Kernel-in-the-loop tests (issue 4): each test boots Debian's kernel in QEMU (TCG) with vcan0
//! and two v4l2loopback cameras, runs a guest scenario script from tests/vm/scenarios, and
//! asserts here, on the host, on what came back. Run alone with
//! `cargo test --release --test vm`; see tests/vm/README.md (also for native runs, no QEMU).
//!
//! A test that cannot boot the VM fails; none of them is ever skipped.
//!
//! These smoke scenarios prove the infrastructure (kernel stacks, devices, results path)
//! before the daemon exists; flyd's scenarios will be the same shape, with
//! `.bin(env!("CARGO_BIN_EXE_flyd"))`.

#[path = "vm/harness.rs"]
mod harness;

// The frame pattern the guest's v4l2-smoke writes and checks; checked again here.
#[path = "vm/guest/src/pattern.rs"]
#[allow(dead_code)] // the host checks frames; it never makes them
mod pattern;

use std::path::Path;

use harness::{Run, Scenario, guest_tool};

#[test]
fn vcan_frame_sent_with_cansend_is_in_the_candump_log() {
    let run = Scenario::new("vcan_smoke").run();
    run.assert_success();
    check_vcan_smoke(&run);
    run.report("candump -L logged exactly the one frame cansend sent: vcan0 123#DEADBEEF");
}

fn check_vcan_smoke(run: &Run) {
    // candump -L lines: "(1700000000.123456) vcan0 123#DEADBEEF"
    let log = run.read_to_string("candump.log");
    let frames: Vec<(&str, &str)> = log
        .lines()
        .filter_map(|line| {
            let mut words = line.split_whitespace().skip(1);
            Some((words.next()?, words.next()?))
        })
        .collect();
    assert_eq!(frames, [("vcan0", "123#DEADBEEF")], "candump.log:\n{log}");
    assert_eq!(run.result("vcan")["sent"], "123#DEADBEEF");
}

/// native.sh is what a host with real vcan0 and v4l2loopback runs (no QEMU): run it inside the
/// guest, with bash and GNU timeout as on such a host, so the documented command stays true.
#[test]
fn native_runner_runs_the_vcan_scenario_where_the_devices_exist() {
    let vm = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vm");
    let run = Scenario::new("native_selftest")
        .bin("/bin/bash")
        .bin("/usr/bin/timeout")
        .bin(vm.join("native.sh"))
        .bin(vm.join("lib.sh"))
        .bin(vm.join("scenarios/vcan_smoke.sh"))
        .run();
    run.assert_success();
    let native = run.nested_native("native");
    native.assert_success();
    check_vcan_smoke(&native);
    run.report("native.sh found vcan0 and both cameras, ran vcan_smoke: its checks pass");
}

#[test]
fn v4l2loopback_frames_written_to_the_output_come_back_from_mmap_capture() {
    let run = Scenario::new("v4l2_smoke")
        .bin(guest_tool("v4l2-smoke"))
        .run();
    run.assert_success();

    let mut checked = Vec::new();
    for (camera, label) in [(0u8, "flyd-left"), (1, "flyd-right")] {
        let result = run.result(&format!("camera{camera}"));
        let frames: usize = result["frames"].parse().expect("frames=N");
        let bytes = run.read(&format!("capture{camera}.yuyv"));
        assert_eq!(
            bytes.len(),
            frames * pattern::FRAME_LEN,
            "capture{camera}.yuyv holds {} bytes, expected {frames} frames of {}",
            bytes.len(),
            pattern::FRAME_LEN
        );
        let mut indices = Vec::new();
        for (n, frame) in bytes.chunks(pattern::FRAME_LEN).enumerate() {
            let (got_camera, index) = pattern::identify(frame)
                .unwrap_or_else(|e| panic!("{label} ({}) frame {n}: {e}", result["device"]));
            assert_eq!(
                got_camera, camera,
                "{label} frame {n} is from another camera"
            );
            indices.push(index);
        }
        assert!(
            indices.windows(2).all(|w| w[0] < w[1]),
            "{label}: frame indices not increasing: {indices:?}"
        );
        checked.push(format!(
            "{label} {}: {frames} YUYV 64x48 frames intact, indices {indices:?}",
            result["device"]
        ));
    }
    run.report(&checked.join("; "));
}
