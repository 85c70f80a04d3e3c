//! From perception to CLEAR / SLOW / STOP: a pure state machine.
//!
//! No clock, no I/O: the caller passes the monotonic time of each snapshot, so every behaviour
//! is reproducible in a test.
//!
//! # What the command is decided on ([`DecisionMode`])
//! - **`obstacle`** (default): the confirmed nearest obstacle in the corridor
//!   ([`crate::perception`]), at distance `d` metres (its near bound,
//!   [`crate::perception::Obstacle::near`]), and the vehicle's speed `v` (m/s). A
//!   command's *reach* is the distance the vehicle needs to stop with that command's
//!   deceleration: `v reaction_time + v^2 / (2 decel) + margin` (Autoware's AEB and RSS use the
//!   same form). The obstacle is taken where it will be when the next evidence can change the
//!   command: `d' = d - v latency`, the latency being the evidence's age plus a frame period
//!   ([`DecisionInput::latency`]): a STOP decided on the next frame would come a frame's
//!   travel too late. The level is STOP if `d' <= reach(STOP)`, SLOW if `d' <= reach(SLOW)`,
//!   else CLEAR; no obstacle is CLEAR. At 30 km/h with the defaults (0.5 s, 2 m, 4 and 1.5 m/s^2):
//!   STOP within 14.9 m, SLOW within 29.3 m. SLOW requests `slow_decel`; STOP `stop_decel`, or
//!   when the obstacle is already nearer what the distance left needs, up to `max_decel`
//!   ([`DecisionConfig::max_decel`]).
//! - **`global-warning`**: the paper's rule. `w` the global warning (the mean fly warning),
//!   STOP if `w >= stop_threshold`, SLOW if `w >= slow_threshold`. Its scale follows the images'
//!   gradients and textures: thresholds written in it carry over from no camera or scene to
//!   another (0.002-0.01 on real KITTI roads, 0.06 on hw-mock's empty road).
//!
//! - **An obstacle that moves** ([`DecisionInput::obstacle_speed`]: its speed over the ground
//!   along the path, credited only once its motion is established and less two standard errors,
//!   never for an oncoming one; SLOW is judged with it less one,
//!   [`DecisionInput::obstacle_speed_slow`]: the early, gentle level, with STOP still on
//!   guard at two): the reach above becomes what the encounter uses of the gap
//!   ([`encounter::consumed`]) plus the margin, the vehicle braking with the command's
//!   deceleration after the reaction time, the obstacle braking from now with
//!   `lead_decel / stop_decel` of it (STOP: 3 m/s^2 by default, firm braking in traffic;
//!   SLOW: 1.1 m/s^2). The vehicle so keeps a quarter of each command's deceleration to close
//!   the speed difference: an obstacle that brakes harder shows as its speed drops (its speed
//!   is measured over the last half second), and the next evidence decides on that.
//!   RSS's worst case (the obstacle braking at 8 m/s^2, harder than the vehicle) asks a gap of
//!   2 s for a following at 50 km/h without a STOP, which no traffic keeps; with the defaults
//!   a car followed at the vehicle's speed asks a SLOW within 2.6 m and a STOP within 3.5 m
//!   (at 30 and at 50 km/h; the evidence's latency counts the closing speed only,
//!   `d - (v - u) latency`). A STOP requests the deceleration that keeps the margin under the
//!   same assumption, between `stop_decel` and `max_decel`. A still obstacle
//!   (`obstacle_speed` 0) is decided exactly as above.
//!
//! Both are a ratio per command, `reach / d` or `w / threshold`: the command's level is asked
//! when its ratio is at least 1, and the ratio must fall below `release_ratio` to release it.
//!
//! # Rules
//! 1. **Escalation is immediate**: a level above the current command becomes the command at once.
//! 2. **Release needs time** (hysteresis + hold): STOP is left only once its ratio has stayed
//!    below `release_ratio` *continuously* for `stop_hold` (an obstacle beyond
//!    `reach / release_ratio`, a warning below `threshold * release_ratio`), with perception
//!    healthy throughout; SLOW likewise for `slow_hold`. Both holds must be > 0, so one good
//!    snapshot never releases anything. The steps are evaluated together: after a long calm,
//!    STOP may go straight to CLEAR.
//! 3. **Faults fail safe**: when any fault bit in `fault_mask` is set, or the input cannot be
//!    true (a warning NaN, infinite or negative; an obstacle distance or a speed NaN or
//!    negative), the command becomes `max(current, safe_command)`: a STOP is never downgraded
//!    by a fault. A valid input during a fault may still raise the command, never lower it.
//!    Snapshots taken during a fault do not count towards a hold: after recovery the holds
//!    start again.
//! 4. **Start-up is a fault**: before the first healthy snapshots there is no evidence that the
//!    road is clear, so the decider starts at `safe_command` (reason FAULT_FALLBACK) and reaches
//!    CLEAR only through rule 2.
//! 5. **Shutdown** latches `max(current, safe_command)` with reason SHUTDOWN.
//!
//! The reason is PERCEPTION when the perception output alone justifies the command,
//! FAULT_FALLBACK while a fault is active or while a command entered because of one is still
//! held, SHUTDOWN at the end.

use std::time::Duration;

use thiserror::Error;

use crate::status::FaultBits;

named_enum! {
    /// What the vehicle is asked to do. Ordered by severity: `Clear < Slow < Stop`, so
    /// "the more cautious of two commands" is `max`.
    pub enum Command {
        /// No obstacle of concern: no request.
        Clear = 0 => "CLEAR",
        /// Slow down with the requested deceleration.
        Slow = 1 => "SLOW",
        /// Stop with the requested deceleration.
        Stop = 2 => "STOP",
    }
}

named_enum! {
    /// Why the current command is what it is.
    pub enum CommandReason {
        /// The perception output alone justifies the command.
        Perception = 0 => "PERCEPTION",
        /// Perception is not trusted (fault, invalid warning, not yet started), or the command is
        /// still held from such a period: the command is the configured safe fallback or higher.
        FaultFallback = 1 => "FAULT_FALLBACK",
        /// flyd is shutting down; the command is the last one it will send.
        Shutdown = 2 => "SHUTDOWN",
    }
}

named_enum! {
    /// What the command is decided on (see the module docs).
    pub enum DecisionMode {
        /// The confirmed nearest obstacle against the stopping distance at the vehicle's speed.
        Obstacle = 0 => "obstacle",
        /// The paper's global warning against thresholds.
        GlobalWarning = 1 => "global-warning",
    }
}

/// Tuning of the [`Decider`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecisionConfig {
    pub mode: DecisionMode,
    /// `global-warning` mode: warning at or above which SLOW is commanded.
    pub slow_threshold: f64,
    /// `global-warning` mode: warning at or above which STOP is commanded.
    pub stop_threshold: f64,
    /// A command is released once its ratio (see the module docs) stays below this, in (0, 1]:
    /// the gap is the hysteresis.
    pub release_ratio: f64,
    /// How long SLOW's ratio must stay below `release_ratio` before SLOW is released.
    pub slow_hold: Duration,
    /// How long STOP's ratio must stay below `release_ratio` before STOP is released.
    pub stop_hold: Duration,
    /// Command while perception is faulty: SLOW or STOP (never CLEAR).
    pub safe_command: Command,
    /// Fault bits that make perception untrusted (default: all).
    pub fault_mask: FaultBits,
    /// Requested deceleration for SLOW, m/s² (and the one its reach assumes).
    pub slow_decel: f64,
    /// Requested deceleration for STOP, m/s².
    pub stop_decel: f64,
    /// The most a STOP requests, m/s²: a STOP decided with the obstacle already nearer than
    /// the STOP distance (confirmed late, or on the corridor only once the vehicle's paths
    /// agree) requests what the distance left needs, `v^2 / (2 (d - v (latency +
    /// reaction_time) - margin))`, between `stop_decel` and this.
    pub max_decel: f64,
    /// `obstacle` mode: time from the obstacle's evidence to the brakes acting, s.
    pub reaction_time: Duration,
    /// `obstacle` mode: distance kept to the obstacle once stopped, m.
    pub margin: f64,
    /// `obstacle` mode: how hard an obstacle that moves is assumed to brake when STOP is
    /// judged, m/s^2; SLOW assumes the same share of its own deceleration (see the module
    /// docs).
    pub lead_decel: f64,
}

impl Default for DecisionConfig {
    fn default() -> Self {
        Self {
            mode: DecisionMode::Obstacle,
            slow_threshold: 0.5,
            stop_threshold: 1.5,
            release_ratio: 0.8,
            slow_hold: Duration::from_millis(500),
            stop_hold: Duration::from_millis(1000),
            safe_command: Command::Slow,
            fault_mask: FaultBits::all(),
            slow_decel: 1.5,
            stop_decel: 4.0,
            max_decel: 9.0,
            reaction_time: Duration::from_millis(500),
            margin: 2.0,
            lead_decel: 3.0,
        }
    }
}

/// A [`DecisionConfig`] the decider refuses.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum DecisionConfigError {
    #[error("thresholds must be finite with 0 < slow ({slow}) <= stop ({stop})")]
    Thresholds { slow: f64, stop: f64 },
    #[error("release_ratio must be in (0, 1], got {0}")]
    ReleaseRatio(f64),
    #[error("hold times must be > 0 (one snapshot must never release a command)")]
    ZeroHold,
    #[error("safe_command must be SLOW or STOP")]
    UnsafeFallback,
    #[error("deceleration for {command} must be finite and > 0, got {value}")]
    Decel { command: Command, value: f64 },
    #[error("the stopping distance needs SLOW's deceleration ({slow}) <= STOP's ({stop})")]
    DecelOrder { slow: f64, stop: f64 },
    #[error("max_decel ({max}) must be at least stop_decel ({stop})")]
    MaxDecel { stop: f64, max: f64 },
    #[error("margin must be finite and >= 0, got {0}")]
    Margin(f64),
    /// A value beyond what a vehicle can mean (the bounds are the variant's `range`).
    #[error("{key} must be within {range}, got {value}")]
    OutOfRange {
        key: &'static str,
        value: f64,
        range: &'static str,
    },
}

impl DecisionConfig {
    pub fn validate(&self) -> Result<(), DecisionConfigError> {
        let (slow, stop) = (self.slow_threshold, self.stop_threshold);
        if !(slow.is_finite() && stop.is_finite() && slow > 0.0 && slow <= stop) {
            return Err(DecisionConfigError::Thresholds { slow, stop });
        }
        if !(self.release_ratio > 0.0 && self.release_ratio <= 1.0) {
            return Err(DecisionConfigError::ReleaseRatio(self.release_ratio));
        }
        if self.slow_hold.is_zero() || self.stop_hold.is_zero() {
            return Err(DecisionConfigError::ZeroHold);
        }
        if self.safe_command == Command::Clear {
            return Err(DecisionConfigError::UnsafeFallback);
        }
        for (command, value) in [
            (Command::Slow, self.slow_decel),
            (Command::Stop, self.stop_decel),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(DecisionConfigError::Decel { command, value });
            }
        }
        if self.slow_decel > self.stop_decel {
            return Err(DecisionConfigError::DecelOrder {
                slow: self.slow_decel,
                stop: self.stop_decel,
            });
        }
        if !(self.max_decel.is_finite() && self.max_decel >= self.stop_decel) {
            return Err(DecisionConfigError::MaxDecel {
                stop: self.stop_decel,
                max: self.max_decel,
            });
        }
        if !(self.margin.is_finite() && self.margin >= 0.0) {
            return Err(DecisionConfigError::Margin(self.margin));
        }
        // What a vehicle can mean: a threshold the CAN signal can carry (GlobalWarning
        // saturates at 65.534), decelerations a car brakes with (1 g is ~9.8 m/s^2), reaction
        // times and margins of metres and seconds, holds under a minute.
        let secs = |d: Duration| d.as_secs_f64();
        let checks: [(&'static str, f64, f64, f64, &'static str); 9] = [
            ("stop_threshold", stop, 0.0, 65.0, "(0, 65]"),
            ("slow_decel", self.slow_decel, 0.5, 10.0, "0.5..=10 m/s^2"),
            ("stop_decel", self.stop_decel, 1.0, 10.0, "1..=10 m/s^2"),
            ("max_decel", self.max_decel, 1.0, 10.0, "1..=10 m/s^2"),
            (
                "reaction_time_ms",
                secs(self.reaction_time) * 1e3,
                0.0,
                3000.0,
                "0..=3000 ms",
            ),
            ("margin_m", self.margin, 0.0, 20.0, "0..=20 m"),
            ("lead_decel", self.lead_decel, 1.0, 10.0, "1..=10 m/s^2"),
            (
                "slow_hold_ms",
                secs(self.slow_hold) * 1e3,
                0.0,
                60_000.0,
                "(0, 60000] ms",
            ),
            (
                "stop_hold_ms",
                secs(self.stop_hold) * 1e3,
                0.0,
                60_000.0,
                "(0, 60000] ms",
            ),
        ];
        for (key, value, lo, hi, range) in checks {
            if !(lo..=hi).contains(&value) {
                return Err(DecisionConfigError::OutOfRange { key, value, range });
            }
        }
        Ok(())
    }

    /// The deceleration requested with `command` (0 for CLEAR).
    pub fn decel_for(&self, command: Command) -> f64 {
        match command {
            Command::Clear => 0.0,
            Command::Slow => self.slow_decel,
            Command::Stop => self.stop_decel,
        }
    }

    /// `obstacle` mode: the distance within which an obstacle asks for `command` (SLOW or
    /// STOP) at `speed` m/s: `v reaction_time + v^2 / (2 decel) + margin`, metres.
    pub fn reach(&self, command: Command, speed: f64) -> f64 {
        self.reach_at(self.decel_for(command), speed)
    }

    /// The distance within which braking with `decel` m/s^2 must start at `speed` m/s to
    /// stop short by the margin: `v reaction_time + v^2 / (2 decel) + margin`, metres (0
    /// without a deceleration).
    pub fn reach_at(&self, decel: f64, speed: f64) -> f64 {
        if decel <= 0.0 {
            return 0.0;
        }
        speed * self.reaction_time.as_secs_f64() + speed * speed / (2.0 * decel) + self.margin
    }

    /// `obstacle` mode: [`DecisionConfig::reach`] with the obstacle ahead at `obstacle_speed`
    /// m/s along the path (see the module docs): what the encounter uses of the gap when the
    /// vehicle brakes with `command`, plus the margin. The still obstacle's reach when
    /// `obstacle_speed` is 0.
    pub fn reach_behind(&self, command: Command, speed: f64, obstacle_speed: f64) -> f64 {
        if obstacle_speed <= 0.0 {
            return self.reach(command, speed);
        }
        let decel = self.decel_for(command);
        if decel <= 0.0 {
            return 0.0;
        }
        let rho = self.reaction_time.as_secs_f64();
        encounter::consumed(
            speed,
            obstacle_speed,
            rho,
            decel,
            self.assumed_braking(command),
        ) + self.margin
    }

    /// How hard an obstacle that moves is assumed to brake when `command` is judged:
    /// `lead_decel` for STOP, the same share of SLOW's deceleration for SLOW.
    fn assumed_braking(&self, command: Command) -> f64 {
        self.lead_decel * self.decel_for(command) / self.stop_decel
    }
}

/// One perception snapshot as the decider sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecisionInput {
    /// The global warning (`global-warning` mode; NaN, ±inf and negative values count as a
    /// fault there).
    pub global_warning: f64,
    /// The confirmed nearest obstacle's distance, metres (`obstacle` mode; NaN or negative is
    /// a fault there).
    pub obstacle: Option<f64>,
    /// Its speed over the ground along the path that the decision may credit, m/s: 0 for an
    /// obstacle taken as still (a motion not established, oncoming, or uncertain); see
    /// [`crate::perception::Tracked::decision_speed`]. NaN, infinite or negative counts as 0
    /// (still: the conservative reading, never a fault).
    pub obstacle_speed: f64,
    /// The speed SLOW is judged with, m/s: the same, credited less one standard error instead
    /// of two ([`crate::perception::Tracked::slow_speed`]); taken as `obstacle_speed` where
    /// that is higher.
    pub obstacle_speed_slow: f64,
    /// The obstacle stands beside the corridor and is only predicted to walk into it
    /// ([`crate::perception::crossing`]): a prediction is acted on a stage later than an
    /// obstacle in the path. SLOW where one in the path would be STOPped for (within the
    /// reach of `stop_decel`), STOP at the latest moment the brakes still stop short of it
    /// (its reach at `max_decel`). Someone who walks towards the road and stops at its kerb
    /// is then braked for gently, if at all; a car parked beside the lane whose inner edge
    /// the flies read 18 m ahead as moving in (hw-mock, 30 km/h) is not slowed for, where
    /// SLOW's own reach (29.3 m) took it.
    pub obstacle_entering: bool,
    /// The vehicle's speed, m/s (`obstacle` mode; NaN or negative is a fault there).
    pub speed: f64,
    /// `obstacle` mode: seconds the vehicle drives before the next evidence can change the
    /// command: the age of this evidence (from its frame's capture) plus a frame period. The
    /// obstacle is taken that much nearer, `d - v latency` (NaN, infinite or negative is a
    /// fault there).
    pub latency: f64,
    /// Active faults; those in [`DecisionConfig::fault_mask`] make perception untrusted.
    pub faults: FaultBits,
}

impl DecisionInput {
    /// A healthy snapshot of global warning `global_warning`, no obstacle, at standstill.
    pub fn healthy(global_warning: f64) -> Self {
        Self {
            global_warning,
            obstacle: None,
            obstacle_speed: 0.0,
            obstacle_speed_slow: 0.0,
            obstacle_entering: false,
            speed: 0.0,
            latency: 0.0,
            faults: FaultBits::empty(),
        }
    }

    /// A healthy snapshot with the confirmed obstacle at `distance` (if any) at `speed` m/s.
    pub fn at_speed(obstacle: Option<f64>, speed: f64) -> Self {
        Self {
            obstacle,
            speed,
            ..Self::healthy(0.0)
        }
    }

    /// The more alarming of two snapshots taken between two commands (so that none is lost):
    /// the higher warning, the nearer obstacle and the lower speed credited to it, the higher
    /// speed, every fault; an invalid value of either stays (it is a fault).
    pub fn worst(self, other: Self) -> Self {
        let invalid = |v: f64| !(v.is_finite() && v >= 0.0);
        let high = |a: f64, b: f64| {
            if invalid(a) {
                a
            } else if invalid(b) {
                b
            } else {
                a.max(b)
            }
        };
        let obstacle = match (self.obstacle, other.obstacle) {
            (Some(a), Some(b)) => Some(if a.is_nan() || b.is_nan() || a < 0.0 || b < 0.0 {
                f64::NAN
            } else {
                a.min(b)
            }),
            (a, b) => a.or(b),
        };
        let lower = |command| match (self.obstacle, other.obstacle) {
            (Some(_), Some(_)) => self.credited_for(command).min(other.credited_for(command)),
            (Some(_), None) => self.credited_for(command),
            (None, Some(_)) => other.credited_for(command),
            (None, None) => 0.0,
        };
        let (obstacle_speed, obstacle_speed_slow) = (lower(Command::Stop), lower(Command::Slow));
        // Taken as only entering when every obstacle of the two is.
        let obstacle_entering = match (self.obstacle, other.obstacle) {
            (Some(_), Some(_)) => self.obstacle_entering && other.obstacle_entering,
            (Some(_), None) => self.obstacle_entering,
            (None, Some(_)) => other.obstacle_entering,
            (None, None) => false,
        };
        Self {
            global_warning: high(self.global_warning, other.global_warning),
            obstacle,
            obstacle_speed,
            obstacle_speed_slow,
            obstacle_entering,
            speed: high(self.speed, other.speed),
            latency: high(self.latency, other.latency),
            faults: self.faults | other.faults,
        }
    }

    /// [`DecisionInput::obstacle_speed`] as the decision takes it (0 unless finite and > 0).
    pub fn credited(&self) -> f64 {
        let u = self.obstacle_speed;
        if u.is_finite() && u > 0.0 { u } else { 0.0 }
    }

    /// The speed `command` is judged with: SLOW's [`DecisionInput::obstacle_speed_slow`] (at
    /// least [`DecisionInput::credited`]), STOP's [`DecisionInput::credited`]; 0 for CLEAR.
    pub fn credited_for(&self, command: Command) -> f64 {
        match command {
            Command::Clear => 0.0,
            Command::Stop => self.credited(),
            Command::Slow => {
                let u = self.obstacle_speed_slow;
                if u.is_finite() && u > 0.0 {
                    u.max(self.credited())
                } else {
                    self.credited()
                }
            }
        }
    }
}

/// What to send, and what to log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision {
    pub command: Command,
    pub reason: CommandReason,
    /// m/s², from the config for `command`.
    pub requested_decel: f64,
    /// The command differs from the previous decision's (log it).
    pub changed: bool,
    pub previous: Command,
    /// Perception was untrusted for this snapshot (always `false` once shut down: the input
    /// is ignored then).
    pub fault: bool,
}

/// Per command, how far into its level the input is: asked at >= 1 (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ratios {
    slow: f64,
    stop: f64,
}

/// The state machine; see the module docs for the rules.
#[derive(Debug, Clone)]
pub struct Decider {
    config: DecisionConfig,
    command: Command,
    reason: CommandReason,
    /// Since when (healthy snapshots only) SLOW's ratio is below the release ratio.
    below_slow_release_since: Option<Duration>,
    /// Since when (healthy snapshots only) STOP's ratio is below the release ratio.
    below_stop_release_since: Option<Duration>,
    /// The deceleration the latest trusted evidence needs to stop before its obstacle, m/s²
    /// (0: none; infinite: no room left).
    needed: f64,
    shut_down: bool,
}

impl Decider {
    pub fn new(config: DecisionConfig) -> Result<Self, DecisionConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            command: config.safe_command,
            reason: CommandReason::FaultFallback,
            below_slow_release_since: None,
            below_stop_release_since: None,
            needed: 0.0,
            shut_down: false,
        })
    }

    pub fn config(&self) -> &DecisionConfig {
        &self.config
    }

    /// The current command (before any update: the safe command).
    pub fn command(&self) -> Command {
        self.command
    }

    /// Whether a valid `input` asks for more than the current command (an escalation, which
    /// the control thread sends at once instead of at the next period).
    pub fn escalates(&self, input: &DecisionInput) -> bool {
        !self.shut_down && self.ratios(input).is_some_and(|r| level(r) > self.command)
    }

    /// Feeds one snapshot taken at monotonic time `now`. Times must not go backwards; if they
    /// do, elapsed time counts as zero (holds get longer, never shorter).
    pub fn update(&mut self, input: DecisionInput, now: Duration) -> Decision {
        let previous = self.command;
        if self.shut_down {
            return self.decision(previous, false);
        }
        let cfg = self.config;
        let ratios = self.ratios(&input);
        let fault = ratios.is_none() || input.faults.intersects(cfg.fault_mask);
        let level = ratios.map_or(Command::Clear, level);

        self.needed = if fault { 0.0 } else { self.needed_by(&input) };
        if let (false, Some(r)) = (fault, ratios) {
            Self::track(
                &mut self.below_stop_release_since,
                r.stop < cfg.release_ratio,
                now,
            );
            Self::track(
                &mut self.below_slow_release_since,
                r.slow < cfg.release_ratio,
                now,
            );
            let mut command = self.command.max(level);
            if command == Command::Stop
                && Self::held(self.below_stop_release_since, cfg.stop_hold, now)
            {
                command = Command::Slow;
            }
            if command == Command::Slow
                && Self::held(self.below_slow_release_since, cfg.slow_hold, now)
            {
                command = Command::Clear;
            }
            // Release levels are below the levels, so this cannot bite; it states the
            // invariant that a release never undercuts what the input asks for.
            command = command.max(level);
            self.command = command;
            if level >= command {
                self.reason = CommandReason::Perception;
            }
            // Otherwise the command is held above the input's level: keep the reason that
            // brought it there (hysteresis after PERCEPTION, hold after FAULT_FALLBACK).
        } else {
            // Untrusted snapshots are no evidence of a clear road: holds restart after recovery.
            self.below_slow_release_since = None;
            self.below_stop_release_since = None;
            self.command = self.command.max(cfg.safe_command).max(level);
            self.reason = CommandReason::FaultFallback;
        }
        self.decision(previous, fault)
    }

    /// The final decision: `max(current, safe_command)`, reason SHUTDOWN, latched (later
    /// updates return it unchanged).
    pub fn shutdown(&mut self) -> Decision {
        let previous = self.command;
        self.command = self.command.max(self.config.safe_command);
        self.reason = CommandReason::Shutdown;
        self.shut_down = true;
        self.decision(previous, false)
    }

    /// What `input` asks for, whatever the current command: the level of the mode's ratios
    /// (CLEAR for an input that cannot be true).
    pub fn level(&self, input: &DecisionInput) -> Command {
        self.ratios(input).map_or(Command::Clear, level)
    }

    /// The mode's ratios, `None` for an input that cannot be true.
    fn ratios(&self, input: &DecisionInput) -> Option<Ratios> {
        let c = &self.config;
        let valid = |v: f64| v.is_finite() && v >= 0.0;
        match c.mode {
            DecisionMode::GlobalWarning => {
                let w = input.global_warning;
                valid(w).then(|| Ratios {
                    slow: w / c.slow_threshold,
                    stop: w / c.stop_threshold,
                })
            }
            DecisionMode::Obstacle => {
                let (v, latency) = (input.speed, input.latency);
                if !(valid(v) && valid(latency)) {
                    return None;
                }
                match input.obstacle {
                    None => Some(Ratios {
                        slow: 0.0,
                        stop: 0.0,
                    }),
                    // +inf is a valid "nothing within range".
                    Some(d) if d.is_nan() || d < 0.0 => None,
                    Some(d) => {
                        // Where the obstacle will be when the next evidence can act.
                        // Both move on meanwhile (a still one: `v - 0` is `v`, bit for bit).
                        let ratio = |command| {
                            let u = input.credited_for(command);
                            let d = d - (v - u) * latency;
                            let reach = match (command, input.obstacle_entering) {
                                (Command::Stop, true) => {
                                    c.reach_at(c.max_decel.max(c.stop_decel), v)
                                }
                                (_, true) => c.reach_behind(Command::Stop, v, u),
                                _ => c.reach_behind(command, v, u),
                            };
                            if d > 0.0 { reach / d } else { f64::INFINITY }
                        };
                        Some(Ratios {
                            slow: ratio(Command::Slow),
                            stop: ratio(Command::Stop),
                        })
                    }
                }
            }
        }
    }

    fn track(since: &mut Option<Duration>, below: bool, now: Duration) {
        if !below {
            *since = None;
        } else if since.is_none() {
            *since = Some(now);
        }
    }

    fn held(since: Option<Duration>, hold: Duration, now: Duration) -> bool {
        since.is_some_and(|t| now.saturating_sub(t) >= hold)
    }

    /// `obstacle` mode: the deceleration that stops the vehicle `margin` before the obstacle
    /// of `input`, after its latency and the reaction time (0 without one or standing still;
    /// infinite when that leaves no room).
    fn needed_by(&self, input: &DecisionInput) -> f64 {
        let c = &self.config;
        let (v, latency) = (input.speed, input.latency);
        match (c.mode, input.obstacle) {
            (DecisionMode::Obstacle, Some(d))
                if d.is_finite()
                    && v.is_finite()
                    && v > 0.0
                    && latency.is_finite()
                    && input.credited() > 0.0 =>
            {
                let (u, rho) = (input.credited(), c.reaction_time.as_secs_f64());
                let room = d - (v - u) * latency.max(0.0) - c.margin;
                let b = c.assumed_braking(Command::Stop);
                encounter::needed(v, u, rho, room, |_| b, c.max_decel)
            }
            (DecisionMode::Obstacle, Some(d))
                if d.is_finite() && v.is_finite() && v > 0.0 && latency.is_finite() =>
            {
                let room = d - v * (latency.max(0.0) + c.reaction_time.as_secs_f64()) - c.margin;
                if room > 0.0 {
                    v * v / (2.0 * room)
                } else {
                    f64::INFINITY
                }
            }
            _ => 0.0,
        }
    }

    fn decision(&self, previous: Command, fault: bool) -> Decision {
        let c = &self.config;
        // A STOP on the evidence asks for what its distance needs, at least `stop_decel`.
        let requested_decel = if self.command == Command::Stop
            && self.reason == CommandReason::Perception
            && !self.shut_down
        {
            self.needed
                .clamp(c.stop_decel, c.max_decel.max(c.stop_decel))
        } else {
            c.decel_for(self.command)
        };
        Decision {
            command: self.command,
            reason: self.reason,
            requested_decel,
            changed: self.command != previous,
            previous,
            fault,
        }
    }
}

/// The level of `r`: STOP if its STOP ratio is at least 1, SLOW if its SLOW one is.
fn level(r: Ratios) -> Command {
    if r.stop >= 1.0 {
        Command::Stop
    } else if r.slow >= 1.0 {
        Command::Slow
    } else {
        Command::Clear
    }
}

pub mod encounter;
#[cfg(test)]
mod tests;
