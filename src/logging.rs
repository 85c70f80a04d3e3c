//! Log output: `tracing` events as JSON lines for journald, or human-readable on a terminal.
//!
//! With `format = "auto"` (the default) the choice follows stdout: a terminal gets the
//! human-readable format with colours, anything else (journald, a pipe, a file) one JSON object
//! per line, whose fields `journalctl -o json` and `jq` can filter. Logs go to stderr when
//! stdout carries the candump log (`can.log = "-"`), so the two never mix.

use std::io::IsTerminal;

use tracing_subscriber::fmt::writer::BoxMakeWriter;

use crate::config::LogFormat;

/// Where the log lines go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogTarget {
    Stdout,
    Stderr,
}

/// Whether `format` means JSON for `target` (auto: JSON unless it is a terminal).
pub fn use_json(format: LogFormat, target: LogTarget) -> bool {
    match format {
        LogFormat::Json => true,
        LogFormat::Human => false,
        LogFormat::Auto => match target {
            LogTarget::Stdout => !std::io::stdout().is_terminal(),
            LogTarget::Stderr => !std::io::stderr().is_terminal(),
        },
    }
}

/// Installs the global subscriber (once per process; later calls are ignored).
pub fn init(format: LogFormat, level: tracing::Level, target: LogTarget) {
    let writer = match target {
        LogTarget::Stdout => BoxMakeWriter::new(std::io::stdout),
        LogTarget::Stderr => BoxMakeWriter::new(std::io::stderr),
    };
    let builder = tracing_subscriber::fmt()
        .with_max_level(level)
        .with_writer(writer)
        .with_thread_names(true);
    // `try_init` fails only when a subscriber is already installed (tests): keep that one.
    let _ = if use_json(format, target) {
        builder
            .json()
            .flatten_event(true)
            .with_current_span(false)
            .try_init()
    } else {
        let ansi = match target {
            LogTarget::Stdout => std::io::stdout().is_terminal(),
            LogTarget::Stderr => std::io::stderr().is_terminal(),
        };
        builder.with_ansi(ansi).try_init()
    };
}
