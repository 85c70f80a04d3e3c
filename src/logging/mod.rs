//! Log output: `tracing` events to the systemd journal, as JSON lines, or as human text, and
//! never more of them than a reader can take.
//!
//! With `format = "auto"` (the default) the choice follows the log stream: the stream systemd
//! connected to the journal (`$JOURNAL_STREAM`) gets native journal entries (priority from the
//! level, every field a `FLYD_*` field: [`journal`]); a terminal gets human-readable text with
//! colours; anything else (a pipe, a file) one JSON object per line. `json`, `human` and
//! `journal` force one. Logs go to stderr when stdout carries the candump log (`can.log =
//! "-"`), so the two never mix. Every output sits behind the [`governor`]: a per-callsite rate
//! limit that counts what it holds back.

use std::io::IsTerminal;
use std::os::fd::AsFd;

use tracing::level_filters::LevelFilter;
use tracing_subscriber::Registry;
use tracing_subscriber::fmt::writer::BoxMakeWriter;
use tracing_subscriber::layer::{Layer, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;

use crate::config::LogFormat;

/// A static callsite for a line the logging writes itself (a summary, a notice), declared as
/// `tracing-log` declares its own: `own_callsite!(Type, STATIC, META_STATIC, level, fields)`.
macro_rules! own_callsite {
    ($ty:ident, $cs:ident, $meta:ident, $level:expr, $fields:expr) => {
        struct $ty;
        static $cs: $ty = $ty;
        static $meta: tracing::Metadata<'static> = tracing::Metadata::new(
            "log summary",
            "flyd::logging",
            $level,
            Some(file!()),
            Some(line!()),
            Some(module_path!()),
            tracing_core::field::FieldSet::new($fields, tracing_core::identify_callsite!(&$cs)),
            tracing_core::metadata::Kind::EVENT,
        );
        impl tracing_core::callsite::Callsite for $ty {
            fn set_interest(&self, _: tracing_core::subscriber::Interest) {}
            fn metadata(&self) -> &tracing::Metadata<'_> {
                &$meta
            }
        }
    };
}

/// The `Layer` methods a wrapping layer passes on unchanged to its field `$inner` (all but
/// `on_event`, which the wrapper decides), in an `impl<S, L: Layer<S>> Layer<S>` block.
macro_rules! forward_layer {
    ($inner:ident) => {
        fn on_register_dispatch(&self, subscriber: &tracing::Dispatch) {
            self.$inner.on_register_dispatch(subscriber);
        }
        fn on_layer(&mut self, subscriber: &mut S) {
            self.$inner.on_layer(subscriber);
        }
        fn register_callsite(
            &self,
            metadata: &'static tracing::Metadata<'static>,
        ) -> tracing_core::subscriber::Interest {
            self.$inner.register_callsite(metadata)
        }
        fn enabled(&self, metadata: &tracing::Metadata<'_>, ctx: Context<'_, S>) -> bool {
            self.$inner.enabled(metadata, ctx)
        }
        fn on_new_span(
            &self,
            attrs: &tracing::span::Attributes<'_>,
            id: &tracing::span::Id,
            ctx: Context<'_, S>,
        ) {
            self.$inner.on_new_span(attrs, id, ctx);
        }
        fn max_level_hint(&self) -> Option<tracing::level_filters::LevelFilter> {
            self.$inner.max_level_hint()
        }
        fn on_record(
            &self,
            span: &tracing::span::Id,
            values: &tracing::span::Record<'_>,
            ctx: Context<'_, S>,
        ) {
            self.$inner.on_record(span, values, ctx);
        }
        fn on_follows_from(
            &self,
            span: &tracing::span::Id,
            follows: &tracing::span::Id,
            ctx: Context<'_, S>,
        ) {
            self.$inner.on_follows_from(span, follows, ctx);
        }
        fn event_enabled(&self, event: &tracing::Event<'_>, ctx: Context<'_, S>) -> bool {
            self.$inner.event_enabled(event, ctx)
        }
        fn on_enter(&self, id: &tracing::span::Id, ctx: Context<'_, S>) {
            self.$inner.on_enter(id, ctx);
        }
        fn on_exit(&self, id: &tracing::span::Id, ctx: Context<'_, S>) {
            self.$inner.on_exit(id, ctx);
        }
        fn on_close(&self, id: tracing::span::Id, ctx: Context<'_, S>) {
            self.$inner.on_close(id, ctx);
        }
        fn on_id_change(
            &self,
            old: &tracing::span::Id,
            new: &tracing::span::Id,
            ctx: Context<'_, S>,
        ) {
            self.$inner.on_id_change(old, new, ctx);
        }
        unsafe fn downcast_raw(&self, id: std::any::TypeId) -> Option<*const ()> {
            if id == std::any::TypeId::of::<Self>() {
                Some(self as *const Self as *const ())
            } else {
                // SAFETY: forwarded as is; the wrapped layer answers for its own types.
                unsafe { self.$inner.downcast_raw(id) }
            }
        }
    };
}

pub mod governor;
pub mod journal;

pub use governor::request_flush;

/// Where the log lines go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogTarget {
    Stdout,
    Stderr,
}

/// What the lines are written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    Journal,
    Json,
    Human,
}

/// `value` rounded to `decimals` places, for a log field: a figure a person reads
/// (`speed_kmh=30`, not `30.000000000000004`, a km/h worked out from m/s).
pub fn shown(value: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    if value.is_finite() {
        (value * scale).round() / scale
    } else {
        value
    }
}

/// What `format` means for `target`: auto is the journal on the journal's stream, JSON off a
/// terminal, human text on one.
pub fn output(format: LogFormat, target: LogTarget) -> Output {
    match format {
        LogFormat::Journal => Output::Journal,
        LogFormat::Json => Output::Json,
        LogFormat::Human => Output::Human,
        LogFormat::Auto => {
            let (journal, terminal) = match target {
                LogTarget::Stdout => (
                    journal::fd_is_journal(std::io::stdout().as_fd()),
                    std::io::stdout().is_terminal(),
                ),
                LogTarget::Stderr => (
                    journal::fd_is_journal(std::io::stderr().as_fd()),
                    std::io::stderr().is_terminal(),
                ),
            };
            if journal {
                Output::Journal
            } else if terminal {
                Output::Human
            } else {
                Output::Json
            }
        }
    }
}

type Boxed = Box<dyn Layer<Registry> + Send + Sync>;

fn json(target: LogTarget) -> Boxed {
    tracing_subscriber::fmt::layer()
        .with_writer(writer(target))
        .with_thread_names(true)
        .json()
        .flatten_event(true)
        .with_current_span(false)
        .boxed()
}

fn writer(target: LogTarget) -> BoxMakeWriter {
    match target {
        LogTarget::Stdout => BoxMakeWriter::new(std::io::stdout),
        LogTarget::Stderr => BoxMakeWriter::new(std::io::stderr),
    }
}

/// Installs the global subscriber (once per process; later calls are ignored). Returns what
/// the lines are written as.
pub fn init(format: LogFormat, level: tracing::Level, target: LogTarget) -> Output {
    let wanted = output(format, target);
    let mut unavailable = None;
    let layer: Boxed = match wanted {
        Output::Journal => match journal::Journal::connect(json(target)) {
            Ok(j) => j.boxed(),
            Err(e) => {
                unavailable = Some(e);
                json(target)
            }
        },
        Output::Json => json(target),
        Output::Human => {
            let ansi = match target {
                LogTarget::Stdout => std::io::stdout().is_terminal(),
                LogTarget::Stderr => std::io::stderr().is_terminal(),
            };
            tracing_subscriber::fmt::layer()
                .with_writer(writer(target))
                .with_thread_names(true)
                .with_ansi(ansi)
                .boxed()
        }
    };
    let governed = governor::Governor::new(layer, governor::Policy::default());
    // `try_init` fails only when a subscriber is already installed (tests): keep that one.
    let _ = tracing_subscriber::registry()
        .with(governed)
        .with(LevelFilter::from_level(level))
        .try_init();
    match unavailable {
        Some(e) => {
            tracing::warn!(
                socket = journal::SOCKET,
                error = %e,
                "journal socket unavailable: logging JSON lines instead"
            );
            Output::Json
        }
        None => wanted,
    }
}
