//! `flyd replay`: run the evolution on recorded or synthetic frames and write what it found.
//!
//! Outputs, in the output directory:
//! - `flies.csv`: one fly a row, `x,y,z,fitness,warning,u_left,v_left,u_right,v_right` (metres,
//!   pixels; `fitness` is the value selection ranks by, after the region of interest and
//!   sharing; `warning` is computed from the fitness *before* sharing, see [`flyd_core::engine`];
//!   flies outside an image have empty projections);
//! - `overlay.png`: the left image with the best 250 flies as crosses (the paper's figures 5, 7);
//! - `warnings.png`: each fly a spot as dark as its warning (figures 6, 8);
//! - `trace.csv`: one row a generation (frame index, global warning, danger, time).
//!
//! It prints a JSON summary on stdout ([`Summary`]).
//!
//! This is a command at the edge: it reads files and the clock; the engine does neither.

use crate::mock::{MockError, MockStereo};
use flyd_core::calib::{CalibError, Calibration};
use flyd_core::engine::{Engine, EngineError, EngineParams, GenerationStats, Population};
use flyd_core::frame::{FrameError, PixelFormat, PreparedImage, StereoFrame};
use flyd_core::geometry::StereoRig;
use image::{GrayImage, Luma, Rgb, RgbImage};
use serde::Serialize;
use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

/// Number of flies drawn on the overlay, as in the paper's figures.
pub const OVERLAY_FLIES: usize = 250;

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("{path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}")]
    Image {
        path: String,
        #[source]
        source: image::ImageError,
    },
    #[error("calibration")]
    Calibration(#[from] CalibError),
    #[error(
        "{which} image is {got_w}x{got_h} but {calibration} describes a {want_w}x{want_h} camera"
    )]
    ImageSize {
        which: &'static str,
        calibration: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("unknown scenario '{name}' (known: {known})")]
    UnknownScenario { name: String, known: String },
    #[error("hw-mock")]
    Mock(#[from] MockError),
    #[error("frame")]
    Frame(#[from] FrameError),
    #[error("engine")]
    Engine(#[from] EngineError),
}

/// Where replayed frames come from.
pub trait FrameFeed {
    fn rig(&self) -> &StereoRig;
    /// How many frames there are.
    fn frames(&self) -> u64;
    /// Puts frame `index` into `frame` (prepared) and `left` (the left image as captured, for
    /// the overlay).
    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError>;
    /// The frame at which the first obstacle appears, when the feed knows it (a scenario).
    fn first_obstacle(&self) -> Option<u64> {
        None
    }
}

/// One stereo pair, evaluated again and again (the paper's setting).
pub struct PairFeed {
    rig: StereoRig,
    left: RgbImage,
    right: RgbImage,
}

impl PairFeed {
    /// The pair `left`, `right` and its calibration (which must describe their sizes).
    pub fn load(
        left: &Path,
        right: &Path,
        calibration: &Path,
    ) -> Result<(Self, Calibration), ReplayError> {
        let cal = flyd_core::calib::load(calibration)?;
        let (l, r) = (load_rgb(left)?, load_rgb(right)?);
        for (which, img, cam) in [("left", &l, &cal.rig.left), ("right", &r, &cal.rig.right)] {
            if img.dimensions() != (cam.width(), cam.height()) {
                return Err(ReplayError::ImageSize {
                    which,
                    calibration: calibration.display().to_string(),
                    got_w: img.width(),
                    got_h: img.height(),
                    want_w: cam.width(),
                    want_h: cam.height(),
                });
            }
        }
        let feed = Self {
            rig: cal.rig.clone(),
            left: l,
            right: r,
        };
        Ok((feed, cal))
    }
}

impl FrameFeed for PairFeed {
    fn rig(&self) -> &StereoRig {
        &self.rig
    }

    fn frames(&self) -> u64 {
        1
    }

    fn load(
        &mut self,
        _: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        frame.left.prepare(PixelFormat::Rgb8, self.left.as_raw())?;
        frame
            .right
            .prepare(PixelFormat::Rgb8, self.right.as_raw())?;
        left.clone_from(&self.left);
        Ok(())
    }
}

/// A hw-mock scenario rendered through the mock rig.
pub struct ScenarioFeed {
    mock: MockStereo,
    first_obstacle: Option<u64>,
}

impl ScenarioFeed {
    pub fn new(name: &str, width: u32, height: u32) -> Result<Self, ReplayError> {
        let scenario =
            hw_mock::Scenario::by_name(name).ok_or_else(|| ReplayError::UnknownScenario {
                name: name.to_string(),
                known: hw_mock::Scenario::names().join(", "),
            })?;
        let first_obstacle = scenario.first_obstacle_frame().map(u64::from);
        Ok(Self {
            mock: MockStereo::new(scenario, width, height)?,
            first_obstacle,
        })
    }
}

impl FrameFeed for ScenarioFeed {
    fn rig(&self) -> &StereoRig {
        self.mock.rig()
    }

    fn frames(&self) -> u64 {
        self.mock.scenario().frame_count() as u64
    }

    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        let (l, r) = self.mock.frame(index)?;
        frame.left.prepare(PixelFormat::Rgb8, l)?;
        frame.right.prepare(PixelFormat::Rgb8, r)?;
        left.copy_from_slice(l);
        Ok(())
    }

    fn first_obstacle(&self) -> Option<u64> {
        self.first_obstacle
    }
}

/// A finished replay: the engine as it ended, and one trace row per generation.
pub struct Replay {
    pub engine: Engine,
    /// Every fly's match ambiguity on the last frame ([`Engine::ambiguity`]).
    pub ambiguity: Vec<f32>,
    pub trace: Vec<TraceRow>,
    /// The left image of the last frame.
    pub left: RgbImage,
    /// Frames shown.
    pub frames: u64,
}

/// Runs `generations` generations of an engine with `params` on `feed`, a new frame every
/// `per_frame` generations (the last frame stays once the feed has no more).
pub fn run(
    feed: &mut dyn FrameFeed,
    params: EngineParams,
    generations: u64,
    per_frame: u64,
) -> Result<Replay, ReplayError> {
    let mut engine = Engine::new(feed.rig(), params)?;
    let (w, h) = (feed.rig().left.width(), feed.rig().left.height());
    let (rw, rh) = (feed.rig().right.width(), feed.rig().right.height());
    let mut frame = StereoFrame::new(PreparedImage::new(w, h)?, PreparedImage::new(rw, rh)?, 0);
    let mut left = RgbImage::new(w, h);
    let per_frame = per_frame.max(1);
    let mut trace = Vec::with_capacity(usize::try_from(generations).unwrap_or(0));
    let mut index = None;
    for _ in 0..generations {
        let wanted = (trace.len() as u64 / per_frame).min(feed.frames().saturating_sub(1));
        if index != Some(wanted) {
            feed.load(wanted, &mut frame, &mut left)?;
            frame.id = wanted;
            index = Some(wanted);
        }
        let t = Instant::now();
        let stats = engine.step(&frame)?;
        let elapsed = t.elapsed();
        trace.push(TraceRow {
            frame: wanted,
            stats,
            elapsed,
        });
    }
    let mut ambiguity = vec![f32::INFINITY; engine.population().len()];
    let all: Vec<u32> = (0..ambiguity.len() as u32).collect();
    for (flies, out) in all
        .chunks(engine.ambiguity_capacity().max(1))
        .zip(ambiguity.chunks_mut(engine.ambiguity_capacity().max(1)))
    {
        engine.ambiguity(&frame, flies, out)?;
    }
    Ok(Replay {
        engine,
        ambiguity,
        trace,
        left,
        frames: index.map_or(0, |i| i + 1),
    })
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |source| ReplayError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Per-generation timing figures, microseconds.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Timing {
    pub median_us: f64,
    pub p95_us: f64,
    pub min_us: f64,
    pub max_us: f64,
}

impl Timing {
    /// Figures of a set of durations (sorted in place).
    pub fn of(samples: &mut [Duration]) -> Self {
        if samples.is_empty() {
            return Self::default();
        }
        samples.sort_unstable();
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        let at = |q: f64| us(samples[((samples.len() - 1) as f64 * q).round() as usize]);
        Self {
            median_us: at(0.5),
            p95_us: at(0.95),
            min_us: us(samples[0]),
            max_us: us(samples[samples.len() - 1]),
        }
    }
}

impl Summary {
    /// The summary of `replay`, written to `out`.
    pub fn of(replay: &Replay, out: &Path, reaction: Option<Reaction>) -> Self {
        let stats = replay.engine.stats();
        let mut times: Vec<Duration> = replay.trace.iter().map(|r| r.elapsed).collect();
        Self {
            global_warning: stats.global_warning,
            danger: stats.danger,
            generations: stats.generation,
            frames: replay.frames,
            flies: replay.engine.params().flies,
            seed: replay.engine.params().seed,
            time_per_generation: Timing::of(&mut times),
            out_dir: out.display().to_string(),
            reaction,
        }
    }
}

/// The JSON summary printed on stdout.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Mean warning of the final population (the paper's global warning).
    pub global_warning: f64,
    /// Contrast-independent danger of the final population, m^-3 (see the engine docs).
    pub danger: f64,
    pub generations: u64,
    pub frames: u64,
    pub flies: usize,
    pub seed: u64,
    pub time_per_generation: Timing,
    pub out_dir: String,
    /// On a scenario where an obstacle appears: how fast the global warning reacted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reaction: Option<Reaction>,
}

/// How the global warning reacted to an obstacle appearing at frame `appears_at_frame`.
/// Counts are generations from the first one that saw that frame (1 = that generation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Reaction {
    pub appears_at_frame: u64,
    /// The first generation that saw it.
    pub appears_at_generation: u64,
    /// Global warning of the generation before.
    pub before: f64,
    /// Global warning `SETTLE_GENERATIONS` after the first generation that saw the obstacle.
    pub settled: f64,
    /// Generations to reach half of `settled`.
    pub half_settled_after: Option<u64>,
    /// Generations to reach the default SLOW and STOP thresholds of the daemon.
    pub slow_threshold_after: Option<u64>,
    pub stop_threshold_after: Option<u64>,
}

/// "Settled" = the global warning this many generations after the obstacle appeared (issue 2).
pub const SETTLE_GENERATIONS: usize = 50;

impl Reaction {
    /// The reaction in `trace` to an obstacle first shown by frame `frame`; `None` when the
    /// trace does not run `SETTLE_GENERATIONS` past it.
    pub fn of(trace: &[TraceRow], frame: u64, slow: f64, stop: f64) -> Option<Self> {
        let first = trace.iter().position(|r| r.frame >= frame)?;
        let settled = trace.get(first + SETTLE_GENERATIONS)?.stats.global_warning;
        let after = |level: f64| {
            trace[first..]
                .iter()
                .position(|r| r.stats.global_warning >= level)
                .map(|k| k as u64 + 1)
        };
        Some(Self {
            appears_at_frame: frame,
            appears_at_generation: trace[first].stats.generation,
            before: first
                .checked_sub(1)
                .map_or(f64::NAN, |b| trace[b].stats.global_warning),
            settled,
            half_settled_after: after(settled / 2.0),
            slow_threshold_after: after(slow),
            stop_threshold_after: after(stop),
        })
    }
}

/// One row of `trace.csv`.
#[derive(Debug, Clone, Copy)]
pub struct TraceRow {
    pub frame: u64,
    pub stats: GenerationStats,
    pub elapsed: Duration,
}

/// Writes `flies.csv`.
pub fn write_flies_csv(
    pop: &Population,
    ambiguity: &[f32],
    path: &Path,
) -> Result<(), ReplayError> {
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = std::io::BufWriter::new(file);
    let write = |w: &mut std::io::BufWriter<std::fs::File>| -> std::io::Result<()> {
        writeln!(
            w,
            "x,y,z,fitness,warning,u_left,v_left,u_right,v_right,raw_fitness,ambiguity"
        )?;
        let px = |v: f32| {
            if v.is_finite() {
                format!("{v:.3}")
            } else {
                String::new()
            }
        };
        for i in 0..pop.len() {
            writeln!(
                w,
                "{:.5},{:.5},{:.5},{:e},{:e},{},{},{},{},{:e},{}",
                pop.x[i],
                pop.y[i],
                pop.z[i],
                pop.fitness[i],
                pop.warning[i],
                px(pop.u_left[i]),
                px(pop.v_left[i]),
                px(pop.u_right[i]),
                px(pop.v_right[i]),
                pop.raw_fitness[i],
                ambiguity
                    .get(i)
                    .map_or(String::new(), |a| format!("{a:.4}")),
            )?;
        }
        w.flush()
    };
    write(&mut w).map_err(io_err(path))
}

/// Writes `trace.csv`.
pub fn write_trace_csv(rows: &[TraceRow], path: &Path) -> Result<(), ReplayError> {
    let mut out =
        String::from("generation,frame,new_frame,global_warning,danger,visible,time_us\n");
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{:e},{:e},{},{:.1}\n",
            r.stats.generation,
            r.frame,
            r.stats.new_frame as u8,
            r.stats.global_warning,
            r.stats.danger,
            r.stats.visible,
            r.elapsed.as_secs_f64() * 1e6
        ));
    }
    std::fs::write(path, out).map_err(io_err(path))
}

/// The left image with the best `n` flies drawn as crosses.
pub fn overlay(left: &RgbImage, pop: &Population, n: usize) -> RgbImage {
    let mut img = left.clone();
    let (w, h) = (img.width() as i64, img.height() as i64);
    for i in pop.best(n) {
        let (u, v) = (pop.u_left[i], pop.v_left[i]);
        if !(u.is_finite() && v.is_finite()) {
            continue;
        }
        let (cx, cy) = (u.round() as i64, v.round() as i64);
        for d in -3i64..=3 {
            for (x, y) in [(cx + d, cy), (cx, cy + d)] {
                if (0..w).contains(&x) && (0..h).contains(&y) {
                    img.put_pixel(x as u32, y as u32, Rgb([0, 255, 0]));
                }
            }
        }
    }
    img
}

/// A white image where each fly is a 3x3 spot at its left projection, as dark as its warning
/// (scaled to the largest warning of the population).
pub fn warning_map(width: u32, height: u32, pop: &Population) -> GrayImage {
    let mut img = GrayImage::from_pixel(width, height, Luma([255]));
    let max = pop.warning.iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return img;
    }
    // Draw the weakest first so strong warnings stay visible where spots overlap.
    let mut order: Vec<usize> = (0..pop.len()).collect();
    order.sort_by(|&a, &b| pop.warning[a].total_cmp(&pop.warning[b]));
    for i in order {
        let (u, v) = (pop.u_left[i], pop.v_left[i]);
        if !(u.is_finite() && v.is_finite()) || pop.warning[i] <= 0.0 {
            continue;
        }
        let shade = (255.0 * (1.0 - (pop.warning[i] / max).sqrt())).round() as u8;
        let (cx, cy) = (u.round() as i64, v.round() as i64);
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (x, y) = (cx + dx, cy + dy);
                if (0..width as i64).contains(&x) && (0..height as i64).contains(&y) {
                    let p = img.get_pixel_mut(x as u32, y as u32);
                    p.0[0] = p.0[0].min(shade);
                }
            }
        }
    }
    img
}

/// Writes flies.csv, overlay.png, warnings.png and trace.csv into `dir` (created if needed).
pub fn write_outputs(
    dir: &Path,
    engine: &Engine,
    ambiguity: &[f32],
    left: &RgbImage,
    trace: &[TraceRow],
) -> Result<(), ReplayError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let pop = engine.population();
    write_flies_csv(pop, ambiguity, &dir.join("flies.csv"))?;
    write_trace_csv(trace, &dir.join("trace.csv"))?;
    let save_err = |path: &Path| {
        let path = path.display().to_string();
        move |source| ReplayError::Image { path, source }
    };
    let p = dir.join("overlay.png");
    overlay(left, pop, OVERLAY_FLIES)
        .save(&p)
        .map_err(save_err(&p))?;
    let p = dir.join("warnings.png");
    warning_map(left.width(), left.height(), pop)
        .save(&p)
        .map_err(save_err(&p))?;
    Ok(())
}

/// Loads an image file as RGB8.
pub fn load_rgb(path: &Path) -> Result<RgbImage, ReplayError> {
    image::open(path)
        .map(|i| i.to_rgb8())
        .map_err(|source| ReplayError::Image {
            path: path.display().to_string(),
            source,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(warnings: &[f64], frames_from: u64) -> Vec<TraceRow> {
        warnings
            .iter()
            .enumerate()
            .map(|(g, &w)| TraceRow {
                frame: frames_from + g as u64 / 3,
                stats: GenerationStats {
                    generation: g as u64 + 1,
                    global_warning: w,
                    ..GenerationStats::default()
                },
                elapsed: Duration::ZERO,
            })
            .collect()
    }

    #[test]
    fn reaction_counts_generations_from_the_first_that_saw_the_obstacle() {
        // Frames 0..: 3 generations each; the obstacle at frame 2 = generation 7 (index 6).
        let mut w = vec![0.05; 6];
        w.extend([0.1, 0.6, 1.2, 2.0, 3.9, 4.0]);
        w.extend(std::iter::repeat_n(4.0, 60));
        let r = Reaction::of(&trace(&w, 0), 2, 0.5, 1.5).expect("long enough");
        assert_eq!(r.appears_at_generation, 7);
        assert_eq!(r.before, 0.05);
        assert_eq!(r.settled, 4.0);
        assert_eq!(r.slow_threshold_after, Some(2));
        assert_eq!(r.stop_threshold_after, Some(4));
        assert_eq!(r.half_settled_after, Some(4), "2.0 is half of 4.0");
        assert!(
            Reaction::of(&trace(&w[..30], 0), 2, 0.5, 1.5).is_none(),
            "too short"
        );
        let never = Reaction::of(&trace(&[0.05; 80], 0), 2, 0.5, 1.5).expect("long enough");
        assert_eq!(never.stop_threshold_after, None);
    }
}
