//! The items' runs summed up: one row an item, and the JSON of every run.

use super::manifest::{Expect, Item};
use super::outcome::Outcome;
use serde::Serialize;
use std::fmt;

/// Every item's runs.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub seeds: u64,
    pub items: Vec<ItemReport>,
}

/// One item over the seeds.
#[derive(Debug, Clone, Serialize)]
pub struct ItemReport {
    pub name: String,
    pub label: Item,
    /// Runs that meet the label.
    pub ok: usize,
    /// Runs of an item with an obstacle that did not STOP as labelled.
    pub misses: usize,
    /// Of the frames judged over every run of an item without an obstacle to stop for, the
    /// share with a SLOW (and no STOP), and with a STOP.
    pub false_slow_rate: Option<f64>,
    pub false_stop_rate: Option<f64>,
    /// |confirmed distance - labelled distance| over the runs that confirmed one, metres:
    /// median and largest.
    pub distance_error_median: Option<f64>,
    pub distance_error_max: Option<f64>,
    /// Of the runs against a `truth`: the share of flies within 1 px, lowest and median.
    pub within_1px_min: Option<f64>,
    pub within_1px_median: Option<f64>,
    /// Of the same runs: the most of the fittest unique flies on one pixel, on any seed.
    pub most_on_one_pixel: Option<usize>,
    /// Why the runs that failed did.
    pub failures: Vec<String>,
    pub runs: Vec<Outcome>,
}

impl Report {
    /// The report of `items`, `runs[i]` the runs of `items[i]` in seed order.
    pub fn of(items: &[Item], runs: Vec<Vec<Outcome>>, seeds: u64) -> Self {
        let items = items
            .iter()
            .zip(runs)
            .map(|(item, runs)| ItemReport::of(item, runs))
            .collect();
        Self { seeds, items }
    }

    /// Every run of every item meets its label.
    pub fn passed(&self) -> bool {
        self.items.iter().all(|i| i.ok == i.runs.len())
    }
}

impl ItemReport {
    fn of(item: &Item, runs: Vec<Outcome>) -> Self {
        let ok = runs.iter().filter(|r| r.verdict.passed()).count();
        let failures = runs
            .iter()
            .zip(1..)
            .filter_map(|(r, seed)| match &r.verdict {
                super::Verdict::Fail(why) => Some(format!("seed {seed}: {why}")),
                _ => None,
            })
            .collect();
        let wants_stop = item.expect.wants_stop();
        let frames: u64 = runs.iter().map(|r| r.frames).sum();
        let rate = |n: u64| (!wants_stop && frames > 0).then(|| n as f64 / frames as f64);
        let mut errors: Vec<f64> = match (item.expect, item.distance) {
            (Expect::Stop, Some(want)) => runs
                .iter()
                .filter_map(|r| r.obstacle.map(|d| (d - want).abs()))
                .collect(),
            _ => Vec::new(),
        };
        errors.sort_by(f64::total_cmp);
        let mut within: Vec<f64> = runs
            .iter()
            .filter_map(|r| r.accuracy.map(|a| a.within_1px))
            .collect();
        within.sort_by(f64::total_cmp);
        Self {
            within_1px_min: within.first().copied(),
            within_1px_median: within.get(within.len() / 2).copied(),
            most_on_one_pixel: runs
                .iter()
                .filter_map(|r| r.accuracy.map(|a| a.most_on_one_pixel))
                .max(),
            name: item.name.clone(),
            label: item.clone(),
            ok,
            misses: if wants_stop { runs.len() - ok } else { 0 },
            false_slow_rate: rate(runs.iter().map(|r| r.slow_frames).sum()),
            false_stop_rate: rate(runs.iter().map(|r| r.stop_frames).sum()),
            distance_error_median: errors.get(errors.len() / 2).copied(),
            distance_error_max: errors.last().copied(),
            failures,
            runs,
        }
    }

    /// The runs' commands: a letter a seed for a still pair (the last command: C, S, T =
    /// CLEAR, SLOW, STOP; ? = error), `STOP/SLOW` frames a seed for a sequence or scenario.
    fn commands(&self) -> String {
        let still = self.label.pair.is_some();
        let each = self.runs.iter().map(|r| {
            if r.error.is_some() {
                return "?".to_string();
            }
            if still {
                match r.command.as_str() {
                    "CLEAR" => "C",
                    "SLOW" => "S",
                    "STOP" => "T",
                    _ => "?",
                }
                .to_string()
            } else {
                format!("{}/{}", r.stop_frames, r.slow_frames)
            }
        });
        let parts: Vec<String> = each.collect();
        parts.join(if still { "" } else { " " })
    }

    /// What the item's label is about, over the runs: distances, reaction, where it stopped.
    fn detail(&self) -> String {
        let range = |v: &mut Vec<f64>, digits: usize| {
            v.sort_by(f64::total_cmp);
            match (v.first(), v.last()) {
                (Some(a), Some(b)) => format!("{a:.digits$}-{b:.digits$} m ({})", v.len()),
                _ => "-".into(),
            }
        };
        if self.label.expect.closed_loop() {
            return self.closed_loop_detail();
        }
        match self.label.expect {
            Expect::StopWithin => {
                let mut g: Vec<u64> = self.runs.iter().filter_map(|r| r.stop_after).collect();
                g.sort_unstable();
                match (g.first(), g.last()) {
                    (Some(a), Some(b)) => format!("STOP after {a}-{b} generations"),
                    _ => "no STOP".into(),
                }
            }
            Expect::StopBefore => {
                let mut stop: Vec<f64> = self.runs.iter().filter_map(|r| r.stop_at_m).collect();
                let mut slow: Vec<f64> = self.runs.iter().filter_map(|r| r.slow_at_m).collect();
                format!(
                    "first STOP at {}, SLOW at {}",
                    range(&mut stop, 1),
                    range(&mut slow, 1)
                )
            }
            _ => {
                let mut d: Vec<f64> = self.runs.iter().filter_map(|r| r.obstacle).collect();
                range(&mut d, 2)
            }
        }
    }
}

impl ItemReport {
    /// A closed loop's runs: contacts, where the vehicle stopped, how hard it braked, when
    /// it first did and the time to collision then, the speed it lost.
    fn closed_loop_detail(&self) -> String {
        let loops: Vec<_> = self
            .runs
            .iter()
            .filter_map(|r| r.closed_loop.as_ref())
            .collect();
        let span = |mut v: Vec<f64>, digits: usize, unit: &str| {
            v.sort_by(f64::total_cmp);
            match (v.first(), v.last()) {
                (Some(a), Some(b)) => format!("{a:.digits$}-{b:.digits$}{unit} ({})", v.len()),
                _ => "-".into(),
            }
        };
        let contacts = loops.iter().filter(|c| c.contact).count();
        let mut parts = vec![format!("contact {contacts}/{}", loops.len())];
        if contacts > 0 {
            parts.push(format!(
                "impact {}",
                span(
                    loops.iter().filter_map(|c| c.impact_kmh).collect(),
                    1,
                    " km/h"
                )
            ));
        }
        let stopped: Vec<f64> = loops.iter().filter_map(|c| c.stopped_gap_m).collect();
        if !stopped.is_empty() {
            parts.push(format!("stopped short by {}", span(stopped, 1, " m")));
        }
        let activated = loops.iter().filter(|c| c.activated()).count();
        if activated > 0 {
            parts.push(format!(
                "peak decel req {} reached {}",
                span(
                    loops.iter().map(|c| c.peak_requested_decel).collect(),
                    1,
                    ""
                ),
                span(loops.iter().map(|c| c.peak_decel).collect(), 1, " m/s^2"),
            ));
            let ttc: Vec<f64> = loops.iter().filter_map(|c| c.first_stop_ttc_s).collect();
            if !ttc.is_empty() {
                parts.push(format!("first STOP at TTC {}", span(ttc, 2, " s")));
            }
            parts.push(format!(
                "speed lost {}",
                span(loops.iter().map(|c| c.speed_lost_kmh).collect(), 1, " km/h")
            ));
        } else {
            parts.push("no SLOW, no STOP".into());
        }
        parts.join(", ")
    }
}

fn percent(rate: Option<f64>) -> String {
    rate.map_or("-".into(), |r| format!("{:.1}%", 100.0 * r))
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:26} {:14} {:>7} {:>6} {:>7} {:>7} {:>11} {:>15}  commands per seed; distances",
            "item", "label", "ok", "misses", "f.SLOW", "f.STOP", "dist.err", "1px min/med pile"
        )?;
        for i in &self.items {
            let err = match (i.distance_error_median, i.distance_error_max) {
                (Some(m), Some(x)) => format!("{m:.2}/{x:.2}"),
                _ => "-".into(),
            };
            let acc = match (i.within_1px_min, i.within_1px_median, i.most_on_one_pixel) {
                (Some(a), Some(m), Some(p)) => {
                    format!("{:.0}/{:.0}% {p:>4}", 100.0 * a, 100.0 * m)
                }
                _ => "-".into(),
            };
            writeln!(
                f,
                "{:26} {:14} {:>3}/{:<3} {:>6} {:>7} {:>7} {:>11} {:>15}  {}  {}",
                i.name,
                i.label.expect.name(),
                i.ok,
                i.runs.len(),
                i.misses,
                percent(i.false_slow_rate),
                percent(i.false_stop_rate),
                err,
                acc,
                i.commands(),
                i.detail()
            )?;
        }
        let failed: Vec<&ItemReport> = self.items.iter().filter(|i| i.ok < i.runs.len()).collect();
        if failed.is_empty() {
            write!(f, "every label met on seeds 1-{}", self.seeds)
        } else {
            writeln!(f, "labels not met:")?;
            for i in &failed {
                writeln!(f, "  {}: {}", i.name, i.failures.join("; "))?;
            }
            write!(f, "{} of {} items failed", failed.len(), self.items.len())
        }
    }
}
