//! Bounded logs: a per-callsite rate limit in front of the output.
//!
//! Every callsite (one `warn!` in the source) may write `burst` lines at once, then
//! `per_second` lines a second (a token bucket); what it emits beyond that is counted, not
//! written. The count goes out as a line of its own, "N similar messages suppressed", at the
//! callsite's level (a suppressed error is still counted under `journalctl -p err`): before
//! the callsite's next line, or, if it stays quiet, with the next line of any callsite once
//! [`Policy::summary_every`] has passed, and at the latest when the daemon stops
//! ([`request_flush`]). Nothing is dropped without being counted.
//!
//! Other crates' callsites (the Foxglove server logs an ERROR per client it drops) have a
//! smaller budget, are written at WARN at most (a client's bad handshake is no fault of
//! flyd's), and their summary says what the suppressed messages were about, addresses and
//! numbers folded ("1636 x Dropping client … handshake failed").
//!
//! The hot path (a line let through) locks one mutex, looks its callsite up and allocates
//! nothing once the callsite has been seen.

use std::collections::HashMap;
use std::fmt::{self, Write as _};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use tracing::field::{Field, Visit};
use tracing::{Event, Level, Metadata, Subscriber};
use tracing_core::callsite::{Callsite, Identifier};
use tracing_core::field::Value;
use tracing_subscriber::layer::{Context, Layer};

/// How many lines a callsite may write: `burst` at once, then `per_second`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    pub burst: f64,
    pub per_second: f64,
}

/// The budgets of flyd's own callsites and of other crates', and how often a quiet callsite's
/// suppressed count is reported.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Policy {
    pub own: Budget,
    pub third_party: Budget,
    pub summary_every: Duration,
}

impl Default for Policy {
    /// A warning repeated at 1 kHz writes 10 lines, then one line and its count every 2 s
    /// (about a line a second); a Foxglove message repeated per client writes 5, then one and
    /// its count every 5 s.
    fn default() -> Self {
        Self {
            own: Budget {
                burst: 10.0,
                per_second: 0.5,
            },
            third_party: Budget {
                burst: 5.0,
                per_second: 0.2,
            },
            summary_every: Duration::from_secs(5),
        }
    }
}

/// The crates whose callsites are flyd's own (targets are module paths).
const OWN_CRATES: &[&str] = &["flyd", "flyd_core", "hw_mock"];

fn is_own(target: &str) -> bool {
    let krate = target.split("::").next().unwrap_or(target);
    OWN_CRATES.contains(&krate)
}

/// Set by [`request_flush`]: the next event reports every pending count.
static FLUSH: AtomicBool = AtomicBool::new(false);

/// Reports every suppressed count with the next event, however recent (the daemon calls it
/// before its last line).
pub fn request_flush() {
    FLUSH.store(true, Ordering::Release);
}

/// Monotonic time since the governor started; a test drives its own.
pub type Clock = Arc<dyn Fn() -> Duration + Send + Sync>;

/// The rate limit around the output layer `L` (the JSON, human or journal writer).
pub struct Governor<L> {
    inner: L,
    policy: Policy,
    clock: Clock,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    buckets: HashMap<Identifier, Bucket>,
    swept: Duration,
}

/// One callsite's tokens and what it had suppressed since its last report.
struct Bucket {
    tokens: f64,
    refilled: Duration,
    budget: Budget,
    suppressed: u64,
    since: Duration,
    /// The last suppressed message (own callsites), or the kinds of suppressed messages with
    /// their counts (other crates'), at most [`KINDS`] of them, the rest in `other`.
    last: String,
    kinds: Vec<(String, u64)>,
    other: u64,
    meta: &'static Metadata<'static>,
}

const KINDS: usize = 4;

/// A count to write: what was suppressed at one callsite.
struct Summary {
    meta: &'static Metadata<'static>,
    suppressed: u64,
    seconds: f64,
    about: String,
}

impl Bucket {
    fn new(meta: &'static Metadata<'static>, budget: Budget, now: Duration) -> Self {
        Self {
            tokens: budget.burst,
            refilled: now,
            budget,
            suppressed: 0,
            since: now,
            last: String::new(),
            kinds: Vec::new(),
            other: 0,
            meta,
        }
    }

    /// Takes one token if there is one.
    fn take(&mut self, now: Duration) -> bool {
        let dt = now.saturating_sub(self.refilled).as_secs_f64();
        self.refilled = now;
        self.tokens = (self.tokens + dt * self.budget.per_second).min(self.budget.burst);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }

    fn suppress(&mut self, event: &Event<'_>, own: bool, now: Duration) {
        if self.suppressed == 0 {
            self.since = now;
        }
        self.suppressed += 1;
        self.last.clear();
        event.record(&mut Text(&mut self.last));
        if !own {
            let kind = fold_numbers(&self.last);
            if let Some(k) = self.kinds.iter_mut().find(|(t, _)| *t == kind) {
                k.1 += 1;
            } else if self.kinds.len() < KINDS {
                self.kinds.push((kind, 1));
            } else {
                self.other += 1;
            }
        }
    }

    /// The pending count, if any, and a clean slate.
    fn report(&mut self, now: Duration) -> Option<Summary> {
        if self.suppressed == 0 {
            return None;
        }
        let mut about = String::new();
        let meta = self.meta;
        if is_own(meta.target()) {
            let _ = write!(about, "last: {}", self.last);
        } else {
            for (i, (kind, n)) in self.kinds.iter().enumerate() {
                let sep = if i == 0 { "" } else { "; " };
                let _ = write!(about, "{sep}{n} x {kind}");
            }
            if self.other > 0 {
                let _ = write!(about, "; {} others", self.other);
            }
        }
        let summary = Summary {
            meta,
            suppressed: self.suppressed,
            seconds: now.saturating_sub(self.since).as_secs_f64(),
            about,
        };
        self.suppressed = 0;
        self.kinds.clear();
        self.other = 0;
        Some(summary)
    }
}

impl<L> Governor<L> {
    pub fn new(inner: L, policy: Policy) -> Self {
        let start = Instant::now();
        Self::with_clock(inner, policy, Arc::new(move || start.elapsed()))
    }

    pub fn with_clock(inner: L, policy: Policy, clock: Clock) -> Self {
        Self {
            inner,
            policy,
            clock,
            state: Mutex::new(State::default()),
        }
    }

    /// Whether `event` may be written now, and the counts to write before it.
    fn admit(&self, event: &Event<'_>, summaries: &mut Vec<Summary>) -> bool {
        let now = (self.clock)();
        let meta = event.metadata();
        let own = is_own(meta.target());
        let budget = if own {
            self.policy.own
        } else {
            self.policy.third_party
        };
        // A poisoned lock only means a writer panicked mid-update: the counts are still counts.
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        let flush = FLUSH.swap(false, Ordering::AcqRel);
        if flush || now.saturating_sub(state.swept) >= self.policy.summary_every {
            state.swept = now;
            let every = self.policy.summary_every;
            for b in state.buckets.values_mut() {
                if b.suppressed > 0
                    && (flush || now.saturating_sub(b.since) >= every)
                    && let Some(s) = b.report(now)
                {
                    summaries.push(s);
                }
            }
        }
        let bucket = state
            .buckets
            .entry(meta.callsite())
            .or_insert_with(|| Bucket::new(meta, budget, now));
        if bucket.take(now) {
            summaries.extend(bucket.report(now));
            true
        } else {
            bucket.suppress(event, own, now);
            false
        }
    }
}

impl<S, L> Layer<S> for Governor<L>
where
    S: Subscriber,
    L: Layer<S>,
{
    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        let mut summaries = Vec::new();
        let admitted = self.admit(event, &mut summaries);
        for s in &summaries {
            self.write_summary(s, &ctx);
        }
        if !admitted {
            return;
        }
        let meta = event.metadata();
        if !is_own(meta.target()) && *meta.level() < Level::WARN {
            // `Level`'s order: ERROR is the smallest. Another crate's ERROR is written as WARN.
            let mut text = String::new();
            event.record(&mut Text(&mut text));
            let values: [Option<&dyn Value>; 2] = [
                Some(&text.as_str() as &dyn Value),
                Some(&meta.target() as &dyn Value),
            ];
            let meta = THIRD_PARTY.metadata();
            self.inner.on_event(
                &Event::new(meta, &meta.fields().value_set_all(&values)),
                ctx,
            );
            return;
        }
        self.inner.on_event(event, ctx);
    }

    forward_layer!(inner);
}

impl<L> Governor<L> {
    fn write_summary<S>(&self, s: &Summary, ctx: &Context<'_, S>)
    where
        S: Subscriber,
        L: Layer<S>,
    {
        let own = is_own(s.meta.target());
        let level = if own {
            *s.meta.level()
        } else {
            (*s.meta.level()).max(Level::WARN)
        };
        let callsite = format!(
            "{}:{}",
            s.meta.file().unwrap_or("?"),
            s.meta.line().unwrap_or(0)
        );
        let message = format!(
            "{} similar messages suppressed in {:.1} s ({} at {}): {}",
            s.suppressed,
            s.seconds,
            s.meta.target(),
            callsite,
            s.about
        );
        let values: [Option<&dyn Value>; 5] = [
            Some(&message.as_str() as &dyn Value),
            Some(&s.suppressed as &dyn Value),
            Some(&s.seconds as &dyn Value),
            Some(&s.meta.target() as &dyn Value),
            Some(&callsite.as_str() as &dyn Value),
        ];
        let meta = summary_callsite(level).metadata();
        self.inner.on_event(
            &Event::new(meta, &meta.fields().value_set_all(&values)),
            ctx.clone(),
        );
    }
}

/// An event's text: its message, then its other fields as `name=value`.
struct Text<'a>(&'a mut String);

impl Visit for Text<'_> {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() == "message" {
            let rest = std::mem::take(self.0);
            let _ = write!(self.0, "{value:?}");
            if !rest.is_empty() {
                self.0.push(' ');
                self.0.push_str(&rest);
            }
        } else {
            if !self.0.is_empty() {
                self.0.push(' ');
            }
            let _ = write!(self.0, "{}={value:?}", field.name());
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.record_debug(field, &format_args!("{value}"));
        } else {
            if !self.0.is_empty() {
                self.0.push(' ');
            }
            let _ = write!(self.0, "{}={value}", field.name());
        }
    }
}

/// `text` with every run of digits, hex digits, dots, colons and brackets that holds a digit
/// (an address, a port, a count) folded to `…`: what messages that differ only by the client
/// they name have in common.
pub fn fold_numbers(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut run = String::new();
    let flush = |run: &mut String, out: &mut String| {
        if run.chars().any(|c| c.is_ascii_digit()) {
            out.push('…');
        } else {
            out.push_str(run);
        }
        run.clear();
    };
    for c in text.chars() {
        if c.is_ascii_hexdigit() || matches!(c, '.' | ':' | '[' | ']') {
            run.push(c);
        } else {
            flush(&mut run, &mut out);
            out.push(c);
        }
    }
    flush(&mut run, &mut out);
    out
}

const SUMMARY_FIELDS: &[&str] = &["message", "suppressed", "seconds", "origin", "callsite"];
own_callsite!(
    SumError,
    SUM_ERROR,
    SUM_ERROR_META,
    Level::ERROR,
    SUMMARY_FIELDS
);
own_callsite!(
    SumWarn,
    SUM_WARN,
    SUM_WARN_META,
    Level::WARN,
    SUMMARY_FIELDS
);
own_callsite!(
    SumInfo,
    SUM_INFO,
    SUM_INFO_META,
    Level::INFO,
    SUMMARY_FIELDS
);
own_callsite!(
    SumDebug,
    SUM_DEBUG,
    SUM_DEBUG_META,
    Level::DEBUG,
    SUMMARY_FIELDS
);
own_callsite!(
    SumTrace,
    SUM_TRACE,
    SUM_TRACE_META,
    Level::TRACE,
    SUMMARY_FIELDS
);
own_callsite!(
    ThirdParty,
    THIRD_PARTY,
    THIRD_PARTY_META,
    Level::WARN,
    &["message", "origin"]
);

fn summary_callsite(level: Level) -> &'static dyn Callsite {
    match level {
        Level::ERROR => &SUM_ERROR,
        Level::WARN => &SUM_WARN,
        Level::INFO => &SUM_INFO,
        Level::DEBUG => &SUM_DEBUG,
        _ => &SUM_TRACE,
    }
}

#[cfg(test)]
mod tests;
