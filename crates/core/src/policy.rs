//! The policies the daemon and every replay share, written once: what the decider is given
//! each command period ([`PeriodInput`], [`Chosen`]), the faults a sensor verdict raises
//! ([`camera_error`]) and the blind-camera debounce ([`BlindDebounce`]).
//!
//! A command period's input is
//!
//! - the **worst** snapshot taken since the previous command ([`DecisionInput::worst`]: the
//!   nearest confirmed obstacle, the highest global warning; a spike between two commands is
//!   not lost, releases stay conservative);
//! - else, when none was taken since, the newest trusted snapshot's again, at this command's
//!   time;
//! - else (nothing trusted yet: the population still warms up) an input that cannot be true
//!   in either decision mode ([`untrusted`]): the decider's fault path, the safe command;
//!
//! and the decider gets it with the faults active at the command ([`Chosen::with_faults`]).
//! [`DecisionStep`] is that written once, the period's input and the [`Decider`] together:
//! `flyd run` (the control thread), `flyd replay --mcap` (a recording's commands decided
//! again) and `flyd replay` on a pair, a scenario, a sequence or a closed loop (a command each
//! generation) each drive one, so a replay tells the truth about the daemon.

use std::time::Duration;

use crate::decision::{
    Command, Decider, Decision, DecisionConfig, DecisionConfigError, DecisionInput,
};
use crate::sensor::SensorFaults;
use crate::status::FaultBits;

/// Where a command period's input came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputSource {
    /// The worst of the snapshots taken since the previous command.
    Taken,
    /// None taken since: the newest trusted snapshot again.
    Latest,
    /// No trusted snapshot yet: [`untrusted`].
    Untrusted,
}

/// No trusted snapshot: an input that cannot be true in either mode (a NaN warning, no speed),
/// so the decider takes its fault path.
pub fn untrusted() -> DecisionInput {
    DecisionInput {
        global_warning: f64::NAN,
        ..DecisionInput::at_speed(None, f64::NAN)
    }
}

/// The trusted snapshots taken since the last command, kept as their worst.
#[derive(Debug, Clone, Copy, Default)]
pub struct PeriodInput {
    worst: Option<DecisionInput>,
}

/// A command period's input and where it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chosen {
    pub from: InputSource,
    /// As the snapshots gave it (its faults theirs, none in the daemon).
    pub input: DecisionInput,
}

impl Chosen {
    /// What the decider is given: the input with the faults active at the command (they
    /// replace the snapshots').
    pub fn with_faults(&self, faults: FaultBits) -> DecisionInput {
        DecisionInput {
            faults,
            ..self.input
        }
    }
}

impl PeriodInput {
    /// A trusted snapshot's input (one of a population past its warm-up).
    pub fn observe(&mut self, input: DecisionInput) {
        self.worst = Some(match self.worst {
            Some(worst) => worst.worst(input),
            None => input,
        });
    }

    /// The worst snapshot taken since the last command, if any (what an escalation between
    /// two periodic commands is judged on).
    pub fn pending(&self) -> Option<DecisionInput> {
        self.worst
    }

    /// This period's input: the worst taken since the last command (forgotten: the next
    /// period starts afresh), else `latest()` (the newest trusted snapshot's input at this
    /// command's time, asked only when nothing was taken), else [`untrusted`].
    pub fn choose(&mut self, latest: impl FnOnce() -> Option<DecisionInput>) -> Chosen {
        match self.worst.take() {
            Some(input) => Chosen {
                from: InputSource::Taken,
                input,
            },
            None => Self::fallback(latest()),
        }
    }

    /// A period in which nothing was taken: the newest trusted snapshot's input, else
    /// [`untrusted`] (what [`PeriodInput::choose`] gives when nothing was taken).
    pub fn fallback(latest: Option<DecisionInput>) -> Chosen {
        match latest {
            Some(input) => Chosen {
                from: InputSource::Latest,
                input,
            },
            None => Chosen {
                from: InputSource::Untrusted,
                input: untrusted(),
            },
        }
    }
}

/// The decision's step: the trusted snapshots of a command period ([`PeriodInput`]) and the
/// [`Decider`] they are decided by, with the faults active at the command.
#[derive(Debug, Clone)]
pub struct DecisionStep {
    period: PeriodInput,
    decider: Decider,
}

/// A command decided, and the input it was decided on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decided {
    pub chosen: Chosen,
    pub decision: Decision,
}

impl DecisionStep {
    pub fn new(config: DecisionConfig) -> Result<Self, DecisionConfigError> {
        Ok(Self {
            period: PeriodInput::default(),
            decider: Decider::new(config)?,
        })
    }

    pub fn decider(&self) -> &Decider {
        &self.decider
    }

    /// The command in force (before any decision: the safe command).
    pub fn command(&self) -> Command {
        self.decider.command()
    }

    /// A trusted snapshot's input (one of a population past its warm-up).
    pub fn observe(&mut self, input: DecisionInput) {
        self.period.observe(input);
    }

    /// Whether a snapshot taken since the last command asks for more than the command in
    /// force: an escalation, sent at once instead of at the next period.
    pub fn escalates(&self) -> bool {
        self.period
            .pending()
            .is_some_and(|input| self.decider.escalates(&input))
    }

    /// The command at `now`: this period's input ([`PeriodInput::choose`], `latest` asked
    /// only when nothing was taken) with the faults active now.
    pub fn decide(
        &mut self,
        now: Duration,
        faults: FaultBits,
        latest: impl FnOnce() -> Option<DecisionInput>,
    ) -> Decided {
        let chosen = self.period.choose(latest);
        self.decide_chosen(chosen, faults, now)
    }

    /// The command at `now` when a snapshot was taken since the last one, else none (a
    /// replay's cadence: a command a generation on that generation's snapshot; the
    /// warm-up's generations are not decided).
    pub fn decide_taken(&mut self, now: Duration, faults: FaultBits) -> Option<Decided> {
        self.period
            .pending()
            .is_some()
            .then(|| self.decide(now, faults, || None))
    }

    /// The command at `now` on an input chosen by [`DecisionStep::replayed_choice`] (a
    /// recording's choice), with the faults active now.
    pub fn decide_chosen(&mut self, chosen: Chosen, faults: FaultBits, now: Duration) -> Decided {
        Decided {
            chosen,
            decision: self.decider.update(chosen.with_faults(faults), now),
        }
    }

    /// What a recording's choice `from` was: the worst snapshot taken since the last command
    /// (forgotten), `latest` again, or untrusted.
    pub fn replayed_choice(
        &mut self,
        from: InputSource,
        latest: impl FnOnce() -> Option<DecisionInput>,
    ) -> Chosen {
        match from {
            InputSource::Taken => self.period.choose(|| None),
            InputSource::Latest => PeriodInput::fallback(latest()),
            InputSource::Untrusted => PeriodInput::fallback(None),
        }
    }

    /// The last command ([`Decider::shutdown`]).
    pub fn shutdown(&mut self) -> Decision {
        self.decider.shutdown()
    }
}

/// The fault a sensor verdict raises for the decider: any sensor fault (uniform, frozen,
/// mismatched, blind) is CAMERA_ERROR.
pub fn camera_error(sensor: SensorFaults) -> FaultBits {
    if sensor.is_empty() {
        FaultBits::empty()
    } else {
        FaultBits::CAMERA_ERROR
    }
}

/// The perception is blind: after the warm-up, fewer than `matched` of the flies match on
/// texture ([`crate::engine::GenerationStats::matched`]) on `pairs` new pairs in a row
/// (a camera delivers noise or is covered, or the calibration no longer fits): the sensor
/// fault BLIND. One generation that matches again clears it.
#[derive(Debug, Clone, Copy)]
pub struct BlindDebounce {
    /// Share of the flies matching under which a pair counts (`evolution.blind_matched`).
    pub matched: f64,
    /// New pairs in a row before BLIND (`evolution.blind_pairs`).
    pub pairs: u32,
    count: u32,
}

/// What one generation did to the debounce.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Blindness {
    pub blind: bool,
    /// It was not blind before this generation, or was and is no longer.
    pub changed: bool,
    /// New pairs in a row that matched nowhere.
    pub pairs: u32,
}

impl BlindDebounce {
    pub fn new(matched: f64, pairs: u32) -> Self {
        Self {
            matched,
            pairs,
            count: 0,
        }
    }

    /// One generation: whether its population still warms up, the share of its flies that
    /// matched, whether it ran on a new pair.
    pub fn observe(&mut self, warming_up: bool, matched: f64, new_frame: bool) -> Blindness {
        let was_blind = self.count >= self.pairs;
        if warming_up || matched >= self.matched {
            self.count = 0;
        } else if new_frame {
            self.count = self.count.saturating_add(1);
        }
        let blind = self.count >= self.pairs;
        Blindness {
            blind,
            changed: blind != was_blind,
            pairs: self.count,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot(warning: f64, obstacle: Option<f64>) -> DecisionInput {
        DecisionInput {
            global_warning: warning,
            ..DecisionInput::at_speed(obstacle, 10.0)
        }
    }

    #[test]
    fn a_period_takes_its_worst_snapshot_else_the_latest_else_an_untrusted_input() {
        let mut period = PeriodInput::default();
        // Nothing trusted yet: the fault path, and `latest` is asked.
        let chosen = period.choose(|| None);
        assert_eq!(chosen.from, InputSource::Untrusted);
        assert!(chosen.input.global_warning.is_nan() && chosen.input.speed.is_nan());
        // Two snapshots in one period: the worst of both, once.
        period.observe(snapshot(0.2, Some(30.0)));
        period.observe(snapshot(0.1, Some(12.0)));
        assert_eq!(period.pending().map(|i| i.obstacle), Some(Some(12.0)));
        let chosen = period.choose(|| panic!("not asked when a snapshot was taken"));
        assert_eq!(chosen.from, InputSource::Taken);
        assert_eq!(
            (chosen.input.global_warning, chosen.input.obstacle),
            (0.2, Some(12.0))
        );
        // None since: the latest again.
        let chosen = period.choose(|| Some(snapshot(0.05, None)));
        assert_eq!(chosen.from, InputSource::Latest);
        assert_eq!(chosen.input.global_warning, 0.05);
        // The faults at the command replace the snapshots'.
        let faulty = DecisionInput {
            faults: FaultBits::CAMERA_ERROR,
            ..snapshot(0.1, None)
        };
        period.observe(faulty);
        let given = period.choose(|| None).with_faults(FaultBits::empty());
        assert_eq!(given.faults, FaultBits::empty());
    }

    #[test]
    fn the_decision_step_is_the_period_input_and_the_decider_together() {
        use crate::decision::{Command, DecisionConfig};
        let config = DecisionConfig::default();
        let mut step = DecisionStep::new(config).expect("valid");
        let mut period = PeriodInput::default();
        let mut decider = Decider::new(config).expect("valid");
        let ms = Duration::from_millis;
        // Nothing taken: no replay decision, and the daemon's is the fault path, as the
        // decider's alone.
        assert!(
            step.clone()
                .decide_taken(ms(0), FaultBits::empty())
                .is_none()
        );
        assert!(!step.escalates());
        let mut t = 0;
        let inputs = [None, Some(40.0), Some(9.0), Some(9.5), None, None];
        for obstacle in inputs.into_iter().chain([None; 200]) {
            t += 20;
            let input = DecisionInput::at_speed(obstacle, 8.0);
            step.observe(input);
            period.observe(input);
            let escalates = decider.escalates(&period.pending().expect("taken"));
            assert_eq!(step.escalates(), escalates);
            let chosen = period.choose(|| None);
            let want = decider.update(chosen.with_faults(FaultBits::empty()), ms(t));
            let got = step.decide_taken(ms(t), FaultBits::empty()).expect("taken");
            assert_eq!((got.chosen, got.decision), (chosen, want));
        }
        // STOP for the near obstacle, released to CLEAR after the holds.
        assert_eq!(step.command(), Command::Clear);
        // The latest is asked only when nothing was taken; faults go to the decider.
        let d = step.decide(ms(t + 20), FaultBits::CAMERA_ERROR, || {
            Some(DecisionInput::at_speed(None, 8.0))
        });
        assert_eq!(d.chosen.from, InputSource::Latest);
        assert_eq!(d.decision.command, Command::Slow);
        assert!(d.decision.fault);
        // A recording's choice: taken (the pending snapshot forgotten), latest, untrusted.
        step.observe(DecisionInput::at_speed(Some(30.0), 8.0));
        let latest = step.replayed_choice(InputSource::Latest, || None);
        assert_eq!(latest.from, InputSource::Untrusted, "no latest given");
        let taken = step.replayed_choice(InputSource::Taken, || None);
        assert_eq!(taken.input.obstacle, Some(30.0));
        assert!(step.decide_taken(ms(t + 40), FaultBits::empty()).is_none());
        assert_eq!(
            step.shutdown().reason,
            crate::decision::CommandReason::Shutdown
        );
    }

    #[test]
    fn any_sensor_fault_is_camera_error() {
        assert_eq!(camera_error(SensorFaults::empty()), FaultBits::empty());
        for f in [
            SensorFaults::BLIND,
            SensorFaults::FROZEN | SensorFaults::UNIFORM,
        ] {
            assert_eq!(camera_error(f), FaultBits::CAMERA_ERROR);
        }
    }

    #[test]
    fn blind_after_pairs_new_pairs_matching_nowhere_and_clear_at_once() {
        let mut d = BlindDebounce::new(0.25, 3);
        // The warm-up never counts.
        for _ in 0..5 {
            assert!(!d.observe(true, 0.0, true).blind);
        }
        assert_eq!(d.observe(false, 0.1, true).pairs, 1);
        // Generations on the same pair do not count.
        assert_eq!(d.observe(false, 0.1, false).pairs, 1);
        assert!(!d.observe(false, 0.1, true).blind);
        let third = d.observe(false, 0.1, true);
        assert_eq!((third.blind, third.changed), (true, true));
        assert!(!d.observe(false, 0.1, true).changed);
        let matched = d.observe(false, 0.3, false);
        assert_eq!(
            (matched.blind, matched.changed, matched.pairs),
            (false, true, 0)
        );
    }
}
