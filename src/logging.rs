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

/// An error and its causes as one line, `outer: inner: ...`, leaving out a cause whose text the
/// message before it already contains: many of flyd's errors (and the `image` crate's) put their
/// cause into their own message as well as exposing it as the source, and `{:#}` printed such
/// causes twice ("x.png: Invalid PNG signature.: Invalid PNG signature.").
pub fn error_chain(error: &(dyn std::error::Error + 'static)) -> String {
    let mut line = String::new();
    let mut previous = String::new();
    for cause in std::iter::successors(Some(error), |e| e.source()) {
        let text = cause.to_string();
        if !previous.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
        previous = text;
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Layer(&'static str, Option<Box<Layer>>);
    impl std::fmt::Display for Layer {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(self.0)
        }
    }
    impl std::error::Error for Layer {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            self.1.as_deref().map(|l| l as _)
        }
    }

    #[test]
    fn error_chain_names_each_cause_once() {
        let repeated = || {
            Layer(
                "x.png: bad signature",
                Some(Box::new(Layer("bad signature", None))),
            )
        };
        assert_eq!(error_chain(&repeated()), "x.png: bad signature");
        let context = Layer(
            "cannot start the engine",
            Some(Box::new(Layer("parameter 'flies': too few", None))),
        );
        assert_eq!(
            error_chain(&context),
            "cannot start the engine: parameter 'flies': too few"
        );
        let wrapped = anyhow::Error::new(repeated()).context("replay");
        assert_eq!(
            error_chain(wrapped.as_ref()),
            "replay: x.png: bad signature"
        );
    }
}
