//! The closed loop: a hw-mock vehicle that obeys flyd, its cameras rendered from where it
//! really is ([`ClosedLoopFeed`]), and what came of it ([`ClosedLoopReport`]).
//!
//! The replay loop ([`super::run`]) drives it in lockstep: each generation's command goes to
//! the vehicle ([`FrameFeed::obey`]), which brakes through its actuator
//! ([`hw_mock::vehicle`]) until the next; a new frame is rendered from the vehicle's pose at
//! its capture time, and the vehicle's speed and yaw rate, with a wheel-speed sensor's and a
//! gyro's noise, are the motion flyd is given for it (what `VCU_Motion` carries). Nothing reads
//! a clock: a seed gives the same run bit for bit.
//!
//! The vehicle obeys once flyd's perception has decided a first time (the start-up's safe
//! command, before the population is trusted, is the system not yet armed: Euro NCAP's runs
//! start with the system active), and not before the case's warm-up (`warmup_s`: the
//! protocol's steady state, the vehicle driven at its set speed). A run ends at contact, one second after the vehicle came to
//! a standstill under a brake request, one second after its rear passed the last actor, or
//! at the case's end.

use std::path::Path;
use std::time::Duration;

use flyd_core::decision::{Command, CommandReason, Decision};
use flyd_core::frame::StereoFrame;
use flyd_core::geometry::StereoRig;
use flyd_core::kinematics::VehicleMotion;
use hw_mock::closed_loop::Case;
use hw_mock::vehicle::Vehicle;
use image::RgbImage;
use serde::Serialize;

use super::{FrameFeed, ReplayError};

pub mod plot;
use crate::mock::{MockStereo, mock_rig, vehicle_rig};

/// The frame rate of the closed loop's cameras.
pub const FPS: f64 = 30.0;
/// The wheel-speed sensor's noise (1 sigma), m/s, and the gyro's, rad/s.
pub const SPEED_NOISE: f64 = 0.05;
pub const YAW_RATE_NOISE: f64 = 0.002;
/// How long a run goes on after the vehicle stood still under a brake request, seconds.
const AFTER_STANDSTILL: f64 = 1.0;
/// How long a run goes on after the vehicle's rear passed the last actor, seconds.
const AFTER_PASSING: f64 = 1.0;
/// The longest the vehicle is integrated between two contact checks, seconds.
const CHECK_STEP: f64 = 0.005;

/// One moment of a closed-loop run (a command: a generation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopSample {
    /// Seconds since the start.
    pub t: f64,
    pub speed_kmh: f64,
    /// From the front bumper to the nearest actor in the vehicle's width, metres.
    pub gap_m: Option<f64>,
    pub requested_decel: f64,
    pub decel: f64,
    pub command: Command,
}

/// A tracked obstacle's measured motion against the truth, at a count of sightings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MotionCheck {
    pub sightings: u32,
    /// Its speed over the ground along the path, measured and true, m/s.
    pub speed: f64,
    pub truth: f64,
    pub sigma: f64,
    pub established: bool,
}

/// What a closed-loop run came to.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ClosedLoopReport {
    pub case: String,
    pub start_kmh: f64,
    /// The vehicle touched an actor, at this speed relative to it, km/h.
    pub contact: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub impact_kmh: Option<f64>,
    /// Stopped under a brake request, this far short of the nearest actor, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped_gap_m: Option<f64>,
    /// The nearest the front bumper came to an actor in its width, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_gap_m: Option<f64>,
    pub end_kmh: f64,
    /// Set speed less the lowest speed, km/h: for a case with nothing to brake for, the speed
    /// lost for nothing.
    pub speed_lost_kmh: f64,
    /// The most deceleration flyd requested and the brakes gave, m/s^2.
    pub peak_requested_decel: f64,
    pub peak_decel: f64,
    /// The fastest the request rose (between two commands) and the brakes' deceleration
    /// changed, m/s^3.
    pub peak_requested_jerk: f64,
    pub peak_jerk: f64,
    /// When the request first peaked, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peak_requested_at_s: Option<f64>,
    /// The first SLOW and STOP after the system was armed (any reason), seconds, and the time
    /// to collision then (the gap over the closing speed; none when not closing).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_slow_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_slow_ttc_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_stop_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_stop_ttc_s: Option<f64>,
    /// How the confirmed obstacle's measured speed over the ground ([`flyd_core::perception::motion`])
    /// compares with the truth, by the sightings of its track: (sightings, estimate, truth,
    /// standard error, established), the first generation with that many; only while the
    /// track is the nearest actor in the vehicle's width (within 3 m of it).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub motion_by_sightings: Vec<MotionCheck>,
    /// When the system was armed (its perception's first decision), seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub armed_s: Option<f64>,
    pub seconds: f64,
    /// The run over time, a sample a command.
    #[serde(skip)]
    pub samples: Vec<LoopSample>,
}

impl ClosedLoopReport {
    /// Whether flyd asked for anything but CLEAR once armed.
    pub fn activated(&self) -> bool {
        self.first_slow_s.is_some() || self.first_stop_s.is_some()
    }

    /// Writes the run over time: `closed_loop.csv` (a row a command) and `closed_loop.svg`
    /// ([`plot`]) in `dir`.
    pub fn write(&self, dir: &Path) -> Result<(), ReplayError> {
        let path = dir.join("closed_loop.csv");
        let mut csv = String::from("t,speed_kmh,gap_m,requested_decel,decel,command\n");
        for s in &self.samples {
            let gap = s.gap_m.map_or(String::new(), |g| format!("{g:.3}"));
            csv.push_str(&format!(
                "{:.4},{:.3},{gap},{:.3},{:.3},{}\n",
                s.t, s.speed_kmh, s.requested_decel, s.decel, s.command
            ));
        }
        std::fs::write(&path, csv).map_err(|source| ReplayError::Io {
            path: path.display().to_string(),
            source,
        })?;
        plot::write_svg(self, &dir.join("closed_loop.svg"))
            .map_err(|e| ReplayError::Usage(e.to_string()))
    }
}

/// A closed-loop case as a feed: frames rendered from the vehicle's pose, the vehicle driven
/// by the commands the replay decides.
pub struct ClosedLoopFeed {
    case: Case,
    mock: MockStereo,
    vehicle: Vehicle,
    frames: u64,
    /// The measured motion at each frame rendered (index: frame).
    motion: Vec<VehicleMotion>,
    noise: u64,
    armed: bool,
    report: ClosedLoopReport,
    stopped_at: Option<f64>,
    /// When the vehicle's rear passed the last actor.
    passed_at: Option<f64>,
    /// The lowest speed so far, m/s.
    slowest: f64,
    last_request: Option<(f64, f64)>,
}

impl ClosedLoopFeed {
    /// `case` through the mock rig at `width` x `height` (or the vehicle rig, when the case
    /// asks for it), the sensors' noise drawn from `seed`.
    pub fn new(case: Case, width: u32, height: u32, seed: u64) -> Result<Self, ReplayError> {
        let rig = if case.rig == "vehicle" {
            vehicle_rig()
        } else {
            mock_rig(width, height)
        }
        .map_err(crate::mock::MockError::from)?;
        let scenario = hw_mock::Scenario::by_name("empty-road")
            .ok_or_else(|| ReplayError::Usage("hw-mock has no empty-road scenario".to_string()))?;
        let mock = MockStereo::with_rig(scenario, rig, hw_mock::SensorModel::default())?;
        let vehicle = Vehicle::new(case.vehicle, case.speed)
            .map_err(|e| ReplayError::Usage(format!("case '{}': {e}", case.name)))?;
        let frames = (case.seconds * FPS).ceil() as u64 + 1;
        let slowest = case.speed;
        let report = ClosedLoopReport {
            case: case.name.clone(),
            start_kmh: case.speed * 3.6,
            end_kmh: case.speed * 3.6,
            ..ClosedLoopReport::default()
        };
        Ok(Self {
            case,
            mock,
            vehicle,
            frames,
            motion: Vec::new(),
            noise: hw_mock::splitmix64(seed ^ 0xC105_ED10_0B00),
            armed: false,
            report,
            stopped_at: None,
            passed_at: None,
            slowest,
            last_request: None,
        })
    }

    pub fn case(&self) -> &Case {
        &self.case
    }

    /// A standard normal draw from the feed's own generator.
    fn gaussian(&mut self) -> f64 {
        let mut uniform = || {
            self.noise = hw_mock::splitmix64(self.noise);
            // 53 bits in (0, 1].
            ((self.noise >> 11) as f64 + 1.0) / (1u64 << 53) as f64
        };
        let (u1, u2) = (uniform(), uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Integrates the vehicle up to `time`, checking for contact on the way; nothing moves
    /// once the run has ended.
    fn advance(&mut self, time: f64) {
        // The vehicle's clock is whole steps: within half of one is there.
        while !self.ended() && self.vehicle.state().time + 0.5 * hw_mock::vehicle::STEP < time {
            let next = (self.vehicle.state().time + CHECK_STEP).min(time);
            self.vehicle.advance_to(next);
            let s = self.vehicle.state();
            self.slowest = self.slowest.min(s.speed);
            if let Some(gap) = self.case.nearest(s.along, s.time) {
                let r = &mut self.report;
                r.min_gap_m = Some(r.min_gap_m.map_or(gap.distance, |m| m.min(gap.distance)));
                if gap.distance <= 0.0 && !r.contact {
                    r.contact = true;
                    r.impact_kmh = Some(((s.speed - gap.actor_speed) * 3.6).max(0.0));
                }
            }
            if self.passed_at.is_none() && self.case.all_passed(s.along, s.time) {
                self.passed_at = Some(s.time);
            }
            if s.held && self.stopped_at.is_none() {
                self.stopped_at = Some(s.time);
                self.report.stopped_gap_m = self
                    .case
                    .nearest(s.along, s.time)
                    .map(|g| g.distance.max(0.0));
            }
        }
    }

    fn ended(&self) -> bool {
        let s = self.vehicle.state();
        self.report.contact
            || self
                .stopped_at
                .is_some_and(|t| s.time >= t + AFTER_STANDSTILL)
            || self.passed_at.is_some_and(|t| s.time >= t + AFTER_PASSING)
    }

    /// What the run came to so far.
    pub fn report(&self) -> ClosedLoopReport {
        let mut r = self.report.clone();
        let s = self.vehicle.state();
        r.end_kmh = s.speed * 3.6;
        r.seconds = s.time;
        r.peak_decel = self.vehicle.peak_decel();
        r.peak_jerk = self.vehicle.peak_jerk();
        r.speed_lost_kmh = (self.case.speed - self.slowest).max(0.0) * 3.6;
        r
    }
}

impl FrameFeed for ClosedLoopFeed {
    fn rig(&self) -> &StereoRig {
        self.mock.rig()
    }

    fn frames(&self) -> u64 {
        self.frames
    }

    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        self.advance(index as f64 / FPS);
        let s = self.vehicle.state();
        let scene = self.case.scene(s.along, s.time);
        let yaw_rate = self.case.yaw_rate(s.along, s.speed);
        let measured = VehicleMotion {
            speed: (s.speed + SPEED_NOISE * self.gaussian()).max(0.0),
            yaw_rate: yaw_rate + YAW_RATE_NOISE * self.gaussian(),
        };
        let i = usize::try_from(index).unwrap_or(usize::MAX);
        if self.motion.len() <= i {
            let last = self.motion.last().copied().unwrap_or(measured);
            self.motion.resize(i, last);
            self.motion.push(measured);
        } else {
            self.motion[i] = measured;
        }
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        let (l, r) = self.mock.render_scene(&scene, index)?;
        super::show_rendered(frame, left, l, r)
    }

    fn motion(&self, index: u64) -> Option<VehicleMotion> {
        let i = usize::try_from(index).unwrap_or(usize::MAX);
        self.motion.get(i).or(self.motion.last()).copied()
    }

    fn motion_source(&self) -> Option<String> {
        Some(format!(
            "closed loop '{}' (the mock vehicle's speed and yaw rate, noise {SPEED_NOISE} m/s, \
             {YAW_RATE_NOISE} rad/s)",
            self.case.name
        ))
    }

    fn obey(&mut self, time: Duration, decision: &Decision) {
        let t = time.as_secs_f64();
        self.advance(t);
        if !self.armed {
            if decision.reason != CommandReason::Perception || t < self.case.warmup {
                return;
            }
            self.armed = true;
            self.report.armed_s = Some(t);
        }
        if self.ended() {
            return;
        }
        let requested = match decision.command {
            Command::Clear => 0.0,
            _ => decision.requested_decel,
        };
        self.vehicle.request(requested);
        let s = self.vehicle.state();
        let gap = self.case.nearest(s.along, s.time);
        let ttc = gap.and_then(|g| {
            let closing = s.speed - g.actor_speed;
            (closing > 0.0).then(|| g.distance.max(0.0) / closing)
        });
        let r = &mut self.report;
        match decision.command {
            Command::Slow if r.first_slow_s.is_none() => {
                r.first_slow_s = Some(t);
                r.first_slow_ttc_s = ttc;
            }
            Command::Stop if r.first_stop_s.is_none() => {
                r.first_stop_s = Some(t);
                r.first_stop_ttc_s = ttc;
                if r.first_slow_s.is_none() {
                    r.first_slow_s = Some(t);
                    r.first_slow_ttc_s = ttc;
                }
            }
            _ => {}
        }
        if requested > r.peak_requested_decel {
            r.peak_requested_decel = requested;
            r.peak_requested_at_s = Some(t);
        }
        if let Some((t0, a0)) = self.last_request
            && t > t0
        {
            r.peak_requested_jerk = r.peak_requested_jerk.max((requested - a0) / (t - t0));
        }
        self.last_request = Some((t, requested));
        r.samples.push(LoopSample {
            t,
            speed_kmh: s.speed * 3.6,
            gap_m: gap.map(|g| g.distance),
            requested_decel: requested,
            decel: s.decel,
            command: decision.command,
        });
    }

    fn tracked(&mut self, _time: Duration, tracked: &flyd_core::perception::Tracked) {
        let (Some(o), Some(m)) = (tracked.confirmed(), tracked.motion) else {
            return;
        };
        let s = self.vehicle.state();
        let Some(gap) = self.case.nearest(s.along, s.time) else {
            return;
        };
        // The same object: the tracked one within 3 m of the actor's near end.
        if (o.distance - (gap.distance + self.case.body.front)).abs() > 3.0 {
            return;
        }
        let checks = &mut self.report.motion_by_sightings;
        if checks.iter().all(|c| c.sightings != m.samples) {
            checks.push(MotionCheck {
                sightings: m.samples,
                speed: m.speed,
                truth: gap.actor_speed,
                sigma: m.speed_sigma,
                established: m.established,
            });
        }
    }

    fn finished(&self) -> bool {
        self.ended()
    }

    fn closed_loop(&self) -> Option<ClosedLoopReport> {
        Some(self.report())
    }
}

#[cfg(test)]
mod tests;
