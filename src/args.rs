//! `flyd`'s command line: the subcommands and their options (clap). What each does is in
//! `main.rs`.

use clap::{Args, Parser, Subcommand};
use flyd_core::engine::EngineParams;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "flyd",
    version,
    about = "Stereo obstacle detection with the Fly Algorithm"
)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Subcommand)]
pub(crate) enum Command {
    /// Run the evolution on a stereo pair or a hw-mock scenario and write what it found.
    Replay(Box<ReplayArgs>),
    /// Replay the labelled recordings of a manifest (eval/*.toml) over seeds and judge every
    /// run against its label; exits 1 when one fails.
    Eval(EvalArgs),
    /// Time generations of the engine on a synthetic scene (single thread).
    Bench(BenchArgs),
    /// Run the daemon: cameras -> fly evolution -> CLEAR/SLOW/STOP on CAN.
    Run(RunArgs),
    /// Check a configuration file (and its calibration) without opening any device.
    CheckConfig {
        /// The TOML configuration file.
        file: PathBuf,
    },
}

#[derive(Args)]
pub(crate) struct BenchArgs {
    /// Population size.
    #[arg(long, default_value_t = EngineParams::default().flies)]
    pub(crate) flies: usize,
    /// Image size of the synthetic scene.
    #[arg(long, default_value_t = 640)]
    pub(crate) width: u32,
    #[arg(long, default_value_t = 480)]
    pub(crate) height: u32,
    /// Generations timed (after a warm-up of 50).
    #[arg(long, default_value_t = 3000)]
    pub(crate) generations: u64,
    /// Generations per new frame (3 = 30 fps at ~10 ms a generation, as the daemon runs).
    #[arg(long, default_value_t = 3)]
    pub(crate) generations_per_frame: u64,
    /// Print JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
    /// Instruction set of the hot loops: baseline, avx2 or avx512 (default: the best this CPU
    /// has; every one gives the same population).
    #[arg(long, value_parser = parse_isa)]
    pub(crate) isa: Option<flyd_core::isa::Isa>,
    /// Take [engine] (but its seed) and [perception] from this daemon configuration (default: the built-in defaults).
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// Play this hw-mock scenario's first 60 frames in order (e.g. `driving`) instead of two
    /// noise draws of `pedestrian-4m`, the flies moved with the scenario's own motion.
    #[arg(long)]
    pub(crate) scenario: Option<String>,
    /// With --scenario: do not move the flies with the vehicle's motion.
    #[arg(long)]
    pub(crate) no_predict: bool,
    /// Instead: reaction time of the whole threaded daemon on hw-mock (config/demo.toml), from
    /// the first frame showing the pedestrian to the first STOP frame, over RUNS runs.
    #[arg(long, value_name = "RUNS", num_args = 0..=1, default_missing_value = "10")]
    pub(crate) end_to_end: Option<usize>,
    /// Instead: flyd's path prediction on real trajectories (KITTI odometry poses: files
    /// poses_NN.txt / poses.txt with their times_NN.txt / times.txt, or folders of them;
    /// default ../shared/data/kitti_poses): at each decision stage's distance, how often an
    /// object on the real path is inside the corridor and one beside it is (docs/path.md).
    /// Takes [decision] and [perception.obstacle] from --config.
    #[arg(long, value_name = "POSES", num_args = 0.., conflicts_with = "end_to_end")]
    pub(crate) path: Option<Vec<PathBuf>>,
    /// With --path: the path model instead of the configuration's: arc (the arc of the
    /// moment), clothoid, clothoid-gated or held.
    #[arg(long, requires = "path", value_parser = ["arc", "clothoid", "clothoid-gated", "held"])]
    pub(crate) path_model: Option<String>,
    /// With --path: white noise added to each moment's yaw rate, rad/s (standard deviation).
    #[arg(long, requires = "path", default_value_t = 0.0)]
    pub(crate) yaw_noise: f64,
}

#[derive(Args)]
pub(crate) struct ReplayArgs {
    /// Left image (PNG or JPEG).
    #[arg(long, requires_all = ["right", "calib"], conflicts_with_all = ["scenario", "sequence"])]
    pub(crate) left: Option<PathBuf>,
    /// Right image (PNG or JPEG).
    #[arg(long)]
    pub(crate) right: Option<PathBuf>,
    /// Calibration: flyd rig TOML, KITTI calib_cam_to_cam.txt or calib.txt, Middlebury
    /// calib.txt or OpenCV stereo YAML.
    #[arg(long)]
    pub(crate) calib: Option<PathBuf>,
    /// A folder of stereo pairs, replayed in name order: left/ + right/, or KITTI's
    /// image_02/data + image_03/data (needs --calib).
    #[arg(long, requires = "calib", conflicts_with = "scenario")]
    pub(crate) sequence: Option<PathBuf>,
    /// With --sequence: the vehicle's motion from this candump log of its bus (`VCU_Motion`,
    /// as `flyd run --can-input` takes it: the log's first frame due with the first image,
    /// every frame checked as the daemon checks it) instead of the folder's poses.txt.
    #[arg(long, value_name = "PATH", requires = "sequence")]
    pub(crate) can_input: Option<PathBuf>,
    /// With --sequence: frames per second of the recording.
    #[arg(long, default_value_t = 10.0)]
    pub(crate) fps: f64,
    /// Generations to run (default on a stereo pair: the warm-up, then long enough for the
    /// start-up's safe command to be released and an obstacle to be confirmed, at least 50;
    /// every frame otherwise).
    #[arg(long)]
    pub(crate) generations: Option<u64>,
    /// Population size (default: the configuration's).
    #[arg(long)]
    pub(crate) flies: Option<usize>,
    /// Seed of the random generator (default: the configuration's).
    #[arg(long)]
    pub(crate) seed: Option<u64>,
    /// Turn the calibration's right camera by this many degrees (its yaw_deg: positive
    /// right) before replaying, the images unchanged: what a knocked camera or a wrong
    /// calibration shows flyd (the summary's `columns` says whether the motion finds it).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub(crate) right_yaw_error: Option<f64>,
    /// A hw-mock scenario instead of a stereo pair: empty-road, pedestrian-4m,
    /// pedestrian-steps-in, car-approaching, driving, driving-to-pedestrian, drive-30, drive-40,
    /// drive-30-to-pedestrian, drive-40-to-pedestrian, drive-30-lane-change, bend-30,
    /// bend-30-to-pedestrian, bend-30-parked-car, bend-40, bend-40-to-pedestrian,
    /// bend-40-parked-car, ramp-30, ramp-30-stopped-car, ramp-30-pedestrian-on-kerb, ramp-40,
    /// ramp-40-stopped-car, s-bend-40, s-bend-40-to-pedestrian (the moving ones decided at
    /// their own speed, the flies moved with it).
    #[arg(long)]
    pub(crate) scenario: Option<String>,
    /// A closed-loop case file (docs/closed-loop.md): hw-mock's vehicle obeys the commands,
    /// its cameras rendered from where it really is; the summary says whether it stopped
    /// short, how hard it braked, and `--out` gets closed_loop.csv and closed_loop.svg.
    /// Shipped: eval/closed-loop/stationary.toml, bend.toml, false-activation.toml (no
    /// reason to brake) and traffic.toml (cars followed, braking, cutting in; pedestrians
    /// crossing); given without --case-name, a file of several cases lists their names.
    #[arg(long, value_name = "FILE.toml", conflicts_with_all = ["scenario", "sequence", "left"])]
    pub(crate) case: Option<PathBuf>,
    /// With --case: which of the file's cases (as `flyd eval` names them, e.g.
    /// `car-stationary-100-30kmh`; default: the file's only one).
    #[arg(long, value_name = "NAME", requires = "case")]
    pub(crate) case_name: Option<String>,
    /// Generations per frame (default: 3 for a scenario, 30 fps at ~10 ms a generation; for a
    /// sequence, what the daemon runs at --fps: a burst of evolution.burst_generations, then
    /// one per evolution.generation_period_ms).
    #[arg(long)]
    pub(crate) generations_per_frame: Option<u64>,
    /// With --scenario: image size.
    #[arg(long, default_value_t = 640)]
    pub(crate) width: u32,
    #[arg(long, default_value_t = 480)]
    pub(crate) height: u32,
    /// The vehicle's speed the decision assumes, km/h, on every frame (default: a scenario's
    /// own speed, else the configuration's vehicle.assumed_speed_kmh, 30).
    #[arg(long, value_name = "KMH")]
    pub(crate) speed: Option<f64>,
    /// Take [engine], [perception], [decision], [vehicle] and [evolution] from this daemon
    /// configuration (default: the built-in defaults).
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// A recording of the daemon (`flyd run --record`): its frames through the same engine and
    /// decider, checked to reproduce the recorded commands bit for bit (with its attached
    /// configuration unless --config is given; --seed changes the seed). Prints a JSON summary;
    /// exits 1 where the replay diverges, saying where.
    #[arg(long, value_name = "FILE.mcap", conflicts_with_all = ["left", "scenario", "sequence"])]
    pub(crate) mcap: Option<PathBuf>,
    /// Output directory.
    #[arg(long, required_unless_present = "mcap")]
    pub(crate) out: Option<PathBuf>,
    /// Also write what the replay saw, found and decided to this MCAP file (frames, flies,
    /// road, obstacle, decisions, the FLYD_Command frames), to open in Foxglove: a KITTI
    /// sequence or a replayed recording becomes a recording.
    #[arg(long, value_name = "FILE.mcap")]
    pub(crate) record: Option<PathBuf>,
}

#[derive(Args)]
pub(crate) struct EvalArgs {
    /// The manifest: `[[item]]`s with their source, rig and label (see eval/real.toml).
    pub(crate) manifest: PathBuf,
    /// Where the items' folders are (default: the manifest's `data`, relative to it).
    #[arg(long)]
    pub(crate) data: Option<PathBuf>,
    /// Runs seeds 1..=N of every item.
    #[arg(long, default_value_t = 20)]
    pub(crate) seeds: u64,
    /// Runs at once (default: the cores this process may use).
    #[arg(long)]
    pub(crate) jobs: Option<usize>,
    /// Take [engine] (but its seed), [perception], [decision], [vehicle] and [evolution] from
    /// this daemon configuration (default: the built-in defaults).
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// Only these items (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    pub(crate) only: Vec<String>,
    /// Also write the report, every run of every item, as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub(crate) json: Option<PathBuf>,
    /// Keep the rigs and every run's replay outputs (trace.csv, overlay.png...) in
    /// DIR/ITEM/seedN.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub(crate) struct RunArgs {
    /// The TOML configuration file.
    #[arg(long)]
    pub(crate) config: PathBuf,
    /// Write CAN frames as candump log lines to PATH (`-` = stdout) instead of the configured
    /// bus: a dry run on the vehicle.
    #[arg(long, value_name = "PATH")]
    pub(crate) can_log: Option<PathBuf>,
    /// Read the frames flyd receives (the vehicle's motion, VCU_Motion) from a candump log
    /// (`candump -l`/`-L` lines), replayed at their recorded pace from the start, instead of
    /// the bus or the mock vehicle: a recorded drive's bus, without a kernel.
    #[arg(long, value_name = "PATH")]
    pub(crate) can_input: Option<PathBuf>,
    /// Stop after SECONDS (default: until SIGTERM/SIGINT, or the end of a mock scenario).
    #[arg(long, value_name = "SECONDS")]
    pub(crate) duration: Option<f64>,
    /// Record to this MCAP file (overrides record.path): the frames, flies, road, obstacle,
    /// decisions, stats and every CAN frame; `flyd replay --mcap` replays it.
    #[arg(long, value_name = "FILE.mcap")]
    pub(crate) record: Option<PathBuf>,
}

fn parse_isa(name: &str) -> std::result::Result<flyd_core::isa::Isa, String> {
    flyd_core::isa::Isa::by_name(name).ok_or_else(|| {
        let names: Vec<&str> = flyd_core::isa::Isa::available()
            .iter()
            .map(|i| i.name())
            .collect();
        format!("this CPU has {}", names.join(", "))
    })
}
