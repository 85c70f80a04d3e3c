//! The mock vehicle's longitudinal dynamics: what a brake request does to its speed.
//!
//! A vehicle that obeys flyd: the driver holds a set speed (CLEAR), and a deceleration request
//! (SLOW, STOP: `FLYD_Command`'s `RequestedDecel`) goes through a brake actuator as a
//! production brake system has one:
//!
//! 1. a **dead time** ([`BrakeConfig::dead_time`], 0.2 s): the request crosses the bus, the
//!    brake ECU arbitrates it and the pump or booster starts (Autoware's vehicle simulator
//!    defaults to 0.1 s for its acceleration command alone; brake-by-wire requests over CAN are
//!    quoted at 0.1-0.3 s);
//! 2. a **first-order rise** ([`BrakeConfig::time_constant`], 0.15 s): the pressure builds
//!    (Autoware's default 0.1 s, 0.3 s fitted on a bus);
//! 3. a **jerk limit** ([`BrakeConfig::jerk_limit`], 30 m/s^3): hydraulic brakes reach full
//!    deceleration (~9-10 m/s^2 on dry asphalt) in roughly 0.3-0.4 s at the fastest;
//! 4. the **tyres' limit** ([`BrakeConfig::max_decel`], 9.5 m/s^2, about 1 g on dry asphalt).
//!
//! The vehicle stops at zero and stays stopped: once a brake request has brought it to a
//! standstill the driver holds it there (an AEB test ends at standstill), so it does not creep
//! on when the request is released. A request released while it still moves gives the driver
//! back: it accelerates back to the set speed at [`VehicleConfig::driver_accel`].
//!
//! Integration is a fixed step ([`STEP`]), so a run is the same bit for bit whatever the
//! times it is advanced to.

use std::collections::VecDeque;

/// The integration step, seconds.
pub const STEP: f64 = 0.001;

/// A brake giving less than this, m/s^2, with no request acting has let go: the driver drives.
const RELEASED: f64 = 0.05;

/// The brake actuator (see the module docs for the figures).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrakeConfig {
    /// From a request to the brakes starting to act, seconds.
    pub dead_time: f64,
    /// The first-order rise of the deceleration towards the request, seconds.
    pub time_constant: f64,
    /// The fastest the deceleration changes, m/s^3.
    pub jerk_limit: f64,
    /// The most the tyres give, m/s^2.
    pub max_decel: f64,
}

impl Default for BrakeConfig {
    fn default() -> Self {
        Self {
            dead_time: 0.2,
            time_constant: 0.15,
            jerk_limit: 30.0,
            max_decel: 9.5,
        }
    }
}

/// The vehicle: its brakes and its driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleConfig {
    pub brake: BrakeConfig,
    /// How the driver gets back to the set speed after a released request, m/s^2.
    pub driver_accel: f64,
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self {
            brake: BrakeConfig::default(),
            driver_accel: 1.0,
        }
    }
}

/// Why a configuration cannot drive.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("vehicle: {key} must be {range}, got {value}")]
pub struct VehicleConfigError {
    pub key: &'static str,
    pub value: f64,
    pub range: &'static str,
}

impl VehicleConfig {
    pub fn validate(&self) -> Result<(), VehicleConfigError> {
        let b = &self.brake;
        let checks: [(&'static str, f64, f64, f64, &'static str); 5] = [
            ("dead_time_s", b.dead_time, 0.0, 2.0, "within 0..=2 s"),
            (
                "time_constant_s",
                b.time_constant,
                0.0,
                2.0,
                "within 0..=2 s",
            ),
            (
                "jerk_limit",
                b.jerk_limit,
                0.1,
                1000.0,
                "within 0.1..=1000 m/s^3",
            ),
            ("max_decel", b.max_decel, 0.5, 15.0, "within 0.5..=15 m/s^2"),
            (
                "driver_accel",
                self.driver_accel,
                0.0,
                10.0,
                "within 0..=10 m/s^2",
            ),
        ];
        for (key, value, lo, hi, range) in checks {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(VehicleConfigError { key, value, range });
            }
        }
        Ok(())
    }
}

/// The vehicle's state at an instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleState {
    /// Seconds since the start.
    pub time: f64,
    /// Metres driven along its path since the start.
    pub along: f64,
    /// Forward speed, m/s (never negative).
    pub speed: f64,
    /// The deceleration the brakes give, m/s^2 (positive braking).
    pub decel: f64,
    /// The deceleration requested now, m/s^2 (0: none).
    pub requested: f64,
    /// Stopped by a brake request and held there by the driver.
    pub held: bool,
}

/// The vehicle, driven in lockstep with flyd: [`Vehicle::request`] at each command, and
/// [`Vehicle::advance_to`] the times in between.
#[derive(Debug, Clone)]
pub struct Vehicle {
    config: VehicleConfig,
    /// The driver's set speed, m/s.
    set_speed: f64,
    state: VehicleState,
    /// The first-order stage's output, before the jerk limit.
    lagged: f64,
    /// Requests not yet through the dead time: (time given, value).
    pending: VecDeque<(f64, f64)>,
    /// The request through the dead time.
    acting: f64,
    /// Integration steps taken (time = steps * STEP, without drift).
    steps: u64,
    /// The most deceleration the brakes gave, m/s^2, and the fastest it changed, m/s^3.
    peak_decel: f64,
    peak_jerk: f64,
}

impl Vehicle {
    /// At `speed` m/s, the driver's set speed, with nothing requested.
    pub fn new(config: VehicleConfig, speed: f64) -> Result<Self, VehicleConfigError> {
        config.validate()?;
        if !(speed.is_finite() && (0.0..=100.0).contains(&speed)) {
            return Err(VehicleConfigError {
                key: "speed",
                value: speed,
                range: "within 0..=100 m/s",
            });
        }
        Ok(Self {
            config,
            set_speed: speed,
            state: VehicleState {
                time: 0.0,
                along: 0.0,
                speed,
                decel: 0.0,
                requested: 0.0,
                held: false,
            },
            lagged: 0.0,
            pending: VecDeque::new(),
            acting: 0.0,
            steps: 0,
            peak_decel: 0.0,
            peak_jerk: 0.0,
        })
    }

    pub fn state(&self) -> VehicleState {
        self.state
    }

    /// The most deceleration the brakes gave so far, m/s^2.
    pub fn peak_decel(&self) -> f64 {
        self.peak_decel
    }

    /// The fastest the brakes' deceleration changed so far, either way, m/s^3.
    pub fn peak_jerk(&self) -> f64 {
        self.peak_jerk
    }

    pub fn config(&self) -> &VehicleConfig {
        &self.config
    }

    /// A deceleration of `decel` m/s^2 requested from now on (0 or less, or not a number:
    /// none).
    pub fn request(&mut self, decel: f64) {
        let decel = if decel.is_finite() {
            decel.max(0.0)
        } else {
            0.0
        };
        if decel != self.state.requested {
            self.state.requested = decel;
            self.pending.push_back((self.state.time, decel));
        }
    }

    /// Integrates up to `time` seconds since the start (nothing if it is not later).
    pub fn advance_to(&mut self, time: f64) {
        if !time.is_finite() {
            return;
        }
        let target = (time / STEP).round().max(0.0) as u64;
        while self.steps < target {
            self.step();
        }
    }

    fn step(&mut self) {
        let b = self.config.brake;
        let now = self.state.time;
        // The requests that have crossed the dead time.
        while let Some(&(given, value)) = self.pending.front() {
            if given + b.dead_time <= now + 1e-9 {
                self.acting = value;
                self.pending.pop_front();
            } else {
                break;
            }
        }
        let wanted = self.acting.min(b.max_decel);
        self.lagged += if b.time_constant > 0.0 {
            (wanted - self.lagged) * (1.0 - (-STEP / b.time_constant).exp())
        } else {
            wanted - self.lagged
        };
        let most = b.jerk_limit * STEP;
        let change = (self.lagged - self.state.decel).clamp(-most, most);
        let s = &mut self.state;
        s.decel = (s.decel + change).clamp(0.0, b.max_decel);
        if self.acting == 0.0 && s.decel < RELEASED {
            // A released brake that has nearly let go has let go: the driver drives.
            s.decel = 0.0;
            self.lagged = 0.0;
        }
        self.peak_decel = self.peak_decel.max(s.decel);
        self.peak_jerk = self.peak_jerk.max(change.abs() / STEP);
        let braking = s.decel > 0.0 || self.acting > 0.0;
        let accel = if s.held {
            0.0
        } else if braking {
            -s.decel
        } else if s.speed < self.set_speed {
            self.config
                .driver_accel
                .min((self.set_speed - s.speed) / STEP)
        } else {
            0.0
        };
        let v0 = s.speed;
        let v1 = (v0 + accel * STEP).max(0.0);
        if v1 < v0 && v1 == 0.0 {
            // Stopped within the step: the distance to where the speed reached zero.
            s.along += if accel < 0.0 {
                v0 * v0 / (-2.0 * accel)
            } else {
                0.0
            };
        } else {
            s.along += 0.5 * (v0 + v1) * STEP;
        }
        s.speed = v1;
        if s.speed == 0.0 && self.acting > 0.0 {
            s.held = true;
        }
        self.steps += 1;
        s.time = self.steps as f64 * STEP;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vehicle(speed: f64) -> Vehicle {
        Vehicle::new(VehicleConfig::default(), speed).expect("valid")
    }

    #[test]
    fn without_a_request_it_holds_the_set_speed() {
        let mut v = vehicle(10.0);
        v.advance_to(2.0);
        let s = v.state();
        assert_eq!((s.speed, s.decel, s.held), (10.0, 0.0, false));
        assert!((s.along - 20.0).abs() < 1e-9, "{}", s.along);
        assert!((s.time - 2.0).abs() < 1e-12);
    }

    #[test]
    fn a_request_acts_after_the_dead_time_rises_with_a_bounded_jerk_and_stops_the_vehicle() {
        let mut v = vehicle(10.0);
        v.advance_to(1.0);
        v.request(6.0);
        v.advance_to(1.0 + 0.199);
        assert_eq!(v.state().decel, 0.0, "nothing within the dead time");
        assert_eq!(v.state().speed, 10.0);
        let (mut last, mut peak_jerk) = (0.0, 0.0_f64);
        let mut t = 1.2;
        while t < 1.6 {
            t += STEP;
            v.advance_to(t);
            peak_jerk = peak_jerk.max((v.state().decel - last) / STEP);
            last = v.state().decel;
        }
        assert!(peak_jerk <= 30.0 + 1e-6, "{peak_jerk}");
        // Within 0.4 s of the dead time, nearly all of it (first-order 0.15 s: e^-2.7).
        assert!(
            v.state().decel > 5.5 && v.state().decel <= 6.0,
            "{}",
            v.state().decel
        );
        v.advance_to(5.0);
        let s = v.state();
        assert_eq!(s.speed, 0.0);
        assert!(s.held);
        // From 10 m/s: 10 m in the first second, 2 m in the dead time, v^2 / (2 a) = 8.3 m
        // braking, and at most 10 m/s over the rise (0.15 s first order, 0.2 s of jerk).
        assert!(s.along > 20.4 && s.along < 23.8, "{}", s.along);
        // Released: the driver holds it where it stopped.
        v.request(0.0);
        v.advance_to(8.0);
        assert_eq!(v.state().speed, 0.0);
        assert_eq!(v.state().along, s.along);
    }

    #[test]
    fn a_released_request_gives_the_driver_back_the_set_speed() {
        let mut v = vehicle(8.0);
        v.request(1.5);
        v.advance_to(1.5);
        let slowed = v.state().speed;
        assert!(slowed < 8.0 && slowed > 6.0, "{slowed}");
        v.request(0.0);
        v.advance_to(6.0);
        let s = v.state();
        assert!((s.speed - 8.0).abs() < 1e-9, "{}", s.speed);
        assert!(!s.held);
        assert_eq!(s.decel, 0.0);
    }

    #[test]
    fn the_tyres_bound_the_deceleration_and_bad_requests_are_none() {
        let mut v = vehicle(20.0);
        v.request(f64::NAN);
        v.advance_to(1.0);
        assert_eq!(v.state().speed, 20.0);
        v.request(50.0);
        v.advance_to(3.0);
        assert!((v.state().decel - 9.5).abs() < 1e-3, "{}", v.state().decel);
        assert!(v.state().decel <= 9.5);
    }

    #[test]
    fn advancing_in_any_steps_gives_the_same_bits() {
        let (mut a, mut b) = (vehicle(12.0), vehicle(12.0));
        a.request(4.0);
        b.request(4.0);
        a.advance_to(2.5);
        for k in 1..=250 {
            b.advance_to(f64::from(k) * 0.01);
        }
        assert_eq!(a.state(), b.state());
    }

    #[test]
    fn bad_configurations_are_refused() {
        let mut c = VehicleConfig::default();
        c.brake.dead_time = -1.0;
        assert_eq!(
            Vehicle::new(c, 10.0).err().map(|e| e.key),
            Some("dead_time_s")
        );
        assert!(Vehicle::new(VehicleConfig::default(), f64::NAN).is_err());
    }
}
