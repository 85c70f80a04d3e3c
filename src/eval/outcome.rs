//! One run of an item: what the replay decided, and whether that meets the item's label.

use super::manifest::{Expect, Item};
use crate::replay::{Replay, Summary};
use flyd_core::decision::{Command, CommandReason};
use serde::Serialize;

/// What one replay of an item decided (frames after the warm-up, within the item's `frames`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Outcome {
    /// Why the run did not finish.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The command of the last generation, and why.
    pub command: String,
    pub reason: String,
    /// Frames judged, and of those, frames with a STOP (with a SLOW and no STOP) from the
    /// perception.
    pub frames: u64,
    pub stop_frames: u64,
    pub slow_frames: u64,
    /// The confirmed obstacle of the last generation, metres.
    pub obstacle: Option<f64>,
    /// The nearest confirmed obstacle on the frames judged, metres.
    pub nearest_confirmed: Option<f64>,
    /// The first frame with a SLOW or STOP from the perception, and with a STOP (any
    /// generation, the warm-up's included: a scenario's obstacle may come early).
    pub first_slow_frame: Option<u64>,
    pub first_stop_frame: Option<u64>,
    /// Generations from the scenario's obstacle appearing to the first STOP.
    pub stop_after: Option<u64>,
    /// Where the obstacle was when the first STOP (SLOW) came, metres (`stop-before`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stop_at_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slow_at_m: Option<f64>,
    /// The right image's row correction applied, px, and where it came from.
    pub row_correction_px: f64,
    pub row_correction: &'static str,
    /// Where the motion came from (`assumed`, `fixed`, `feed`) and the feed's source.
    pub speed_source: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion_source: Option<String>,
    /// The declared mount against the road measured (none: the run did not finish).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mount: Option<flyd_core::perception::mount_check::MountReport>,
    /// The right camera's yaw against the motion, on a sequence
    /// ([`flyd_core::rectification::yaw`]; none: not checked, or the run did not finish).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub columns: Option<flyd_core::rectification::yaw::ColumnReport>,
    /// Against the item's `truth`, when it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accuracy: Option<Accuracy>,
    /// A closed-loop case's outcome (contact, impact speed, gap, braking).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<crate::replay::closed_loop::ClosedLoopReport>,
    /// The label met, or why not.
    pub verdict: Verdict,
}

/// How the flies obstacles are built from agree with a disparity map: the [`ACCURACY_FLIES`]
/// fittest (raw fitness) of those whose match is unique (ambiguity at most the obstacle
/// stage's `max_ambiguity`) on the last frame, at the pixels the map knows, each pixel once
/// (its fittest fly: a dozen flies bred onto one pixel are one measurement, not twelve).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Accuracy {
    /// Share within 1 px and within 3 px of the map's disparity.
    pub within_1px: f64,
    pub within_3px: f64,
    /// Pixels with a known disparity under those flies.
    pub pixels: usize,
    /// The most of those flies on one pixel (every pixel, known or not): sharing should keep
    /// a match from taking many flies that then search nothing.
    pub most_on_one_pixel: usize,
}

/// Flies [`Accuracy`] looks at (the paper's figures draw the best 250).
pub const ACCURACY_FLIES: usize = 250;

impl Accuracy {
    /// `run`'s flies against `truth`; `None` when none of them is at a pixel it knows.
    pub fn of(run: &Replay, truth: &flyd_core::dataset::DisparityMap) -> Option<Self> {
        let pop = run.perception.engine().population();
        let max = run.settings.perception.obstacle.max_ambiguity;
        let mut unique: Vec<usize> = (0..pop.len())
            .filter(|&i| {
                pop.raw_fitness[i] > 0.0
                    && run.ambiguity.get(i).is_some_and(|&a| f64::from(a) <= max)
            })
            .collect();
        unique.sort_by(|&a, &b| pop.raw_fitness[b].total_cmp(&pop.raw_fitness[a]));
        unique.truncate(ACCURACY_FLIES);
        let (mut n, mut one, mut three) = (0usize, 0usize, 0usize);
        let mut seen = std::collections::HashMap::new();
        for i in unique {
            let (u, v) = (pop.u_left[i].round(), pop.v_left[i].round());
            // Each pixel once (a negative or NaN coordinate is outside the map).
            let inside = u >= 0.0 && v >= 0.0;
            if !inside {
                continue;
            }
            let count = seen.entry((u as usize, v as usize)).or_insert(0usize);
            *count += 1;
            if *count > 1 {
                continue;
            }
            let Some(t) = truth.get(u as usize, v as usize) else {
                continue;
            };
            let error = (f64::from(pop.u_left[i] - pop.u_right[i]) - f64::from(t)).abs();
            n += 1;
            one += usize::from(error <= 1.0);
            three += usize::from(error <= 3.0);
        }
        (n > 0).then(|| Self {
            within_1px: one as f64 / n as f64,
            within_3px: three as f64 / n as f64,
            pixels: n,
            most_on_one_pixel: seen.values().copied().max().unwrap_or(0),
        })
    }
}

/// Whether a run meets its item's label.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
#[serde(tag = "result", content = "why", rename_all = "lowercase")]
pub enum Verdict {
    Pass,
    #[default]
    Pending,
    Fail(String),
}

impl Verdict {
    pub fn passed(&self) -> bool {
        *self == Self::Pass
    }
}

impl Outcome {
    /// A run that did not finish.
    pub fn failed(why: &str) -> Self {
        Self {
            error: Some(why.to_string()),
            command: "?".into(),
            reason: "?".into(),
            verdict: Verdict::Fail(format!("error: {why}")),
            ..Self::default()
        }
    }

    /// What `run` decided, judged against `item`.
    pub fn of(item: &Item, run: &Replay, summary: &Summary) -> Self {
        let warmup = run.settings.warmup_generations;
        let judged = |frame: u64| item.frames.is_none_or(|[a, b]| (a..=b).contains(&frame));
        let perception_alarm = |r: &&crate::replay::TraceRow| {
            r.reason == CommandReason::Perception && r.command > Command::Clear
        };
        let mut o = Self {
            command: summary.last.command.clone(),
            reason: summary.last.reason.clone(),
            obstacle: run
                .trace
                .last()
                .and_then(|r| r.tracked.confirmed())
                .map(|ob| ob.distance),
            row_correction_px: run.settings.right_row_shift,
            row_correction: run.row_correction.map_or("none", |c| c.source),
            speed_source: summary.speed_source,
            motion_source: summary.motion_source.clone(),
            stop_after: summary.reaction.and_then(|r| r.stop_command_after),
            closed_loop: run.closed_loop.clone(),
            mount: Some(summary.mount),
            columns: summary.columns,
            ..Self::default()
        };
        for r in run.trace.iter().filter(perception_alarm) {
            o.first_slow_frame.get_or_insert(r.frame);
            if r.command == Command::Stop {
                o.first_stop_frame.get_or_insert(r.frame);
            }
        }
        let mut last_frame = None;
        let mut worst = Command::Clear;
        let close = |frame: Option<u64>, worst: Command, o: &mut Self| {
            if frame.is_some() {
                o.frames += 1;
                match worst {
                    Command::Stop => o.stop_frames += 1,
                    Command::Slow => o.slow_frames += 1,
                    _ => {}
                }
            }
        };
        for r in run
            .trace
            .iter()
            .filter(|r| r.stats.generation > warmup && judged(r.frame))
        {
            if last_frame != Some(r.frame) {
                close(last_frame, worst, &mut o);
                last_frame = Some(r.frame);
                worst = Command::Clear;
            }
            if perception_alarm(&r) {
                worst = worst.max(r.command);
            }
            if let Some(ob) = r.tracked.confirmed() {
                o.nearest_confirmed = Some(
                    o.nearest_confirmed
                        .map_or(ob.distance, |d| d.min(ob.distance)),
                );
            }
        }
        close(last_frame, worst, &mut o);
        o.verdict = o.judge(item, run.settings.fps);
        o
    }

    fn judge(&mut self, item: &Item, fps: f64) -> Verdict {
        let fail = |why: String| Verdict::Fail(why);
        match item.expect {
            Expect::Clear => {
                if self.stop_frames + self.slow_frames > 0 || self.command != "CLEAR" {
                    return fail(format!(
                        "false alarm ({} STOP, {} SLOW frames, ends {})",
                        self.stop_frames, self.slow_frames, self.command
                    ));
                }
            }
            Expect::NoStop => {
                if self.stop_frames > 0 {
                    return fail(format!("false STOP on {} frames", self.stop_frames));
                }
            }
            Expect::NothingNearer => {
                let d = item.distance.unwrap_or_default();
                if let Some(n) = self.nearest_confirmed.filter(|n| *n < d) {
                    return fail(format!("obstacle confirmed at {n:.2} m"));
                }
            }
            Expect::Stop => {
                let (want, tol) = (
                    item.distance.unwrap_or_default(),
                    item.tolerance.unwrap_or_default(),
                );
                match self.obstacle {
                    Some(d) if self.command == "STOP" => {
                        if (d - want).abs() > tol {
                            return fail(format!("obstacle at {d:.2} m"));
                        }
                    }
                    _ => return fail("missed".into()),
                }
            }
            Expect::StopWithin => {
                let within = item.generations.unwrap_or_default();
                if self.stop_frames == 0 || self.stop_after.is_none_or(|g| g > within) {
                    return fail(match self.stop_after {
                        Some(g) => format!("STOP after {g} generations"),
                        None => "no STOP".into(),
                    });
                }
            }
            Expect::NoContact
            | Expect::ImpactBelow
            | Expect::NoActivation
            | Expect::PeakDecelBelow => {
                let Some(c) = &self.closed_loop else {
                    return fail("not a closed loop".into());
                };
                return judge_closed_loop(item, c);
            }
            Expect::StopBefore => {
                let (from, kmh, stopping) = (
                    item.from.unwrap_or_default(),
                    item.kmh.unwrap_or_default(),
                    item.stopping.unwrap_or_default(),
                );
                let at = |frame: u64| from - kmh / 3.6 * frame as f64 / fps;
                self.slow_at_m = self.first_slow_frame.map(at);
                let Some(stop) = self.first_stop_frame else {
                    return fail("no STOP".into());
                };
                let at = at(stop);
                self.stop_at_m = Some(at);
                if at <= stopping {
                    return fail(format!("STOP at {at:.1} m"));
                }
            }
        }
        Verdict::Pass
    }
}

/// A closed loop's outcome against its label.
fn judge_closed_loop(item: &Item, c: &crate::replay::closed_loop::ClosedLoopReport) -> Verdict {
    let impact = c.impact_kmh.unwrap_or_default();
    let why = match item.expect {
        Expect::NoContact if c.contact => Some(format!("contact at {impact:.1} km/h")),
        Expect::ImpactBelow if c.contact && impact >= item.impact_kmh.unwrap_or_default() => {
            Some(format!("contact at {impact:.1} km/h"))
        }
        Expect::NoActivation if c.activated() => Some(match (c.first_stop_s, c.first_slow_s) {
            (Some(t), _) => format!(
                "STOP at {t:.2} s, {:.1} m/s^2, {:.1} km/h lost",
                c.peak_requested_decel, c.speed_lost_kmh
            ),
            (None, t) => format!(
                "SLOW at {:.2} s, {:.1} km/h lost",
                t.unwrap_or_default(),
                c.speed_lost_kmh
            ),
        }),
        Expect::PeakDecelBelow if c.peak_decel >= item.decel.unwrap_or_default() => {
            Some(format!("the brakes gave {:.1} m/s^2", c.peak_decel))
        }
        _ => None,
    };
    why.map_or(Verdict::Pass, Verdict::Fail)
}
