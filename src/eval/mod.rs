//! `flyd eval MANIFEST`: labelled recordings replayed over seeds, the way a user validates
//! flyd on their own rig.
//!
//! Every item of the manifest ([`manifest`]) is replayed (in this process, `flyd replay`'s
//! [`crate::replay::Request`]) once a seed, the runs spread over worker threads; each run is
//! judged against the item's label ([`outcome`]) and the items are reported one row each
//! ([`report`]).

pub mod manifest;
pub mod outcome;
pub mod report;

pub use manifest::{Expect, Item, Manifest, ManifestError};
pub use outcome::{Outcome, Verdict};
pub use report::{ItemReport, Report};

use crate::config::DaemonConfig;
use crate::replay::{ReplayError, Request, Source};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// How `flyd eval` runs a manifest.
#[derive(Debug, Clone)]
pub struct Options {
    /// Where the items' folders are.
    pub data: PathBuf,
    /// Seeds 1..=seeds.
    pub seeds: u64,
    /// Worker threads.
    pub jobs: usize,
    /// The configuration every replay takes (`[engine]` but its seed, `[perception]`, ...).
    pub config: DaemonConfig,
    /// Where the rigs written from `mount` go (and, with `outputs`, each run's replay files).
    pub work: PathBuf,
    /// Write each run's replay outputs (trace.csv, ...) under `work/ITEM/seedN`.
    pub outputs: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("{path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("starting a worker thread")]
    Spawn(#[source] std::io::Error),
    /// Items' folders missing under the data folder: said once, with the fix.
    #[error(
        "{missing} of the items' folders are not in {data} (the first: {first}); give `--data \
         DIR`, the folder that holds them (the manifest's `data`, relative to it, by default)"
    )]
    MissingData {
        data: String,
        first: String,
        missing: usize,
    },
}

/// The replay request of `item`, seed `seed`, its rig at `rig` (when it has a folder).
fn request(item: &Item, data: &Path, rig: Option<&Path>, seed: u64) -> Request {
    let calib = rig.map(Path::to_path_buf).unwrap_or_default();
    let size = || {
        item.size
            .as_deref()
            .and_then(manifest::parse_size)
            .unwrap_or((640, 480))
    };
    let source = if let Some(case) = &item.case {
        let (width, height) = size();
        Source::ClosedLoop {
            case: case.clone(),
            width,
            height,
        }
    } else if let Some(name) = &item.scenario {
        let (width, height) = size();
        Source::Scenario {
            name: name.clone(),
            width,
            height,
        }
    } else if let Some(dir) = &item.sequence {
        Source::Sequence {
            dir: data.join(dir),
            calib,
            fps: item.fps.unwrap_or(10.0),
            can_input: item.can_input.as_ref().map(|f| data.join(dir).join(f)),
        }
    } else {
        let dir = data.join(item.pair.as_deref().unwrap_or_default());
        let (left, right) = match &item.frame {
            Some(f) => (dir.join("left").join(f), dir.join("right").join(f)),
            None => (dir.join("im0.png"), dir.join("im1.png")),
        };
        Source::Pair { left, right, calib }
    };
    Request {
        source,
        flies: item.flies,
        seed: Some(seed),
        speed_kmh: item.speed_kmh,
        generations: None,
        generations_per_frame: None,
        right_yaw_error_deg: None,
    }
}

/// The folder an item's data lives in.
fn folder(item: &Item, data: &Path) -> Option<PathBuf> {
    item.pair
        .as_deref()
        .or(item.sequence.as_deref())
        .map(|d| data.join(d))
}

/// The item's rig: its `rig` file, or a rig written to `work` that imports the folder's
/// `calib.txt` and places it at `mount`.
fn rig_of(item: &Item, data: &Path, work: &Path) -> Result<Option<PathBuf>, EvalError> {
    let Some(dir) = folder(item, data) else {
        return Ok(None);
    };
    if let Some(rig) = &item.rig {
        return Ok(Some(dir.join(rig)));
    }
    let [x, y, z] = item.mount.unwrap_or_default();
    let calib = dir.join("calib.txt");
    let calib = std::path::absolute(&calib).unwrap_or(calib);
    let text = format!(
        "# Written by flyd eval for item '{}'.\n[import]\nfile = {:?}\n\n[mount]\nposition = [{x:?}, {y:?}, {z:?}]\n",
        item.name,
        calib.display().to_string()
    );
    let dir = work.join(&item.name);
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| EvalError::Io { path, source }
    };
    std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    let path = dir.join("rig.toml");
    std::fs::write(&path, text).map_err(io(&path))?;
    Ok(Some(path))
}

/// Runs every item of `items` on seeds 1..=`options.seeds` and judges each run.
pub fn run(items: &[Item], options: &Options) -> Result<Report, EvalError> {
    run_with_progress(items, options, |_| {})
}

/// How far a run of [`run_with_progress`] is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress<'a> {
    /// Runs finished, of `total`.
    pub done: usize,
    pub total: usize,
    /// The run that just finished.
    pub item: &'a str,
    pub seed: u64,
    /// Since the start.
    pub elapsed: std::time::Duration,
}

impl Progress<'_> {
    /// One line for a terminal: the count, the run that finished, the time spent and the
    /// time left at the pace so far.
    pub fn line(&self) -> String {
        let minutes = |d: std::time::Duration| {
            let s = d.as_secs();
            if s >= 60 {
                format!("{}m{:02}s", s / 60, s % 60)
            } else {
                format!("{s}s")
            }
        };
        let left = (self.done > 0).then(|| {
            self.elapsed
                .mul_f64((self.total - self.done.min(self.total)) as f64 / self.done as f64)
        });
        format!(
            "eval: {}/{} runs ({} seed {} done), {} elapsed{}",
            self.done,
            self.total,
            self.item,
            self.seed,
            minutes(self.elapsed),
            left.map_or(String::new(), |l| format!(", about {} left", minutes(l)))
        )
    }
}

/// [`run`], calling `progress` after each run (from the worker that finished it).
pub fn run_with_progress(
    items: &[Item],
    options: &Options,
    progress: impl Fn(Progress<'_>) + Sync,
) -> Result<Report, EvalError> {
    let started = std::time::Instant::now();
    let finished = AtomicUsize::new(0);
    let absent: Vec<PathBuf> = items
        .iter()
        .filter_map(|item| folder(item, &options.data))
        .filter(|dir| !dir.is_dir())
        .collect();
    if let Some(first) = absent.first() {
        return Err(EvalError::MissingData {
            data: options.data.display().to_string(),
            first: first.display().to_string(),
            missing: absent.len(),
        });
    }
    let rigs = items
        .iter()
        .map(|item| rig_of(item, &options.data, &options.work))
        .collect::<Result<Vec<_>, _>>()?;
    let jobs: Vec<(usize, u64)> = (0..items.len())
        .flat_map(|i| (1..=options.seeds).map(move |s| (i, s)))
        .collect();
    let results: Mutex<Vec<Option<Outcome>>> = Mutex::new(vec![None; jobs.len()]);
    let next = AtomicUsize::new(0);
    std::thread::scope(|scope| -> Result<(), EvalError> {
        for worker in 0..options.jobs.clamp(1, jobs.len().max(1)) {
            let (jobs, results, next, rigs) = (&jobs, &results, &next, &rigs);
            let (finished, progress) = (&finished, &progress);
            std::thread::Builder::new()
                .name(format!("flyd-eval-{worker}"))
                .spawn_scoped(scope, move || {
                    loop {
                        let j = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&(i, seed)) = jobs.get(j) else {
                            break;
                        };
                        let outcome = run_one(&items[i], rigs[i].as_deref(), seed, options);
                        if let Ok(mut r) = results.lock()
                            && let Some(slot) = r.get_mut(j)
                        {
                            *slot = Some(outcome);
                        }
                        progress(Progress {
                            done: finished.fetch_add(1, Ordering::Relaxed) + 1,
                            total: jobs.len(),
                            item: &items[i].name,
                            seed,
                            elapsed: started.elapsed(),
                        });
                    }
                })
                .map_err(EvalError::Spawn)?;
        }
        Ok(())
    })?;
    if options.outputs {
        // Why each run braked, at a glance.
        let index = options.work.join("index.html");
        crate::replay::decided::write_index(&options.work).map_err(|source| EvalError::Io {
            path: index.display().to_string(),
            source,
        })?;
    }
    let results = results.into_inner().unwrap_or_else(|p| p.into_inner());
    let mut per_item: Vec<Vec<Outcome>> = vec![Vec::new(); items.len()];
    for ((i, _), outcome) in jobs.iter().zip(results) {
        per_item[*i].push(outcome.unwrap_or_else(|| Outcome::failed("the run did not finish")));
    }
    Ok(Report::of(items, per_item, options.seeds))
}

/// One replay of `item` on `seed`, judged.
fn run_one(item: &Item, rig: Option<&Path>, seed: u64, options: &Options) -> Outcome {
    let replay = || -> Result<Outcome, ReplayError> {
        let request = request(item, &options.data, rig, seed);
        let prepared = request.prepare(&options.config)?;
        let (run, reaction) = prepared.run(&options.config)?;
        let out = options.work.join(&item.name).join(format!("seed{seed}"));
        if options.outputs {
            crate::replay::write_outputs(&out, &run)?;
        }
        let summary = crate::replay::Summary::of(&run, &out, reaction);
        let mut outcome = Outcome::of(item, &run, &summary);
        if let (Some(truth), Some(dir)) = (&item.truth, folder(item, &options.data)) {
            let map = flyd_core::dataset::read_pfm(&dir.join(truth))
                .map_err(|e| ReplayError::Usage(flyd_core::chain::Chain(&e).to_string()))?;
            outcome.accuracy = outcome::Accuracy::of(&run, &map);
        }
        Ok(outcome)
    };
    replay().unwrap_or_else(|e| Outcome::failed(&flyd_core::chain::Chain(&e).to_string()))
}

#[cfg(test)]
mod tests {
    use super::Progress;
    use std::time::Duration;

    #[test]
    fn progress_says_what_is_done_and_what_is_left_at_the_pace_so_far() {
        let p = |done, secs| Progress {
            done,
            total: 116,
            item: "drive-40",
            seed: 3,
            elapsed: Duration::from_secs(secs),
        };
        assert_eq!(
            p(29, 290).line(),
            "eval: 29/116 runs (drive-40 seed 3 done), 4m50s elapsed, about 14m30s left"
        );
        assert_eq!(
            p(116, 5).line(),
            "eval: 116/116 runs (drive-40 seed 3 done), 5s elapsed, about 0s left"
        );
        assert_eq!(
            p(0, 0).line(),
            "eval: 0/116 runs (drive-40 seed 3 done), 0s elapsed"
        );
    }
}
