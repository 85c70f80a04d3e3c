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
        let checks: [(&'static str, f64, f64, f64, &'static str); 8] = [
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
        let decel = self.decel_for(command);
        if decel <= 0.0 {
            return 0.0;
        }
        speed * self.reaction_time.as_secs_f64() + speed * speed / (2.0 * decel) + self.margin
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
    /// the higher warning, the nearer obstacle, the higher speed, every fault; an invalid
    /// value of either stays (it is a fault).
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
        Self {
            global_warning: high(self.global_warning, other.global_warning),
            obstacle,
            speed: high(self.speed, other.speed),
            latency: high(self.latency, other.latency),
            faults: self.faults | other.faults,
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
                        let d = d - v * latency;
                        let ratio = |command| {
                            let reach = c.reach(command, v);
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

#[cfg(test)]
mod tests {
    use super::*;
    use Command::{Clear, Slow, Stop};

    const NONE: FaultBits = FaultBits::empty();
    const STALE: FaultBits = FaultBits::SNAPSHOT_STALE;

    /// Thresholds 0.3 / 0.6, ratio 0.5 (release below 0.15 / 0.3), holds 200 / 500 ms.
    fn cfg() -> DecisionConfig {
        DecisionConfig {
            slow_threshold: 0.3,
            stop_threshold: 0.6,
            release_ratio: 0.5,
            slow_hold: Duration::from_millis(200),
            stop_hold: Duration::from_millis(500),
            safe_command: Slow,
            fault_mask: FaultBits::all(),
            slow_decel: 1.5,
            stop_decel: 4.0,
            mode: DecisionMode::GlobalWarning,
            ..DecisionConfig::default()
        }
    }

    /// Runs `steps` of (ms, warning, faults) through a fresh decider and compares the commands;
    /// on mismatch, prints the whole trace.
    fn check_with(
        config: DecisionConfig,
        steps: &[(u64, f64, FaultBits)],
        expected: &[Command],
    ) -> Vec<Decision> {
        assert_eq!(steps.len(), expected.len(), "test table is malformed");
        let mut decider = Decider::new(config).expect("valid config");
        let decisions: Vec<Decision> = steps
            .iter()
            .map(|&(ms, w, faults)| {
                decider.update(
                    DecisionInput {
                        faults,
                        ..DecisionInput::healthy(w)
                    },
                    Duration::from_millis(ms),
                )
            })
            .collect();
        let got: Vec<Command> = decisions.iter().map(|d| d.command).collect();
        if got != expected {
            let trace: Vec<String> = steps
                .iter()
                .zip(&got)
                .zip(expected)
                .map(|((s, g), e)| {
                    format!(
                        "t={:>5} w={:<6} faults={:<20} got {:<5} want {}{}",
                        s.0,
                        s.1,
                        s.2.to_string(),
                        g.name(),
                        e.name(),
                        if g == e { "" } else { "   <--" }
                    )
                })
                .collect();
            panic!("command sequence differs:\n{}", trace.join("\n"));
        }
        decisions
    }

    fn check(steps: &[(u64, f64, FaultBits)], expected: &[Command]) -> Vec<Decision> {
        check_with(cfg(), steps, expected)
    }

    /// Three calm snapshots that take a fresh decider from its start-up SLOW to CLEAR.
    const WARM: [(u64, f64, FaultBits); 3] = [(0, 0.0, NONE), (100, 0.0, NONE), (200, 0.0, NONE)];
    const WARM_CMDS: [Command; 3] = [Slow, Slow, Clear];

    fn warm_then(steps: &[(u64, f64, FaultBits)], expected: &[Command]) -> Vec<Decision> {
        let all_steps: Vec<_> = WARM.iter().chain(steps).copied().collect();
        let all_expected: Vec<_> = WARM_CMDS.iter().chain(expected).copied().collect();
        check(&all_steps, &all_expected)[WARM.len()..].to_vec()
    }

    #[test]
    fn starts_safe_and_clears_only_after_the_hold() {
        let d = check(
            &[
                (0, 0.0, NONE),
                (100, 0.0, NONE),
                (199, 0.0, NONE),
                (200, 0.0, NONE),
            ],
            &[Slow, Slow, Slow, Clear],
        );
        assert_eq!(d[0].reason, CommandReason::FaultFallback);
        assert_eq!(d[2].reason, CommandReason::FaultFallback);
        assert!(!d[2].changed);
        assert_eq!(d[3].reason, CommandReason::Perception);
        assert!(d[3].changed);
        assert_eq!(d[3].requested_decel, 0.0);
    }

    #[test]
    fn escalates_only_above_the_current_command() {
        let mut d = Decider::new(cfg()).expect("valid");
        let ms = Duration::from_millis;
        // Start-up SLOW: only a STOP-level warning escalates.
        assert!(
            !d.escalates(&DecisionInput::healthy(0.4)) && d.escalates(&DecisionInput::healthy(0.6))
        );
        for t in [0, 100, 200] {
            d.update(DecisionInput::healthy(0.0), ms(t));
        }
        assert_eq!(d.command(), Clear);
        assert!(!d.escalates(&DecisionInput::healthy(0.29)), "below SLOW");
        assert!(
            d.escalates(&DecisionInput::healthy(0.3)) && d.escalates(&DecisionInput::healthy(5.0))
        );
        assert!(
            !d.escalates(&DecisionInput::healthy(f64::NAN))
                && !d.escalates(&DecisionInput::healthy(-1.0)),
            "faults are not escalations"
        );
        d.update(DecisionInput::healthy(0.7), ms(300));
        assert_eq!(d.command(), Stop);
        assert!(
            !d.escalates(&DecisionInput::healthy(9.0)),
            "nothing above STOP"
        );
        d.shutdown();
        assert!(
            !d.escalates(&DecisionInput::healthy(9.0)),
            "latched after shutdown"
        );
    }

    #[test]
    fn rise_to_slow() {
        let d = warm_then(
            &[(300, 0.29, NONE), (400, 0.3, NONE), (500, 0.59, NONE)],
            &[Clear, Slow, Slow],
        );
        assert!(d[1].changed && d[1].previous == Clear);
        assert_eq!(d[1].reason, CommandReason::Perception);
        assert_eq!(d[1].requested_decel, 1.5);
    }

    #[test]
    fn rise_to_stop_directly_and_through_slow() {
        warm_then(&[(300, 0.6, NONE)], &[Stop]);
        let d = warm_then(
            &[(300, 0.4, NONE), (400, 0.7, NONE), (500, 5.0, NONE)],
            &[Slow, Stop, Stop],
        );
        assert_eq!(d[1].requested_decel, 4.0);
        assert!(d[1].changed && !d[2].changed);
    }

    #[test]
    fn hysteresis_keeps_stop_and_slow_between_release_level_and_threshold() {
        // STOP, then w just under the STOP threshold (0.59) and just above its release level
        // (0.3) for a long time: STOP stays. Then SLOW band above SLOW release (0.15): SLOW
        // stays.
        let mut steps = vec![(300, 0.8, NONE)];
        let mut want = vec![Stop];
        for t in (400..=3000).step_by(100) {
            steps.push((t, if t % 200 == 0 { 0.59 } else { 0.3 }, NONE));
            want.push(Stop);
        }
        steps.extend([(3100, 0.29, NONE), (3600, 0.29, NONE)]);
        want.extend([Stop, Slow]);
        for t in (3700..=6000).step_by(100) {
            steps.push((t, if t % 200 == 0 { 0.29 } else { 0.15 }, NONE));
            want.push(Slow);
        }
        let d = warm_then(&steps, &want);
        assert!(d.iter().all(|d| d.reason == CommandReason::Perception));
    }

    #[test]
    fn stop_needs_continuous_calm_for_the_whole_hold() {
        warm_then(
            &[
                (300, 0.9, NONE),  // STOP
                (400, 0.0, NONE),  // one good snapshot: no release
                (800, 0.0, NONE),  // 400 ms < 500 ms hold
                (850, 0.45, NONE), // above release level 0.3: hold restarts
                (900, 0.1, NONE),  // calm again from 900
                (1300, 0.1, NONE), // 400 ms
                (1399, 0.1, NONE), // 499 ms
                (1400, 0.1, NONE), // 500 ms: STOP released; SLOW calm since 900 too -> CLEAR
            ],
            &[Stop, Stop, Stop, Stop, Stop, Stop, Stop, Clear],
        );
    }

    #[test]
    fn stop_releases_to_slow_when_warning_is_still_in_the_slow_band() {
        warm_then(
            &[
                (300, 0.9, NONE),
                (400, 0.2, NONE), // below STOP release (0.3), above SLOW release (0.15)
                (900, 0.2, NONE), // STOP hold done -> SLOW
                (1000, 0.1, NONE), // below SLOW release from 1000
                (1199, 0.1, NONE),
                (1200, 0.1, NONE), // 200 ms -> CLEAR
            ],
            &[Stop, Stop, Slow, Slow, Slow, Clear],
        );
    }

    #[test]
    fn slow_hold() {
        warm_then(
            &[
                (300, 0.35, NONE),
                (350, 0.1, NONE),
                (500, 0.1, NONE),
                (520, 0.2, NONE), // back into the SLOW band: hold restarts
                (600, 0.1, NONE),
                (799, 0.1, NONE),
                (800, 0.1, NONE),
            ],
            &[Slow, Slow, Slow, Slow, Slow, Slow, Clear],
        );
    }

    #[test]
    fn fault_gives_safe_command_and_recovery_needs_the_hold() {
        let d = warm_then(
            &[
                (300, 0.0, STALE),
                (
                    400,
                    0.0,
                    FaultBits::LEFT_CAMERA_STALE | FaultBits::STEREO_SKEW,
                ),
                (500, 0.0, NONE), // healthy again: calm counted from here
                (600, 0.0, NONE),
                (699, 0.0, NONE),
                (700, 0.0, NONE), // 200 ms of healthy calm -> CLEAR
            ],
            &[Slow, Slow, Slow, Slow, Slow, Clear],
        );
        assert!(d[0].fault && d[0].changed);
        assert_eq!(d[0].reason, CommandReason::FaultFallback);
        assert!(!d[2].fault);
        assert_eq!(
            d[4].reason,
            CommandReason::FaultFallback,
            "still held because of the fault"
        );
        assert_eq!(d[5].reason, CommandReason::Perception);
    }

    #[test]
    fn calm_before_a_fault_does_not_count_after_it() {
        warm_then(
            &[
                (300, 0.35, NONE), // SLOW
                (400, 0.0, NONE),  // calm from 400
                (550, 0.0, STALE), // fault resets the hold
                (600, 0.0, NONE),  // calm from 600
                (700, 0.0, NONE),  // would be 300 ms since 400, but only 100 since 600
                (800, 0.0, NONE),
            ],
            &[Slow, Slow, Slow, Slow, Slow, Clear],
        );
    }

    #[test]
    fn fault_while_stopping_keeps_stop() {
        let d = warm_then(
            &[
                (300, 0.9, NONE),
                (400, 0.0, STALE),
                (500, f64::NAN, FaultBits::CAMERA_ERROR),
                (600, 0.0, NONE),
                (1000, 0.0, NONE),
                (1100, 0.0, NONE), // 500 ms of healthy calm since 600 -> CLEAR
            ],
            &[Stop, Stop, Stop, Stop, Stop, Clear],
        );
        assert_eq!(d[1].reason, CommandReason::FaultFallback);
        assert_eq!(d[1].requested_decel, 4.0);
    }

    #[test]
    fn high_warning_during_a_fault_still_escalates() {
        warm_then(&[(300, 0.0, STALE), (400, 0.9, STALE)], &[Slow, Stop]);
    }

    #[test]
    fn fault_stop_as_safe_command() {
        let config = DecisionConfig {
            safe_command: Stop,
            ..cfg()
        };
        check_with(
            config,
            &[
                (0, 0.0, NONE),
                (500, 0.0, NONE),
                (600, 0.0, STALE),
                (700, 0.0, NONE),
            ],
            &[Stop, Clear, Stop, Stop],
        );
    }

    #[test]
    fn non_finite_or_negative_warning_is_a_fault() {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.1] {
            let d = warm_then(&[(300, bad, NONE), (400, 0.0, NONE)], &[Slow, Slow]);
            assert!(d[0].fault, "{bad}");
            assert_eq!(d[0].reason, CommandReason::FaultFallback, "{bad}");
            assert!(!d[1].fault);
        }
        // -0.0 is a valid (zero) warning.
        let d = warm_then(&[(300, -0.0, NONE)], &[Clear]);
        assert!(!d[0].fault);
    }

    #[test]
    fn faults_outside_the_mask_are_ignored() {
        let config = DecisionConfig {
            fault_mask: FaultBits::all() & !FaultBits::CAN_TX_ERROR,
            ..cfg()
        };
        check_with(
            config,
            &[
                (0, 0.0, NONE),
                (200, 0.0, FaultBits::CAN_TX_ERROR),
                (300, 0.0, FaultBits::CAN_TX_ERROR | STALE),
            ],
            &[Slow, Clear, Slow],
        );
    }

    #[test]
    fn time_going_backwards_never_shortens_a_hold() {
        warm_then(
            &[
                (1000, 0.9, NONE),
                (1100, 0.0, NONE),
                (900, 0.0, NONE),
                (1599, 0.0, NONE),
            ],
            &[Stop, Stop, Stop, Stop],
        );
    }

    #[test]
    fn shutdown_latches_the_safe_command() {
        let mut decider = Decider::new(cfg()).expect("valid");
        for ms in [0, 100, 200] {
            decider.update(DecisionInput::healthy(0.0), Duration::from_millis(ms));
        }
        assert_eq!(decider.command(), Clear);
        let d = decider.shutdown();
        assert_eq!(
            (d.command, d.reason, d.changed),
            (Slow, CommandReason::Shutdown, true)
        );
        let later = decider.update(DecisionInput::healthy(0.0), Duration::from_secs(10));
        assert_eq!(
            (later.command, later.reason),
            (Slow, CommandReason::Shutdown)
        );

        // A STOP stays a STOP at shutdown.
        let mut decider = Decider::new(cfg()).expect("valid");
        decider.update(DecisionInput::healthy(0.9), Duration::ZERO);
        assert_eq!(decider.shutdown().command, Stop);
    }

    #[test]
    fn config_validation() {
        let bad = [
            DecisionConfig {
                slow_threshold: 0.7,
                ..cfg()
            },
            DecisionConfig {
                stop_threshold: f64::NAN,
                ..cfg()
            },
            DecisionConfig {
                slow_threshold: 0.0,
                ..cfg()
            },
            DecisionConfig {
                release_ratio: 1.5,
                ..cfg()
            },
            DecisionConfig {
                release_ratio: 0.0,
                ..cfg()
            },
            DecisionConfig {
                stop_hold: Duration::ZERO,
                ..cfg()
            },
            DecisionConfig {
                safe_command: Clear,
                ..cfg()
            },
            DecisionConfig {
                stop_decel: -1.0,
                ..cfg()
            },
            DecisionConfig {
                slow_decel: 5.0,
                ..cfg()
            },
            DecisionConfig {
                margin: f64::NAN,
                ..cfg()
            },
        ];
        for config in bad {
            assert!(Decider::new(config).is_err(), "{config:?}");
        }
        assert!(Decider::new(DecisionConfig::default()).is_ok());
    }

    /// Invariants over a long pseudo-random run, checked against the history directly:
    /// - never below the warning's own level while healthy,
    /// - never below the safe command while faulty,
    /// - any release from STOP (or SLOW) is preceded by `hold` of healthy snapshots all below
    ///   that command's release level.
    #[test]
    fn invariants_hold_on_a_random_run() {
        let config = cfg();
        let mut decider = Decider::new(config).expect("valid");
        let mut rnd = crate::test_support::xorshift64(0x9E37_79B9_7F4A_7C15);
        let mut history: Vec<(Duration, f64, bool)> = Vec::new();
        let mut t = Duration::ZERO;
        let mut previous = decider.command();
        for _ in 0..20_000 {
            t += Duration::from_millis(10 + rnd() % 90);
            let r = rnd();
            let w = match r % 10 {
                0 => 0.7,
                1..=2 => 0.2 + (r % 100) as f64 / 1000.0,
                _ => (r % 140) as f64 / 1000.0,
            };
            let faults = if rnd().is_multiple_of(50) {
                STALE
            } else {
                NONE
            };
            let input = DecisionInput {
                faults,
                ..DecisionInput::healthy(w)
            };
            let d = decider.update(input, t);
            let fault = !faults.is_empty();
            history.push((t, w, fault));

            if fault {
                assert!(d.command >= config.safe_command, "fault at {t:?}");
            } else {
                assert!(d.command >= decider.level(&input), "below level at {t:?}");
            }
            for (released, threshold, hold) in [
                (Stop, config.stop_threshold, config.stop_hold),
                (Slow, config.slow_threshold, config.slow_hold),
            ] {
                if previous >= released && d.command < released {
                    // The calm streak: the newest snapshots, all healthy and below the release
                    // level. The release is legal only if the streak began `hold` ago or more.
                    let release = threshold * config.release_ratio;
                    let streak_start = history
                        .iter()
                        .rev()
                        .take_while(|(_, hw, hf)| *hw < release && !hf)
                        .last()
                        .map(|(ht, _, _)| *ht);
                    assert!(
                        streak_start.is_some_and(|s| t - s >= hold),
                        "{released} released at {t:?}, calm only since {streak_start:?}"
                    );
                }
            }
            previous = d.command;
        }
    }

    /// 30 km/h in m/s.
    const KMH30: f64 = 30.0 / 3.6;

    #[test]
    fn stopping_distances_at_30_kmh() {
        let c = DecisionConfig::default();
        // 8.33 * 0.5 + 8.33^2 / 8 + 2 = 14.85 m; with 1.5 m/s^2, 29.31 m.
        assert!((c.reach(Stop, KMH30) - 14.8472).abs() < 1e-3);
        assert!((c.reach(Slow, KMH30) - 29.3148).abs() < 1e-3);
        assert_eq!(c.reach(Stop, 0.0), c.margin);
        assert_eq!(c.reach(Clear, KMH30), 0.0);
    }

    #[test]
    fn the_obstacle_is_judged_where_it_will_be_when_the_next_evidence_comes() {
        let c = DecisionConfig::default();
        let d = Decider::new(c).expect("valid");
        // 15.2 m ahead at 30 km/h: beyond STOP's 14.85 m now, within it after 50 ms of
        // evidence age and a 33 ms frame (0.69 m nearer).
        let now = DecisionInput::at_speed(Some(15.2), KMH30);
        assert_eq!(d.level(&now), Slow);
        let later = DecisionInput {
            latency: 0.083,
            ..now
        };
        assert_eq!(d.level(&later), Stop);
        // Standing still, latency changes nothing.
        let still = DecisionInput {
            latency: 10.0,
            ..DecisionInput::at_speed(Some(2.5), 0.0)
        };
        assert_eq!(d.level(&still), Clear);
        for bad in [f64::NAN, -0.1, f64::INFINITY] {
            let input = DecisionInput {
                latency: bad,
                ..now
            };
            assert_eq!(d.level(&input), Clear, "latency {bad}: a fault, no level");
            assert!(d.clone().update(input, Duration::ZERO).fault);
        }
        // Nearer than the travel within the latency: STOP.
        let passed = DecisionInput {
            latency: 1.0,
            ..DecisionInput::at_speed(Some(5.0), KMH30)
        };
        assert_eq!(d.level(&passed), Stop);
    }

    /// Runs (ms, obstacle distance) at 30 km/h through an obstacle-mode decider, warmed up
    /// with no obstacle for the default holds, and returns the commands.
    fn obstacle_run(steps: &[(u64, Option<f64>)]) -> Vec<Command> {
        let mut d = Decider::new(DecisionConfig::default()).expect("valid");
        let ms = Duration::from_millis;
        for t in (0..=600).step_by(100) {
            d.update(DecisionInput::at_speed(None, KMH30), ms(t));
        }
        assert_eq!(d.command(), Clear);
        steps
            .iter()
            .map(|&(t, o)| {
                d.update(DecisionInput::at_speed(o, KMH30), ms(1000 + t))
                    .command
            })
            .collect()
    }

    #[test]
    fn an_obstacle_within_the_stopping_distance_stops() {
        let commands = obstacle_run(&[
            (0, Some(40.0)),
            (100, Some(29.0)),
            (200, Some(14.8)),
            (300, Some(14.0)),
            // Beyond STOP's reach / release_ratio = 18.6 m for the 1 s hold: SLOW.
            (1200, Some(19.0)),
            (2199, Some(19.0)),
            (2300, Some(19.0)),
            // Beyond SLOW's reach / 0.8 = 36.6 m for 0.5 s: CLEAR.
            (2400, Some(37.0)),
            (2950, Some(37.0)),
        ]);
        assert_eq!(
            commands,
            [Clear, Slow, Stop, Stop, Stop, Stop, Slow, Slow, Clear]
        );
    }

    #[test]
    fn a_late_stop_asks_for_what_the_distance_left_needs() {
        let c = DecisionConfig::default();
        let stop = |distance: f64| {
            let mut d = Decider::new(c).expect("valid");
            d.update(DecisionInput::at_speed(None, KMH30), Duration::ZERO);
            d.update(
                DecisionInput::at_speed(Some(distance), KMH30),
                Duration::from_millis(700),
            )
        };
        // At the STOP distance (14.85 m at 30 km/h): stop_decel.
        let in_time = stop(14.8);
        assert_eq!(in_time.command, Stop);
        assert!((in_time.requested_decel - 4.0).abs() < 0.05, "{in_time:?}");
        // 11 m: 8.33^2 / (2 (11 - 8.33 * 0.5 - 2)) = 7.18 m/s^2.
        let late = stop(11.0);
        assert!((late.requested_decel - 7.18).abs() < 0.01, "{late:?}");
        // No room left: the most it asks for.
        assert_eq!(stop(5.0).requested_decel, c.max_decel);
        // A fault's STOP asks for stop_decel, whatever the distance.
        let mut d = Decider::new(DecisionConfig {
            safe_command: Stop,
            ..c
        })
        .expect("valid");
        let fault = d.update(
            DecisionInput {
                faults: STALE,
                ..DecisionInput::at_speed(Some(5.0), KMH30)
            },
            Duration::ZERO,
        );
        assert_eq!((fault.command, fault.requested_decel), (Stop, 4.0));
        // max_decel below stop_decel is refused.
        assert!(matches!(
            DecisionConfig {
                max_decel: 3.0,
                ..c
            }
            .validate(),
            Err(DecisionConfigError::MaxDecel { .. })
        ));
    }

    #[test]
    fn at_standstill_only_the_margin_counts() {
        let mut d = Decider::new(DecisionConfig::default()).expect("valid");
        let at = |o| DecisionInput::at_speed(o, 0.0);
        assert!(d.escalates(&at(Some(1.9))), "inside the 2 m margin");
        d.update(at(None), Duration::ZERO);
        assert_eq!(d.level(&at(Some(2.1))), Clear);
        assert_eq!(d.level(&at(Some(2.0))), Stop);
    }

    #[test]
    fn an_obstacle_or_speed_that_cannot_be_true_is_a_fault() {
        let d = Decider::new(DecisionConfig::default()).expect("valid");
        for input in [
            DecisionInput::at_speed(Some(f64::NAN), KMH30),
            DecisionInput::at_speed(Some(-1.0), KMH30),
            DecisionInput::at_speed(None, f64::NAN),
            DecisionInput::at_speed(None, -3.0),
        ] {
            let mut d = d.clone();
            let out = d.update(input, Duration::ZERO);
            assert!(out.fault && out.command == Slow, "{input:?}: {out:?}");
        }
        // The warning is not what this mode decides on: a NaN there is no fault.
        let mut d = d.clone();
        let input = DecisionInput {
            global_warning: f64::NAN,
            ..DecisionInput::at_speed(None, KMH30)
        };
        assert!(!d.update(input, Duration::ZERO).fault);
    }

    #[test]
    fn the_worst_of_two_snapshots_keeps_the_nearest_obstacle() {
        let a = DecisionInput {
            global_warning: 0.2,
            ..DecisionInput::at_speed(Some(12.0), 5.0)
        };
        let b = DecisionInput {
            global_warning: 0.9,
            faults: STALE,
            ..DecisionInput::at_speed(Some(20.0), 6.0)
        };
        let w = a.worst(b);
        assert_eq!(
            (w.global_warning, w.obstacle, w.speed, w.faults),
            (0.9, Some(12.0), 6.0, STALE)
        );
        assert_eq!(
            a.worst(DecisionInput::at_speed(None, 5.0)).obstacle,
            Some(12.0)
        );
        assert!(
            a.worst(DecisionInput::at_speed(Some(f64::NAN), 5.0))
                .obstacle
                .is_some_and(f64::is_nan)
        );
        assert!(
            a.worst(DecisionInput::healthy(f64::NAN))
                .global_warning
                .is_nan()
        );
    }
}
