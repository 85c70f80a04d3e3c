//! systemd notifications of the real threaded daemon, received on a datagram socket bound here
//! (the way systemd's NOTIFY_SOCKET works), which the test hands the daemon with a watchdog
//! interval (what `flyd run` reads from NOTIFY_SOCKET and WATCHDOG_USEC).

mod mock_daemon;

use std::os::unix::net::UnixDatagram;
use std::sync::atomic::Ordering;
use std::time::Duration;

use flyd_core::can::bus::BusError;
use flyd_core::status::{FaultBits, State};
use mock_daemon::*;

/// The test's `control.can_silence`.
const SILENCE: Duration = Duration::from_millis(200);

fn drain(socket: &UnixDatagram) -> Vec<String> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while let Ok(n) = socket.recv(&mut buf) {
        out.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    out
}

fn stale_statuses(frames: &[Frame]) -> usize {
    statuses(frames)
        .iter()
        .filter(|s| s.faults.contains(FaultBits::LEFT_CAMERA_STALE))
        .count()
}

#[test]
fn ready_watchdog_only_while_healthy_status_and_stopping() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&path).expect("bind");
    socket.set_nonblocking(true).expect("nonblocking");
    let notifier =
        flyd::daemon::ServiceNotifier::new(Some(&path), Some(Duration::from_millis(100)));

    let mut config = config();
    config.control.can_silence = SILENCE;
    let d = start_notifying(config, notifier);
    d.wait_for("RUNNING", |f| {
        statuses(f).iter().any(|s| s.state == State::Running)
    });
    d.wait_for("a few statuses", |f| statuses(f).len() >= 20);
    let mut got = drain(&socket);
    let ready = got
        .iter()
        .position(|m| m.lines().any(|l| l == "READY=1"))
        .expect("READY=1");
    let first_ping = got
        .iter()
        .position(|m| m == "WATCHDOG=1\n")
        .expect("watchdog pinged while healthy");
    assert!(ready < first_ping, "{got:?}");
    assert!(
        got[..ready]
            .iter()
            .any(|m| m.starts_with("EXTEND_TIMEOUT_USEC=")),
        "start timeout extended before READY: {got:?}"
    );
    assert!(got.iter().any(|m| m.starts_with("STATUS=")), "{got:?}");

    // A stalled camera stops the pings: once a status frame reports it stale, every ping sent
    // before is already in the socket (same thread, sent in order).
    d.control.stall_left.store(true, Ordering::Relaxed);
    d.wait_for("the stale fault", |f| stale_statuses(f) >= 1);
    got.extend(drain(&socket));
    d.wait_for("the stale fault to last", |f| stale_statuses(f) >= 25);
    let during = drain(&socket);
    assert!(
        !during.iter().any(|m| m == "WATCHDOG=1\n"),
        "no ping while a camera is stale: {during:?}"
    );
    d.control.stall_left.store(false, Ordering::Relaxed);
    d.wait_for("RUNNING again", |f| {
        statuses(f)
            .last()
            .is_some_and(|s| s.state == State::Running && s.faults.is_empty())
    });
    let t0 = std::time::Instant::now();
    let mut after = Vec::new();
    while !after.iter().any(|m| m == "WATCHDOG=1\n") {
        assert!(t0.elapsed() < GUARD, "pings resume after recovery");
        std::thread::sleep(Duration::from_millis(10));
        after.extend(drain(&socket));
    }
    // CAN writes failing (the adapter gone): once no frame has gone out for `can_silence`, the
    // pings stop, so systemd restarts a daemon that cannot send; they resume with the bus.
    d.bus.set_failing(Some(BusError::NoDevice {
        errno: libc::ENODEV,
    }));
    std::thread::sleep(SILENCE * 2);
    drain(&socket);
    std::thread::sleep(SILENCE * 3);
    let silent = drain(&socket);
    assert!(
        !silent.iter().any(|m| m == "WATCHDOG=1\n"),
        "no ping while nothing goes out on CAN: {silent:?}"
    );
    d.bus.set_failing(None);
    let t0 = std::time::Instant::now();
    let mut after = Vec::new();
    while !after.iter().any(|m| m == "WATCHDOG=1\n") {
        assert!(
            t0.elapsed() < GUARD,
            "pings resume when frames go out again"
        );
        std::thread::sleep(Duration::from_millis(10));
        after.extend(drain(&socket));
    }
    let _ = d.stop();
    let last = drain(&socket);
    assert!(
        last.last().is_some_and(|m| m.starts_with("STOPPING=1\n")),
        "{last:?}"
    );
}
