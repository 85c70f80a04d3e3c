use super::*;
use crate::decision::{Command, CommandReason};
use crate::sensor::SensorFaults;
use crate::status::{FaultBits, State};

#[test]
fn command_msg_carries_the_decision() {
    use crate::decision::{Decider, DecisionConfig, DecisionInput};
    let mut decider = Decider::new(DecisionConfig::default()).expect("valid");
    let input = DecisionInput {
        global_warning: 9.0,
        ..DecisionInput::at_speed(Some(3.0), 30.0 / 3.6)
    };
    let d = decider.update(input, Duration::ZERO);
    let msg = CommandMsg::of(&d, 9.0);
    assert_eq!(
        (
            msg.command,
            msg.requested_decel,
            msg.global_warning,
            msg.reason
        ),
        // 3 m ahead at 30 km/h leaves no room: the most a STOP asks for.
        (Command::Stop, 9.0, 9.0, CommandReason::Perception)
    );
}
use crate::can::crc::crc8_j1850;

fn c(v: u8) -> AliveCounter {
    AliveCounter::new(v).expect("valid counter")
}

fn sample_command() -> CommandMsg {
    CommandMsg {
        command: Command::Stop,
        requested_decel: 4.25,
        global_warning: 0.734,
        reason: CommandReason::Perception,
    }
}

#[test]
fn counter_wraps_after_14_and_never_yields_15() {
    let mut counter = AliveCounter::ZERO;
    let seen: Vec<u8> = (0..31).map(|_| counter.advance().value()).collect();
    let want: Vec<u8> = (0..31).map(|i| (i % 15) as u8).collect();
    assert_eq!(seen, want);
    assert_eq!(AliveCounter::new(15), None);
    assert_eq!(c(14).next(), c(0));
}

#[test]
fn counter_delta_is_modulo_15() {
    assert_eq!(c(3).delta(c(3)), 0);
    assert_eq!(c(3).delta(c(4)), 1);
    assert_eq!(c(14).delta(c(0)), 1);
    assert_eq!(c(13).delta(c(2)), 4);
}

#[test]
fn known_command_frame() {
    // Hand-computed: Command=2 in the high nibble of byte 1 with counter 5 in the low
    // nibble; decel 4.25 -> 425 = 0x01A9; warning 0.734 -> 734 = 0x02DE; reason 0.
    let bytes = sample_command().encode(c(5));
    assert_eq!(&bytes[1..], &[0x25, 0xA9, 0x01, 0xDE, 0x02, 0x00, 0x00]);
    let mut crc_input = vec![0x20, 0x01];
    crc_input.extend_from_slice(&bytes[1..]);
    assert_eq!(bytes[0], crc8_j1850(&crc_input));
}

#[test]
fn roundtrips() {
    let cmd = sample_command();
    let (back, counter) = CommandMsg::decode_with(&cmd.encode(c(9)), 0x0120).expect("decodes");
    assert_eq!(counter, c(9));
    assert_eq!(back, cmd);

    let status = StatusMsg {
        state: State::Fault,
        faults: FaultBits::STEREO_SKEW | FaultBits::INTERNAL,
        perception_age: Duration::from_millis(987),
        sensor: SensorFaults::FROZEN | SensorFaults::BLIND,
        motion_fault: true,
        generations_per_sec: 64.0,
        cam_fps_left: 14.5,
        cam_fps_right: 15.0,
    };
    assert_eq!(StatusMsg::decode(&status.encode(c(14))), Ok(status));

    let obstacle = ObstacleMsg {
        valid: true,
        distance: 12.34,
        lateral: -1.5,
        confidence: 87.0,
        confirmed: true,
        height: 1.76,
        road_measured: true,
    };
    assert_eq!(ObstacleMsg::decode(&obstacle.encode(c(0))), Ok(obstacle));
    let road_only = ObstacleMsg {
        road_measured: true,
        ..ObstacleMsg::NONE
    };
    assert_eq!(ObstacleMsg::decode(&road_only.encode(c(2))), Ok(road_only));
    assert_eq!(
        ObstacleMsg::decode(&ObstacleMsg::NONE.encode(c(1))),
        Ok(ObstacleMsg::NONE)
    );
}

#[test]
fn every_enum_value_roundtrips() {
    for &command in Command::ALL {
        for &reason in CommandReason::ALL {
            let msg = CommandMsg {
                command,
                reason,
                ..sample_command()
            };
            assert_eq!(CommandMsg::decode(&msg.encode(c(1))), Ok(msg));
        }
    }
    for &state in State::ALL {
        let msg = StatusMsg {
            state,
            faults: FaultBits::all(),
            perception_age: Duration::ZERO,
            sensor: SensorFaults::from_bits(0x0F),
            motion_fault: false,
            generations_per_sec: 0.0,
            cam_fps_left: 0.0,
            cam_fps_right: 0.0,
        };
        assert_eq!(StatusMsg::decode(&msg.encode(c(1))), Ok(msg));
    }
}

#[test]
fn values_saturate_instead_of_wrapping() {
    let cmd = CommandMsg {
        requested_decel: 1e9,
        global_warning: 1e9,
        ..sample_command()
    };
    let back = CommandMsg::decode(&cmd.encode(c(0))).expect("decodes");
    assert_eq!(back.requested_decel, 655.35);
    assert_eq!(back.global_warning, CommandMsg::GLOBAL_WARNING_MAX);

    let neg = CommandMsg {
        requested_decel: -3.0,
        global_warning: -1.0,
        ..sample_command()
    };
    let back = CommandMsg::decode(&neg.encode(c(0))).expect("decodes");
    assert_eq!((back.requested_decel, back.global_warning), (0.0, 0.0));

    let inf = CommandMsg {
        global_warning: f64::INFINITY,
        ..sample_command()
    };
    let back = CommandMsg::decode(&inf.encode(c(0))).expect("decodes");
    assert_eq!(back.global_warning, CommandMsg::GLOBAL_WARNING_MAX);

    let status = StatusMsg {
        state: State::Running,
        faults: FaultBits::empty(),
        perception_age: Duration::MAX,
        sensor: SensorFaults::empty(),
        motion_fault: false,
        generations_per_sec: 5000.0,
        cam_fps_left: 1000.0,
        cam_fps_right: -5.0,
    };
    let back = StatusMsg::decode(&status.encode(c(0))).expect("decodes");
    assert_eq!(back.perception_age, Duration::from_millis(4095));
    assert_eq!(back.generations_per_sec, 510.0);
    assert_eq!(back.cam_fps_left, 127.5);
    assert_eq!(back.cam_fps_right, 0.0);

    let far = ObstacleMsg {
        valid: true,
        distance: 700.0,
        lateral: -400.0,
        confidence: 250.0,
        confirmed: false,
        height: 9.0,
        road_measured: false,
    };
    let back = ObstacleMsg::decode(&far.encode(c(0))).expect("decodes");
    assert_eq!(back.height, 5.1);
    assert_eq!(back.distance, 655.35);
    assert_eq!(back.lateral, -327.68);
    assert_eq!(back.confidence, 100.0);
    let right = ObstacleMsg {
        lateral: 400.0,
        ..far
    };
    let back = ObstacleMsg::decode(&right.encode(c(0))).expect("decodes");
    assert_eq!(back.lateral, 327.67);
}

#[test]
fn nan_warning_is_sent_as_invalid() {
    let cmd = CommandMsg {
        global_warning: f64::NAN,
        ..sample_command()
    };
    let bytes = cmd.encode(c(0));
    assert_eq!(&bytes[4..6], &[0xFF, 0xFF]);
    let back = CommandMsg::decode(&bytes).expect("decodes");
    assert!(back.global_warning.is_nan());
}

#[test]
fn obstacle_without_finite_position_is_sent_as_none() {
    for bad in [f64::NAN, f64::INFINITY] {
        let msg = ObstacleMsg {
            valid: true,
            distance: bad,
            lateral: 0.0,
            confidence: 50.0,
            confirmed: true,
            height: 1.7,
            road_measured: false,
        };
        assert_eq!(
            ObstacleMsg::decode(&msg.encode(c(2))),
            Ok(ObstacleMsg::NONE)
        );
    }
}

#[test]
fn decode_rejects_bad_frames() {
    let good = sample_command().encode(c(3));
    assert_eq!(
        CommandMsg::decode(&good[..7]),
        Err(DecodeError::WrongLength { actual: 7 })
    );

    // Any single bit flip in bytes 0..=7 must be caught by the CRC.
    for byte in 0..FRAME_LEN {
        for bit in 0..8 {
            let mut bad = good;
            bad[byte] ^= 1 << bit;
            assert!(
                matches!(
                    CommandMsg::decode(&bad),
                    Err(DecodeError::CrcMismatch { .. })
                ),
                "flip byte {byte} bit {bit} not detected"
            );
        }
    }

    // Right layout, wrong Data ID (e.g. a Status frame read as a Command).
    assert!(matches!(
        CommandMsg::decode_with(&good, StatusMsg::DEFAULT_DATA_ID),
        Err(DecodeError::CrcMismatch { .. })
    ));
}

/// Frames with a correct CRC but a field out of range (as a faulty sender could produce).
#[test]
fn decode_rejects_out_of_range_values() {
    fn resealed(mut bytes: [u8; 8], data_id: u16) -> [u8; 8] {
        bytes[0] = e2e_crc(data_id, &bytes[1..]);
        bytes
    }
    let good = sample_command().encode(c(3));

    let mut counter15 = good;
    counter15[1] |= 0x0F;
    assert_eq!(
        CommandMsg::decode(&resealed(counter15, 0x0120)),
        Err(DecodeError::InvalidCounter(15))
    );

    let mut command3 = good;
    command3[1] = (command3[1] & 0x0F) | 0x30;
    assert_eq!(
        CommandMsg::decode(&resealed(command3, 0x0120)),
        Err(DecodeError::OutOfRange {
            signal: "Command",
            raw: 3
        })
    );

    let mut reason7 = good;
    reason7[6] = 0x07;
    assert_eq!(
        CommandMsg::decode(&resealed(reason7, 0x0120)),
        Err(DecodeError::OutOfRange {
            signal: "CommandReason",
            raw: 7
        })
    );

    let status = StatusMsg {
        state: State::Running,
        faults: FaultBits::empty(),
        perception_age: Duration::ZERO,
        sensor: SensorFaults::empty(),
        motion_fault: false,
        generations_per_sec: 0.0,
        cam_fps_left: 0.0,
        cam_fps_right: 0.0,
    }
    .encode(c(0));
    let mut state6 = status;
    state6[1] = 0x60;
    assert_eq!(
        StatusMsg::decode(&resealed(state6, 0x0121)),
        Err(DecodeError::OutOfRange {
            signal: "State",
            raw: 6
        })
    );
    // Bit 15 is MotionFault, not part of State.
    let mut motion = status;
    motion[1] = 0x90;
    let decoded = StatusMsg::decode(&resealed(motion, 0x0121)).expect("decodes");
    assert_eq!(
        (decoded.state, decoded.motion_fault),
        (State::Running, true)
    );

    let mut conf = ObstacleMsg::NONE.encode(c(0));
    conf[6] = 101;
    assert_eq!(
        ObstacleMsg::decode(&resealed(conf, 0x0122)),
        Err(DecodeError::OutOfRange {
            signal: "Confidence",
            raw: 101
        })
    );
}

#[test]
fn reserved_bits_are_zero_and_ignored() {
    let bytes = sample_command().encode(c(0));
    assert_eq!(bytes[6] & 0xF0, 0);
    assert_eq!(bytes[7], 0);
    let mut with_reserved = bytes;
    with_reserved[7] = 0xAB;
    with_reserved[0] = e2e_crc(0x0120, &with_reserved[1..]);
    assert_eq!(CommandMsg::decode(&with_reserved), Ok(sample_command()));
}

#[test]
fn fault_bits_behave_like_flags() {
    let mut f = FaultBits::empty();
    assert!(f.is_empty());
    f.insert(FaultBits::STEREO_SKEW | FaultBits::INTERNAL);
    assert_eq!(f.bits(), 0b1000_0100);
    assert!(f.contains(FaultBits::STEREO_SKEW));
    assert!(!f.contains(FaultBits::STEREO_SKEW | FaultBits::CAN_TX_ERROR));
    assert!(f.intersects(FaultBits::STEREO_SKEW | FaultBits::CAN_TX_ERROR));
    f.set(FaultBits::INTERNAL, false);
    assert_eq!(f, FaultBits::STEREO_SKEW);
    assert_eq!(format!("{f:?}"), "FaultBits(STEREO_SKEW)");
    assert_eq!(
        (FaultBits::LEFT_CAMERA_STALE | FaultBits::SNAPSHOT_STALE).to_string(),
        "LEFT_CAMERA_STALE|SNAPSHOT_STALE"
    );
    assert_eq!(FaultBits::empty().to_string(), "none");
    assert_eq!(FaultBits::all().names().count(), 8);
}

#[test]
fn motion_roundtrips_and_saturates() {
    let msg = MotionMsg {
        valid: true,
        speed: -2.5,
        yaw_rate: 0.1234,
    };
    let (back, counter) = MotionMsg::decode_with(&msg.encode(c(6)), 0x0110).expect("decodes");
    assert_eq!((back, counter), (msg, c(6)));
    // 12.34 m/s = 1234 = 0x04D2 in bytes 2-3; valid in bit 12.
    let bytes = MotionMsg {
        valid: true,
        speed: 12.34,
        yaw_rate: 0.0,
    }
    .encode(c(1));
    assert_eq!(&bytes[1..4], &[0x11, 0xD2, 0x04]);
    let fast = MotionMsg {
        valid: true,
        speed: 1e6,
        yaw_rate: -1e6,
    };
    let back = MotionMsg::decode(&fast.encode(c(0))).expect("decodes");
    assert_eq!((back.speed, back.yaw_rate), (327.67, -3.2768));
    let nan = MotionMsg {
        valid: true,
        speed: f64::NAN,
        yaw_rate: 0.0,
    };
    assert!(!MotionMsg::decode(&nan.encode(c(0))).expect("decodes").valid);
    assert!(matches!(
        MotionMsg::decode(&fast.encode(c(0))[..6]),
        Err(DecodeError::WrongLength { actual: 6 })
    ));
}

#[test]
fn command_severity_order() {
    assert!(Command::Clear < Command::Slow && Command::Slow < Command::Stop);
    assert_eq!(Command::Slow.max(Command::Stop), Command::Stop);
}
