//! The threaded daemon on hw-mock cameras with injected faults (`[[cameras.mock_faults]]`):
//! the sensor failures that used to read as a clear road with a pedestrian 4 m ahead.
//!
//! Each test injects one fault between `FROM` and `TO` seconds of the pedestrian-4m scenario
//! (5 s, 30 fps, 320x240, 1000 flies) and checks, on the frames the daemon sent: no CLEAR while
//! the fault lasts, the fault's bits (CAMERA_ERROR and its `SensorFaults` bit, or the stale
//! bit of a dropped camera) in every status from `SETTLE` after its start to its end, and none
//! of them once the images are healthy again. `SETTLE` is a deadlock-style allowance of 30
//! frames, not a latency target: the latencies measured are printed.

mod mock_daemon;

use std::time::Duration;

use flyd::bus::MemoryBus;
use flyd::config::{CameraSource, DaemonConfig};
use flyd::daemon::{self, MonotonicClock, Shutdown};
use flyd::mock::camera::{FaultCamera, FaultKind, MockFault, mock_cameras};
use flyd_core::can::messages::StatusMsg;
use flyd_core::decision::Command;
use flyd_core::sensor::SensorFaults;
use flyd_core::status::{FaultBits, State};
use mock_daemon::{Frame, GUARD, decode_all};

const FROM: f64 = 1.5;
const TO: f64 = 3.0;
const SETTLE: f64 = 1.0;

fn config() -> DaemonConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/demo.toml");
    let mut c = DaemonConfig::load(&path).expect("config/demo.toml");
    c.cameras.width = 320;
    c.cameras.height = 240;
    c.engine.flies = 1000;
    c
}

/// Runs pedestrian-4m with `faults` to its end; every frame sent, with its time since start.
fn run(faults: &[MockFault]) -> Vec<(f64, Frame)> {
    let _ = tracing_subscriber::fmt()
        .with_test_writer()
        .with_max_level(tracing::Level::INFO)
        .try_init();
    let mut config = config();
    config.cameras.source = CameraSource::Mock {
        scenario: "pedestrian-4m".into(),
        faults: faults.to_vec(),
        looped: false,
    };
    let clock = MonotonicClock::shared();
    let bus_clock = clock.clone();
    let bus = MemoryBus::new(move || bus_clock.now());
    let start = clock.now();
    let (w, h) = (config.cameras.width, config.cameras.height);
    let (left, right, _) =
        mock_cameras("pedestrian-4m", w, h, &clock, faults).expect("mock cameras");
    let b = bus.clone();
    let handle = daemon::spawn_named("test-daemon", move || {
        daemon::run(
            (Box::new(left), Box::new(right)),
            Box::new(b),
            clock,
            &config,
            Shutdown::new(),
            daemon::ServiceNotifier::none(),
        )
    })
    .expect("spawn");
    let t0 = std::time::Instant::now();
    while !handle.is_finished() {
        assert!(t0.elapsed() < GUARD, "the scenario did not end");
        std::thread::sleep(Duration::from_millis(20));
    }
    handle.join().expect("joined").expect("the daemon ran");
    let recorded = bus.frames();
    let frames = decode_all(&recorded);
    recorded
        .iter()
        .zip(frames)
        .map(|(r, f)| (r.timestamp.saturating_sub(start).as_secs_f64(), f))
        .collect()
}

fn statuses(frames: &[(f64, Frame)]) -> impl Iterator<Item = (f64, &StatusMsg)> {
    frames.iter().filter_map(|(t, f)| match f {
        Frame::Status(s, _) => Some((*t, s)),
        _ => None,
    })
}

/// Injects `kind` on `camera` and checks what the daemon sent (see the module docs); `bit`
/// is the sensor fault expected, `stale` the stale-camera bit instead for a dropped camera.
fn check(kind: FaultKind, camera: FaultCamera, bit: Option<SensorFaults>, stale: FaultBits) {
    let fault = MockFault {
        kind,
        camera,
        from_s: FROM,
        to_s: TO,
        gain: 0.05,
    };
    let frames = run(&[fault]);
    let what = format!("{kind:?} on {camera:?}");
    // The pedestrian was seen before the fault.
    assert!(
        frames
            .iter()
            .any(|(t, f)| *t < FROM
                && matches!(f, Frame::Command(c, _) if c.command == Command::Stop)),
        "{what}: no STOP for the pedestrian before the fault"
    );
    // Never CLEAR while the fault lasts (nor while it is being confirmed or cleared).
    for (t, f) in &frames {
        if let Frame::Command(c, _) = f
            && (FROM..TO + 0.2).contains(t)
        {
            assert_ne!(c.command, Command::Clear, "{what}: CLEAR at {t:.3} s");
        }
    }
    let expected = |s: &StatusMsg| match bit {
        Some(b) => s.faults.contains(FaultBits::CAMERA_ERROR) && s.sensor.contains(b),
        None => s.faults.intersects(stale),
    };
    let raised = statuses(&frames)
        .find(|(t, s)| *t >= FROM && expected(s))
        .map(|(t, _)| t);
    let raised = raised.unwrap_or_else(|| panic!("{what}: the fault was never reported"));
    for (t, s) in statuses(&frames).filter(|(t, _)| (FROM + SETTLE..TO).contains(t)) {
        assert!(expected(s), "{what}: at {t:.3} s the status says {s:?}");
        assert!(
            matches!(s.state, State::Degraded | State::Fault),
            "{what}: state {} at {t:.3} s",
            s.state
        );
    }
    // Healthy again by the end of the scenario (2 s after the fault).
    let last = statuses(&frames)
        .filter(|(_, s)| s.state != State::Shutdown)
        .last()
        .map(|(_, s)| *s)
        .expect("statuses");
    assert!(
        last.sensor.is_empty() && last.faults.is_empty(),
        "{what}: still faulty at the end: {last:?}"
    );
    let cleared = statuses(&frames)
        .find(|(t, s)| *t >= TO && !expected(s))
        .map_or(f64::NAN, |(t, _)| t);
    println!(
        "{what}: reported {:.0} ms after the fault began, cleared {:.0} ms after it ended",
        (raised - FROM) * 1e3,
        (cleared - TO) * 1e3
    );
}

#[test]
fn both_cameras_black_is_a_uniform_image_fault_not_a_clear_road() {
    check(
        FaultKind::Black,
        FaultCamera::Both,
        Some(SensorFaults::UNIFORM),
        FaultBits::empty(),
    );
}

#[test]
fn both_cameras_grey_is_a_uniform_image_fault_not_a_clear_road() {
    check(
        FaultKind::Grey,
        FaultCamera::Both,
        Some(SensorFaults::UNIFORM),
        FaultBits::empty(),
    );
}

#[test]
fn both_cameras_white_is_a_uniform_image_fault_not_a_clear_road() {
    check(
        FaultKind::White,
        FaultCamera::Both,
        Some(SensorFaults::UNIFORM),
        FaultBits::empty(),
    );
}

#[test]
fn only_the_left_camera_black_is_a_uniform_image_fault() {
    check(
        FaultKind::Black,
        FaultCamera::Left,
        Some(SensorFaults::UNIFORM),
        FaultBits::empty(),
    );
}

#[test]
fn a_frozen_camera_with_fresh_timestamps_is_a_frozen_image_fault() {
    check(
        FaultKind::Frozen,
        FaultCamera::Right,
        Some(SensorFaults::FROZEN),
        FaultBits::empty(),
    );
}

#[test]
fn both_cameras_frozen_is_a_frozen_image_fault() {
    check(
        FaultKind::Frozen,
        FaultCamera::Both,
        Some(SensorFaults::FROZEN),
        FaultBits::empty(),
    );
}

#[test]
fn a_camera_delivering_noise_is_blind() {
    check(
        FaultKind::Noise,
        FaultCamera::Left,
        Some(SensorFaults::BLIND),
        FaultBits::empty(),
    );
}

#[test]
fn a_camera_stuck_at_a_dark_gain_is_a_fault() {
    // Gain 0.05: the left image keeps ~3 grey levels of contrast.
    check(
        FaultKind::Dark,
        FaultCamera::Left,
        Some(SensorFaults::UNIFORM),
        FaultBits::empty(),
    );
}

#[test]
fn a_camera_dropping_every_frame_is_stale() {
    check(
        FaultKind::Drop,
        FaultCamera::Right,
        None,
        FaultBits::RIGHT_CAMERA_STALE,
    );
}

#[test]
fn mock_faults_are_validated_with_the_config() {
    let base = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/demo.toml"),
    )
    .expect("demo.toml");
    let dir = tempfile::tempdir().expect("tempdir");
    let with = |fault: &str| {
        let text = base.replacen(
            "[calibration]",
            &format!("[[cameras.mock_faults]]\n{fault}\n\n[calibration]"),
            1,
        );
        let path = dir.path().join("c.toml");
        std::fs::write(&path, text).expect("write");
        DaemonConfig::load(&path)
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    assert_eq!(
        with("kind = \"black\"\ncamera = \"left\"\nfrom_s = 1\nto_s = 2"),
        Ok(())
    );
    for bad in [
        "kind = \"black\"\ncamera = \"left\"\nfrom_s = 2\nto_s = 1",
        "kind = \"dark\"\ncamera = \"left\"\nfrom_s = 1\nto_s = 2\ngain = 0",
        "kind = \"purple\"\ncamera = \"left\"\nfrom_s = 1\nto_s = 2",
        "kind = \"black\"\ncamera = \"middle\"\nfrom_s = 1\nto_s = 2",
        "kind = \"black\"\ncamera = \"left\"\nfrom_s = nan\nto_s = 2",
    ] {
        let e = with(bad).expect_err(bad);
        assert!(e.contains("mock_faults"), "{bad}: {e}");
    }
}
