//! The `flyd` command: glue between the command line and the library.

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use flyd::replay::{self, Request, Source};
use flyd_core::engine::EngineParams;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use flyd::config::{self, CanTarget, DaemonConfig};
use flyd::daemon::{self, MonotonicClock, Shutdown, hardware};
use flyd::logging::{self, LogTarget};

#[derive(Parser)]
#[command(
    name = "flyd",
    version,
    about = "Stereo obstacle detection with the Fly Algorithm"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the evolution on a stereo pair or a hw-mock scenario and write what it found.
    Replay(ReplayArgs),
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
struct BenchArgs {
    /// Population size.
    #[arg(long, default_value_t = EngineParams::default().flies)]
    flies: usize,
    /// Image size of the synthetic scene.
    #[arg(long, default_value_t = 640)]
    width: u32,
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Generations timed (after a warm-up of 50).
    #[arg(long, default_value_t = 3000)]
    generations: u64,
    /// Generations per new frame (3 = 30 fps at ~10 ms a generation, as the daemon runs).
    #[arg(long, default_value_t = 3)]
    generations_per_frame: u64,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Instruction set of the hot loops: baseline, avx2 or avx512 (default: the best this CPU
    /// has; every one gives the same population).
    #[arg(long, value_parser = parse_isa)]
    isa: Option<flyd_core::isa::Isa>,
    /// Take [engine] (but its seed) and [perception] from this daemon configuration (default: the built-in defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Play this hw-mock scenario's first 60 frames in order (e.g. `driving`) instead of two
    /// noise draws of `pedestrian-4m`, the flies moved with the scenario's own motion.
    #[arg(long)]
    scenario: Option<String>,
    /// With --scenario: do not move the flies with the vehicle's motion.
    #[arg(long)]
    no_predict: bool,
    /// Instead: reaction time of the whole threaded daemon on hw-mock (config/demo.toml), from
    /// the first frame showing the pedestrian to the first STOP frame, over RUNS runs.
    #[arg(long, value_name = "RUNS", num_args = 0..=1, default_missing_value = "10")]
    end_to_end: Option<usize>,
    /// Instead: flyd's path prediction on real trajectories (KITTI odometry poses: files
    /// poses_NN.txt / poses.txt with their times_NN.txt / times.txt, or folders of them;
    /// default ../shared/data/kitti_poses): at each decision stage's distance, how often an
    /// object on the real path is inside the corridor and one beside it is (docs/path.md).
    /// Takes [decision] and [perception.obstacle] from --config.
    #[arg(long, value_name = "POSES", num_args = 0.., conflicts_with = "end_to_end")]
    path: Option<Vec<PathBuf>>,
    /// With --path: the path model instead of the configuration's: arc (the arc of the
    /// moment), clothoid, clothoid-gated or held.
    #[arg(long, requires = "path", value_parser = ["arc", "clothoid", "clothoid-gated", "held"])]
    path_model: Option<String>,
    /// With --path: white noise added to each moment's yaw rate, rad/s (standard deviation).
    #[arg(long, requires = "path", default_value_t = 0.0)]
    yaw_noise: f64,
}

#[derive(Args)]
struct ReplayArgs {
    /// Left image (PNG or JPEG).
    #[arg(long, requires_all = ["right", "calib"], conflicts_with_all = ["scenario", "sequence"])]
    left: Option<PathBuf>,
    /// Right image (PNG or JPEG).
    #[arg(long)]
    right: Option<PathBuf>,
    /// Calibration: flyd rig TOML, KITTI calib_cam_to_cam.txt or calib.txt, Middlebury
    /// calib.txt or OpenCV stereo YAML.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// A folder of stereo pairs, replayed in name order: left/ + right/, or KITTI's
    /// image_02/data + image_03/data (needs --calib).
    #[arg(long, requires = "calib", conflicts_with = "scenario")]
    sequence: Option<PathBuf>,
    /// With --sequence: the vehicle's motion from this candump log of its bus (`VCU_Motion`,
    /// as `flyd run --can-input` takes it: the log's first frame due with the first image,
    /// every frame checked as the daemon checks it) instead of the folder's poses.txt.
    #[arg(long, value_name = "PATH", requires = "sequence")]
    can_input: Option<PathBuf>,
    /// With --sequence: frames per second of the recording.
    #[arg(long, default_value_t = 10.0)]
    fps: f64,
    /// Generations to run (default on a stereo pair: the warm-up, then long enough for the
    /// start-up's safe command to be released and an obstacle to be confirmed, at least 50;
    /// every frame otherwise).
    #[arg(long)]
    generations: Option<u64>,
    /// Population size (default: the configuration's).
    #[arg(long)]
    flies: Option<usize>,
    /// Seed of the random generator (default: the configuration's).
    #[arg(long)]
    seed: Option<u64>,
    /// A hw-mock scenario instead of a stereo pair: empty-road, pedestrian-4m,
    /// pedestrian-steps-in, car-approaching, driving, driving-to-pedestrian, drive-30, drive-40,
    /// drive-30-to-pedestrian, drive-40-to-pedestrian, drive-30-lane-change, bend-30,
    /// bend-30-to-pedestrian, bend-30-parked-car, bend-40, bend-40-to-pedestrian,
    /// bend-40-parked-car, ramp-30, ramp-30-stopped-car, ramp-30-pedestrian-on-kerb, ramp-40,
    /// ramp-40-stopped-car, s-bend-40, s-bend-40-to-pedestrian (the moving ones decided at
    /// their own speed, the flies moved with it).
    #[arg(long)]
    scenario: Option<String>,
    /// Generations per frame (default: 3 for a scenario, 30 fps at ~10 ms a generation; for a
    /// sequence, what the daemon runs at --fps: a burst of evolution.burst_generations, then
    /// one per evolution.generation_period_ms).
    #[arg(long)]
    generations_per_frame: Option<u64>,
    /// With --scenario: image size.
    #[arg(long, default_value_t = 640)]
    width: u32,
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// The vehicle's speed the decision assumes, km/h, on every frame (default: a scenario's
    /// own speed, else the configuration's vehicle.assumed_speed_kmh, 30).
    #[arg(long, value_name = "KMH")]
    speed: Option<f64>,
    /// Take [engine], [perception], [decision], [vehicle] and [evolution] from this daemon
    /// configuration (default: the built-in defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// A recording of the daemon (`flyd run --record`): its frames through the same engine and
    /// decider, checked to reproduce the recorded commands bit for bit (with its attached
    /// configuration unless --config is given; --seed changes the seed). Prints a JSON summary;
    /// exits 1 where the replay diverges, saying where.
    #[arg(long, value_name = "FILE.mcap", conflicts_with_all = ["left", "scenario", "sequence"])]
    mcap: Option<PathBuf>,
    /// Output directory.
    #[arg(long, required_unless_present = "mcap")]
    out: Option<PathBuf>,
    /// Also write what the replay saw, found and decided to this MCAP file (frames, flies,
    /// road, obstacle, decisions, the FLYD_Command frames), to open in Foxglove: a KITTI
    /// sequence or a replayed recording becomes a recording.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
}

#[derive(Args)]
struct EvalArgs {
    /// The manifest: `[[item]]`s with their source, rig and label (see eval/real.toml).
    manifest: PathBuf,
    /// Where the items' folders are (default: the manifest's `data`, relative to it).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Runs seeds 1..=N of every item.
    #[arg(long, default_value_t = 20)]
    seeds: u64,
    /// Runs at once (default: the cores this process may use).
    #[arg(long)]
    jobs: Option<usize>,
    /// Take [engine] (but its seed), [perception], [decision], [vehicle] and [evolution] from
    /// this daemon configuration (default: the built-in defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Only these items (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Also write the report, every run of every item, as JSON to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Keep the rigs and every run's replay outputs (trace.csv, overlay.png...) in
    /// DIR/ITEM/seedN.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct RunArgs {
    /// The TOML configuration file.
    #[arg(long)]
    config: PathBuf,
    /// Write CAN frames as candump log lines to PATH (`-` = stdout) instead of the configured
    /// bus: a dry run on the vehicle.
    #[arg(long, value_name = "PATH")]
    can_log: Option<PathBuf>,
    /// Read the frames flyd receives (the vehicle's motion, VCU_Motion) from a candump log
    /// (`candump -l`/`-L` lines), replayed at their recorded pace from the start, instead of
    /// the bus or the mock vehicle: a recorded drive's bus, without a kernel.
    #[arg(long, value_name = "PATH")]
    can_input: Option<PathBuf>,
    /// Stop after SECONDS (default: until SIGTERM/SIGINT, or the end of a mock scenario).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Record to this MCAP file (overrides record.path): the frames, flies, road, obstacle,
    /// decisions, stats and every CAN frame; `flyd replay --mcap` replays it.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
}

/// Writes a line to stdout: a full disk or a closed pipe is an error (exit 1 with a message),
/// never a panic as `println!` makes it.
fn say_line(args: std::fmt::Arguments) -> Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_fmt(args)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush())
        .context("writing to standard output")
}

macro_rules! say {
    ($($arg:tt)*) => {
        say_line(format_args!($($arg)*))
    };
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Replay(args) => replay_command(args),
        Command::Eval(args) => eval_command(&args),
        Command::Bench(args) => bench_command(args),
        Command::Run(args) => cmd_run(&args),
        Command::CheckConfig { file } => cmd_check_config(&file),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Not eprintln!: a closed stderr must not turn an error into a panic.
            let _ = writeln!(
                std::io::stderr(),
                "flyd: {}",
                flyd_core::chain::Chain(e.as_ref())
            );
            ExitCode::FAILURE
        }
    }
}

fn replay_command(args: ReplayArgs) -> Result<()> {
    if let Some(path) = &args.mcap {
        return replay_recording(path, &args);
    }
    let Some(out) = args.out.clone() else {
        bail!("replay needs --out DIR");
    };
    let config = match &args.config {
        Some(path) => config::check(path)?,
        None => DaemonConfig::with_rig(flyd::mock::mock_rig(640, 480)?),
    };
    let source = if let Some(name) = &args.scenario {
        Source::Scenario {
            name: name.clone(),
            width: args.width,
            height: args.height,
        }
    } else if let Some(dir) = &args.sequence {
        let Some(calib) = &args.calib else {
            bail!("--sequence needs --calib");
        };
        Source::Sequence {
            dir: dir.clone(),
            calib: calib.clone(),
            fps: args.fps,
            can_input: args.can_input.clone(),
        }
    } else {
        let (Some(left), Some(right), Some(calib)) = (&args.left, &args.right, &args.calib) else {
            bail!(
                "replay needs --left, --right and --calib, --sequence and --calib, or --scenario"
            );
        };
        Source::Pair {
            left: left.clone(),
            right: right.clone(),
            calib: calib.clone(),
        }
    };
    let request = Request {
        source,
        flies: args.flies,
        seed: args.seed,
        speed_kmh: args.speed,
        generations: args.generations,
        generations_per_frame: args.generations_per_frame,
    };
    let prepared = request.prepare(&config).context("replay")?;
    let record = args.record.as_deref();
    let summary =
        replay::command::replay_to(prepared, &config, &out, record, args.config.as_deref())
            .context("replay")?;
    if let Some(note) = &summary.note {
        eprintln!("flyd replay: note: {note}");
    }
    say!("{}", serde_json::to_string_pretty(&summary)?)?;
    Ok(())
}

/// `flyd eval MANIFEST`.
fn eval_command(args: &EvalArgs) -> Result<()> {
    let manifest = flyd::eval::Manifest::load(&args.manifest)?;
    let mut items = manifest.items.clone();
    if !args.only.is_empty() {
        if let Some(unknown) = args
            .only
            .iter()
            .find(|n| !items.iter().any(|i| &i.name == *n))
        {
            bail!(
                "--only {unknown}: no item of that name in {}",
                args.manifest.display()
            );
        }
        items.retain(|i| args.only.contains(&i.name));
    }
    if args.seeds == 0 {
        bail!("--seeds 0: nothing to run");
    }
    let base = args.manifest.parent().unwrap_or(Path::new("."));
    let data = match (&args.data, &manifest.data) {
        (Some(d), _) => d.clone(),
        (None, Some(d)) => base.join(d),
        (None, None) => PathBuf::from("."),
    };
    let config = match &args.config {
        Some(path) => config::check(path)?,
        None => DaemonConfig::with_rig(flyd::mock::mock_rig(640, 480)?),
    };
    let temp;
    let work = match &args.out {
        Some(dir) => dir.clone(),
        None => {
            temp = tempfile::Builder::new()
                .prefix("flyd-eval-")
                .tempdir()
                .context("a folder for the items' rigs")?;
            temp.path().to_path_buf()
        }
    };
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
    });
    let options = flyd::eval::Options {
        data,
        seeds: args.seeds,
        jobs,
        config,
        work,
        outputs: args.out.is_some(),
    };
    // On a terminal, one line that says how far it is (rewritten in place); elsewhere
    // (a pipe, CI's log) nothing but the report.
    let terminal = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let report = flyd::eval::run_with_progress(&items, &options, |p| {
        if terminal {
            eprint!("\r\x1b[2K{}", p.line());
            if p.done == p.total {
                eprintln!();
            }
        }
    })?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    say!("{report}")?;
    if !report.passed() {
        bail!("labels not met (see above)");
    }
    Ok(())
}

/// `flyd replay --mcap FILE [--config C] [--seed S] [--record OUT]`.
fn replay_recording(path: &Path, args: &ReplayArgs) -> Result<()> {
    let summary = replay::command::replay_recording(
        path,
        args.config.as_deref(),
        args.seed,
        args.record.as_deref(),
    )
    .with_context(|| format!("replaying {}", path.display()))?;
    say!("{}", serde_json::to_string_pretty(&summary)?)?;
    match &summary.divergence {
        None => Ok(()),
        Some(d) => bail!(
            "the replay diverges from the recording ({}) at {:.3} s{}: {}",
            d.what,
            d.t,
            d.generation
                .map_or(String::new(), |g| format!(", generation {g}")),
            d.detail
        ),
    }
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

fn bench_command(args: BenchArgs) -> Result<()> {
    if let Some(runs) = args.end_to_end {
        return bench_end_to_end_command(runs, args.json);
    }
    if let Some(paths) = &args.path {
        return bench_path_command(&args, paths);
    }
    let config = args.config.as_deref().map(config::check).transpose()?;
    let report = flyd::bench::generations(&flyd::bench::GenerationBench {
        flies: args.flies,
        width: args.width,
        height: args.height,
        generations: args.generations,
        generations_per_frame: args.generations_per_frame,
        isa: args.isa,
        perception: config.as_ref().map(|c| c.perception).unwrap_or_default(),
        // The seed stays the benchmark's: the same population whatever the file says.
        engine: config
            .as_ref()
            .map_or_else(EngineParams::default, |c| EngineParams {
                seed: EngineParams::default().seed,
                ..c.engine.clone()
            }),
        scenario: args.scenario.clone(),
        predict: !args.no_predict,
    })?;
    if args.json {
        say!("{}", serde_json::to_string_pretty(&report)?)?;
    } else {
        say!("{report}")?;
    }
    Ok(())
}

/// `flyd bench --path [POSES...]`: the path prediction on real trajectories.
fn bench_path_command(args: &BenchArgs, paths: &[PathBuf]) -> Result<()> {
    use flyd::path_bench::{Drive, PathBenchConfig};
    use flyd_core::path::PathModel;
    let config = args.config.as_deref().map(config::check).transpose()?;
    let decision = config.as_ref().map(|c| c.decision).unwrap_or_default();
    let obstacle = config
        .as_ref()
        .map(|c| c.perception.obstacle)
        .unwrap_or_default();
    let model = match args.path_model.as_deref() {
        Some("arc") => PathModel::Clothoid { window: 0.0 },
        Some("clothoid") => PathModel::Clothoid {
            window: obstacle.path_rate_window_s,
        },
        Some("clothoid-gated") => PathModel::ClothoidGated {
            window: obstacle.path_rate_window_s,
        },
        Some("held") => PathModel::Held {
            hold: obstacle.path_hold_s,
        },
        _ => obstacle.path(),
    };
    let default = [PathBuf::from("../shared/data/kitti_poses")];
    let paths = if paths.is_empty() {
        &default[..]
    } else {
        paths
    };
    let mut drives = Vec::new();
    for p in paths {
        drives.extend(
            Drive::load(p).with_context(|| format!("reading the drives at {}", p.display()))?,
        );
    }
    if !(args.yaw_noise.is_finite() && args.yaw_noise >= 0.0) {
        bail!(
            "--yaw-noise must be a standard deviation in rad/s, got {}",
            args.yaw_noise
        );
    }
    let report = flyd::path_bench::run(
        &drives,
        &PathBenchConfig {
            decision,
            half_width: obstacle.corridor_half_width,
            model,
            yaw_noise: args.yaw_noise,
        },
    );
    if args.json {
        say!("{}", serde_json::to_string_pretty(&report)?)?;
    } else {
        say!("{report}")?;
    }
    Ok(())
}

/// `flyd check-config FILE`: what start-up checks, without devices.
fn cmd_check_config(file: &Path) -> anyhow::Result<()> {
    let config = config::check(file)?;
    say!(
        "{}: ok ({}x{} at {} fps, {} flies, depths {}-{} m, CAN {})",
        file.display(),
        config.cameras.width,
        config.cameras.height,
        config.cameras.fps,
        config.engine.flies,
        config.engine.min_depth,
        config.engine.max_depth,
        match &config.can.target {
            CanTarget::Interface(iface) => iface.clone(),
            CanTarget::Log { path, .. } => format!("log {}", path.display()),
        }
    )?;
    let rig = config.load_calibration()?.rig;
    let mock = config.calibration == config::CalibrationSource::BuiltinMock;
    let short = config.resolution(&rig).filter(|r| !r.enough());
    if let Some(r) = short.filter(|_| mock) {
        // hw-mock's simulated pair is what it is: nothing to change in this file.
        say!(
            "{}: note: the built-in mock rig resolves {:.1} m within decision.margin_m = {}, \
             short of the SLOW distance at vehicle.assumed_speed_kmh = {:.0} ({:.1} m): a real \
             rig's calibration file is checked against it",
            file.display(),
            r.resolved,
            r.margin,
            r.speed * 3.6,
            r.slow_distance,
        )?;
    } else if let Some(r) = short {
        eprintln!(
            "{}: warning: the rig cannot resolve the SLOW distance at vehicle.assumed_speed_kmh \
             = {:.0}: one pixel of disparity at {:.1} m is {:.1} m of depth (Z^2 / (f B)), more \
             than decision.margin_m = {}; it resolves {:.1} m within the margin",
            file.display(),
            r.speed * 3.6,
            r.slow_distance,
            r.error_per_pixel,
            r.margin,
            r.resolved,
        );
    }
    Ok(())
}

/// `flyd run --config FILE [--can-log PATH] [--duration SECONDS]`.
fn cmd_run(args: &RunArgs) -> anyhow::Result<()> {
    let mut config = config::check(&args.config)?;
    if let Some(path) = &args.can_log {
        let iface = match &config.can.target {
            CanTarget::Interface(iface) => iface.clone(),
            CanTarget::Log { iface, .. } => iface.clone(),
        };
        config.can.target = CanTarget::Log {
            path: path.clone(),
            iface,
        };
    }
    if let Some(path) = &args.record {
        config.record.path = Some(path.clone());
    }
    let duration = args
        .duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .ok()
                .filter(|d| !d.is_zero())
                .with_context(|| format!("--duration {s}: must be a positive number of seconds"))
        })
        .transpose()?;
    // One flyd per CAN interface: two would interleave contradicting commands with their own
    // alive counters. Held until exit (the kernel releases it with the process).
    let _bus_lock = match &config.can.target {
        CanTarget::Interface(iface) => Some(daemon::lock_interface(iface)?),
        CanTarget::Log { .. } => None,
    };
    // The candump log on stdout and JSON logs must not interleave: logs go to stderr then.
    let log_target = match &config.can.target {
        CanTarget::Log { path, .. } if path == Path::new("-") => LogTarget::Stderr,
        _ => LogTarget::Stdout,
    };
    let log_output = logging::init(config.logging.format, config.logging.level, log_target);
    tracing::debug!(output = ?log_output, "logging");

    let shutdown = Shutdown::new();
    // SIGHUP ends flyd as SIGTERM does (a safe command and a SHUTDOWN status first); there is
    // no reload: `systemctl restart flyd` applies a new configuration.
    for signal in [
        signal_hook::consts::SIGTERM,
        signal_hook::consts::SIGINT,
        signal_hook::consts::SIGHUP,
    ] {
        signal_hook::flag::register(signal, shutdown.flag().clone())
            .with_context(|| format!("installing the handler of signal {signal}"))?;
    }
    // A file over RLIMIT_FSIZE (systemd's LimitFSIZE=, `ulimit -f`) must fail its write with
    // EFBIG (a recorder fault: logged, flyd drives on), not kill the daemon with SIGXFSZ.
    // SAFETY: setting a signal's disposition to SIG_IGN installs no handler code; it is done
    // here, before any thread that writes files is started.
    if unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) } == libc::SIG_ERR {
        bail!("ignoring SIGXFSZ: {}", std::io::Error::last_os_error());
    }
    if let Some(duration) = duration {
        let timer = shutdown.clone();
        daemon::spawn_named("flyd-duration", move || {
            if !timer.sleep(duration) {
                tracing::info!(seconds = duration.as_secs_f64(), "--duration reached");
                timer.request();
            }
        })
        .context("starting the --duration timer")?;
    }

    let clock = MonotonicClock::shared();
    let cameras = hardware::open_cameras(&config, &clock)?;
    let tx = hardware::open_bus(&config.can.target)?;
    let rx = hardware::open_receiver(&config, args.can_input.as_deref(), &clock)?;
    tracing::info!(config = %args.config.display(), "flyd starting");
    let report = run_daemon(
        cameras,
        daemon::CanPort { tx, rx },
        clock,
        &config,
        shutdown,
    )?;
    // Counts of messages held back by the rate limit go out with the last line.
    logging::request_flush();
    tracing::info!(
        ended_by = ?report.ended_by,
        generations = report.generations,
        commands = report.control.commands_sent,
        can_errors = report.control.can_errors,
        faults_seen = %report.control.faults_seen,
        motion_accepted = report.control.motion_accepted,
        motion_rejected = report.control.motion_rejected,
        frames_left = report.left.frames,
        frames_right = report.right.frames,
        pairs = report.pairs,
        snapshots = report.control.snapshots,
        record_dropped = report.recording.as_ref().map(|r| r.dropped),
        "flyd stopped"
    );
    if let Some(recording) = &report.recording
        && recording.writer.failed
    {
        tracing::error!("the recording is incomplete: it stopped on a write error (see above)");
    }
    Ok(())
}

fn run_daemon(
    cameras: daemon::Cameras,
    bus: daemon::CanPort,
    clock: daemon::SharedClock,
    config: &DaemonConfig,
    shutdown: Shutdown,
) -> anyhow::Result<daemon::RunReport> {
    // The only place the daemon learns about systemd: its environment, read once.
    let notifier = daemon::ServiceNotifier::from_env();
    Ok(daemon::run(
        cameras, bus, clock, config, shutdown, notifier,
    )?)
}

/// `flyd bench --end-to-end [RUNS] [--json]`: the daemon's reaction on hw-mock.
fn bench_end_to_end_command(runs: usize, json: bool) -> Result<()> {
    let report = daemon::bench_end_to_end(runs)?;
    if json {
        say!("{}", serde_json::to_string_pretty(&report)?)?;
    } else {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1} ms"));
        say!(
            "end to end on {} ({}x{}, {} flies), {} runs: reaction median {}, p95 {} \
             (of which capture-to-STOP-frame pipeline, median {}); \
             {} without STOP, {} with a STOP before the obstacle",
            report.scenario,
            report.width,
            report.height,
            report.flies,
            report.runs,
            ms(report.median_ms),
            ms(report.p95_ms),
            ms(report.pipeline_median_ms),
            report.misses,
            report.false_stops
        )?;
    }
    Ok(())
}
