//! flyd on the CAN bus: the message contract, its E2E protection, and the transports.
//!
//! The contract is `config/flyd.dbc`; `tests/dbc.rs` holds this code to it signal by signal.
//!
//! | message         | default ID | Data ID | period | content |
//! |-----------------|-----------:|--------:|-------:|---------|
//! | `FLYD_Command`  | 0x120 | 0x0120 | 20 ms  | CLEAR / SLOW / STOP, deceleration, global warning, reason |
//! | `FLYD_Status`   | 0x121 | 0x0121 | 20 ms  | state, fault bits, perception age, rates |
//! | `FLYD_Obstacle` | 0x122 | 0x0122 | 100 ms | nearest relevant obstacle |
//! | `FLYD_Path` | 0x123 | 0x0123 | 100 ms | the path the corridor follows |
//! | `FLYD_ObstacleMotion` | 0x124 | 0x0124 | with `FLYD_Obstacle` | its closing speed, time to collision, speed |
//! | `VCU_Motion` (received) | 0x110 | 0x0110 | 20 ms | the vehicle's speed and yaw rate ([`motion_monitor`]) |
//!
//! Every frame: 8 bytes, byte 0 = CRC-8 SAE J1850 over (Data ID lo, Data ID hi, bytes 1..=7),
//! byte 1 low nibble = alive counter 0..=14 (AUTOSAR E2E profile 1 style). IDs, Data IDs and
//! periods are runtime settings ([`CanConfig`]); both ends must agree on all three.
//!
//! - [`crc`]: the CRC.
//! - [`messages`]: typed messages, byte layout, saturation rules, decoding checks.
//! - [`bus`]: the [`bus::CanBus`] trait, SocketCAN / candump-log / in-memory backends, error
//!   classes (retryable vs fatal).
//! - [`candump`]: the `candump -l` line format, both ways.
//! - [`motion_monitor`]: the vehicle's `VCU_Motion` frames checked (E2E, counter, age, plausibility)
//!   before their motion is trusted.

pub mod bus;
pub mod candump;
pub mod crc;
pub mod messages;
pub mod motion_monitor;

use std::time::Duration;

use serde::Deserialize;
use thiserror::Error;

use bus::{BusError, CanBus};
use candump::CAN_SFF_MAX;
use messages::{
    AliveCounter, CanMessage, CommandMsg, MotionMsg, ObstacleMotionMsg, ObstacleMsg, PathMsg,
    StatusMsg,
};

/// Where and how often one message is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MessageConfig {
    /// Standard 11-bit CAN ID.
    pub id: u32,
    /// E2E Data ID folded into the CRC (see [`crc`]).
    pub data_id: u16,
    /// Transmission period, ms.
    pub period_ms: u32,
}

impl MessageConfig {
    /// The defaults of message `M` (those of `config/flyd.dbc`).
    pub fn default_for<M: CanMessage>() -> Self {
        Self {
            id: M::DEFAULT_ID,
            data_id: M::DEFAULT_DATA_ID,
            period_ms: u32::try_from(M::DEFAULT_PERIOD.as_millis()).unwrap_or(u32::MAX),
        }
    }

    pub fn period(&self) -> Duration {
        Duration::from_millis(u64::from(self.period_ms))
    }
}

/// The runtime CAN settings; a missing table in the config file keeps that message's defaults.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CanConfig {
    pub command: MessageConfig,
    pub status: MessageConfig,
    pub obstacle: MessageConfig,
    pub path: MessageConfig,
    /// `FLYD_ObstacleMotion`, sent with `FLYD_Obstacle`.
    pub obstacle_motion: MessageConfig,
    /// `VCU_Motion`, received: its period is the sender's, what staleness is counted in.
    pub motion: MessageConfig,
}

impl Default for CanConfig {
    fn default() -> Self {
        Self {
            command: MessageConfig::default_for::<CommandMsg>(),
            status: MessageConfig::default_for::<StatusMsg>(),
            obstacle: MessageConfig::default_for::<ObstacleMsg>(),
            path: MessageConfig::default_for::<PathMsg>(),
            obstacle_motion: MessageConfig::default_for::<ObstacleMotionMsg>(),
            motion: MessageConfig::default_for::<MotionMsg>(),
        }
    }
}

/// A [`CanConfig`] that cannot work.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CanConfigError {
    #[error("{message}: CAN ID {id:#x} is not a standard 11-bit ID")]
    IdNotStandard { message: &'static str, id: u32 },
    #[error("{a} and {b} share CAN ID {id:#x}")]
    DuplicateId {
        a: &'static str,
        b: &'static str,
        id: u32,
    },
    #[error("{a} and {b} share Data ID {data_id:#06x}: their frames would be interchangeable")]
    DuplicateDataId {
        a: &'static str,
        b: &'static str,
        data_id: u16,
    },
    #[error("{message}: period must be at least 1 ms")]
    ZeroPeriod { message: &'static str },
    /// Receivers time out after a few periods: a longer one hides a dead sender.
    #[error("{message}: period must be at most {max} ms, got {got}")]
    PeriodTooLong {
        message: &'static str,
        max: u32,
        got: u32,
    },
}

impl CanConfig {
    fn named(&self) -> [(&'static str, MessageConfig); 6] {
        [
            (CommandMsg::NAME, self.command),
            (StatusMsg::NAME, self.status),
            (ObstacleMsg::NAME, self.obstacle),
            (PathMsg::NAME, self.path),
            (ObstacleMotionMsg::NAME, self.obstacle_motion),
            (MotionMsg::NAME, self.motion),
        ]
    }

    pub fn validate(&self) -> Result<(), CanConfigError> {
        let named = self.named();
        for (message, m) in named {
            if m.id > CAN_SFF_MAX {
                return Err(CanConfigError::IdNotStandard { message, id: m.id });
            }
            if m.period_ms == 0 {
                return Err(CanConfigError::ZeroPeriod { message });
            }
            // The command and the status are what the VCU watches for a live flyd (3 missed
            // periods), the motion what flyd watches for a live VCU; the obstacle and the
            // path are information.
            let max = if message == ObstacleMsg::NAME
                || message == PathMsg::NAME
                || message == ObstacleMotionMsg::NAME
            {
                1000
            } else {
                100
            };
            if m.period_ms > max {
                return Err(CanConfigError::PeriodTooLong {
                    message,
                    max,
                    got: m.period_ms,
                });
            }
        }
        for (i, (a, ma)) in named.iter().enumerate() {
            for (b, mb) in &named[i + 1..] {
                if ma.id == mb.id {
                    return Err(CanConfigError::DuplicateId { a, b, id: ma.id });
                }
                if ma.data_id == mb.data_id {
                    return Err(CanConfigError::DuplicateDataId {
                        a,
                        b,
                        data_id: ma.data_id,
                    });
                }
            }
        }
        Ok(())
    }
}

/// Sends flyd's messages on a bus with their configured IDs and Data IDs, each with its own
/// alive counter.
///
/// The counter advances on every send *attempt*, failed or not (as AUTOSAR E2E protect does):
/// a receiver sees a failed transmission as a lost frame (counter gap), which is what it was.
/// When to send (the periods) is the caller's loop's business.
pub struct Transmitter<B: CanBus> {
    bus: B,
    config: CanConfig,
    command_counter: AliveCounter,
    status_counter: AliveCounter,
    obstacle_counter: AliveCounter,
    path_counter: AliveCounter,
    obstacle_motion_counter: AliveCounter,
}

impl<B: CanBus> Transmitter<B> {
    pub fn new(bus: B, config: CanConfig) -> Result<Self, CanConfigError> {
        config.validate()?;
        Ok(Self {
            bus,
            config,
            command_counter: AliveCounter::ZERO,
            status_counter: AliveCounter::ZERO,
            obstacle_counter: AliveCounter::ZERO,
            path_counter: AliveCounter::ZERO,
            obstacle_motion_counter: AliveCounter::ZERO,
        })
    }

    pub fn config(&self) -> &CanConfig {
        &self.config
    }

    pub fn send_command(&mut self, msg: &CommandMsg) -> Result<(), BusError> {
        let m = self.config.command;
        let data = msg.encode_with(self.command_counter.advance(), m.data_id);
        self.bus.send(m.id, &data)
    }

    pub fn send_status(&mut self, msg: &StatusMsg) -> Result<(), BusError> {
        let m = self.config.status;
        let data = msg.encode_with(self.status_counter.advance(), m.data_id);
        self.bus.send(m.id, &data)
    }

    pub fn send_obstacle(&mut self, msg: &ObstacleMsg) -> Result<(), BusError> {
        let m = self.config.obstacle;
        let data = msg.encode_with(self.obstacle_counter.advance(), m.data_id);
        self.bus.send(m.id, &data)
    }

    pub fn send_path(&mut self, msg: &PathMsg) -> Result<(), BusError> {
        let m = self.config.path;
        let data = msg.encode_with(self.path_counter.advance(), m.data_id);
        self.bus.send(m.id, &data)
    }

    pub fn send_obstacle_motion(&mut self, msg: &ObstacleMotionMsg) -> Result<(), BusError> {
        let m = self.config.obstacle_motion;
        let data = msg.encode_with(self.obstacle_motion_counter.advance(), m.data_id);
        self.bus.send(m.id, &data)
    }

    pub fn bus(&self) -> &B {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    pub fn into_bus(self) -> B {
        self.bus
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decision::{Command, CommandReason};
    use std::sync::{Arc, Mutex};

    /// A frame the [`Recorder`] accepted.
    struct RecordedFrame {
        id: u32,
        data: Vec<u8>,
    }

    /// The smallest bus: records what it accepts, fails the sends it is told to fail. Clones
    /// share the recording.
    #[derive(Clone, Default)]
    struct Recorder {
        frames: Arc<Mutex<Vec<RecordedFrame>>>,
        fail: Arc<Mutex<Option<BusError>>>,
    }

    impl Recorder {
        fn frames(&self) -> std::sync::MutexGuard<'_, Vec<RecordedFrame>> {
            self.frames.lock().expect("not poisoned")
        }

        fn fail_next(&self, error: BusError) {
            *self.fail.lock().expect("not poisoned") = Some(error);
        }
    }

    impl CanBus for Recorder {
        fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
            if let Some(error) = self.fail.lock().expect("not poisoned").take() {
                return Err(error);
            }
            let data = data.to_vec();
            self.frames().push(RecordedFrame { id, data });
            Ok(())
        }
    }

    fn command() -> CommandMsg {
        CommandMsg {
            command: Command::Slow,
            requested_decel: 1.5,
            global_warning: 0.42,
            reason: CommandReason::Perception,
        }
    }

    #[test]
    fn default_config_is_valid_and_matches_message_defaults() {
        let cfg = CanConfig::default();
        assert_eq!(cfg.validate(), Ok(()));
        assert_eq!(
            (cfg.command.id, cfg.status.id, cfg.obstacle.id),
            (0x120, 0x121, 0x122)
        );
        assert_eq!(cfg.obstacle.period(), Duration::from_millis(100));
    }

    #[test]
    fn config_from_toml_overrides_per_message() {
        let cfg: CanConfig =
            toml::from_str("[command]\nid = 0x200\ndata_id = 0x1234\nperiod_ms = 10\n")
                .expect("parses");
        assert_eq!(
            cfg.command,
            MessageConfig {
                id: 0x200,
                data_id: 0x1234,
                period_ms: 10
            }
        );
        assert_eq!(cfg.status, CanConfig::default().status);
        assert!(toml::from_str::<CanConfig>("[command]\nid = 1\n").is_err());
    }

    #[test]
    fn config_validation() {
        let mut cfg = CanConfig::default();
        cfg.status.id = 0x120;
        assert!(matches!(
            cfg.validate(),
            Err(CanConfigError::DuplicateId { id: 0x120, .. })
        ));
        let mut cfg = CanConfig::default();
        cfg.obstacle.data_id = cfg.command.data_id;
        assert!(matches!(
            cfg.validate(),
            Err(CanConfigError::DuplicateDataId { .. })
        ));
        let mut cfg = CanConfig::default();
        cfg.command.id = 0x800;
        assert!(matches!(
            cfg.validate(),
            Err(CanConfigError::IdNotStandard { .. })
        ));
        let mut cfg = CanConfig::default();
        cfg.status.period_ms = 0;
        assert!(matches!(
            cfg.validate(),
            Err(CanConfigError::ZeroPeriod { .. })
        ));
    }

    #[test]
    fn transmitter_uses_configured_ids_and_counts_per_message() {
        let bus = Recorder::default();
        let mut cfg = CanConfig::default();
        cfg.command.id = 0x300;
        cfg.command.data_id = 0xBEEF;
        let mut tx = Transmitter::new(bus.clone(), cfg).expect("valid config");

        for _ in 0..16 {
            tx.send_command(&command()).expect("sent");
        }
        tx.send_obstacle(&ObstacleMsg::NONE).expect("sent");

        let frames = bus.frames();
        let commands: Vec<&RecordedFrame> = frames.iter().filter(|f| f.id == 0x300).collect();
        assert_eq!(commands.len(), 16);
        let counters: Vec<u8> = commands
            .iter()
            .map(|f| {
                CommandMsg::decode_with(&f.data, 0xBEEF)
                    .expect("decodes with the configured Data ID")
                    .1
                    .value()
            })
            .collect();
        assert_eq!(
            counters,
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 0]
        );
        // The default Data ID no longer matches: a receiver configured differently rejects it.
        assert!(CommandMsg::decode(&commands[0].data).is_err());

        let obstacle = frames
            .iter()
            .find(|f| f.id == 0x122)
            .expect("obstacle sent");
        let (_, counter) =
            ObstacleMsg::decode_with(&obstacle.data, ObstacleMsg::DEFAULT_DATA_ID).expect("ok");
        assert_eq!(
            counter,
            AliveCounter::ZERO,
            "each message has its own counter"
        );
    }

    #[test]
    fn transmitter_counter_advances_on_failed_sends() {
        let bus = Recorder::default();
        let mut tx = Transmitter::new(bus.clone(), CanConfig::default()).expect("valid");
        tx.send_status(&status()).expect("sent");
        bus.fail_next(BusError::QueueFull { attempts: 3 });
        assert!(tx.send_status(&status()).is_err());
        tx.send_status(&status()).expect("sent");
        let counters: Vec<u8> = bus
            .frames()
            .iter()
            .map(|f| {
                StatusMsg::decode_with(&f.data, StatusMsg::DEFAULT_DATA_ID)
                    .expect("ok")
                    .1
                    .value()
            })
            .collect();
        assert_eq!(counters, [0, 2]);
    }

    fn status() -> StatusMsg {
        StatusMsg {
            state: crate::status::State::Running,
            faults: crate::status::FaultBits::empty(),
            perception_age: Duration::from_millis(30),
            sensor: crate::sensor::SensorFaults::empty(),
            motion_fault: false,
            generations_per_sec: 100.0,
            cam_fps_left: 30.0,
            cam_fps_right: 30.0,
        }
    }
}
