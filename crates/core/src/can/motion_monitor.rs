//! The vehicle's own motion, as the vehicle reports it on CAN (`VCU_Motion`), checked before
//! it is trusted.
//!
//! [`MotionMonitor`] takes every received frame of the motion's CAN ID with its receive time
//! and keeps the last motion it trusts. A frame is **rejected** (counted by class, never
//! trusted) when
//!
//! - its length is not 8 (a wrong DLC), its CRC does not match the Data ID, its alive counter
//!   is 15 (E2E: [`MotionMsg::decode_with`]);
//! - its counter repeats the previous frame's (a stuck sender re-sending one frame);
//! - its values are implausible: a speed beyond [`MAX_FORWARD_SPEED`] or
//!   [`MAX_REVERSE_SPEED`], a yaw rate beyond [`MAX_YAW_RATE`], or a change of speed from the
//!   last trusted frame faster than [`MAX_ACCEL`] over the time the counters say passed
//!   (counter gap x period: receive times jitter with the bus load, the sender's period does
//!   not).
//!
//! The motion is **known** ([`MotionStatus::Known`]) while the newest accepted frame is at most
//! `stale` old (default 3 periods), says `MotionValid` = 1, and at least [`TRUST_AFTER`] frames
//! were accepted since the motion was last unknown. Otherwise it is a fault
//! ([`MotionFault`]): the decision then assumes the configured highest speed, never a lower
//! one ([`MotionMonitor::decision_speed`]). A stream of rejected frames becomes the fault
//! `stale` after the last good one.
//!
//! Pure: no clock, no I/O; times are the caller's (the daemon's monotonic clock).

use std::time::Duration;

use super::messages::{AliveCounter, CanMessage, DecodeError, MotionMsg};
use crate::kinematics::VehicleMotion;

/// Fastest plausible forward speed, m/s (270 km/h): beyond, a frame is rejected.
pub const MAX_FORWARD_SPEED: f64 = 75.0;
/// Fastest plausible reverse speed, m/s (magnitude; 72 km/h).
pub const MAX_REVERSE_SPEED: f64 = 20.0;
/// Largest plausible yaw rate magnitude, rad/s (86 deg/s: a car at full lock at walking pace).
pub const MAX_YAW_RATE: f64 = 1.5;
/// Largest plausible change of speed, m/s^2 (1.5 g: no car brakes or accelerates harder).
pub const MAX_ACCEL: f64 = 15.0;
/// Speed changes within this are never implausible (two raw steps plus rounding), m/s.
const SPEED_SLACK: f64 = 0.05;
/// Accepted frames needed after an unknown motion before it is trusted again.
pub const TRUST_AFTER: u32 = 2;

/// The monitor's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionConfig {
    /// E2E Data ID of `VCU_Motion`.
    pub data_id: u16,
    /// The sender's period (what a counter step means in time).
    pub period: Duration,
    /// No accepted frame for this long: [`MotionFault::Stale`].
    pub stale: Duration,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            data_id: MotionMsg::DEFAULT_DATA_ID,
            period: MotionMsg::DEFAULT_PERIOD,
            stale: 3 * MotionMsg::DEFAULT_PERIOD,
        }
    }
}

named_enum! {
    /// Why the motion is not known.
    pub enum MotionFault {
        /// No frame accepted yet (or not yet [`TRUST_AFTER`] of them).
        Missing = 0 => "MISSING",
        /// The newest accepted frame is older than `stale`.
        Stale = 1 => "STALE",
        /// The vehicle says its motion is not valid (`MotionValid` = 0).
        Invalid = 2 => "INVALID",
    }
}

/// What the decision may use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionStatus {
    /// Trusted motion, received at `at`.
    Known { motion: VehicleMotion, at: Duration },
    /// Not known, and why.
    Unknown(MotionFault),
}

impl MotionStatus {
    pub fn fault(&self) -> Option<MotionFault> {
        match self {
            Self::Known { .. } => None,
            Self::Unknown(f) => Some(*f),
        }
    }

    pub fn motion(&self) -> Option<VehicleMotion> {
        match self {
            Self::Known { motion, .. } => Some(*motion),
            Self::Unknown(_) => None,
        }
    }
}

/// Why a frame was not accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// Not 8 bytes.
    Length,
    /// CRC mismatch (corrupt, or another message's Data ID).
    Crc,
    /// Counter 15.
    Counter,
    /// The counter of the previous frame again.
    Repeated,
    /// Speed or yaw rate out of the plausible ranges, or a jump no vehicle makes.
    Implausible,
}

/// Frames seen, by outcome.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotionCounters {
    pub accepted: u64,
    pub wrong_length: u64,
    pub bad_crc: u64,
    pub bad_counter: u64,
    pub repeated: u64,
    pub implausible: u64,
    /// Frames missing between accepted ones (counter gaps).
    pub lost: u64,
}

impl MotionCounters {
    /// Every rejected frame.
    pub fn rejected(&self) -> u64 {
        self.wrong_length + self.bad_crc + self.bad_counter + self.repeated + self.implausible
    }
}

/// The last accepted frame.
#[derive(Debug, Clone, Copy)]
struct Accepted {
    msg: MotionMsg,
    counter: AliveCounter,
    at: Duration,
}

/// Checks `VCU_Motion` frames and keeps the motion it trusts (see the module docs).
#[derive(Debug, Clone)]
pub struct MotionMonitor {
    config: MotionConfig,
    last: Option<Accepted>,
    /// Counter of the last frame that passed E2E (accepted or implausible).
    last_counter: Option<AliveCounter>,
    /// Accepted frames since the motion was last unknown.
    streak: u32,
    counters: MotionCounters,
}

impl MotionMonitor {
    pub fn new(config: MotionConfig) -> Self {
        Self {
            config,
            last: None,
            last_counter: None,
            streak: 0,
            counters: MotionCounters::default(),
        }
    }

    pub fn config(&self) -> &MotionConfig {
        &self.config
    }

    pub fn counters(&self) -> MotionCounters {
        self.counters
    }

    /// One received frame of the motion's ID, received at `at`: accepted (`Ok`) or rejected.
    pub fn receive(&mut self, data: &[u8], at: Duration) -> Result<MotionMsg, Rejection> {
        let result = self.check(data, at);
        let c = &mut self.counters;
        match result {
            Ok(_) => c.accepted += 1,
            Err(Rejection::Length) => c.wrong_length += 1,
            Err(Rejection::Crc) => c.bad_crc += 1,
            Err(Rejection::Counter) => c.bad_counter += 1,
            Err(Rejection::Repeated) => c.repeated += 1,
            Err(Rejection::Implausible) => c.implausible += 1,
        }
        result
    }

    fn check(&mut self, data: &[u8], at: Duration) -> Result<MotionMsg, Rejection> {
        let (msg, counter) =
            MotionMsg::decode_with(data, self.config.data_id).map_err(|e| match e {
                DecodeError::WrongLength { .. } => Rejection::Length,
                DecodeError::CrcMismatch { .. } => Rejection::Crc,
                DecodeError::InvalidCounter(_) | DecodeError::OutOfRange { .. } => {
                    Rejection::Counter
                }
            })?;
        let previous = self.last_counter.replace(counter);
        if previous.is_some_and(|p| p.delta(counter) == 0) {
            return Err(Rejection::Repeated);
        }
        if msg.valid && !self.plausible(&msg, counter, at) {
            return Err(Rejection::Implausible);
        }
        if self
            .status(at)
            .fault()
            .is_some_and(|f| f != MotionFault::Missing)
        {
            // Unknown until TRUST_AFTER frames in a row arrive again.
            self.streak = 0;
        }
        if let Some(last) = self.last {
            self.counters.lost += u64::from(last.counter.delta(counter).saturating_sub(1));
        }
        self.streak = self.streak.saturating_add(1);
        self.last = Some(Accepted { msg, counter, at });
        Ok(msg)
    }

    fn plausible(&self, msg: &MotionMsg, counter: AliveCounter, at: Duration) -> bool {
        let in_range = (-MAX_REVERSE_SPEED..=MAX_FORWARD_SPEED).contains(&msg.speed)
            && msg.yaw_rate.abs() <= MAX_YAW_RATE;
        if !in_range {
            return false;
        }
        match self.last {
            Some(last) if last.msg.valid => {
                // Time passed by the sender's clock (counter steps), and at least by the
                // receiver's: a long silence allows any change.
                let steps = f64::from(last.counter.delta(counter).max(1));
                let by_counter = steps * self.config.period.as_secs_f64();
                let by_clock = at.saturating_sub(last.at).as_secs_f64();
                let dt = by_counter.max(by_clock);
                (msg.speed - last.msg.speed).abs() <= MAX_ACCEL * dt + SPEED_SLACK
            }
            _ => true,
        }
    }

    /// The motion at `now`.
    pub fn status(&self, now: Duration) -> MotionStatus {
        let Some(last) = self.last else {
            return MotionStatus::Unknown(MotionFault::Missing);
        };
        if now.saturating_sub(last.at) > self.config.stale {
            return MotionStatus::Unknown(MotionFault::Stale);
        }
        if !last.msg.valid {
            return MotionStatus::Unknown(MotionFault::Invalid);
        }
        if self.streak < TRUST_AFTER {
            return MotionStatus::Unknown(MotionFault::Missing);
        }
        MotionStatus::Known {
            motion: VehicleMotion {
                speed: last.msg.speed,
                yaw_rate: last.msg.yaw_rate,
            },
            at: last.at,
        }
    }

    /// The speed the stopping distance is computed with at `now`, m/s: the measured forward
    /// speed while the motion is known (0 when reversing: a forward-looking flyd does not
    /// brake a reversing vehicle), else `fallback` (the configured highest speed).
    pub fn decision_speed(&self, now: Duration, fallback: f64) -> f64 {
        match self.status(now) {
            MotionStatus::Known { motion, .. } => motion.speed.max(0.0),
            MotionStatus::Unknown(_) => fallback,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::crc::e2e_crc;

    const MS: Duration = Duration::from_millis(1);

    fn frame(speed: f64, counter: u8) -> [u8; 8] {
        let c = AliveCounter::new(counter).expect("counter");
        MotionMsg {
            valid: true,
            speed,
            yaw_rate: 0.05,
        }
        .encode(c)
    }

    /// A monitor fed `n` good frames at 20 ms, speed 10 m/s, from t = 0.
    fn fed(n: u8) -> MotionMonitor {
        let mut m = MotionMonitor::new(MotionConfig::default());
        for k in 0..n {
            m.receive(&frame(10.0, k % 15), u32::from(k) * 20 * MS)
                .expect("good frame");
        }
        m
    }

    #[test]
    fn good_frames_are_trusted_after_two() {
        let mut m = MotionMonitor::new(MotionConfig::default());
        assert_eq!(
            m.status(Duration::ZERO),
            MotionStatus::Unknown(MotionFault::Missing)
        );
        assert_eq!(m.decision_speed(Duration::ZERO, 13.9), 13.9);
        m.receive(&frame(10.0, 0), Duration::ZERO)
            .expect("accepted");
        assert_eq!(m.status(MS).fault(), Some(MotionFault::Missing));
        m.receive(&frame(10.1, 1), 20 * MS).expect("accepted");
        let status = m.status(21 * MS);
        assert_eq!(
            status.motion(),
            Some(VehicleMotion {
                speed: 10.1,
                yaw_rate: 0.05
            })
        );
        assert_eq!(m.decision_speed(21 * MS, 13.9), 10.1);
        assert_eq!(m.counters().accepted, 2);
    }

    #[test]
    fn silence_is_stale_after_three_periods() {
        let m = fed(5);
        let last = 80 * MS;
        assert!(m.status(last + 60 * MS).motion().is_some());
        assert_eq!(
            m.status(last + 61 * MS),
            MotionStatus::Unknown(MotionFault::Stale)
        );
        assert_eq!(m.decision_speed(last + 61 * MS, 13.9), 13.9);
    }

    #[test]
    fn bad_frames_are_counted_and_never_trusted() {
        let mut m = fed(3);
        let at = 60 * MS;
        // Bad CRC.
        let mut bad = frame(10.0, 3);
        bad[3] ^= 0x10;
        assert_eq!(m.receive(&bad, at), Err(Rejection::Crc));
        // Another message's Data ID (a FLYD_Status frame on this ID).
        let mut other = frame(10.0, 3);
        other[0] = e2e_crc(0x0121, &other[1..]);
        assert_eq!(m.receive(&other, at), Err(Rejection::Crc));
        // Wrong DLC.
        assert_eq!(m.receive(&frame(10.0, 3)[..7], at), Err(Rejection::Length));
        assert_eq!(m.receive(&[], at), Err(Rejection::Length));
        // Counter 15.
        let mut c15 = frame(10.0, 3);
        c15[1] |= 0x0F;
        c15[0] = e2e_crc(0x0110, &c15[1..]);
        assert_eq!(m.receive(&c15, at), Err(Rejection::Counter));
        // Repeated counter (the last accepted was 2).
        assert_eq!(m.receive(&frame(10.0, 2), at), Err(Rejection::Repeated));
        // 300 m/s, and a jump of 5 m/s in 20 ms.
        assert_eq!(m.receive(&frame(300.0, 3), at), Err(Rejection::Implausible));
        assert_eq!(m.receive(&frame(15.0, 4), at), Err(Rejection::Implausible));
        assert_eq!(m.receive(&frame(-30.0, 5), at), Err(Rejection::Implausible));
        let yaw = MotionMsg {
            valid: true,
            speed: 10.0,
            yaw_rate: 2.0,
        }
        .encode(AliveCounter::new(6).expect("counter"));
        assert_eq!(m.receive(&yaw, at), Err(Rejection::Implausible));
        let c = m.counters();
        assert_eq!(
            (
                c.bad_crc,
                c.wrong_length,
                c.bad_counter,
                c.repeated,
                c.implausible
            ),
            (2, 2, 1, 1, 4)
        );
        assert_eq!(c.rejected(), 10);
        // None of them moved the trusted speed; a plausible frame is accepted again.
        assert_eq!(m.decision_speed(at, 13.9), 10.0);
        assert_eq!(
            m.receive(&frame(10.2, 7), 80 * MS).map(|f| f.speed),
            Ok(10.2)
        );
        assert_eq!(m.counters().lost, 4, "counters 3..=6 never accepted");
    }

    #[test]
    fn only_bad_frames_become_the_stale_fault() {
        let mut m = fed(3);
        for k in 0..10u32 {
            let mut bad = frame(10.0, 3);
            bad[0] ^= 1;
            let _ = m.receive(&bad, (60 + 20 * k) * MS);
        }
        assert_eq!(m.status(200 * MS).fault(), Some(MotionFault::Stale));
    }

    #[test]
    fn the_vehicle_saying_invalid_is_a_fault() {
        let mut m = fed(3);
        let invalid = MotionMsg {
            valid: false,
            speed: 0.0,
            yaw_rate: 0.0,
        }
        .encode(AliveCounter::new(3).expect("counter"));
        assert!(m.receive(&invalid, 60 * MS).is_ok());
        assert_eq!(m.status(61 * MS).fault(), Some(MotionFault::Invalid));
        assert_eq!(m.decision_speed(61 * MS, 13.9), 13.9);
        // Valid again: trusted after two frames, whatever speed (no jump check from invalid).
        m.receive(&frame(3.0, 4), 80 * MS).expect("accepted");
        assert_eq!(m.status(81 * MS).fault(), Some(MotionFault::Missing));
        m.receive(&frame(3.0, 5), 100 * MS).expect("accepted");
        assert_eq!(m.decision_speed(101 * MS, 13.9), 3.0);
    }

    #[test]
    fn a_long_silence_allows_any_change_and_lost_frames_stretch_the_jump_check() {
        let mut m = fed(3);
        // 4 frames lost (counter 2 -> 7): 100 ms, 1.5 m/s allowed.
        assert!(m.receive(&frame(11.4, 7), 140 * MS).is_ok());
        // A second later, standing still.
        assert!(m.receive(&frame(0.0, 8), 1140 * MS).is_ok());
    }

    #[test]
    fn reversing_is_no_speed_towards_what_is_ahead() {
        let mut m = MotionMonitor::new(MotionConfig::default());
        m.receive(&frame(-2.0, 0), Duration::ZERO)
            .expect("accepted");
        m.receive(&frame(-2.0, 1), 20 * MS).expect("accepted");
        assert_eq!(m.decision_speed(20 * MS, 13.9), 0.0);
    }
}
