//! The `flyd` command: glue between the command line and the library.

use anyhow::{Context, Result, bail};
use clap::Parser;
use flyd::replay::{self, Request, Source};
use flyd_core::engine::EngineParams;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use flyd::config::{self, CanTarget, DaemonConfig};
use flyd::daemon::{self, MonotonicClock, Shutdown, hardware};
use flyd::logging::{self, LogTarget};

mod args;
use args::{BenchArgs, Cli, Command, EvalArgs, ReplayArgs, RunArgs};

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
        Command::Replay(args) => replay_command(*args),
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

/// The case `name` of the closed-loop case file `file` (its only one when no name is given).
fn closed_loop_case(file: &Path, name: Option<&str>) -> Result<hw_mock::closed_loop::Case> {
    let text =
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let parsed: hw_mock::closed_loop::CaseFile =
        toml::from_str(&text).with_context(|| format!("{}", file.display()))?;
    let mut cases = parsed
        .cases()
        .with_context(|| format!("{}", file.display()))?;
    let names = || {
        cases
            .iter()
            .map(|c| c.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    match name {
        Some(n) => match cases.iter().position(|c| c.name == n) {
            Some(i) => Ok(cases.swap_remove(i)),
            None => bail!("{}: no case '{n}' (its cases: {})", file.display(), names()),
        },
        None if cases.len() == 1 => Ok(cases.swap_remove(0)),
        None => bail!(
            "{} holds {} cases: name one with --case-name ({})",
            file.display(),
            cases.len(),
            names()
        ),
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
    let source = if let Some(file) = &args.case {
        Source::ClosedLoop {
            case: Box::new(closed_loop_case(file, args.case_name.as_deref())?),
            width: args.width,
            height: args.height,
        }
    } else if let Some(name) = &args.scenario {
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
        right_yaw_error_deg: args.right_yaw_error,
    };
    let prepared = request.prepare(&config).context("replay")?;
    let record = args.record.as_deref();
    let declared_height = prepared.feed.rig().left.centre().y;
    let (focal, baseline) = (
        prepared.feed.rig().right.intrinsics().fx,
        prepared.feed.rig().baseline(),
    );
    let summary =
        replay::command::replay_to(prepared, &config, &out, record, args.config.as_deref())
            .context("replay")?;
    if let Some(note) = &summary.note {
        eprintln!("flyd replay: note: {note}");
    }
    for warning in summary.mount_warnings(declared_height) {
        eprintln!("flyd replay: warning: {warning}");
    }
    if let Some(warning) = summary.columns_warning(focal, baseline) {
        eprintln!("flyd replay: warning: {warning}");
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
             than decision.margin_m = {}; it resolves {:.1} m within the margin. To resolve it: \
             f B of at least {:.0} px m (now {:.0}: a longer baseline, a longer focal length or \
             a wider image), or decision.margin_m = {:.1}",
            file.display(),
            r.speed * 3.6,
            r.slow_distance,
            r.error_per_pixel,
            r.margin,
            r.resolved,
            // What is enough, rounded up so that it is.
            (r.slow_distance.powi(2) / r.margin.max(1e-9)).ceil(),
            r.slow_distance.powi(2) / r.error_per_pixel.max(1e-9),
            (r.error_per_pixel * 10.0).ceil() / 10.0,
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
