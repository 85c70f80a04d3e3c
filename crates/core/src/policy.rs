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
//! `flyd run` (the control thread), `flyd replay --mcap` (a recording's commands decided
//! again) and `flyd replay` on a pair, a scenario or a sequence (a command each generation)
//! all take their input here, so a replay tells the truth about the daemon.

use crate::decision::DecisionInput;
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
