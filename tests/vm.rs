//! Kernel-in-the-loop tests (issue 4): each test boots Debian's kernel in QEMU (TCG) with vcan0
//! and two v4l2loopback cameras, runs a guest scenario script from tests/vm/scenarios, and
//! asserts here, on the host, on what came back. Run alone with
//! `cargo test --release --test vm`; see tests/vm/README.md (also for native runs, no QEMU).
//!
//! A test that cannot boot the VM fails; none of them is ever skipped.
//!
//! The smoke scenarios prove the infrastructure (kernel stacks, devices, results path, the
//! feeder); the flyd scenarios run the release flyd, unchanged, on the two cameras that
//! flyd-feeder plays a hw-mock scenario into, and decode vcan0 with config/flyd.dbc. Under TCG
//! the guest is ~10x slower than this machine: the flyd scenarios count camera frames (the
//! feeder's timeline), not milliseconds. The pedestrian and SIGTERM tests share one boot.

mod flyd_cli;
#[path = "vm/harness.rs"]
mod harness;

// The frame pattern the guest's v4l2-smoke writes and checks; checked again here.
#[path = "vm/guest/src/pattern.rs"]
#[allow(dead_code)] // the host checks frames; it never makes them
mod pattern;

#[path = "vm/can_log.rs"]
mod can_log;
mod dbc_signals;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

use can_log::{Decoder, Frame};
use flyd::capture::convert::rgb_to_yuyv;
use flyd::mock::MockStereo;
use flyd_core::status::FaultBits;
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
        .bin(vm.join("host.sh"))
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
            // The feeder's conversion: what the guest's cameras deliver.
            rgb_to_yuyv(l, width as usize, &mut out[0]).expect("YUYV");
            rgb_to_yuyv(r, width as usize, &mut out[1]).expect("YUYV");
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

// ---------------------------------------------------------------------------------------------
// The release flyd in the guest: flyd-feeder plays a hw-mock scenario into the two loopback
// cameras, flyd captures them through V4L2 and sends on vcan0; candump logs the bus.

/// A flyd scenario (tests/vm/scenarios/flyd_*.sh) with what every one of them needs.
fn flyd_scenario(name: &str) -> Scenario {
    let vm = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vm");
    Scenario::new(name)
        .bin(env!("CARGO_BIN_EXE_flyd"))
        .bin(guest_tool("flyd-feeder"))
        .bin(vm.join("scenarios/flyd_common.sh"))
        .input(vm.join("config/flyd-vm.toml"))
        .input(vm.join("config/mock-rig-320x240.toml"))
        .timeout(Duration::from_secs(300))
}

/// Boots a flyd scenario, one at a time: flyd's timing (stale cameras, stereo pairing, the
/// bus period) suffers when two emulated guests share this machine's two cores, while the
/// smoke scenarios may run beside one.
fn run_flyd(scenario: Scenario) -> FlydRun {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _turn = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    FlydRun::new(scenario.run())
}

/// What a flyd scenario brought back, parsed.
struct FlydRun {
    run: Run,
    frames: Vec<Frame>,
    timeline: Vec<TimelineRow>,
    /// flyd_event NAME -> (feeder frame index, its realtime), if the feeder had written one.
    events: BTreeMap<String, Option<(u32, f64)>>,
    /// flyd's JSON log lines (other lines, e.g. a panic, are in `log_text`).
    log: Vec<serde_json::Value>,
    log_text: String,
}

impl FlydRun {
    fn new(run: Run) -> FlydRun {
        run.assert_success();
        let frames = Decoder::new().decode_log(&run.read_to_string("candump.log"));
        let timeline = timeline(&run);
        let events = run
            .read_to_string("events.txt")
            .lines()
            .map(|line| {
                let w: Vec<&str> = line.split_whitespace().collect();
                assert_eq!(w.len(), 3, "events.txt line {line:?}");
                let at = (w[1] != "-").then(|| {
                    (
                        w[1].parse().expect("frame index"),
                        w[2].parse().expect("time"),
                    )
                });
                (w[0].to_string(), at)
            })
            .collect();
        let log_text = run.read_to_string("flyd.log");
        let log = log_text
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect();
        FlydRun {
            run,
            frames,
            timeline,
            events,
            log,
            log_text,
        }
    }

    fn event(&self, name: &str) -> (u32, f64) {
        self.events
            .get(name)
            .copied()
            .flatten()
            .unwrap_or_else(|| panic!("no event {name} with a frame: {:?}", self.events))
    }

    fn messages(&self, name: &str) -> Vec<&Frame> {
        self.frames.iter().filter(|f| f.message == name).collect()
    }

    /// Realtime at which the feeder wrote scenario frame `index`.
    fn frame_time(&self, index: u32) -> f64 {
        self.timeline
            .iter()
            .find(|r| r.index == index)
            .unwrap_or_else(|| panic!("the feeder never wrote frame {index}"))
            .time
    }

    /// Feeder frames written in (from, to]: a duration counted in camera frames.
    fn frames_between(&self, from: f64, to: f64) -> usize {
        self.timeline
            .iter()
            .filter(|r| r.time > from && r.time <= to)
            .count()
    }

    /// Log events whose message contains `text`.
    fn logged(&self, text: &str) -> Vec<&serde_json::Value> {
        self.log
            .iter()
            .filter(|l| l["message"].as_str().is_some_and(|m| m.contains(text)))
            .collect()
    }

    /// flyd's own account of a run, one line an event: decision changes, faults, and each
    /// stats line's obstacle, pairs and generations. What a failed assertion on commands shows.
    fn story(&self) -> String {
        let text = |v: &serde_json::Value| match v {
            serde_json::Value::String(s) => s.clone(),
            serde_json::Value::Null => "-".to_string(),
            other => other.to_string(),
        };
        self.log
            .iter()
            .filter_map(|l| {
                let at = l["timestamp"].as_str().map_or("?", |t| t.get(11..23).unwrap_or(t));
                let line = match l["message"].as_str()? {
                    "decision changed" => {
                        format!("decision {} ({})", text(&l["to"]), text(&l["reason"]))
                    }
                    m @ ("fault raised" | "fault cleared") => format!("{m} {}", text(&l["fault"])),
                    m if m.starts_with("vehicle motion") => m.to_string(),
                    "stats" => format!(
                        "stats: obstacle {} m confirmed {} on {} flies; {} pairs, {} rejected, {} gen/s; motion {} {} km/h",
                        text(&l["obstacle_m"]),
                        text(&l["obstacle_confirmed"]),
                        text(&l["obstacle_flies"]),
                        text(&l["pairs"]),
                        text(&l["pair_rejects"]),
                        text(&l["generations_per_sec"]),
                        text(&l["motion"]),
                        text(&l["speed_kmh"]),
                    ),
                    _ => return None,
                };
                Some(format!("  {at} {line}"))
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn exit_code(&self) -> i32 {
        self.run.result("flyd")["exit"].parse().expect("exit=N")
    }

    /// flyd exited 0 at the end of the scenario (SIGTERM), whatever the scenario did to it.
    fn assert_exited_cleanly(&self) {
        assert_eq!(
            self.exit_code(),
            0,
            "flyd must not crash; log:\n{}",
            tail(&self.log_text, 20)
        );
    }

    /// The feeder's first frame with `label` for camera `side` ("left" or "right") and its
    /// first real frame after that: the episode a fault scenario injected.
    fn episode(&self, side: &str, label: &str) -> (&TimelineRow, &TimelineRow) {
        let of = |row: &TimelineRow| {
            if side == "left" {
                row.left.clone()
            } else {
                row.right.clone()
            }
        };
        let start = self
            .timeline
            .iter()
            .find(|row| of(row) == label)
            .unwrap_or_else(|| panic!("the feeder never fed {label} to the {side} camera"));
        let end = self
            .timeline
            .iter()
            .find(|row| row.index > start.index && of(row) == "frame")
            .unwrap_or_else(|| panic!("the feeder never resumed the {side} camera"));
        (start, end)
    }

    /// Checks that hold for every run: all CRCs valid, every message's alive counter +1 mod 15
    /// from frame to frame, command and status periods near the DBC's cycle time. Silences on
    /// the bus longer than `max_gap` seconds (the CAN-down scenario) break the counter chain;
    /// their number is returned with a summary for the report.
    fn check_bus_with_gaps(&self, max_gap: f64) -> (String, usize) {
        let decoder = Decoder::new();
        assert!(!self.frames.is_empty(), "no CAN frames at all");
        // flyd's frames; a scenario's own (VCU_Motion) may be bad on purpose.
        let bad: Vec<&Frame> = self
            .frames
            .iter()
            .filter(|f| f.message.starts_with("FLYD_") && !f.crc_ok)
            .collect();
        assert!(
            bad.is_empty(),
            "{} frames with a wrong CRC, first {:?}",
            bad.len(),
            bad[0]
        );
        let mut out = vec![format!("{} frames, every CRC valid", self.frames.len())];
        let mut gaps = 0;
        for name in [
            "FLYD_Command",
            "FLYD_Status",
            "FLYD_Obstacle",
            "FLYD_Path",
            "FLYD_ObstacleMotion",
        ] {
            let msgs = self.messages(name);
            assert!(msgs.len() > 10, "only {} {name} frames", msgs.len());
            for w in msgs.windows(2) {
                if w[1].time - w[0].time > max_gap {
                    gaps += 1;
                    continue;
                }
                assert_eq!(
                    w[1].counter(),
                    (w[0].counter() + 1) % 15,
                    "{name}: alive counter {} then {} (at {} and {})",
                    w[0].counter(),
                    w[1].counter(),
                    w[0].time,
                    w[1].time
                );
            }
            let mut periods: Vec<f64> = msgs
                .windows(2)
                .map(|w| (w[1].time - w[0].time) * 1e3)
                .collect();
            periods.sort_by(f64::total_cmp);
            let median = periods[periods.len() / 2];
            let p95 = periods[periods.len() * 95 / 100];
            let cycle = decoder.cycle_ms(name) as f64;
            // The control thread paces against its clock: the median holds under emulation;
            // single periods stretch when the 2 emulated CPUs are busy.
            assert!(
                (median - cycle).abs() <= 0.25 * cycle,
                "{name}: median period {median:.1} ms, DBC cycle {cycle} ms"
            );
            out.push(format!(
                "{name} x{} counters +1 mod 15, period median {median:.1} ms p95 {p95:.1} ms (DBC {cycle} ms)",
                msgs.len()
            ));
        }
        (out.join("; "), gaps)
    }

    /// [`check_bus_with_gaps`] for runs where the bus never went quiet (no gap over 1 s).
    fn check_bus(&self) -> String {
        let (summary, gaps) = self.check_bus_with_gaps(1.0);
        assert_eq!(gaps, 0, "the bus went quiet for over 1 s");
        summary
    }

    /// Status frames from `from` (realtime) until SIGTERM.
    fn statuses_from(&self, from: f64) -> Vec<&Frame> {
        let sigterm = self.event("sigterm").1;
        self.messages("FLYD_Status")
            .into_iter()
            .filter(|f| f.time >= from && f.time < sigterm)
            .collect()
    }

    fn commands_from(&self, from: f64) -> Vec<&Frame> {
        let sigterm = self.event("sigterm").1;
        self.messages("FLYD_Command")
            .into_iter()
            .filter(|f| f.time >= from && f.time < sigterm)
            .collect()
    }
}

fn faults(status: &Frame) -> FaultBits {
    FaultBits::from_bits(status.value("FaultBits") as u8)
}

/// How many of `frames` have each label of `signal`, e.g. "RUNNING x40, DEGRADED x3".
fn label_counts(frames: &[&Frame], signal: &str) -> String {
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for f in frames {
        *counts.entry(f.label(signal)).or_default() += 1;
    }
    counts
        .iter()
        .map(|(l, n)| format!("{l} x{n}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn pedestrian_run() -> &'static FlydRun {
    static RUN: OnceLock<FlydRun> = OnceLock::new();
    RUN.get_or_init(|| run_flyd(flyd_scenario("flyd_pedestrian")))
}

/// The rig file the guest's flyd loads is the mock rig the feeder renders through.
#[test]
fn guest_rig_file_is_the_feeders_mock_rig() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vm/config/mock-rig-320x240.toml");
    let file = flyd_core::calib::load(&path).expect("loads").rig;
    let mock = flyd::mock::mock_rig(320, 240).expect("valid");
    for (side, a, b) in [
        ("left", &file.left, &mock.left),
        ("right", &file.right, &mock.right),
    ] {
        for p in [
            [0.0, 0.5, 4.0],
            [1.5, 0.0, 8.0],
            [-2.0, 1.8, 3.0],
            [0.3, 0.2, 20.0],
        ] {
            let p = nalgebra::Point3::new(p[0], p[1], p[2]);
            let (pa, pb) = (a.pixel_from_vehicle(&p), b.pixel_from_vehicle(&p));
            let (pa, pb) = (pa.expect("projects"), pb.expect("projects"));
            assert!(
                (pa - pb).norm() < 1e-6,
                "{side}: {p:?} projects to {pa:?} with the file, {pb:?} with mock_rig"
            );
        }
    }
}

#[test]
fn flyd_sends_stop_after_the_pedestrian_steps_in() {
    let r = pedestrian_run();
    let bus = r.check_bus();
    let world = World::by_name("pedestrian-steps-in").expect("scenario");
    let appear = world.first_obstacle_frame().expect("a pedestrian");
    let t_appear = r.frame_time(appear);
    let commands = r.messages("FLYD_Command");
    let sigterm = r.event("sigterm").1;
    let early_stop: Vec<&&Frame> = commands
        .iter()
        .filter(|f| f.time < t_appear && f.label("Command") == "STOP")
        .collect();
    assert!(
        early_stop.is_empty(),
        "STOP before the pedestrian appeared (frame {appear}): {:?}",
        early_stop[0]
    );
    let first_stop = commands
        .iter()
        .find(|f| f.label("Command") == "STOP")
        .unwrap_or_else(|| {
            panic!(
                "no STOP command at all; flyd.log tail:\n{}",
                tail(&r.log_text, 20)
            )
        });
    let reaction_frames = r.frames_between(t_appear, first_stop.time);
    // The daemon's bound (issue 3): median <= 50 ms at 30 fps, i.e. the STOP leaves while the
    // first or second frame showing the pedestrian is the newest. Under TCG the guest runs
    // 10 fps and bursts of 6 generations of 1000 flies: measured 1-2 frames (4 runs); the
    // bound is 3 frames, one frame of slack for a guest stalled by a loaded host.
    assert!(
        reaction_frames <= 3,
        "first STOP {reaction_frames} camera frames after the pedestrian appeared"
    );
    let after: Vec<&&Frame> = commands
        .iter()
        .filter(|f| f.time >= first_stop.time && f.time < sigterm)
        .collect();
    let stops = after
        .iter()
        .filter(|f| f.label("Command") == "STOP")
        .count();
    assert!(
        stops * 10 >= after.len() * 9,
        "only {stops} of {} commands after the first STOP are STOP",
        after.len()
    );
    let statuses: Vec<&Frame> = r
        .messages("FLYD_Status")
        .into_iter()
        .filter(|f| f.time >= first_stop.time && f.time < sigterm)
        .collect();
    let running = statuses
        .iter()
        .filter(|f| f.label("State") == "RUNNING")
        .count();
    let obstacles: Vec<&Frame> = r
        .messages("FLYD_Obstacle")
        .into_iter()
        .filter(|f| {
            f.time >= first_stop.time && f.time < sigterm && f.label("ObstacleValid") == "VALID"
        })
        .collect();
    let distance = obstacles.last().map_or(f64::NAN, |f| f.value("Distance"));
    r.run.report(&format!(
        "pedestrian at frame {appear}: first STOP (reason {}) {reaction_frames} camera frames later \
         ({:.0} ms under TCG), none before; {stops}/{} commands STOP afterwards; status RUNNING in \
         {running}/{} statuses; last obstacle distance {distance:.2} m; {bus}",
        first_stop.label("CommandReason"),
        (first_stop.time - t_appear) * 1e3,
        after.len(),
        statuses.len()
    ));
}

#[test]
fn flyd_sends_shutdown_status_and_exits_0_on_sigterm() {
    let r = pedestrian_run();
    assert_eq!(
        r.exit_code(),
        0,
        "flyd's exit code; log tail:\n{}",
        tail(&r.log_text, 20)
    );
    let (sig_frame, sigterm) = r.event("sigterm");
    let (exit_frame, exited) = r.event("flyd-exited");
    let statuses = r.messages("FLYD_Status");
    let last = statuses.last().expect("status frames");
    assert_eq!(
        last.label("State"),
        "SHUTDOWN",
        "last status frame {last:?}"
    );
    assert!(last.time >= sigterm, "the SHUTDOWN status predates SIGTERM");
    let shutdown_statuses = statuses
        .iter()
        .filter(|f| f.label("State") == "SHUTDOWN")
        .count();
    let last_command = r
        .messages("FLYD_Command")
        .last()
        .copied()
        .expect("commands");
    assert_eq!(last_command.label("CommandReason"), "SHUTDOWN");
    let after: Vec<&Frame> = r.frames.iter().filter(|f| f.time > last.time).collect();
    assert!(
        after.iter().all(|f| f.message != "FLYD_Status"),
        "status frames after the SHUTDOWN one: {after:?}"
    );
    assert!(
        !r.logged("shutting down").is_empty(),
        "no 'shutting down' log event"
    );
    let stopped = r.logged("flyd stopped");
    assert_eq!(stopped.len(), 1, "one 'flyd stopped' event");
    r.run.report(&format!(
        "SIGTERM at feeder frame {sig_frame}: last status SHUTDOWN ({shutdown_statuses} such), last \
         command {} reason SHUTDOWN, exit code 0 by feeder frame {exit_frame} ({:.0} ms under TCG); \
         log: shutting down, flyd stopped {}",
        last_command.label("Command"),
        (exited - sigterm) * 1e3,
        stopped[0]
    ));
}

fn tail(text: &str, lines: usize) -> String {
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

#[test]
fn flyd_never_stops_on_an_empty_road_and_reports_running() {
    let r = run_flyd(flyd_scenario("flyd_empty_road"));
    let bus = r.check_bus();
    assert_eq!(r.exit_code(), 0);
    let stops: Vec<&Frame> = r
        .messages("FLYD_Command")
        .into_iter()
        .filter(|f| f.label("Command") == "STOP")
        .collect();
    assert!(stops.is_empty(), "STOP on an empty road: {:?}", stops[0]);
    let start = r.frame_time(0);
    let statuses = r.statuses_from(start);
    let commands = r.commands_from(start);
    let running = statuses
        .iter()
        .filter(|f| f.label("State") == "RUNNING")
        .count();
    let fault = statuses
        .iter()
        .filter(|f| f.label("State") == "FAULT")
        .count();
    // Under emulation the dequeue-time stereo pairing now and then rejects a few pairs in a row
    // (STEREO_SKEW, DEGRADED for a moment); the run as a whole must be RUNNING.
    assert!(
        running * 4 >= statuses.len() * 3,
        "RUNNING in only {running} of {} statuses: {}",
        statuses.len(),
        label_counts(&statuses, "State")
    );
    assert_eq!(fault, 0, "FAULT state on an empty road");
    // CLEAR once warmed up: after the first CLEAR, nothing the perception asks for is more
    // (a SLOW may still come from a fault: FAULT_FALLBACK while DEGRADED), and CLEAR is what
    // the vehicle gets most of the time.
    let from_clear: Vec<&&Frame> = commands
        .iter()
        .skip_while(|f| f.label("Command") != "CLEAR")
        .collect();
    let perception_alarms: Vec<&&&Frame> = from_clear
        .iter()
        .filter(|f| f.label("Command") != "CLEAR" && f.label("CommandReason") == "PERCEPTION")
        .collect();
    assert!(
        perception_alarms.is_empty(),
        "{} commands above CLEAR from perception on an empty road, the first {:?}",
        perception_alarms.len(),
        perception_alarms.first()
    );
    let clear = from_clear
        .iter()
        .filter(|f| f.label("Command") == "CLEAR")
        .count();
    assert!(
        !from_clear.is_empty() && clear * 4 >= from_clear.len() * 3,
        "CLEAR in only {clear} of {} commands after the first CLEAR: {}",
        from_clear.len(),
        label_counts(&commands, "Command")
    );
    let last = statuses.last().expect("statuses");
    let mut seen = FaultBits::empty();
    for f in &statuses {
        seen = FaultBits::from_bits(seen.bits() | faults(f).bits());
    }
    r.run.report(&format!(
        "empty road, {} frames played: no STOP in {} commands ({}), CLEAR in {clear} of the {} \
         from the first CLEAR, none above it from perception; states {}; faults seen {seen}; \
         last status before SIGTERM {}; exit 0; {bus}",
        r.timeline.len(),
        r.messages("FLYD_Command").len(),
        label_counts(&commands, "Command"),
        from_clear.len(),
        label_counts(&statuses, "State"),
        last.label("State"),
    ));
}

#[test]
fn flyd_flags_a_stalled_camera_falls_back_and_recovers() {
    let r = run_flyd(flyd_scenario("flyd_camera_stops"));
    let bus = r.check_bus();
    assert_eq!(r.exit_code(), 0);
    let (stop_at, resume) = r.episode("left", "skip");
    let last_left = r.frame_time(stop_at.index - 1);
    let stale = FaultBits::LEFT_CAMERA_STALE;
    let statuses = r.statuses_from(r.frame_time(0));
    let first_stale = statuses
        .iter()
        .find(|f| f.time > last_left && faults(f).contains(stale))
        .unwrap_or_else(|| {
            panic!(
                "no LEFT_CAMERA_STALE after the left camera stopped; states {}",
                label_counts(&statuses, "State")
            )
        });
    assert!(
        first_stale.time < resume.time,
        "stale raised only after the camera resumed"
    );
    let raise_frames = r.frames_between(last_left, first_stale.time);
    // flyd's limit is stale_frames = 6 frame periods after the last frame *captured*; under
    // emulation the capture thread runs behind the feeder's writes (it keeps up with 5-9 of the
    // 10 fps, the loopback buffers the rest): measured 13 frames after the last write.
    assert!(
        raise_frames <= 6 + 14,
        "LEFT_CAMERA_STALE raised {raise_frames} frames after the last left frame written (limit 6)"
    );
    let raised = r
        .logged("fault raised")
        .into_iter()
        .find(|l| l["fault"] == "LEFT_CAMERA_STALE")
        .expect("no 'fault raised' LEFT_CAMERA_STALE log event");
    let age_ms = raised["left_frame_age_ms"]
        .as_u64()
        .expect("left_frame_age_ms");
    // On flyd's own clock: raised once the newest left frame is 6 frame periods (600 ms) old,
    // and no more than 3 frame periods late (its control loop runs every 20 ms).
    assert!(
        (600..=900).contains(&age_ms),
        "raised at a left frame age of {age_ms} ms; the limit is 6 frames, 600 ms"
    );
    assert_eq!(first_stale.label("State"), "DEGRADED");
    // The safe command (SLOW) from the first command after the stale status until it clears.
    let commands = r.commands_from(first_stale.time);
    let during: Vec<&&Frame> = commands.iter().filter(|f| f.time < resume.time).collect();
    assert!(!during.is_empty());
    for c in &during {
        assert_eq!(c.label("Command"), "SLOW", "command while stale: {c:?}");
        assert_eq!(c.label("CommandReason"), "FAULT_FALLBACK", "{c:?}");
    }
    let cleared = statuses
        .iter()
        .find(|f| f.time > resume.time && !faults(f).contains(stale))
        .expect("LEFT_CAMERA_STALE never cleared after the camera resumed");
    let clear_frames = r.frames_between(resume.time, cleared.time);
    assert!(
        clear_frames <= 10,
        "stale cleared {clear_frames} frames after the resume"
    );
    let running = statuses
        .iter()
        .find(|f| f.time > resume.time && f.label("State") == "RUNNING")
        .expect("never RUNNING again after the camera resumed");
    let recover_frames = r.frames_between(resume.time, running.time);
    assert!(
        recover_frames <= 20,
        "RUNNING again {recover_frames} frames after the resume"
    );
    let stale_logged = r
        .logged("fault raised")
        .into_iter()
        .any(|l| l["fault"] == "LEFT_CAMERA_STALE");
    assert!(
        stale_logged,
        "no 'fault raised' LEFT_CAMERA_STALE log event"
    );
    r.run.report(&format!(
        "left camera silent for frames {}..{}: LEFT_CAMERA_STALE + DEGRADED {raise_frames} frames \
         after its last frame written (stale_frames 6; flyd logged it at a frame age of {age_ms} ms), {} commands SLOW/FAULT_FALLBACK meanwhile; stale \
         cleared {clear_frames} frames and RUNNING {recover_frames} frames after it resumed; logged; {bus}",
        stop_at.index,
        resume.index - 1,
        during.len()
    ));
}

#[test]
fn flyd_flags_a_camera_delivering_noise_and_recovers() {
    camera_fault_falls_back_and_recovers("flyd_garbage", "garbage", 3, "perception blind", 8);
}

/// A black right camera on a real v4l2loopback device (YUYV Y=16) used to read as a clear
/// road (every uniform window "matched"): UNIFORM, CAMERA_ERROR, the safe command.
#[test]
fn flyd_flags_a_black_camera_and_recovers() {
    camera_fault_falls_back_and_recovers("flyd_black", "black", 2, "image uniform", 1);
}

/// A right camera repeating one frame with fresh timestamps used to read as a clear road:
/// FROZEN, CAMERA_ERROR, the safe command.
#[test]
fn flyd_flags_a_frozen_camera_and_recovers() {
    camera_fault_falls_back_and_recovers("flyd_frozen", "frozen", 4, "image frozen", 2);
}

/// The right camera gets `feed` for a stretch of an empty road (scenario `name`): no
/// CAMERA_ERROR before, CAMERA_ERROR with the `sensor` bit of FLYD_Status.SensorFaults and
/// DEGRADED within `frames` pairs (+ the emulation's capture lag), only non-CLEAR
/// FAULT_FALLBACK commands meanwhile, `logged` in the log, RUNNING again afterwards.
fn camera_fault_falls_back_and_recovers(
    name: &str,
    feed: &str,
    frames: usize,
    logged: &str,
    sensor: u8,
) {
    let r = run_flyd(flyd_scenario(name));
    let bus = r.check_bus();
    r.assert_exited_cleanly();
    let (start, end) = r.episode("right", feed);
    let (t_start, t_end) = (r.frame_time(start.index), r.frame_time(end.index));
    let error = FaultBits::CAMERA_ERROR;
    let statuses = r.statuses_from(r.frame_time(0));
    assert!(
        statuses
            .iter()
            .filter(|f| f.time < t_start)
            .all(|f| !faults(f).contains(error)),
        "CAMERA_ERROR before the {feed} frames"
    );
    let first = statuses
        .iter()
        .find(|f| f.time > t_start && faults(f).contains(error))
        .unwrap_or_else(|| {
            panic!(
                "no CAMERA_ERROR while the right camera delivered {feed} frames; states {}",
                label_counts(&statuses, "State")
            )
        });
    assert!(
        first.time < t_end,
        "raised only after the {feed} frames ended"
    );
    let raise_frames = r.frames_between(t_start, first.time);
    // Under emulation flyd's capture runs several frames behind the feeder (see the stalled-
    // camera test): bound `frames` + 14.
    assert!(
        raise_frames <= frames + 14,
        "CAMERA_ERROR raised {raise_frames} frames after the first {feed} frame"
    );
    assert_eq!(first.label("State"), "DEGRADED");
    let sensor_bits = first.value("SensorFaults") as u8;
    assert!(
        sensor_bits & sensor != 0,
        "SensorFaults {sensor_bits:#x} lacks {sensor:#x} with {feed} frames"
    );
    let commands = r.commands_from(first.time);
    let during: Vec<&&Frame> = commands.iter().filter(|f| f.time < t_end).collect();
    assert!(!during.is_empty());
    for c in &during {
        assert_ne!(
            c.label("Command"),
            "CLEAR",
            "command with {feed} frames: {c:?}"
        );
        assert_eq!(c.label("CommandReason"), "FAULT_FALLBACK", "{c:?}");
    }
    let cleared = statuses
        .iter()
        .find(|f| f.time > t_end && !faults(f).contains(error))
        .unwrap_or_else(|| panic!("CAMERA_ERROR never cleared after the {feed} frames"));
    let running = statuses
        .iter()
        .find(|f| f.time > t_end && f.label("State") == "RUNNING")
        .unwrap_or_else(|| panic!("never RUNNING again after the {feed} frames"));
    let (clear_frames, recover_frames) = (
        r.frames_between(t_end, cleared.time),
        r.frames_between(t_end, running.time),
    );
    assert!(
        recover_frames <= 30,
        "RUNNING again {recover_frames} frames after the {feed} frames ended"
    );
    let n = r.logged(logged).len();
    assert!(n >= 1, "no '{logged}' log event");
    r.run.report(&format!(
        "right camera {feed} for frames {}..{}: CAMERA_ERROR + DEGRADED (SensorFaults \
         {sensor_bits:#x}) {raise_frames} frames after the first, {} commands \
         non-CLEAR/FAULT_FALLBACK meanwhile, '{logged}' logged; cleared {clear_frames} and \
         RUNNING {recover_frames} frames after real frames returned; {bus}",
        start.index,
        end.index - 1,
        during.len()
    ));
}

#[test]
fn flyd_survives_vcan_down_and_up_and_sends_again() {
    let r = run_flyd(flyd_scenario("flyd_can_down"));
    let (bus, gaps) = r.check_bus_with_gaps(1.0);
    assert_eq!(
        r.exit_code(),
        0,
        "flyd must outlive the interface going down"
    );
    let (down_frame, down) = r.event("can-down");
    let (up_frame, up) = r.event("can-up");
    let before = r
        .commands_from(0.0)
        .into_iter()
        .filter(|f| f.time < down)
        .count();
    let during = r
        .frames
        .iter()
        .filter(|f| f.time > down && f.time < up)
        .count();
    let after = r.commands_from(up);
    assert!(
        before > 10,
        "{before} commands before the interface went down"
    );
    assert_eq!(during, 0, "frames on the bus while it was down");
    assert!(
        after.len() > 20,
        "only {} commands after the interface came up",
        after.len()
    );
    assert!(gaps >= 1, "no silence on the bus while it was down");
    let failed = r.logged("CAN write failed");
    let recovered = r.logged("CAN writes recovered");
    assert_eq!(
        failed.len(),
        1,
        "one 'CAN write failed' per episode: {failed:?}"
    );
    assert_eq!(
        recovered.len(),
        1,
        "one 'CAN writes recovered': {recovered:?}"
    );
    let errors = recovered[0]["errors"].as_u64().expect("errors field");
    assert!(errors > 0);
    let stopped = r.logged("flyd stopped");
    let total_errors = stopped[0]["can_errors"].as_u64().expect("can_errors");
    assert!(total_errors >= errors);
    let first_after = r
        .frames
        .iter()
        .find(|f| f.time > up)
        .expect("frames after up");
    r.run.report(&format!(
        "vcan0 down at feeder frame {down_frame}, up at {up_frame} ({:.1} s): no frames meanwhile, \
         flyd kept running; logged 'CAN write failed' ({}) once and 'CAN writes recovered' with \
         {errors} errors; {total_errors} CAN errors in the final report; sending again {:.0} ms \
         after up, {} commands after; exit 0; {bus}",
        up - down,
        failed[0]["error"],
        (first_after.time - up) * 1e3,
        after.len()
    ));
}

/// The CAN adapter vanishing (`ip link del`, as a USB adapter re-enumerating) used to leave
/// flyd DEGRADED and silent forever, watchdog still pinged: it reopens the interface once it
/// is back and sends again.
#[test]
fn flyd_reopens_a_vanished_can_interface_and_sends_again() {
    let r = run_flyd(flyd_scenario("flyd_can_vanish"));
    let (bus, gaps) = r.check_bus_with_gaps(1.0);
    assert_eq!(r.exit_code(), 0, "flyd must outlive the interface");
    let (gone_frame, gone) = r.event("can-gone");
    let (back_frame, back) = r.event("can-back");
    let before = r
        .commands_from(0.0)
        .into_iter()
        .filter(|f| f.time < gone)
        .count();
    let after = r.commands_from(back);
    assert!(
        before > 10,
        "{before} commands before the interface vanished"
    );
    assert!(
        after.len() > 20,
        "only {} commands after the interface came back: not reopened",
        after.len()
    );
    assert!(gaps >= 1, "no silence on the bus while it was gone");
    let vanished = r.logged("CAN interface gone");
    let reopened = r.logged("CAN interface (re)opened");
    assert!(!vanished.is_empty(), "no 'CAN interface gone' log event");
    assert!(
        !reopened.is_empty(),
        "no 'CAN interface (re)opened' log event"
    );
    let first_after = r
        .frames
        .iter()
        .find(|f| f.time > back)
        .expect("frames after the interface came back");
    r.run.report(&format!(
        "vcan0 deleted at feeder frame {gone_frame}, re-created at {back_frame} ({:.1} s): flyd \
         kept running, logged 'CAN interface gone' {} time(s) and reopened it; sending again \
         {:.0} ms after it came back, {} commands after; exit 0; {bus}",
        back - gone,
        vanished.len(),
        (first_after.time - back) * 1e3,
        after.len()
    ));
}

/// The yaw rate of flyd_motion's vehicle from 5 s on (a gentle left bend), rad/s.
const MOTION_YAW_RATE: f64 = 0.05;

/// The host's script of the vehicle's bus for flyd_motion: `VCU_Motion` every 20 ms, standing
/// still for 5 s, then driving off at 5 m/s^2 to 30 km/h, held to 9 s, turning left at
/// [`MOTION_YAW_RATE`] from 5 s; a bad frame every 250 ms among the good ones (a flipped CRC,
/// an E2E-valid 300 m/s, a DLC of 7, a repeated counter).
/// Returns the candump log and the counts of good and bad frames.
fn motion_log() -> (String, u64, u64) {
    use flyd_core::can::candump::format_candump_line;
    use flyd_core::can::messages::{AliveCounter, MotionMsg};
    let t0 = Duration::from_secs(1_764_000_000);
    let mut text = String::new();
    let mut line = |t: Duration, data: &[u8]| {
        text.push_str(&format_candump_line(t0 + t, "vcan0", 0x110, data));
        text.push('\n');
    };
    let mut counter = AliveCounter::ZERO;
    let (mut good, mut bad) = (0, 0);
    for k in 0..450u32 {
        let t = Duration::from_millis(20 * u64::from(k));
        let s = t.as_secs_f64();
        let msg = MotionMsg {
            valid: true,
            speed: (5.0 * (s - 5.0)).clamp(0.0, 30.0 / 3.6),
            yaw_rate: if s >= 5.0 { MOTION_YAW_RATE } else { 0.0 },
        };
        let data = msg.encode(counter.advance());
        line(t, &data);
        good += 1;
        let after = t + Duration::from_millis(5);
        match k % 50 {
            10 => {
                let mut flipped = data;
                flipped[3] ^= 0x40;
                line(after, &flipped);
            }
            22 => line(
                after,
                &MotionMsg {
                    speed: 300.0,
                    ..msg
                }
                .encode(counter.advance()),
            ),
            35 => line(after, &data[..7]),
            47 => line(after, &data),
            _ => continue,
        }
        bad += 1;
    }
    (text, good, bad)
}

/// The vehicle's motion on vcan0 (issue 16): canplayer sends `VCU_Motion` while the pedestrian
/// stands 4 m ahead. Without it flyd assumes 30 km/h (MotionFault, STOP); standing still it
/// sees no reason to brake 4 m away (CLEAR), whatever the bad frames say; driving off it
/// stops; when the frames stop, MotionFault within the configured age and STOP at the
/// assumed speed.
#[test]
fn flyd_decides_at_the_speed_the_vehicle_sends_and_at_the_assumed_one_without_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (log, good, bad) = motion_log();
    let input = dir.path().join("motion.log");
    std::fs::write(&input, log).expect("write motion.log");
    let r = run_flyd(flyd_scenario("flyd_motion").input(input));
    let bus = r.check_bus();
    r.assert_exited_cleanly();
    let vcu = r.messages("VCU_Motion");
    let (first, last) = (
        vcu.first().expect("VCU_Motion on the bus").time,
        vcu.last().expect("VCU_Motion on the bus").time,
    );
    assert_eq!(
        vcu.len() as u64,
        good + bad,
        "candump saw what canplayer sent"
    );
    let fault = |f: &&Frame| f.label("MotionFault") == "UNKNOWN";
    let statuses = r.statuses_from(0.0);
    let window = |from: f64, to: f64| -> Vec<&Frame> {
        statuses
            .iter()
            .copied()
            .filter(|f| f.time >= from && f.time < to)
            .collect()
    };
    let commands = |from: f64, to: f64| -> Vec<&Frame> {
        r.commands_from(from)
            .into_iter()
            .filter(|f| f.time < to)
            .collect()
    };
    let running = statuses
        .iter()
        .find(|f| f.label("State") == "RUNNING")
        .expect("flyd RUNNING")
        .time;

    // Before the first frame: no motion, MotionFault, and STOP at the assumed 30 km/h once the
    // pedestrian (there from the start) is confirmed: under TCG that took up to ~3 s after
    // RUNNING, which is why the scenario starts canplayer a second after flyd logs that STOP.
    let before = window(running, first);
    assert!(
        !before.is_empty() && before.iter().all(fault),
        "{}",
        label_counts(&before, "MotionFault")
    );
    let confirmed = r
        .messages("FLYD_Obstacle")
        .into_iter()
        .find(|f| f.time > running && f.label("ObstacleConfirmed") == "CONFIRMED")
        .map(|f| f.time)
        .expect("the pedestrian confirmed");
    assert!(
        confirmed < first - 0.5,
        "confirmed {:.1} s after RUNNING only",
        confirmed - running
    );
    // Every command while the pedestrian is confirmed is STOP: the decision takes the assumed
    // 30 km/h, not a lower speed. Whether the pedestrian stays confirmed for the seconds before
    // the frames is perception under TCG (on a loaded CI host the guest once lost it for a
    // second and a half); flyd_pedestrian bounds that (>= 90 % STOP after it steps in): here
    // the share is reported.
    let obstacles = r.messages("FLYD_Obstacle");
    let held_on: Vec<(&Frame, bool)> = commands(confirmed, first)
        .into_iter()
        .map(|c| {
            let seen = obstacles
                .iter()
                .rev()
                .find(|o| o.time <= c.time)
                .is_some_and(|o| o.label("ObstacleConfirmed") == "CONFIRMED");
            (c, seen)
        })
        .collect();
    let while_confirmed: Vec<&Frame> = held_on
        .iter()
        .filter(|(_, seen)| *seen)
        .map(|(c, _)| *c)
        .collect();
    assert!(
        !while_confirmed.is_empty() && while_confirmed.iter().all(|c| c.label("Command") == "STOP"),
        "STOP at the assumed speed while the pedestrian is confirmed: {}; flyd's log:\n{}",
        label_counts(&while_confirmed, "Command"),
        r.story()
    );
    let before_frames: Vec<&Frame> = held_on.iter().map(|(c, _)| *c).collect();
    let stop_share = before_frames
        .iter()
        .filter(|c| c.label("Command") == "STOP")
        .count() as f64
        / before_frames.len() as f64;

    // Standing still (the frames' first 5 s): motion known, CLEAR once STOP's hold is over,
    // the bad frames (a 300 m/s among them) ignored.
    let standing = window(first + 0.3, first + 5.0);
    let known = standing.iter().filter(|f| !fault(f)).count();
    assert!(
        known * 100 >= standing.len() * 95,
        "motion known on {known} of {} statuses while standing",
        standing.len()
    );
    // Perception asks for nothing (a STEREO_SKEW episode of the emulated cameras may still
    // bring SLOW, FAULT_FALLBACK: that is the fault's, whatever the speed).
    let standing_cmds = commands(first + 2.5, first + 5.0);
    let clear = standing_cmds
        .iter()
        .filter(|c| c.label("Command") == "CLEAR")
        .count();
    assert!(
        clear * 2 > standing_cmds.len()
            && standing_cmds.iter().all(|c| {
                c.label("Command") == "CLEAR" || c.label("CommandReason") == "FAULT_FALLBACK"
            }),
        "standing 4 m before the pedestrian: {} ({}); flyd's log:\n{}",
        label_counts(&standing_cmds, "Command"),
        label_counts(&standing_cmds, "CommandReason"),
        r.story()
    );

    // Driving off: the stopping distance reaches the pedestrian at ~2.2 m/s (5.45 s).
    let stop_at = commands(first + 5.0, last)
        .into_iter()
        .find(|c| c.label("Command") == "STOP")
        .map(|c| c.time - first)
        .expect("a STOP driving off");
    assert!(stop_at < 6.0, "first STOP {stop_at:.2} s into the frames");
    let driving = commands(first + 6.0, last + 2.0);
    assert!(
        driving.iter().all(|c| c.label("Command") == "STOP"),
        "{}; flyd's log:\n{}",
        label_counts(&driving, "Command"),
        r.story()
    );

    // Silence: MotionFault within the configured age (5 periods, 100 ms) and a status period.
    let lost = statuses
        .iter()
        .find(|f| f.time > last && fault(f))
        .map(|f| f.time - last)
        .expect("MotionFault after the last frame");
    assert!(
        lost <= 0.35,
        "MotionFault {:.0} ms after the last frame",
        lost * 1e3
    );
    let after = window(last + lost, last + 2.0);
    assert!(
        after.iter().all(fault),
        "{}",
        label_counts(&after, "MotionFault")
    );

    // The path (FLYD_Path): straight ahead before the frames; turning left from 5 s, the arc
    // of the moment at once and the corridor's centre line once the turn has been held for
    // perception.obstacle.path_hold_s (2 s): at 30 km/h both yaw rate / speed. Never right.
    let paths = r.messages("FLYD_Path");
    let straight_before: Vec<&Frame> = paths
        .iter()
        .copied()
        .filter(|f| f.time > running && f.time < first)
        .collect();
    assert!(
        !straight_before.is_empty()
            && straight_before
                .iter()
                .all(|f| f.label("PathValid") == "STRAIGHT"),
        "before the frames: {}",
        label_counts(&straight_before, "PathValid")
    );
    let k = MOTION_YAW_RATE / (30.0 / 3.6);
    let near = |f: &Frame, signal: &str| (f.value(signal) - k).abs() <= 0.15 * k;
    let now_at = paths
        .iter()
        .find(|f| f.time > first + 6.7 && near(f, "CurvatureNow"))
        .map(|f| f.time - first);
    let held_at = paths
        .iter()
        .find(|f| f.time > first + 7.0 && near(f, "Curvature"))
        .map(|f| f.time - first);
    assert!(
        now_at.is_some() && held_at.is_some(),
        "curvature {k:.4} 1/m: of the moment {now_at:?} s, held {held_at:?} s into the frames; \
         FLYD_Path: {:?}",
        paths
            .iter()
            .filter(|f| f.time > first)
            .map(|f| (
                f.time - first,
                f.value("Curvature"),
                f.value("CurvatureNow")
            ))
            .collect::<Vec<_>>()
    );
    assert!(
        paths
            .iter()
            .all(|f| f.value("Curvature") >= 0.0 && f.value("CurvatureNow") >= 0.0),
        "a path turning right"
    );

    // Every frame was counted, the bad ones rejected.
    let stopped = r.logged("flyd stopped");
    let report = stopped.first().expect("the 'flyd stopped' event");
    assert_eq!(report["motion_rejected"], bad, "{report}");
    assert_eq!(report["motion_accepted"], good, "{report}");
    r.run.report(&format!(
        "{good} VCU_Motion frames and {bad} bad ones (CRC, 300 m/s, DLC 7, repeat) by canplayer: \
         before them MotionFault, the pedestrian confirmed {:.1} s after RUNNING, then STOP (30 km/h \
         assumed) on every command while it was confirmed ({:.0} % of the commands until the \
         frames); standing still known on {known}/{} \
         statuses and CLEAR 4 m before the pedestrian ({clear} of {} commands, the others \
         FAULT_FALLBACK); driving off, first STOP {stop_at:.2} s \
         into the frames (the stopping distance reaches 4 m at 5.45 s); after the last frame \
         MotionFault in {:.0} ms, STOP; FLYD_Path at {k:.4} 1/m ({MOTION_YAW_RATE} rad/s at \
         30 km/h): the arc of the moment {:.2} s, the held path {:.2} s into the frames; \
         rejected {bad}, accepted {good}; {bus}",
        confirmed - running,
        stop_share * 100.0,
        standing.len(),
        standing_cmds.len(),
        lost * 1e3,
        now_at.unwrap_or(f64::NAN),
        held_at.unwrap_or(f64::NAN)
    ));
}

#[test]
fn flyd_names_a_camera_with_the_wrong_format_and_raises_a_fault() {
    let r = run_flyd(flyd_scenario("flyd_bad_format"));
    let bus = r.check_bus();
    r.assert_exited_cleanly();
    let right = r.run.result("devices")["right"].clone();
    let errors = r.logged("camera error");
    // The first warning may be "not open" (flyd opens cameras in their threads); the format
    // error must follow as a warning of its own.
    let error = errors
        .iter()
        .find(|l| {
            l["camera"] == right.as_str()
                && l["error"]
                    .as_str()
                    .is_some_and(|t| t.contains("160") && t.contains("320"))
        })
        .unwrap_or_else(|| panic!("no camera error for {right} giving both sizes: {errors:?}"));
    assert_eq!(error["level"], "WARN");
    assert_eq!(error["side"], "right");
    let text = error["error"].as_str().expect("error text");
    assert!(
        text.contains(&right),
        "the error does not name {right}: {text}"
    );
    // Every camera is "not open" until its thread opens it; the left one must have no other.
    assert!(
        errors
            .iter()
            .all(|l| l["side"] != "left"
                || l["error"].as_str().is_some_and(|t| t.ends_with("not open"))),
        "the left camera (right format) reported an error: {errors:?}"
    );
    let statuses = r.statuses_from(r.frame_time(0));
    let with_error = statuses
        .iter()
        .filter(|f| faults(f).contains(FaultBits::CAMERA_ERROR))
        .count();
    assert!(
        with_error * 10 >= statuses.len() * 9,
        "CAMERA_ERROR in only {with_error} of {} statuses",
        statuses.len()
    );
    assert!(statuses.iter().all(|f| f.label("State") != "RUNNING"));
    let commands = r.commands_from(r.frame_time(0));
    assert!(
        commands.iter().all(|c| c.label("Command") != "CLEAR"),
        "CLEAR while a camera is in error"
    );
    r.run.report(&format!(
        "right camera {right} at 160x120: logged WARN 'camera error' naming it: {text:?}; CAMERA_ERROR \
         in {with_error}/{} statuses ({}), commands {}; no crash, exit 0; {bus}",
        statuses.len(),
        label_counts(&statuses, "State"),
        label_counts(&commands, "Command"),
    ));
}

/// Recording through V4L2 and vcan: flyd records (`--record`) while the pedestrian steps in;
/// the frames it recorded (as captured from the loopback cameras and converted from YUYV)
/// replay on the host, with the configuration it ran with, to the same `FLYD_Command` frames
/// byte for byte, and the frames the recording says were sent are those candump saw on vcan0.
#[test]
fn flyd_records_through_v4l2_and_the_recording_replays_to_the_commands_seen_on_vcan0() {
    let r = run_flyd(flyd_scenario("flyd_record"));
    r.check_bus();
    r.assert_exited_cleanly();
    let dir = tempfile::tempdir().expect("tempdir");
    let mcap = dir.path().join("drive.mcap");
    std::fs::write(&mcap, r.run.read("drive.mcap")).expect("write the recording");
    let data = std::fs::read(&mcap).expect("read");

    // The attached configuration, beside the rig file it names, as on the guest.
    let summary = mcap::Summary::read(&data)
        .expect("a complete MCAP file")
        .expect("with a summary");
    let index = summary
        .attachment_indexes
        .iter()
        .find(|a| a.name == "config.toml")
        .expect("config.toml attached");
    let config = mcap::read::attachment(&data, index).expect("attachment");
    let config_file = dir.path().join("flyd.toml");
    std::fs::write(&config_file, &config.data[..]).expect("write config");
    let vm = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vm/config");
    std::fs::copy(
        vm.join("mock-rig-320x240.toml"),
        dir.path().join("mock-rig-320x240.toml"),
    )
    .expect("rig");

    // What the recording says was sent, against vcan0.
    let mut sent = Vec::new();
    let mut images = 0;
    for m in mcap::MessageStream::new(&data).expect("messages") {
        let m = m.expect("message");
        match m.channel.topic.as_str() {
            "/can/tx" => {
                let v: serde_json::Value = serde_json::from_slice(&m.data).expect("json");
                sent.push((
                    v["id"].as_u64().expect("id") as u32,
                    v["data"].as_str().expect("data").to_string(),
                ));
            }
            "/camera/left/image" | "/camera/right/image" => images += 1,
            _ => {}
        }
    }
    let on_bus: Vec<(u32, String)> = r
        .frames
        .iter()
        .filter(|f| f.message.starts_with("FLYD_"))
        .map(|f| (f.id, f.data.iter().map(|b| format!("{b:02X}")).collect()))
        .collect();
    assert!(images > 100, "{images} images recorded");
    assert!(sent.len() > 200, "{} frames recorded as sent", sent.len());
    assert_eq!(
        sent.len(),
        on_bus.len(),
        "frames recorded as sent vs seen on vcan0"
    );
    // The first difference and what surrounds it: a run once differed here (2026-12-06, in
    // a clean-clone CI; 4 reruns passed), and the assertion said no more than that.
    if let Some(k) = sent.iter().zip(&on_bus).position(|(a, b)| a != b) {
        let around = k.saturating_sub(3)..(k + 4).min(sent.len());
        panic!(
            "the recorded frames differ from vcan0's from frame {k} of {}: recorded {:X?}, \
             on vcan0 {:X?}",
            sent.len(),
            &sent[around.clone()],
            &on_bus[around]
        );
    }

    // The replay on the host.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_flyd"))
        .arg("replay")
        .arg("--mcap")
        .arg(&mcap)
        .arg("--config")
        .arg(&config_file)
        .output()
        .expect("flyd replay runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: serde_json::Value = serde_json::from_str(&stdout).expect("summary");
    let commands = on_bus.iter().filter(|(id, _)| *id == 0x120).count();
    assert_eq!(
        s["commands_recorded"].as_u64(),
        Some(commands as u64),
        "{s}"
    );
    assert_eq!(
        s["commands_identical"].as_u64(),
        Some(commands as u64),
        "{s}"
    );
    assert!(
        s["changes"].as_array().is_some_and(|c| c
            .iter()
            .any(|x| x.as_str().is_some_and(|x| x.ends_with(":STOP")))),
        "the pedestrian's STOP replayed: {s}"
    );
    r.run.report(&format!(
        "{images} images and {} sent frames recorded (= vcan0); replayed {commands}/{commands} \
         commands bit for bit",
        sent.len()
    ));
}

/// The Debian package, built by scripts/package (cargo-deb) for the systemd scenario.
fn debian_package() -> std::path::PathBuf {
    let root = env!("CARGO_MANIFEST_DIR");
    let out = flyd_cli::output_ok(
        std::process::Command::new(Path::new(root).join("scripts/package")).current_dir(root),
        "scripts/package",
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let path = std::path::PathBuf::from(stdout.lines().last().unwrap_or_default().trim());
    assert!(path.is_file(), "scripts/package printed:\n{stdout}");
    path
}

/// flyd as its package installs it, under a real systemd as PID 1 (issue 34): the Debian 12
/// guest of tests/vm/systemd, the package installed with apt, the VM configuration in
/// /etc/flyd, the feeder playing pedestrian-steps-in (tests/vm/scenarios/systemd_flyd.sh).
/// `FLYD_VM_SYSTEMD_DROPIN=FILE.conf` installs FILE as a drop-in for flyd.service first: with
/// `WatchdogSec=0` in it, this test fails (the SIGSTOPped flyd is never restarted).
#[test]
fn systemd_runs_the_package_restarts_flyd_on_a_missed_watchdog_and_upgrades_and_removes_it() {
    let vm = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vm");
    let mut scenario = Scenario::new("systemd_flyd")
        .under_systemd()
        .bin(guest_tool("flyd-feeder"))
        .bin(vm.join("scenarios/flyd_common.sh"))
        .input(vm.join("config/flyd-vm.toml"))
        .input(vm.join("config/mock-rig-320x240.toml"))
        .input(debian_package())
        .timeout(Duration::from_secs(600));
    if let Some(dropin) = std::env::var_os("FLYD_VM_SYSTEMD_DROPIN") {
        scenario = scenario.input(dropin);
    }
    let mut r = run_flyd(scenario);
    // flyd logs natively to the journal under systemd: its events, as its JSON lines would
    // hold them, from the journal's fields.
    let journal = journal_entries(&r, "journal.json");
    r.log = journal
        .iter()
        .filter(|e| is_flyd(e))
        .map(as_log_event)
        .collect();

    // Installed: the unit loaded from the package, neither enabled nor started.
    let installed = r.run.result("installed");
    assert_eq!(installed["enabled"], "disabled", "{installed:?}");
    assert_eq!(installed["active"], "inactive", "{installed:?}");
    assert!(
        installed["unit"].ends_with("/lib/systemd/system/flyd.service"),
        "{installed:?}"
    );
    assert_eq!(
        installed["version"],
        format!("{}-1", env!("CARGO_PKG_VERSION"))
    );

    // Started: `systemctl start` returned with the unit running (Type=notify: only after
    // READY=1), flyd's status text set through sd_notify, the watchdog armed.
    let start = r.run.result("start");
    assert_eq!(
        (start["active"].as_str(), start["substate"].as_str()),
        ("active", "running")
    );
    let show = r.run.read_to_string("show-start.txt");
    for line in ["Type=notify", "WatchdogUSec=2s", "NotifyAccess=main"] {
        assert!(
            show.lines().any(|l| l == line),
            "no {line} in show-start.txt"
        );
    }
    let status_text = show
        .lines()
        .find_map(|l| l.strip_prefix("StatusText="))
        .unwrap_or_default();
    assert!(!status_text.is_empty(), "no STATUS= from flyd at start");
    assert!(
        !r.logged("ready: both cameras deliver").is_empty(),
        "flyd never logged that it sent READY=1"
    );

    // The bus: every CRC valid, counters +1 mod 15 except across the watchdog restart, the
    // stop before the upgrade and the upgrade's restart (a new flyd counts from 0; the
    // upgrade's stop-start leaves the bus quiet for 0.45-0.76 s under TCG).
    let (bus, gaps) = r.check_bus_with_gaps(0.3);
    assert!(
        gaps >= 3,
        "expected the bus to go quiet around the restarts: {gaps} gaps"
    );

    // The pedestrian (scenario frame 30): no STOP before, STOP within 10 camera frames.
    let appears = r.frame_time(30);
    let (_, sigstop) = r.event("sigstop");
    // The feeder's timeline starts at scenario frame 0, once flyd is running (lead-in before).
    let running = r.frame_time(0);
    let commands = r.messages("FLYD_Command");
    assert!(
        !commands
            .iter()
            .any(|f| f.time >= running && f.time < appears && f.label("Command") == "STOP"),
        "STOP before the pedestrian appeared:\n{}",
        r.story()
    );
    let first_stop = commands
        .iter()
        .find(|f| f.time >= appears && f.time < sigstop && f.label("Command") == "STOP")
        .unwrap_or_else(|| panic!("no STOP after the pedestrian:\n{}", r.story()));
    let reaction = r.frames_between(appears, first_stop.time);
    assert!(
        reaction <= 10,
        "STOP {reaction} frames after the pedestrian"
    );

    // systemd-analyze security on the running unit.
    let security = r.run.read_to_string("security.txt");
    let exposure: f64 = security
        .lines()
        .find_map(|l| l.split("Overall exposure level for flyd.service: ").nth(1))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no exposure level in security.txt:\n{security}"));
    assert!(exposure <= 2.0, "exposure {exposure}");

    // The watchdog: the SIGSTOPped flyd killed by systemd's watchdog and restarted, and its
    // frames back on the bus after the restart.
    let watchdog = r.run.result("watchdog");
    assert_eq!(watchdog["restarted"], "yes", "{watchdog:?}");
    let (n0, n1): (u32, u32) = (
        watchdog["nrestarts_before"].parse().unwrap(),
        watchdog["nrestarts"].parse().unwrap(),
    );
    assert!(n1 > n0, "NRestarts {n0} -> {n1}");
    let message = |e: &serde_json::Value| e["MESSAGE"].as_str().unwrap_or_default().to_string();
    assert!(
        journal.iter().any(|e| e["SYSLOG_IDENTIFIER"] == "systemd"
            && message(e).contains("flyd.service: Watchdog timeout")),
        "no watchdog timeout in the journal"
    );
    let (restart_frame, _) = r.event("restarted");
    let (_, again) = r.event("running-again");
    let (_, sigterm) = r.event("sigterm");
    // Frozen, flyd sends nothing: from just after the kill until the watchdog (2 s after the
    // last ping, which came before the kill) could have fired, not one frame. The kill's own
    // realtime stamps, not the feeder's latest frame (which may be long before it).
    let stamps = r.run.result("sigstop");
    let stamp = |k: &str| -> f64 {
        stamps[k]
            .parse()
            .unwrap_or_else(|e| panic!("sigstop {k}={:?}: {e}", stamps[k]))
    };
    let (stop_before, stop_after) = (stamp("before"), stamp("after"));
    assert!(
        stop_before >= sigstop && stop_after >= stop_before && stop_after - stop_before < 1.0,
        "the kill's stamps {stop_before}..{stop_after}, the feeder's frame before it {sigstop}"
    );
    let during_stop = r
        .frames
        .iter()
        .filter(|f| {
            f.message.starts_with("FLYD_")
                && f.time > stop_after + 0.5
                && f.time < stop_before + 2.0
        })
        .count();
    assert_eq!(during_stop, 0, "frames from a SIGSTOPped flyd");
    let before_stop = r
        .frames
        .iter()
        .filter(|f| {
            f.message.starts_with("FLYD_") && f.time > stop_before - 1.0 && f.time < stop_before
        })
        .count();
    assert!(
        before_stop > 20,
        "{before_stop} flyd frames in the second before the kill: the window above would prove nothing"
    );
    let resumed = commands
        .iter()
        .filter(|f| f.time >= again && f.time < sigterm)
        .count();
    assert!(resumed > 20, "{resumed} commands after the restart");

    // The journal holds flyd's own entries, from each of its processes, natively: priority
    // from the level, the named thread, the target, every field a FLYD_* field.
    let flyd_entries: Vec<(String, &serde_json::Value)> = journal
        .iter()
        .filter(|e| is_flyd(e) && field(e, "_SYSTEMD_UNIT") == "flyd.service")
        .map(|e| (field(e, "_PID"), e))
        .collect();
    let pids: std::collections::BTreeSet<&str> =
        flyd_entries.iter().map(|(p, _)| p.as_str()).collect();
    assert!(pids.len() >= 3, "flyd processes in the journal: {pids:?}");
    for (_, e) in &flyd_entries {
        assert!(
            ["3", "4", "6", "7"].contains(&field(e, "PRIORITY").as_str())
                && !field(e, "MESSAGE").is_empty()
                && !field(e, "FLYD_THREAD").is_empty()
                && field(e, "TARGET").starts_with("flyd")
                && !field(e, "CODE_FILE").is_empty(),
            "a flyd entry without its priority, message, thread, target or source: {e}"
        );
        assert!(
            !field(e, "MESSAGE").starts_with('{'),
            "a JSON line in the journal's MESSAGE: {e}"
        );
    }
    // Every field of a stats event is a journal field of its own, and MESSAGE reads as the
    // terminal shows it ("stats name=value ...").
    let (_, stats) = flyd_entries
        .iter()
        .rfind(|(_, e)| {
            field(e, "MESSAGE").starts_with("stats ")
                && !field(e, "FLYD_GENERATIONS_PER_SEC").is_empty()
        })
        .unwrap_or_else(|| panic!("no stats event with its numbers in the journal"));
    let stats_message = field(stats, "MESSAGE");
    let mut stats_fields = 0;
    for (name, _) in stats_message
        .split(' ')
        .skip(1)
        .filter_map(|t| t.split_once('='))
        .filter(|(k, _)| {
            k.chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        })
    {
        let value = field(stats, &format!("FLYD_{}", name.to_ascii_uppercase()));
        assert!(
            stats_message.contains(&format!("{name}={value}")),
            "stats field {name} not a journal field of its own (FLYD_{}={value:?}): {stats}",
            name.to_ascii_uppercase()
        );
        stats_fields += 1;
    }
    assert!(
        stats_fields >= 10,
        "{stats_fields} fields in {stats_message}"
    );
    assert_eq!(field(stats, "PRIORITY"), "6", "stats is INFO");
    let ready = flyd_entries
        .iter()
        .filter(|(_, e)| {
            field(e, "MESSAGE").starts_with("ready: both cameras")
                && field(e, "FLYD_GENERATION").parse::<u64>().is_ok()
        })
        .count();
    assert!(ready >= 3, "{ready} ready events with their generation");

    // `journalctl -u flyd -p err` on the clean run (to frame 55): empty.
    let err_clean = journal_entries(&r, "err-clean.json");
    assert!(
        err_clean.is_empty(),
        "journalctl -u flyd -p err on a clean run: {err_clean:?}"
    );
    // `journalctl -u flyd -p warning` after the black camera: exactly flyd's WARN and ERROR
    // entries of the journal at that moment, the camera's warning among them, no INFO.
    let at_90 = journal_entries(&r, "journal-at-90.json");
    let warnings = journal_entries(&r, "warnings.json");
    let cursors = |v: &[serde_json::Value], pred: &dyn Fn(&serde_json::Value) -> bool| {
        v.iter()
            .filter(|e| is_flyd(e) && pred(e))
            .map(|e| field(e, "__CURSOR"))
            .collect::<std::collections::BTreeSet<_>>()
    };
    let severe = |e: &serde_json::Value| matches!(field(e, "PRIORITY").as_str(), "3" | "4");
    assert!(
        warnings
            .iter()
            .all(|e| field(e, "PRIORITY").parse::<u8>().is_ok_and(|p| p <= 4)),
        "-p warning listed an entry below warning: {warnings:?}"
    );
    let listed = cursors(&warnings, &|_| true);
    let expected = cursors(&at_90, &severe);
    assert!(
        expected.is_subset(&listed),
        "flyd's WARN/ERROR entries missing from -p warning: {:?}",
        expected.difference(&listed).collect::<Vec<_>>()
    );
    let infos = cursors(&at_90, &|e| field(e, "PRIORITY") == "6");
    assert!(
        infos.len() >= 5,
        "{} INFO entries before frame 90",
        infos.len()
    );
    assert!(infos.is_disjoint(&listed), "an INFO entry under -p warning");
    let uniform = warnings
        .iter()
        .find(|e| is_flyd(e) && field(e, "MESSAGE").starts_with("image uniform"))
        .unwrap_or_else(|| panic!("no WARN for the black camera under -p warning: {warnings:?}"));
    assert_eq!(field(uniform, "PRIORITY"), "4");
    assert_eq!(field(uniform, "FLYD_CAMERA"), "right");
    assert_eq!(field(uniform, "TARGET"), "flyd::daemon::evolution");
    assert_eq!(field(uniform, "FLYD_THREAD"), "flyd-evolution");
    // `journalctl -u flyd FLYD_CAMERA=right`: a match on a field of flyd's.
    let matched = journal_entries(&r, "field-match.json");
    assert!(
        !matched.is_empty() && matched.iter().all(|e| field(e, "FLYD_CAMERA") == "right"),
        "journalctl -u flyd FLYD_CAMERA=right: {matched:?}"
    );
    assert!(
        matched
            .iter()
            .any(|e| field(e, "__CURSOR") == field(uniform, "__CURSOR"))
    );
    // systemd/README.md's Logs section, each command as documented.
    let doc_rc: BTreeMap<String, String> = r
        .run
        .read_to_string("doc-commands.txt")
        .lines()
        .filter_map(|l| l.split_once(' '))
        .map(|(n, rc)| (n.to_string(), rc.to_string()))
        .collect();
    let doc = |name: &str, rc: &str, wants: &[&str]| {
        let out = r.run.read_to_string(&format!("doc-{name}.txt"));
        assert_eq!(
            doc_rc.get(name).map(String::as_str),
            Some(rc),
            "{name}: {out}"
        );
        for want in wants {
            assert!(out.contains(want), "{name}: no {want:?} in:\n{out}");
        }
    };
    // -f follows until stopped (timeout's 124); the stats line shows its figures.
    doc("follow", "124", &["flyd["]);
    doc(
        "warning",
        "0",
        &["image uniform or without texture", "camera=right"],
    );
    doc("err", "0", &[]);
    doc("field", "0", &["image uniform", "camera=right"]);
    doc("thread", "0", &["flyd["]);
    doc(
        "verbose",
        "0",
        &["FLYD_THREAD=", "PRIORITY=", "TARGET=flyd"],
    );

    // Stopped: SHUTDOWN status frame, exit 0, nothing from flyd until the upgrade's start.
    // ExecMainStatus: flyd's exit status; Result=success: no timeout, no signal, no core.
    let stop = r.run.result("flyd");
    assert_eq!(
        (stop["exit"].as_str(), stop["result"].as_str()),
        ("0", "success"),
        "{stop:?}"
    );
    let (_, exited) = r.event("flyd-exited");
    let (_, upgrade) = r.event("upgrade-start");
    let statuses = r.messages("FLYD_Status");
    let last = statuses
        .iter()
        .rev()
        .find(|f| f.time < upgrade)
        .expect("status frames");
    assert_eq!(last.label("State"), "SHUTDOWN", "{last:?}");
    assert!(last.time >= sigterm && last.time <= exited, "{last:?}");

    // Upgrade over itself: the edit kept, no .dpkg-* left, flyd restarted on the new binary.
    let upgraded = r.run.result("upgrade");
    assert_eq!(upgraded["kept"], "1", "{upgraded:?}");
    assert_eq!(upgraded["dpkg_files"], "0", "{upgraded:?}");
    assert_eq!(upgraded["active"], "active", "{upgraded:?}");
    assert_eq!(upgraded["restarted"], "yes", "{upgraded:?}");

    // apt remove stops it and keeps the configuration; purge removes the conffiles.
    let removed = r.run.result("remove");
    assert_eq!(removed["active"], "inactive", "{removed:?}");
    assert_eq!(removed["processes"], "0", "{removed:?}");
    assert_eq!(removed["binary"], "gone", "{removed:?}");
    assert_eq!(removed["config"], "kept", "{removed:?}");
    assert_eq!(r.run.result("purge")["conffiles_left"], "0");

    r.run.report(&format!(
        "systemd PID 1; apt install: unit {} disabled, inactive; systemctl start returned \
         active/running (READY=1, STATUS={status_text:?}); STOP {reaction} frames after the \
         pedestrian; security {exposure}; SIGSTOP: watchdog timeout, NRestarts {n0}->{n1} by feeder frame {restart_frame}, \
         no frame while stopped, {resumed} commands after the restart; journal: {} flyd \
         entries from {} processes (stats: {} gen/s, {stats_fields} fields), -p err empty on \
         the clean run, -p warning {} entries (the black camera's among them, no INFO), \
         FLYD_CAMERA=right {} entries; stop: exit 0, last status SHUTDOWN; \
         upgrade kept the edit and restarted flyd; remove stopped it; {bus}",
        installed["unit"],
        flyd_entries.len(),
        pids.len(),
        field(stats, "FLYD_GENERATIONS_PER_SEC"),
        warnings.len(),
        matched.len(),
    ));
}

/// `journalctl -o json` output: one entry a line.
fn journal_entries(r: &FlydRun, file: &str) -> Vec<serde_json::Value> {
    r.run
        .read_to_string(file)
        .lines()
        .map(|l| serde_json::from_str(l).expect("journalctl -o json line"))
        .collect()
}

/// A journal field as text (journalctl writes a value that is not printable UTF-8 as an array
/// of bytes); empty when absent.
fn field(e: &serde_json::Value, name: &str) -> String {
    match &e[name] {
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Array(bytes) => String::from_utf8_lossy(
            &bytes
                .iter()
                .filter_map(|b| b.as_u64().map(|b| b as u8))
                .collect::<Vec<u8>>(),
        )
        .into_owned(),
        _ => String::new(),
    }
}

fn is_flyd(e: &serde_json::Value) -> bool {
    field(e, "SYSLOG_IDENTIFIER") == "flyd"
}

/// A flyd journal entry as flyd's JSON line holds the event: `message` (the journal's MESSAGE,
/// with its `name=value` tail), `level`, and each FLYD_* field by its name.
fn as_log_event(e: &serde_json::Value) -> serde_json::Value {
    let mut v = serde_json::Map::new();
    v.insert("message".into(), field(e, "MESSAGE").into());
    let level = match field(e, "PRIORITY").as_str() {
        "3" => "ERROR",
        "4" => "WARN",
        "6" => "INFO",
        _ => "DEBUG",
    };
    v.insert("level".into(), level.into());
    if let Some(map) = e.as_object() {
        for name in map.keys() {
            if let Some(rest) = name.strip_prefix("FLYD_") {
                v.insert(rest.to_ascii_lowercase(), field(e, name).into());
            }
        }
    }
    serde_json::Value::Object(v)
}
