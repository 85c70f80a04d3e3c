//! `flyd`: the command line. Glue only; the work lives in the library.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::{Parser, Subcommand};

use flyd::config::{self, CanTarget, DaemonConfig};
use flyd::daemon::{self, MonotonicClock, Shutdown, hardware};
use flyd::logging::{self, LogTarget};

#[derive(Debug, Parser)]
#[command(
    name = "flyd",
    version,
    about = "Stereo obstacle detection with the Fly Algorithm"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run the daemon: cameras -> fly evolution -> CLEAR/SLOW/STOP on CAN.
    Run(RunArgs),
    /// Check a configuration file (and its calibration) without opening any device.
    CheckConfig {
        /// The TOML configuration file.
        file: PathBuf,
    },
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// The TOML configuration file.
    #[arg(long)]
    config: PathBuf,
    /// Write CAN frames as candump log lines to PATH (`-` = stdout) instead of the configured
    /// bus: a dry run on the vehicle.
    #[arg(long, value_name = "PATH")]
    can_log: Option<PathBuf>,
    /// Stop after SECONDS (default: until SIGTERM/SIGINT, or the end of a mock scenario).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Cmd::Run(args) => cmd_run(&args),
        Cmd::CheckConfig { file } => cmd_check_config(&file),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("flyd: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `flyd check-config FILE`: what start-up checks, without devices.
fn cmd_check_config(file: &Path) -> anyhow::Result<()> {
    let config = config::check(file)?;
    println!(
        "{}: ok ({}x{} at {} fps, {} flies, CAN {})",
        file.display(),
        config.cameras.width,
        config.cameras.height,
        config.cameras.fps,
        config.engine.flies,
        match &config.can.target {
            CanTarget::Interface(iface) => iface.clone(),
            CanTarget::Log { path, .. } => format!("log {}", path.display()),
        }
    );
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
    let duration = args
        .duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .ok()
                .filter(|d| !d.is_zero())
                .with_context(|| format!("--duration {s}: must be a positive number of seconds"))
        })
        .transpose()?;
    // The candump log on stdout and JSON logs must not interleave: logs go to stderr then.
    let log_target = match &config.can.target {
        CanTarget::Log { path, .. } if path == Path::new("-") => LogTarget::Stderr,
        _ => LogTarget::Stdout,
    };
    logging::init(config.logging.format, config.logging.level, log_target);

    let shutdown = Shutdown::new();
    for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(signal, shutdown.flag().clone())
            .with_context(|| format!("installing the handler of signal {signal}"))?;
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
    let bus = hardware::open_bus(&config.can.target)?;
    tracing::info!(config = %args.config.display(), "flyd starting");
    let report = run_daemon(cameras, bus, clock, &config, shutdown)?;
    tracing::info!(
        ended_by = ?report.ended_by,
        generations = report.generations,
        commands = report.control.commands_sent,
        can_errors = report.control.can_errors,
        faults_seen = %report.control.faults_seen,
        "flyd stopped"
    );
    Ok(())
}

fn run_daemon(
    cameras: daemon::Cameras,
    bus: Box<dyn flyd::can::bus::CanBus>,
    clock: daemon::SharedClock,
    config: &DaemonConfig,
    shutdown: Shutdown,
) -> anyhow::Result<daemon::RunReport> {
    Ok(daemon::run(cameras, bus, clock, config, shutdown)?)
}
