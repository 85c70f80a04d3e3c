use std::io::{self, Write};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver};
use flyd_core::can::candump::CAN_EFF_FLAG;

use super::*;
use flyd_core::can::candump::parse_candump_line;
use flyd_core::clock::ManualClock;

fn os(errno: i32) -> io::Error {
    io::Error::from_raw_os_error(errno)
}

#[test]
fn errno_classification() {
    let cases = [
        (libc::EAGAIN, BusError::WouldBlock, true),
        (libc::ENOBUFS, BusError::QueueFull { attempts: 1 }, true),
        (libc::ENETDOWN, BusError::InterfaceDown, true),
        (
            libc::ENODEV,
            BusError::NoDevice {
                errno: libc::ENODEV,
            },
            false,
        ),
        (
            libc::ENXIO,
            BusError::NoDevice { errno: libc::ENXIO },
            false,
        ),
        (
            libc::EAFNOSUPPORT,
            BusError::Unsupported {
                errno: libc::EAFNOSUPPORT,
            },
            false,
        ),
    ];
    for (errno, want, retryable) in cases {
        let got = classify(&os(errno));
        assert_eq!(got, want, "errno {errno}");
        assert_eq!(got.is_retryable(), retryable, "errno {errno}");
    }
    let other = classify(&os(libc::EPERM));
    assert!(matches!(other, BusError::Io { errno: Some(e), .. } if e == libc::EPERM));
    assert!(other.is_fatal());
    assert!(BusError::BusOff.is_retryable());
    assert!(BusError::InvalidFrame { id: 0x800, len: 0 }.is_fatal());
    assert_eq!(
        classify(&io::Error::from(io::ErrorKind::WouldBlock)),
        BusError::WouldBlock
    );
}

#[test]
fn retry_is_bounded_and_only_for_transient_errors() {
    let policy = RetryPolicy {
        max_attempts: 3,
        delay: Duration::from_micros(7),
    };

    // ENOBUFS forever: exactly max_attempts writes, max_attempts - 1 pauses.
    let (mut writes, mut sleeps) = (0, Vec::new());
    let result = write_with_retry(
        policy,
        || {
            writes += 1;
            Err(os(libc::ENOBUFS))
        },
        |d| sleeps.push(d),
    );
    assert_eq!(result, Err(BusError::QueueFull { attempts: 3 }));
    assert_eq!((writes, sleeps.len()), (3, 2));
    assert!(sleeps.iter().all(|&d| d == Duration::from_micros(7)));

    // Transient then success.
    let mut script = vec![Err(os(libc::EAGAIN)), Err(os(libc::ENOBUFS)), Ok(())].into_iter();
    let result = write_with_retry(policy, || script.next().unwrap_or(Ok(())), |_| {});
    assert_eq!(result, Ok(()));

    // Writes failing with `errno` under `policy`: the result and how many writes it made.
    let failing = |policy, errno| {
        let mut writes = 0;
        let result = write_with_retry(
            policy,
            || Err(os(errno)).inspect_err(|_| writes += 1),
            |_| {},
        );
        (result, writes)
    };
    // Not transient: no retry.
    assert_eq!(
        failing(policy, libc::ENETDOWN),
        (Err(BusError::InterfaceDown), 1)
    );
    // max_attempts 0 still writes once.
    let zero = RetryPolicy {
        max_attempts: 0,
        delay: Duration::ZERO,
    };
    assert_eq!(failing(zero, libc::ENOBUFS).1, 1);

    // EINTR exhausting the attempts is reported as retryable, not as an I/O failure.
    let result = write_with_retry(policy, || Err(os(libc::EINTR)), |_| {});
    assert_eq!(result, Err(BusError::WouldBlock));
}

#[test]
fn bus_off_tracking_from_error_frames() {
    use socketcan::errors::{CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED};
    assert!(next_bus_off_state(false, CAN_ERR_BUSOFF));
    assert!(next_bus_off_state(true, CAN_ERR_CRTL));
    assert!(!next_bus_off_state(true, CAN_ERR_RESTARTED));
    assert!(!next_bus_off_state(false, CAN_ERR_CRTL));
}

#[test]
fn socketcan_frames_are_built_and_checked() {
    use socketcan::{EmbeddedFrame, Id, StandardId};
    let frame = SocketCanBus::make_frame(0x120, &[1, 2, 3]).expect("valid");
    assert_eq!(
        frame.id(),
        Id::Standard(StandardId::new(0x120).expect("id"))
    );
    assert_eq!(frame.data(), &[1, 2, 3]);
    let ext = SocketCanBus::make_frame(0x1234_5678 | CAN_EFF_FLAG, &[]).expect("valid");
    assert!(ext.is_extended());
    assert!(SocketCanBus::make_frame(0x800, &[]).is_err());
    assert!(SocketCanBus::make_frame(0x120, &[0; 9]).is_err());
}

/// This machine has no CAN in its kernel: opening must fail cleanly and be classified as
/// fatal, not panic. (On a machine with vcan the open may succeed; then nothing to check.)
#[test]
fn opening_a_missing_interface_is_a_fatal_error() {
    match SocketCanBus::open("flydnotacan0", RetryPolicy::default()) {
        Ok(_) => panic!("an interface that does not exist opened"),
        Err(e) => assert!(e.is_fatal(), "{e:?}"),
    }
}

#[test]
fn memory_bus_records_with_injected_time_and_shares_state() {
    let clock = ManualClock::new(Duration::from_millis(1000));
    let handle = MemoryBus::new(clock.clone());
    let mut bus: Box<dyn CanBus> = Box::new(handle.clone());

    bus.send(0x120, &[1, 2]).expect("sent");
    clock.advance(Duration::from_millis(20));
    bus.send(0x121, &[3]).expect("sent");

    assert_eq!(
        handle.frames(),
        vec![
            RecordedFrame {
                timestamp: Duration::from_millis(1000),
                id: 0x120,
                data: vec![1, 2]
            },
            RecordedFrame {
                timestamp: Duration::from_millis(1020),
                id: 0x121,
                data: vec![3]
            },
        ]
    );
    assert_eq!(handle.take_frames().len(), 2);
    assert!(handle.frames().is_empty());
}

#[test]
fn memory_bus_simulates_failures() {
    let handle = MemoryBus::new(|| Duration::ZERO);
    let mut bus = handle.clone();
    handle.fail_next(BusError::QueueFull { attempts: 3 });
    handle.fail_next(BusError::BusOff);
    assert_eq!(
        bus.send(0x120, &[]),
        Err(BusError::QueueFull { attempts: 3 })
    );
    assert_eq!(bus.send(0x120, &[]), Err(BusError::BusOff));
    assert_eq!(bus.send(0x120, &[]), Ok(()));

    handle.set_failing(Some(BusError::InterfaceDown));
    assert_eq!(bus.send(0x120, &[]), Err(BusError::InterfaceDown));
    assert_eq!(bus.send(0x120, &[]), Err(BusError::InterfaceDown));
    handle.set_failing(None);
    assert_eq!(bus.send(0x120, &[]), Ok(()));

    assert_eq!(
        bus.send(0x800, &[]),
        Err(BusError::InvalidFrame { id: 0x800, len: 0 })
    );
    assert_eq!(handle.frames().len(), 2);
    assert_eq!(handle.attempts(), 7);
}

#[test]
fn candump_bus_writes_replayable_lines() {
    let clock = ManualClock::new(Duration::new(1_700_000_000, 123_456_000));
    let mut bus = CandumpLogBus::new(Vec::new(), "vcan0", clock.clone());
    bus.send(0x120, &[1, 2, 3, 4, 5, 6, 7, 8]).expect("written");
    clock.advance(Duration::from_millis(20));
    bus.send(0x121, &[0xAB; 8]).expect("written");
    assert!(bus.send(0x120, &[0; 9]).is_err());

    let text = String::from_utf8(bus.into_inner()).expect("utf8");
    assert_eq!(
        text,
        "(1700000000.123456) vcan0 120#0102030405060708\n\
         (1700000000.143456) vcan0 121#ABABABABABABABAB\n"
    );
    let parsed: Vec<_> = text
        .lines()
        .map(|l| parse_candump_line(l).expect("parses"))
        .collect();
    assert_eq!(parsed[1].2, 0x121);
    assert!((parsed[1].0 - parsed[0].0 - 0.020).abs() < 1e-6);
}

#[test]
fn candump_bus_classifies_write_errors() {
    struct Full;
    impl Write for Full {
        fn write(&mut self, _: &[u8]) -> io::Result<usize> {
            Err(io::Error::from_raw_os_error(libc::ENOSPC))
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }
    let mut bus = CandumpLogBus::new(Full, "vcan0", crate::os_clock::SystemClock);
    let err = bus.send(0x120, &[]).expect_err("disk full");
    assert!(err.is_fatal(), "{err:?}");
}

/// The daemon-without-hardware path: Transmitter into a candump log, read back with the
/// parser and decoded, as a canplayer replay would deliver it.
#[test]
fn candump_log_from_transmitter_decodes_back() {
    use flyd_core::can::messages::{CanMessage, CommandMsg, StatusMsg};
    use flyd_core::can::{CanConfig, Transmitter};
    use flyd_core::clock::ManualClock;
    use flyd_core::decision::{Command, CommandReason};
    use flyd_core::status::State;

    let status = StatusMsg {
        state: State::Running,
        faults: flyd_core::status::FaultBits::empty(),
        perception_age: Duration::from_millis(30),
        sensor: flyd_core::sensor::SensorFaults::empty(),
        motion_fault: false,
        generations_per_sec: 100.0,
        cam_fps_left: 30.0,
        cam_fps_right: 30.0,
    };
    let clock = ManualClock::new(Duration::from_secs(1_700_000_000));
    let log = CandumpLogBus::new(Vec::new(), "vcan0", clock.clone());
    let mut tx = Transmitter::new(log, CanConfig::default()).expect("valid");
    for _ in 0..3 {
        tx.send_command(&CommandMsg {
            command: Command::Slow,
            requested_decel: 1.5,
            global_warning: 0.42,
            reason: CommandReason::Perception,
        })
        .expect("written");
        tx.send_status(&status).expect("written");
        clock.advance(Duration::from_millis(20));
    }
    let text = String::from_utf8(tx.into_bus().into_inner()).expect("utf8");

    let mut commands = 0;
    for line in text.lines() {
        let (_, iface, id, data) = parse_candump_line(line).expect("parses");
        assert_eq!(iface, "vcan0");
        match id {
            0x120 => {
                let (msg, counter) =
                    CommandMsg::decode_with(&data, CommandMsg::DEFAULT_DATA_ID).expect("ok");
                assert_eq!(msg.command, Command::Slow);
                assert_eq!(msg.reason, CommandReason::Perception);
                assert_eq!(counter.value(), commands);
                commands += 1;
            }
            0x121 => assert_eq!(StatusMsg::decode(&data), Ok(status)),
            other => panic!("unexpected id {other:#x}"),
        }
    }
    assert_eq!(commands, 3);
}

/// An adapter that vanishes (ENODEV) is reopened with backoff, and one missing at start is
/// waited for; other open failures stay errors.
#[test]
fn a_candump_log_is_received_at_its_recorded_pace() {
    let clock = ManualClock::new(Duration::from_secs(5));
    let log = "(1700000000.100000) vcan0 110#0102030405060708\n\n\
               (1700000000.120000) vcan0 121#AA\n\
               (1700000000.600000) vcan0 110#01\n";
    let mut rx = CandumpReplayRx::parse(log, clock.clone()).expect("parses");
    assert_eq!(rx.remaining(), 3);
    let first = rx.try_recv().expect("ok").expect("due at once");
    assert_eq!(
        (first.id, first.payload()),
        (0x110, &[1, 2, 3, 4, 5, 6, 7, 8][..])
    );
    assert_eq!(rx.try_recv(), Ok(None), "the next is due 20 ms later");
    clock.advance(Duration::from_millis(20));
    assert_eq!(rx.try_recv().expect("ok").map(|f| f.len), Some(1));
    clock.advance(Duration::from_millis(480));
    let short = rx.try_recv().expect("ok").expect("due");
    assert_eq!(
        short.payload(),
        &[1],
        "a wrong DLC is kept for the decoder to reject"
    );
    assert_eq!(rx.try_recv(), Ok(None));
    let bad = CandumpReplayRx::parse("(1.0) vcan0 110#01\nnot a frame\n", clock);
    assert_eq!(bad.err().map(|(line, _)| line), Some(2));
}

#[test]
fn a_vanished_interface_is_reopened_with_backoff() {
    let clock = ManualClock::new(Duration::from_secs(1));
    let present = Arc::new(Mutex::new(false));
    let opens = Arc::new(Mutex::new(0u32));
    let bus = MemoryBus::new(clock.clone());
    let (p, o, b) = (present.clone(), opens.clone(), bus.clone());
    let mut r = ReopeningBus::new(
        "vcan0",
        move || {
            *o.lock().unwrap_or_else(PoisonError::into_inner) += 1;
            if *p.lock().unwrap_or_else(PoisonError::into_inner) {
                Ok(b.clone())
            } else {
                Err(BusError::NoDevice {
                    errno: libc::ENODEV,
                })
            }
        },
        clock.clone(),
    )
    .expect("a missing interface is waited for");
    let count = || *opens.lock().unwrap_or_else(PoisonError::into_inner);
    assert!(!r.is_open());
    assert!(matches!(
        r.send(0x120, &[1]),
        Err(BusError::NoDevice { .. })
    ));
    assert_eq!(count(), 1, "no retry before the backoff");
    clock.advance(Duration::from_millis(50));
    assert!(r.send(0x120, &[1]).is_err());
    assert_eq!(count(), 2);
    clock.advance(Duration::from_millis(60));
    assert!(r.send(0x120, &[1]).is_err());
    assert_eq!(count(), 2, "the backoff doubled to 100 ms");
    *present.lock().unwrap_or_else(PoisonError::into_inner) = true;
    clock.advance(Duration::from_millis(40));
    assert_eq!(r.send(0x120, &[2]), Ok(()));
    assert_eq!(count(), 3);
    assert_eq!(bus.frames().len(), 1);
    // The adapter vanishes: the send fails, the handle is dropped and reopened later.
    bus.fail_next(BusError::NoDevice { errno: libc::ENXIO });
    assert!(r.send(0x120, &[3]).is_err());
    assert!(!r.is_open());
    clock.advance(Duration::from_millis(50));
    assert_eq!(r.send(0x120, &[4]), Ok(()));
    assert_eq!(count(), 4);
    // Other open failures are errors at start.
    let e = ReopeningBus::new(
        "x",
        || Err::<MemoryBus, _>(BusError::Unsupported { errno: 97 }),
        clock,
    );
    assert!(e.is_err());
}
