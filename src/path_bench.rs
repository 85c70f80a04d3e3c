//! `flyd bench --path`: flyd's own path prediction replayed on real trajectories.
//!
//! For every moment of a recorded drive (KITTI odometry poses: where the car really went)
//! above [`MIN_KMH`], the vehicle's motion of that moment (its speed and yaw rate, as
//! `VCU_Motion` reports them: the central difference of the poses around it) goes through
//! the obstacle stage's [`PathEstimator`], as the daemon feeds it frame by frame. At each
//! decision stage's distance for that speed (STOP and SLOW: the decider's
//! `v reaction_time + v^2 / (2 decel) + margin`; a time to collision of 1 s for reference),
//! the bench takes where the car really was that far along its real trajectory, and asks
//! the corridor ([`flyd_core::path::PathEstimate::locate_in`], what the obstacle stage asks of
//! a fly):
//!
//! - **on path**: is an object on the real path there inside the corridor? (It should be:
//!   the vehicle drove into that point.)
//! - **beside D m**: is an object D metres beside the real path (either side, along the
//!   vehicle's lateral axis at that moment) inside it? (It should not be: the car passed it
//!   D minus its half-width clear.)
//!
//! Pure arithmetic over the poses: no image, no randomness, the same figures every run.

use std::path::{Path, PathBuf};

use flyd_core::decision::{Command, DecisionConfig};
use flyd_core::kinematics::VehicleMotion;
use flyd_core::path::{PathEstimator, PathModel};
use nalgebra::Vector3;

use crate::replay::poses::{self, Pose};

/// Moments slower than this are not judged (km/h): below it the decision distances are a
/// few metres and the path of no interest.
pub const MIN_KMH: f64 = 18.0;

/// Offsets of the objects beside the real path, metres.
pub const BESIDE_M: [f64; 3] = [1.5, 2.2, 3.0];

/// Speed bands reported, km/h (the last one open).
const BANDS: [(f64, f64); 4] = [
    (18.0, 30.0),
    (30.0, 40.0),
    (40.0, 50.0),
    (50.0, f64::INFINITY),
];

/// One drive: its poses and their times.
#[derive(Debug, Clone)]
pub struct Drive {
    pub name: String,
    pub poses: Vec<Pose>,
    pub times: Vec<f64>,
}

/// Why a drive cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum DriveError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Poses {
        path: PathBuf,
        source: poses::PosesError,
    },
    #[error("{path}: {found} times for {poses} poses")]
    Times {
        path: PathBuf,
        found: usize,
        poses: usize,
    },
    #[error("{path}: line {line}: {text:?} is not a time in seconds")]
    Time {
        path: PathBuf,
        line: usize,
        text: String,
    },
    #[error("{path}: times must increase (line {line})")]
    Order { path: PathBuf, line: usize },
    #[error("{0}: no poses_*.txt or poses.txt there")]
    Empty(PathBuf),
}

impl Drive {
    /// The drives at `path`: a poses file (`poses.txt`, `poses_NN.txt`, its times beside as
    /// `times.txt` / `times_NN.txt`, else 10 Hz), or a folder of them.
    pub fn load(path: &Path) -> Result<Vec<Self>, DriveError> {
        if !path.is_dir() {
            return Ok(vec![Self::load_file(path)?]);
        }
        let io = |source| DriveError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(path)
            .map_err(io)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("poses") && n.ends_with(".txt"))
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(DriveError::Empty(path.to_path_buf()));
        }
        files.iter().map(|f| Self::load_file(f)).collect()
    }

    fn load_file(path: &Path) -> Result<Self, DriveError> {
        let read = |p: &Path| {
            std::fs::read_to_string(p).map_err(|source| DriveError::Io {
                path: p.to_path_buf(),
                source,
            })
        };
        let poses = poses::parse(&read(path)?).map_err(|source| DriveError::Poses {
            path: path.to_path_buf(),
            source,
        })?;
        let name = path
            .file_stem()
            .and_then(|n| n.to_str())
            .unwrap_or("poses")
            .to_string();
        let times_name = name.replacen("poses", "times", 1) + ".txt";
        let times_path = path.with_file_name(times_name);
        let times = if times_path.is_file() {
            let text = read(&times_path)?;
            let mut times = Vec::with_capacity(poses.len());
            for (n, l) in text.lines().enumerate() {
                let t = l.trim();
                if t.is_empty() {
                    continue;
                }
                let v = t
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| DriveError::Time {
                        path: times_path.clone(),
                        line: n + 1,
                        text: t.to_string(),
                    })?;
                if times.last().is_some_and(|&last| v <= last) {
                    return Err(DriveError::Order {
                        path: times_path.clone(),
                        line: n + 1,
                    });
                }
                times.push(v);
            }
            if times.len() != poses.len() {
                return Err(DriveError::Times {
                    path: times_path,
                    found: times.len(),
                    poses: poses.len(),
                });
            }
            times
        } else {
            (0..poses.len()).map(|i| i as f64 / 10.0).collect()
        };
        Ok(Self { name, poses, times })
    }
}

/// What the bench judges with: the decision's distances and the corridor.
#[derive(Debug, Clone, Copy)]
pub struct PathBenchConfig {
    pub decision: DecisionConfig,
    pub half_width: f64,
    pub model: PathModel,
    /// Standard deviation of white noise added to the yaw rate of each moment, rad/s (a
    /// real sensor's; the poses' own is smoothed), from a fixed seed.
    pub yaw_noise: f64,
}

/// A decision stage's distance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stage {
    Stop,
    Slow,
    /// A time to collision of 1 s (reference).
    Ttc1s,
}

impl Stage {
    pub const ALL: [Stage; 3] = [Stage::Stop, Stage::Slow, Stage::Ttc1s];

    fn distance(self, decision: &DecisionConfig, speed: f64) -> f64 {
        match self {
            Stage::Stop => decision.reach(Command::Stop, speed),
            Stage::Slow => decision.reach(Command::Slow, speed),
            Stage::Ttc1s => speed,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Stage::Stop => "STOP",
            Stage::Slow => "SLOW",
            Stage::Ttc1s => "TTC 1 s",
        }
    }
}

/// The rates of one stage in one speed band.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    pub stage: Stage,
    /// `"18-30"`, ..., `"50+"`, `"all"` (km/h).
    pub band: String,
    pub moments: usize,
    pub median_distance_m: f64,
    /// % of moments whose object on the real path is inside the corridor.
    pub on_path_inside_pct: f64,
    /// % of moments whose object `BESIDE_M[i]` beside the real path (either side) is inside.
    pub beside_inside_pct: [f64; 3],
    /// The real path's offset from the predicted one there, metres: median, 95th and 99th
    /// percentile of its size.
    pub offset_p50_m: f64,
    pub offset_p95_m: f64,
    pub offset_p99_m: f64,
}

/// The bench's result.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PathReport {
    pub drives: usize,
    pub seconds: f64,
    pub kilometres: f64,
    pub model: PathModel,
    pub half_width_m: f64,
    pub slow_decel: f64,
    pub stop_decel: f64,
    pub yaw_noise: f64,
    pub rows: Vec<Row>,
}

/// One judged moment of one stage.
struct Sample {
    kmh: f64,
    distance: f64,
    on_path: bool,
    beside: [bool; 3],
    offset: f64,
}

/// Runs the bench over `drives`.
pub fn run(drives: &[Drive], config: &PathBenchConfig) -> PathReport {
    let mut samples: Vec<Vec<Sample>> = Stage::ALL.iter().map(|_| Vec::new()).collect();
    let (mut seconds, mut metres) = (0.0, 0.0);
    let mut noise = Noise::new(0x5eed_f1d0);
    for drive in drives {
        let n = drive.poses.len().min(drive.times.len());
        if n < 3 {
            continue;
        }
        seconds += drive.times[n - 1] - drive.times[0];
        // Distance travelled to each pose.
        let mut travelled = vec![0.0; n];
        for i in 1..n {
            travelled[i] =
                travelled[i - 1] + (drive.poses[i].position - drive.poses[i - 1].position).norm();
        }
        metres += travelled[n - 1];
        let mut estimator = PathEstimator::with_model(config.model);
        for i in 1..n - 1 {
            let dt = drive.times[i] - drive.times[i - 1];
            let mut motion = poses::motion_between(
                &drive.poses[i - 1],
                &drive.poses[i + 1],
                drive.times[i + 1] - drive.times[i - 1],
            );
            if config.yaw_noise > 0.0 {
                motion.yaw_rate += config.yaw_noise * noise.gaussian();
            }
            let estimate = estimator.update(motion, dt);
            let kmh = motion.speed * 3.6;
            if kmh <= MIN_KMH {
                continue;
            }
            for (stage, out) in Stage::ALL.iter().zip(samples.iter_mut()) {
                let distance = stage.distance(&config.decision, motion.speed);
                let Some((x, z)) = real_point(drive, &travelled, i, distance) else {
                    continue;
                };
                let half = config.half_width as f32;
                let inside = |x: f64| estimate.locate_in(x as f32, z as f32, half).is_some();
                let beside = BESIDE_M.map(|d| inside(x + d) || inside(x - d));
                let offset = if estimate.held.is_straight() {
                    x
                } else {
                    f64::from(estimate.held.locate(x as f32, z as f32).1)
                };
                out.push(Sample {
                    kmh,
                    distance,
                    on_path: inside(x),
                    beside,
                    offset,
                });
            }
        }
    }
    let mut rows = Vec::new();
    for (stage, stage_samples) in Stage::ALL.iter().zip(&samples) {
        let bands = BANDS
            .iter()
            .map(|&(lo, hi)| {
                let name = if hi.is_finite() {
                    format!("{lo}-{hi}")
                } else {
                    format!("{lo}+")
                };
                (name, lo, hi)
            })
            .chain(std::iter::once(("all".to_string(), 0.0, f64::INFINITY)));
        for (band, lo, hi) in bands {
            let judged: Vec<&Sample> = stage_samples
                .iter()
                .filter(|s| s.kmh > lo && s.kmh <= hi)
                .collect();
            rows.push(summarise(*stage, band, &judged));
        }
    }
    PathReport {
        drives: drives.len(),
        seconds,
        kilometres: metres / 1000.0,
        model: config.model,
        half_width_m: config.half_width,
        slow_decel: config.decision.slow_decel,
        stop_decel: config.decision.stop_decel,
        yaw_noise: config.yaw_noise,
        rows,
    }
}

fn summarise(stage: Stage, band: String, judged: &[&Sample]) -> Row {
    let n = judged.len();
    let pct = |count: usize| {
        if n == 0 {
            f64::NAN
        } else {
            100.0 * count as f64 / n as f64
        }
    };
    let mut distances: Vec<f64> = judged.iter().map(|s| s.distance).collect();
    let mut offsets: Vec<f64> = judged.iter().map(|s| s.offset.abs()).collect();
    Row {
        stage,
        band,
        moments: n,
        median_distance_m: quantile(&mut distances, 0.5),
        on_path_inside_pct: pct(judged.iter().filter(|s| s.on_path).count()),
        beside_inside_pct: [0, 1, 2].map(|k| pct(judged.iter().filter(|s| s.beside[k]).count())),
        offset_p50_m: quantile(&mut offsets, 0.5),
        offset_p95_m: quantile(&mut offsets, 0.95),
        offset_p99_m: quantile(&mut offsets, 0.99),
    }
}

fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let at = ((values.len() - 1) as f64 * q).round() as usize;
    values[at.min(values.len() - 1)]
}

/// Where the vehicle really was `distance` metres on from pose `i` along its trajectory, in
/// pose `i`'s vehicle frame `(x right, z ahead)`; `None` past the drive's end.
fn real_point(drive: &Drive, travelled: &[f64], i: usize, distance: f64) -> Option<(f64, f64)> {
    let goal = travelled[i] + distance;
    let j = i + travelled[i..].partition_point(|&s| s < goal);
    if j >= travelled.len() || j == 0 {
        return None;
    }
    let (a, b) = (&drive.poses[j - 1], &drive.poses[j]);
    let span = travelled[j] - travelled[j - 1];
    let t = if span > 0.0 {
        (goal - travelled[j - 1]) / span
    } else {
        0.0
    };
    let at: Vector3<f64> = a.position + (b.position - a.position) * t;
    let here = &drive.poses[i];
    let local = here.rotation.transpose() * (at - here.position);
    Some((local.x, local.z))
}

/// A small deterministic Gaussian source (xorshift64* and Box-Muller): the bench's noise
/// is the same every run.
struct Noise(u64);

impl Noise {
    fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let bits = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11;
        (bits as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn gaussian(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

impl std::fmt::Display for PathReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "path bench: {} drives, {:.1} min, {:.1} km; model {}; corridor +-{} m; SLOW {} m/s^2, STOP {} m/s^2{}",
            self.drives,
            self.seconds / 60.0,
            self.kilometres,
            model_name(&self.model),
            self.half_width_m,
            self.slow_decel,
            self.stop_decel,
            if self.yaw_noise > 0.0 {
                format!("; yaw-rate noise {} rad/s", self.yaw_noise)
            } else {
                String::new()
            }
        )?;
        writeln!(
            f,
            "{:<8} {:>6} {:>8} {:>8} | {:>8} | {:>6} {:>6} {:>6} | {:>5} {:>5} {:>5}",
            "stage",
            "km/h",
            "moments",
            "dist m",
            "on path",
            "1.5 m",
            "2.2 m",
            "3.0 m",
            "p50",
            "p95",
            "p99"
        )?;
        writeln!(
            f,
            "{:<8} {:>6} {:>8} {:>8} | {:>8} | {:>20} | {:>17}",
            "", "", "", "median", "inside %", "beside, inside %", "offset m"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "{:<8} {:>6} {:>8} {:>8.1} | {:>8.2} | {:>6.2} {:>6.2} {:>6.2} | {:>5.2} {:>5.2} {:>5.2}",
                r.stage.name(),
                r.band,
                r.moments,
                r.median_distance_m,
                r.on_path_inside_pct,
                r.beside_inside_pct[0],
                r.beside_inside_pct[1],
                r.beside_inside_pct[2],
                r.offset_p50_m,
                r.offset_p95_m,
                r.offset_p99_m
            )?;
        }
        Ok(())
    }
}

fn model_name(model: &PathModel) -> String {
    match model {
        PathModel::Clothoid { window } if *window == 0.0 => "arc of the moment".to_string(),
        PathModel::Clothoid { window } => format!("clothoid (rate over {window} s)"),
        PathModel::ClothoidGated { window } => {
            format!("clothoid (rate over {window} s), gated by the arc of the moment")
        }
        PathModel::Held { hold } => format!("held {hold} s, gated by the arc of the moment"),
    }
}

/// The motion of a drive's moment `i` (tests).
pub fn motion_at(drive: &Drive, i: usize) -> Option<VehicleMotion> {
    (i >= 1 && i + 1 < drive.poses.len().min(drive.times.len())).then(|| {
        poses::motion_between(
            &drive.poses[i - 1],
            &drive.poses[i + 1],
            drive.times[i + 1] - drive.times[i - 1],
        )
    })
}

#[cfg(test)]
mod tests;
