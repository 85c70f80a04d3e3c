//! Holds the Rust encoder to `config/flyd.dbc`, the CAN contract.
//!
//! Everything about the layout (start bits, lengths, byte order, signedness, factors, offsets,
//! ranges, value tables, IDs, cycle times, Data IDs) is read from the DBC with can-dbc; the test
//! only states *physical* values and enum *names*. A change on one side without the other fails
//! here.

use std::collections::BTreeSet;
use std::time::Duration;

mod dbc_signals;

use can_dbc::{AttributeValue, ByteOrder, Dbc, Message, Signal};
use dbc_signals::{raw_value, value_table};
use flyd_core::can::crc::e2e_crc;
use flyd_core::can::messages::{
    AliveCounter, CanMessage, CommandMsg, MotionMsg, ObstacleMotionMsg, ObstacleMsg, PathMsg,
    StatusMsg,
};
use flyd_core::can::{CanConfig, MessageConfig};
use flyd_core::decision::{Command, CommandReason};
use flyd_core::sensor::SensorFaults;
use flyd_core::status::{FaultBits, State};

fn load() -> Dbc {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/flyd.dbc");
    let text = std::fs::read_to_string(path).expect("config/flyd.dbc is readable");
    Dbc::try_from(text.as_str()).expect("config/flyd.dbc parses")
}

fn message<'a>(dbc: &'a Dbc, name: &str) -> &'a Message {
    dbc.messages
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("message {name} missing from the DBC"))
}

fn signal<'a>(msg: &'a Message, name: &str) -> &'a Signal {
    msg.signals
        .iter()
        .find(|s| s.name == name)
        .unwrap_or_else(|| panic!("signal {}.{name} missing from the DBC", msg.name))
}

fn attr_u64(value: Option<&AttributeValue>, what: &str) -> u64 {
    match value {
        Some(AttributeValue::Uint(v)) => *v,
        Some(AttributeValue::Int(v)) => u64::try_from(*v).expect("non-negative"),
        Some(AttributeValue::Double(v)) if v.fract() == 0.0 && *v >= 0.0 => *v as u64,
        other => panic!("{what}: expected an integer attribute, got {other:?}"),
    }
}

fn numeric(v: &can_dbc::NumericValue) -> f64 {
    match v {
        can_dbc::NumericValue::Uint(u) => *u as f64,
        can_dbc::NumericValue::Int(i) => *i as f64,
        can_dbc::NumericValue::Double(d) => *d,
    }
}

/// The raw value of `sig` in `data`, extracted by the DBC's definition of an Intel signal:
/// bits `start_bit .. start_bit + size` of the frame read as a little-endian integer.
fn physical(sig: &Signal, data: &[u8; 8]) -> f64 {
    raw_value(sig, data) as f64 * sig.factor + sig.offset
}

/// The raw value the DBC's value table gives to `label` for `signal` of `msg`.
fn value_of(dbc: &Dbc, msg: &Message, signal: &str, label: &str) -> i64 {
    value_table(dbc, msg, signal)
        .iter()
        .find(|(_, l)| l == label)
        .map(|(v, _)| *v)
        .unwrap_or_else(|| panic!("{}.{signal}: no value named {label} in the DBC", msg.name))
}

fn data_id(dbc: &Dbc, msg: &Message) -> u16 {
    let v = attr_u64(
        dbc.message_attribute(msg.id, "FlydE2EDataID"),
        &format!("{} FlydE2EDataID", msg.name),
    );
    u16::try_from(v).expect("Data ID fits 16 bits")
}

/// What a signal must read as in an encoded frame.
#[derive(Debug, Clone, Copy)]
enum Want {
    /// This physical value (within a thousandth of a raw step).
    Phys(f64),
    /// The raw value the DBC value table names so.
    Named(&'static str),
    /// The E2E CRC of the frame, with the DBC's Data ID.
    Crc,
    /// The alive counter the frame was encoded with.
    Counter,
}

struct Case {
    message: &'static str,
    counter: u8,
    data: [u8; 8],
    want: Vec<(&'static str, Want)>,
}

fn counter(v: u8) -> AliveCounter {
    AliveCounter::new(v).expect("counter in range")
}

/// The case of `msg` sent with counter `c`: the E2E signals, then `signals`.
fn case<M: CanMessage>(msg: &M, c: u8, signals: Vec<(&'static str, Want)>) -> Case {
    let e2e = [("CRC8", Want::Crc), ("AliveCounter", Want::Counter)];
    Case {
        message: M::NAME,
        counter: c,
        data: msg.encode_with(counter(c), M::DEFAULT_DATA_ID),
        want: e2e.into_iter().chain(signals).collect(),
    }
}

fn command_case(msg: CommandMsg, c: u8) -> Case {
    let signals = vec![
        ("Command", Want::Named(msg.command.name())),
        ("RequestedDecel", Want::Phys(msg.requested_decel)),
        ("GlobalWarning", Want::Phys(msg.global_warning)),
        ("CommandReason", Want::Named(msg.reason.name())),
    ];
    case(&msg, c, signals)
}

fn status_case(msg: StatusMsg, c: u8) -> Case {
    let age = msg.perception_age.as_millis() as f64;
    let signals = vec![
        ("State", Want::Named(msg.state.name())),
        (
            "MotionFault",
            Want::Named(if msg.motion_fault { "UNKNOWN" } else { "OK" }),
        ),
        ("FaultBits", Want::Phys(f64::from(msg.faults.bits()))),
        ("PerceptionAgeMs", Want::Phys(age)),
        ("SensorFaults", Want::Phys(f64::from(msg.sensor.bits()))),
        ("GenerationsPerSec", Want::Phys(msg.generations_per_sec)),
        ("CamFpsLeft", Want::Phys(msg.cam_fps_left)),
        ("CamFpsRight", Want::Phys(msg.cam_fps_right)),
    ];
    case(&msg, c, signals)
}

fn obstacle_case(msg: ObstacleMsg, c: u8) -> Case {
    let valid = if msg.valid { "VALID" } else { "NO_OBSTACLE" };
    let confirmed = if msg.confirmed {
        "CONFIRMED"
    } else {
        "UNCONFIRMED"
    };
    let road = if msg.road_measured {
        "MEASURED"
    } else {
        "PRIOR"
    };
    let signals = vec![
        ("ObstacleValid", Want::Named(valid)),
        ("Distance", Want::Phys(msg.distance)),
        ("Lateral", Want::Phys(msg.lateral)),
        ("Confidence", Want::Phys(msg.confidence)),
        ("ObstacleConfirmed", Want::Named(confirmed)),
        ("RoadMeasured", Want::Named(road)),
        ("Height", Want::Phys(msg.height)),
    ];
    case(&msg, c, signals)
}

fn path_case(msg: PathMsg, c: u8) -> Case {
    let valid = if msg.valid { "VALID" } else { "STRAIGHT" };
    let signals = vec![
        ("PathValid", Want::Named(valid)),
        ("Curvature", Want::Phys(msg.curvature)),
        ("CurvatureNow", Want::Phys(msg.curvature_now)),
    ];
    case(&msg, c, signals)
}

fn obstacle_motion_case(msg: ObstacleMotionMsg, c: u8) -> Case {
    let valid = if msg.obstacle_valid {
        "VALID"
    } else {
        "NO_OBSTACLE"
    };
    let motion = if msg.motion_valid {
        "ESTABLISHED"
    } else {
        "TAKEN_AS_STILL"
    };
    let ttc = if msg.time_to_collision >= flyd_core::can::messages::NOT_CLOSING {
        Want::Named("NOT_CLOSING")
    } else {
        Want::Phys(msg.time_to_collision)
    };
    let signals = vec![
        ("ObstacleValid", Want::Named(valid)),
        ("MotionValid", Want::Named(motion)),
        ("ClosingSpeed", Want::Phys(msg.closing_speed)),
        ("TimeToCollision", ttc),
        ("Speed", Want::Phys(msg.speed)),
    ];
    case(&msg, c, signals)
}

fn motion_case(msg: MotionMsg, c: u8) -> Case {
    let valid = if msg.valid { "VALID" } else { "INVALID" };
    let signals = vec![
        ("MotionValid", Want::Named(valid)),
        ("Speed", Want::Phys(msg.speed)),
        ("YawRate", Want::Phys(msg.yaw_rate)),
    ];
    case(&msg, c, signals)
}

/// Distinct, representable values for every signal, several frames per message so that no
/// signal is only ever checked at 0.
fn cases() -> Vec<Case> {
    vec![
        command_case(
            CommandMsg {
                command: Command::Stop,
                requested_decel: 4.25,
                global_warning: 0.734,
                reason: CommandReason::Perception,
            },
            5,
        ),
        command_case(
            CommandMsg {
                command: Command::Slow,
                requested_decel: 1.5,
                global_warning: 12.5,
                reason: CommandReason::FaultFallback,
            },
            14,
        ),
        command_case(
            CommandMsg {
                command: Command::Clear,
                requested_decel: 0.0,
                global_warning: 0.001,
                reason: CommandReason::Shutdown,
            },
            0,
        ),
        status_case(
            StatusMsg {
                state: State::Degraded,
                faults: FaultBits::LEFT_CAMERA_STALE | FaultBits::CAN_TX_ERROR,
                perception_age: Duration::from_millis(1234),
                sensor: SensorFaults::UNIFORM | SensorFaults::BLIND,
                motion_fault: true,
                generations_per_sec: 118.0,
                cam_fps_left: 29.5,
                cam_fps_right: 30.0,
            },
            3,
        ),
        status_case(
            StatusMsg {
                state: State::Shutdown,
                faults: FaultBits::all(),
                perception_age: Duration::from_millis(4095),
                sensor: SensorFaults::from_bits(0x0F),
                motion_fault: false,
                generations_per_sec: 510.0,
                cam_fps_left: 127.5,
                cam_fps_right: 0.5,
            },
            14,
        ),
        status_case(
            StatusMsg {
                state: State::Init,
                faults: FaultBits::SNAPSHOT_STALE,
                perception_age: Duration::from_millis(7),
                sensor: SensorFaults::FROZEN,
                motion_fault: true,
                generations_per_sec: 2.0,
                cam_fps_left: 0.0,
                cam_fps_right: 15.0,
            },
            9,
        ),
        obstacle_case(
            ObstacleMsg {
                valid: true,
                distance: 12.34,
                lateral: -1.5,
                confidence: 87.0,
                confirmed: true,
                height: 1.72,
                road_measured: true,
            },
            1,
        ),
        obstacle_case(
            ObstacleMsg {
                valid: true,
                distance: 655.35,
                lateral: 327.67,
                confidence: 100.0,
                confirmed: false,
                height: 5.1,
                road_measured: false,
            },
            13,
        ),
        obstacle_case(ObstacleMsg::NONE, 0),
        path_case(
            PathMsg {
                valid: true,
                curvature: 0.01667,
                curvature_now: -0.2,
            },
            5,
        ),
        path_case(
            PathMsg {
                valid: true,
                curvature: -0.32768,
                curvature_now: 0.32767,
            },
            11,
        ),
        path_case(PathMsg::NONE, 0),
        obstacle_motion_case(
            ObstacleMotionMsg {
                obstacle_valid: true,
                motion_valid: true,
                closing_speed: 1.25,
                time_to_collision: 11.2,
                speed: 12.64,
            },
            6,
        ),
        obstacle_motion_case(
            ObstacleMotionMsg {
                obstacle_valid: true,
                motion_valid: false,
                closing_speed: -327.68,
                time_to_collision: flyd_core::can::messages::NOT_CLOSING,
                speed: 327.67,
            },
            13,
        ),
        obstacle_motion_case(ObstacleMotionMsg::NONE, 2),
        motion_case(
            MotionMsg {
                valid: true,
                speed: 13.89,
                yaw_rate: -0.1234,
            },
            4,
        ),
        motion_case(
            MotionMsg {
                valid: true,
                speed: -327.68,
                yaw_rate: 3.2767,
            },
            14,
        ),
        motion_case(
            MotionMsg {
                valid: false,
                speed: 0.0,
                yaw_rate: 0.0,
            },
            0,
        ),
        obstacle_case(
            ObstacleMsg {
                road_measured: true,
                ..ObstacleMsg::NONE
            },
            7,
        ),
    ]
}

#[test]
fn encoder_writes_every_signal_where_the_dbc_says() {
    let dbc = load();
    let mut covered: BTreeSet<(String, String)> = BTreeSet::new();

    for case in cases() {
        let msg = message(&dbc, case.message);
        let names_in_case: BTreeSet<&str> = case.want.iter().map(|(n, _)| *n).collect();
        let names_in_dbc: BTreeSet<&str> = msg.signals.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names_in_case, names_in_dbc,
            "{}: the encoder's signals and the DBC's differ",
            msg.name
        );

        for (name, want) in &case.want {
            let sig = signal(msg, name);
            covered.insert((msg.name.clone(), sig.name.clone()));
            let raw = raw_value(sig, &case.data);
            let phys = physical(sig, &case.data);
            let context = format!("{}.{name} in {:02X?} ({want:?})", msg.name, case.data);
            match *want {
                Want::Phys(v) => assert!(
                    (phys - v).abs() <= sig.factor.abs() * 1e-3,
                    "{context}: DBC reads {phys}, encoder was given {v}"
                ),
                Want::Named(label) => {
                    assert_eq!(raw, value_of(&dbc, msg, name, label), "{context}")
                }
                Want::Crc => assert_eq!(
                    raw,
                    i64::from(e2e_crc(data_id(&dbc, msg), &case.data[1..])),
                    "{context}"
                ),
                Want::Counter => assert_eq!(raw, i64::from(case.counter), "{context}"),
            }
            let (min, max) = (numeric(&sig.min), numeric(&sig.max));
            assert!(
                phys >= min - 1e-9 && phys <= max + 1e-9,
                "{context}: {phys} outside the DBC range [{min}|{max}]"
            );
        }

        // Bits no signal covers are reserved: the encoder must leave them 0.
        let word = u64::from_le_bytes(case.data);
        let used = msg.signals.iter().fold(0u64, |acc, s| {
            let mask = if s.size == 64 {
                u64::MAX
            } else {
                (1u64 << s.size) - 1
            };
            acc | (mask << s.start_bit)
        });
        assert_eq!(word & !used, 0, "{}: reserved bits set", msg.name);
    }

    let all: BTreeSet<(String, String)> = dbc
        .messages
        .iter()
        .flat_map(|m| m.signals.iter().map(|s| (m.name.clone(), s.name.clone())))
        .collect();
    assert_eq!(covered, all, "some DBC signals are never checked");
}

#[test]
fn dbc_frames_are_well_formed() {
    let dbc = load();
    assert_eq!(dbc.messages.len(), 6);
    for msg in &dbc.messages {
        assert_eq!(msg.size, 8, "{}", msg.name);
        assert!(
            matches!(msg.id, can_dbc::MessageId::Standard(id) if id <= 0x7FF),
            "{}: standard 11-bit ID",
            msg.name
        );
        let mut used = 0u64;
        for s in &msg.signals {
            assert_eq!(
                s.byte_order,
                ByteOrder::LittleEndian,
                "{}.{}",
                msg.name,
                s.name
            );
            assert!(s.start_bit + s.size <= 64, "{}.{}", msg.name, s.name);
            let mask = ((1u128 << s.size) - 1) as u64;
            assert_eq!(
                used & (mask << s.start_bit),
                0,
                "{}.{} overlaps",
                msg.name,
                s.name
            );
            used |= mask << s.start_bit;
        }
        // The E2E header is part of every message.
        signal(msg, "CRC8");
        let counter = signal(msg, "AliveCounter");
        assert_eq!(numeric(&counter.max), f64::from(AliveCounter::MAX));
        assert!(
            dbc.message_comment(msg.id).is_some(),
            "{}: no comment",
            msg.name
        );
        for s in &msg.signals {
            assert!(
                dbc.signal_comment(msg.id, &s.name).is_some(),
                "{}.{}: no comment",
                msg.name,
                s.name
            );
        }
    }
}

#[test]
fn ids_data_ids_and_cycle_times_match_the_rust_defaults() {
    fn check<M: CanMessage>(dbc: &Dbc, configured: MessageConfig) {
        let msg = message(dbc, M::NAME);
        assert_eq!(msg.id.raw(), M::DEFAULT_ID, "{} CAN ID", M::NAME);
        assert_eq!(
            msg.id.raw(),
            configured.id,
            "{} CAN ID in CanConfig",
            M::NAME
        );
        assert_eq!(data_id(dbc, msg), M::DEFAULT_DATA_ID, "{} Data ID", M::NAME);
        assert_eq!(data_id(dbc, msg), configured.data_id, "{} Data ID", M::NAME);
        let cycle = attr_u64(
            dbc.message_attribute(msg.id, "GenMsgCycleTime"),
            &format!("{} GenMsgCycleTime", M::NAME),
        );
        assert_eq!(
            Duration::from_millis(cycle),
            M::DEFAULT_PERIOD,
            "{} period",
            M::NAME
        );
        assert_eq!(u64::from(configured.period_ms), cycle, "{} period", M::NAME);
    }
    let dbc = load();
    let cfg = CanConfig::default();
    check::<CommandMsg>(&dbc, cfg.command);
    check::<StatusMsg>(&dbc, cfg.status);
    check::<ObstacleMsg>(&dbc, cfg.obstacle);
    check::<PathMsg>(&dbc, cfg.path);
    check::<ObstacleMotionMsg>(&dbc, cfg.obstacle_motion);
    check::<MotionMsg>(&dbc, cfg.motion);
}

/// The Rust enums and the DBC value tables name the same values the same way, both directions.
#[test]
fn enums_match_the_value_tables() {
    fn check(dbc: &Dbc, msg_name: &str, signal_name: &str, rust: Vec<(u8, &'static str)>) {
        let msg = message(dbc, msg_name);
        let mut table = value_table(dbc, msg, signal_name);
        table.sort();
        let mut rust: Vec<(i64, String)> = rust
            .into_iter()
            .map(|(v, n)| (i64::from(v), n.to_owned()))
            .collect();
        rust.sort();
        assert_eq!(table, rust, "{msg_name}.{signal_name}");
        let sig = signal(msg, signal_name);
        let max_raw = rust.iter().map(|(v, _)| *v).max().unwrap_or(0) as f64;
        assert_eq!(
            (numeric(&sig.min), numeric(&sig.max)),
            (0.0, max_raw),
            "{msg_name}.{signal_name} range"
        );
    }
    let dbc = load();
    check(
        &dbc,
        CommandMsg::NAME,
        "Command",
        Command::ALL.iter().map(|c| (c.raw(), c.name())).collect(),
    );
    check(
        &dbc,
        CommandMsg::NAME,
        "CommandReason",
        CommandReason::ALL
            .iter()
            .map(|c| (c.raw(), c.name()))
            .collect(),
    );
    check(
        &dbc,
        StatusMsg::NAME,
        "State",
        State::ALL.iter().map(|c| (c.raw(), c.name())).collect(),
    );
}

/// Out-of-range inputs land exactly on the DBC's [min|max], and a NaN warning on the DBC's
/// INVALID value.
#[test]
fn saturation_matches_the_dbc_ranges() {
    type Build = fn(f64) -> [u8; 8];
    let c = counter(0);
    let builds: Vec<(&str, &str, Build)> = vec![
        (CommandMsg::NAME, "RequestedDecel", |v| {
            command_with(|m| m.requested_decel = v)
        }),
        (CommandMsg::NAME, "GlobalWarning", |v| {
            command_with(|m| m.global_warning = v)
        }),
        (StatusMsg::NAME, "PerceptionAgeMs", |v| {
            status_with(|m| {
                m.perception_age = if v > 0.0 {
                    Duration::MAX
                } else {
                    Duration::ZERO
                }
            })
        }),
        (StatusMsg::NAME, "GenerationsPerSec", |v| {
            status_with(|m| m.generations_per_sec = v)
        }),
        (StatusMsg::NAME, "CamFpsLeft", |v| {
            status_with(|m| m.cam_fps_left = v)
        }),
        (StatusMsg::NAME, "CamFpsRight", |v| {
            status_with(|m| m.cam_fps_right = v)
        }),
        (ObstacleMsg::NAME, "Distance", |v| {
            obstacle_with(|m| m.distance = v)
        }),
        (ObstacleMsg::NAME, "Lateral", |v| {
            obstacle_with(|m| m.lateral = v)
        }),
        (ObstacleMsg::NAME, "Confidence", |v| {
            obstacle_with(|m| m.confidence = v)
        }),
        (ObstacleMsg::NAME, "Height", |v| {
            obstacle_with(|m| m.height = v)
        }),
        (PathMsg::NAME, "Curvature", |v| {
            path_with(|m| m.curvature = v)
        }),
        (PathMsg::NAME, "CurvatureNow", |v| {
            path_with(|m| m.curvature_now = v)
        }),
    ];
    let dbc = load();
    for (msg_name, sig_name, build) in builds {
        let msg = message(&dbc, msg_name);
        let sig = signal(msg, sig_name);
        for (input, want) in [(1e12, numeric(&sig.max)), (-1e12, numeric(&sig.min))] {
            let got = physical(sig, &build(input));
            assert!(
                (got - want).abs() <= sig.factor.abs() * 1e-3,
                "{msg_name}.{sig_name}: {input} encoded as {got}, DBC range end is {want}"
            );
        }
    }

    let msg = message(&dbc, CommandMsg::NAME);
    let sig = signal(msg, "GlobalWarning");
    let nan = CommandMsg {
        global_warning: f64::NAN,
        ..base_command()
    }
    .encode(c);
    assert_eq!(
        raw_value(sig, &nan),
        value_of(&dbc, msg, "GlobalWarning", "INVALID")
    );
}

fn base_command() -> CommandMsg {
    CommandMsg {
        command: Command::Slow,
        requested_decel: 1.0,
        global_warning: 0.5,
        reason: CommandReason::Perception,
    }
}

fn command_with(f: impl FnOnce(&mut CommandMsg)) -> [u8; 8] {
    let mut m = base_command();
    f(&mut m);
    m.encode(AliveCounter::ZERO)
}

fn status_with(f: impl FnOnce(&mut StatusMsg)) -> [u8; 8] {
    let mut m = StatusMsg {
        state: State::Running,
        faults: FaultBits::empty(),
        perception_age: Duration::from_millis(20),
        sensor: SensorFaults::empty(),
        motion_fault: false,
        generations_per_sec: 100.0,
        cam_fps_left: 30.0,
        cam_fps_right: 30.0,
    };
    f(&mut m);
    m.encode(AliveCounter::ZERO)
}

fn path_with(f: impl FnOnce(&mut PathMsg)) -> [u8; 8] {
    let mut m = PathMsg {
        valid: true,
        curvature: 0.01,
        curvature_now: 0.01,
    };
    f(&mut m);
    m.encode(AliveCounter::ZERO)
}

fn obstacle_with(f: impl FnOnce(&mut ObstacleMsg)) -> [u8; 8] {
    let mut m = ObstacleMsg {
        valid: true,
        distance: 10.0,
        lateral: 0.0,
        confidence: 50.0,
        confirmed: true,
        height: 1.5,
        road_measured: true,
    };
    f(&mut m);
    m.encode(AliveCounter::ZERO)
}

/// The received message, the other way round: a frame laid out from the DBC alone (start
/// bits, sizes, factors, the Data ID attribute), as a VCU built from the DBC would send it,
/// decodes in flyd to the same physical values and is accepted by its motion monitor.
#[test]
fn a_motion_frame_built_from_the_dbc_decodes() {
    use flyd_core::can::motion_monitor::{MotionConfig, MotionMonitor};
    let dbc = load();
    let msg = message(&dbc, MotionMsg::NAME);
    let build = |values: &[(&str, f64)], counter: u8| {
        let mut word = 0u64;
        for (name, phys) in values
            .iter()
            .copied()
            .chain([("AliveCounter", f64::from(counter))])
        {
            let sig = signal(msg, name);
            let raw = ((phys - sig.offset) / sig.factor).round() as i64;
            let mask = (1u64 << sig.size) - 1;
            word |= ((raw as u64) & mask) << sig.start_bit;
        }
        let mut data = word.to_le_bytes();
        data[0] = e2e_crc(data_id(&dbc, msg), &data[1..]);
        data
    };
    let values = [("MotionValid", 1.0), ("Speed", -3.21), ("YawRate", 0.4321)];
    let data = build(&values, 7);
    let (decoded, c) = MotionMsg::decode_with(&data, MotionMsg::DEFAULT_DATA_ID).expect("decodes");
    assert_eq!(c, counter(7));
    assert_eq!(
        decoded,
        MotionMsg {
            valid: true,
            speed: -3.21,
            yaw_rate: 0.4321
        }
    );
    let mut monitor = MotionMonitor::new(MotionConfig::default());
    let ms = Duration::from_millis;
    let speed = [("MotionValid", 1.0), ("Speed", 8.0), ("YawRate", 0.0)];
    monitor.receive(&build(&speed, 0), ms(0)).expect("accepted");
    monitor
        .receive(&build(&speed, 1), ms(20))
        .expect("accepted");
    assert_eq!(monitor.decision_speed(ms(25), 20.0), 8.0);
}

/// A third-party reader decodes every case's frame as the case says: cantools (PyPI, from
/// target/py: scripts/prereqs) loads `config/flyd.dbc` and decodes the frames the Rust
/// encoder wrote, physical values and value-table names.
#[test]
fn cantools_decodes_the_frames_the_encoder_writes() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let py = std::env::var_os("FLYD_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root.join("target/py/bin/python3"));
    let have = std::process::Command::new(&py)
        .args(["-c", "import cantools"])
        .status()
        .is_ok_and(|s| s.success());
    if !have {
        if std::env::var_os("FLYD_ALLOW_NO_PY").is_some() {
            println!("SKIP: cantools not in target/py: the frames are not decoded by it");
            return;
        }
        panic!("cantools not found in target/py: run scripts/prereqs (or FLYD_ALLOW_NO_PY=1)");
    }
    let cases = cases();
    let frames: String = cases
        .iter()
        .map(|c| {
            let hex: String = c.data.iter().map(|b| format!("{b:02x}")).collect();
            format!("{} {hex}\n", c.message)
        })
        .collect();
    let script = r#"
import sys, json, cantools
db = cantools.database.load_file(sys.argv[1])
for line in sys.stdin:
    name, data = line.split()
    msg = db.get_message_by_name(name)
    decoded = msg.decode(bytes.fromhex(data), decode_choices=True)
    print(json.dumps({k: (str(v) if not isinstance(v, (int, float)) else v) for k, v in decoded.items()}))
"#;
    let mut child = std::process::Command::new(&py)
        .args([
            "-c",
            script,
            &root.join("config/flyd.dbc").to_string_lossy(),
        ])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("python runs");
    {
        use std::io::Write;
        let mut stdin = child.stdin.take().expect("stdin");
        stdin.write_all(frames.as_bytes()).expect("frames written");
    }
    let out = child.wait_with_output().expect("python ends");
    assert!(
        out.status.success(),
        "cantools failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), cases.len(), "{text}");
    let dbc = load();
    for (case, line) in cases.iter().zip(lines) {
        let decoded: serde_json::Value = serde_json::from_str(line).expect("json");
        for (name, want) in &case.want {
            let got = &decoded[*name];
            let context = format!("{}.{name}: cantools gave {got} ({want:?})", case.message);
            match *want {
                Want::Phys(v) => {
                    let step = signal(message(&dbc, case.message), name).factor.abs();
                    let got = got.as_f64().unwrap_or(f64::NAN);
                    assert!((got - v).abs() <= step * 0.501, "{context}");
                }
                Want::Named(label) => assert_eq!(got.as_str(), Some(label), "{context}"),
                Want::Crc | Want::Counter => assert!(got.is_number(), "{context}"),
            }
        }
    }
}
