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

// The feeder's RGB -> YUYV conversion, to check on the host what the guest's cameras delivered.
#[path = "vm/guest/src/feeder/yuyv.rs"]
mod yuyv;

use std::path::Path;

use flyd::mock::MockStereo;
use harness::{Run, Scenario, guest_tool};
use hw_mock::Scenario as World;

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

/// The scenario's frames at `width` x `height` as the feeder writes them (YUYV), left and right.
fn feeder_frames(scenario: &str, width: u32, height: u32) -> Vec<[Vec<u8>; 2]> {
    let world = World::by_name(scenario).expect("a hw-mock scenario");
    let n = world.frame_count();
    let mut stereo = MockStereo::new(world, width, height).expect("mock rig");
    (0..n)
        .map(|i| {
            let (l, r) = stereo.frame(i).expect("renders");
            let mut out = [vec![0; l.len() / 3 * 2], vec![0; r.len() / 3 * 2]];
            yuyv::rgb_to_yuyv(l, width as usize, &mut out[0]);
            yuyv::rgb_to_yuyv(r, width as usize, &mut out[1]);
            out
        })
        .collect()
}

/// One line of the feeder's `--timeline`: index, CLOCK_REALTIME seconds, left and right feeds.
#[allow(dead_code)] // the feeds are read by the daemon scenarios
struct TimelineRow {
    index: u32,
    time: f64,
    left: String,
    right: String,
}

fn timeline(run: &Run) -> Vec<TimelineRow> {
    run.read_to_string("timeline.txt")
        .lines()
        .map(|line| {
            let w: Vec<&str> = line.split_whitespace().collect();
            assert_eq!(w.len(), 4, "timeline line {line:?}");
            TimelineRow {
                index: w[0].parse().expect("index"),
                time: w[1].parse().expect("time"),
                left: w[2].to_string(),
                right: w[3].to_string(),
            }
        })
        .collect()
}

#[test]
fn feeder_frames_come_back_from_both_cameras_as_rendered() {
    let run = Scenario::new("feeder_smoke")
        .bin(guest_tool("flyd-feeder"))
        .bin(guest_tool("v4l2-smoke"))
        .run();
    run.assert_success();
    let expected = feeder_frames("pedestrian-steps-in", 320, 240);
    let frame_len = 320 * 240 * 2;
    let frames: usize = run.result("feeder")["frames"].parse().expect("frames=N");
    let mut checked = Vec::new();
    for (camera, label) in [(0usize, "left"), (1, "right")] {
        let bytes = run.read(&format!("grab{camera}.yuyv"));
        assert_eq!(bytes.len(), frames * frame_len, "{label}: grabbed bytes");
        let mut indices = Vec::new();
        for (n, frame) in bytes.chunks(frame_len).enumerate() {
            let index = expected
                .iter()
                .position(|pair| pair[camera] == frame)
                .unwrap_or_else(|| {
                    let other = expected.iter().position(|pair| pair[1 - camera] == frame);
                    panic!("{label} frame {n} is none of the feeder's {label} frames (other camera's frame: {other:?})")
                });
            indices.push(index);
        }
        assert!(
            indices.windows(2).all(|w| w[0] < w[1]),
            "{label}: frame indices not increasing: {indices:?}"
        );
        checked.push(format!(
            "{label}: {frames} frames byte-exact, indices {indices:?}"
        ));
    }
    let rows = timeline(&run);
    assert!(rows.len() > 10, "timeline holds {} frames", rows.len());
    assert!(rows.iter().all(|r| r.left == "frame" && r.right == "frame"));
    let (first, last) = (&rows[0], &rows[rows.len() - 1]);
    let fps = f64::from(last.index - first.index) / (last.time - first.time);
    assert!(fps > 15.0, "the feeder wrote at {fps:.1} fps only");
    let feeder_log = run.read_to_string("feeder.log");
    let prerender = feeder_log
        .lines()
        .find(|l| l.contains("pre-rendered"))
        .unwrap_or("no pre-render line")
        .trim_start_matches("flyd-feeder: ");
    run.report(&format!(
        "{}; {} frames written at {fps:.1} fps (asked 30); {prerender}",
        checked.join("; "),
        rows.len()
    ));
}
