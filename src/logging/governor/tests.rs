use super::*;
use std::sync::atomic::AtomicU64;
use tracing_subscriber::layer::SubscriberExt;

/// What reached the output: level, target and the event's text.
#[derive(Clone, Default)]
struct Capture(Arc<Mutex<Vec<(Level, String, String)>>>);

impl<S: Subscriber> Layer<S> for Capture {
    fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
        let mut text = String::new();
        event.record(&mut Text(&mut text));
        let meta = event.metadata();
        if let Ok(mut v) = self.0.lock() {
            v.push((*meta.level(), meta.target().to_string(), text));
        }
    }
}

impl Capture {
    fn lines(&self) -> Vec<(Level, String, String)> {
        self.0.lock().map(|v| v.clone()).unwrap_or_default()
    }
}

/// A subscriber with the governor in front of a capture, on a clock the test moves.
fn setup() -> (Capture, Arc<AtomicU64>, impl Subscriber) {
    let capture = Capture::default();
    let micros = Arc::new(AtomicU64::new(0));
    let m = micros.clone();
    let clock: Clock = Arc::new(move || Duration::from_micros(m.load(Ordering::Relaxed)));
    let governor = Governor::with_clock(capture.clone(), Policy::default(), clock);
    (
        capture,
        micros,
        tracing_subscriber::registry().with(governor),
    )
}

fn suppressed_in(lines: &[(Level, String, String)]) -> u64 {
    lines
        .iter()
        .filter(|l| l.1 == "flyd::logging")
        .filter_map(|l| l.2.split(" similar messages").next()?.parse::<u64>().ok())
        .sum()
}

#[test]
fn a_warning_at_1_khz_writes_about_a_line_a_second_and_counts_the_rest() {
    let (capture, micros, subscriber) = setup();
    tracing::subscriber::with_default(subscriber, || {
        for i in 0..10_000u64 {
            micros.store(i * 1000, Ordering::Relaxed);
            tracing::warn!(target: "flyd::test", i, "camera flapping");
        }
        // The last count goes out with the daemon's last line.
        micros.store(10_000_000, Ordering::Relaxed);
        request_flush();
        tracing::info!(target: "flyd::test", "flyd stopped");
    });
    let lines = capture.lines();
    let warns: Vec<_> = lines
        .iter()
        .filter(|l| l.2.starts_with("camera flapping"))
        .collect();
    let summaries = lines.iter().filter(|l| l.1 == "flyd::logging").count();
    // 10 s: a burst of 10, then one line every 2 s, each after its count.
    assert!(
        warns.len() <= 10 + 6,
        "{} warnings written in 10 s",
        warns.len()
    );
    assert!(
        warns.len() + summaries <= 10 + 12,
        "{} lines in 10 s",
        warns.len() + summaries
    );
    assert_eq!(
        warns.len() as u64 + suppressed_in(&lines),
        10_000,
        "every warning written or counted"
    );
    // The counts carry the warning's level and what it said last.
    let summary = lines
        .iter()
        .find(|l| l.1 == "flyd::logging")
        .expect("a summary");
    assert_eq!(summary.0, Level::WARN);
    assert!(
        summary.2.contains("last: camera flapping i="),
        "{summary:?}"
    );
    assert!(summary.2.contains("origin=flyd::test"), "{summary:?}");
}

#[test]
fn distinct_callsites_have_their_own_budgets_and_quiet_ones_are_reported_on_time() {
    let (capture, micros, subscriber) = setup();
    tracing::subscriber::with_default(subscriber, || {
        for i in 0..100u64 {
            micros.store(i * 1000, Ordering::Relaxed);
            tracing::error!(target: "flyd::test", "can write failed");
            tracing::info!(target: "flyd::test", "decision changed");
        }
        // Quiet for 6 s; another callsite's line brings the counts out.
        micros.store(6_100_000, Ordering::Relaxed);
        tracing::info!(target: "flyd::test", "stats");
    });
    let lines = capture.lines();
    let n = |t: &str| lines.iter().filter(|l| l.2 == t).count();
    assert_eq!(n("can write failed"), 10);
    assert_eq!(n("decision changed"), 10);
    assert_eq!(n("stats"), 1);
    let summaries: Vec<_> = lines.iter().filter(|l| l.1 == "flyd::logging").collect();
    assert_eq!(summaries.len(), 2, "{summaries:?}");
    assert!(
        summaries
            .iter()
            .any(|s| s.0 == Level::ERROR && s.2.starts_with("90 similar")),
        "{summaries:?}"
    );
    assert_eq!(suppressed_in(&lines), 180);
}

#[test]
fn another_crates_errors_are_warnings_and_their_summary_says_why() {
    let (capture, micros, subscriber) = setup();
    tracing::subscriber::with_default(subscriber, || {
        for i in 0..1000u64 {
            micros.store(i * 1000, Ordering::Relaxed);
            let addr = format!("127.0.0.1:{}", 30000 + i);
            if i % 10 == 0 {
                tracing::error!(target: "foxglove::websocket::server", "Dropping client {addr}: connection reset");
            } else {
                tracing::error!(target: "foxglove::websocket::server", "Dropping client {addr}: handshake failed");
            }
        }
        micros.store(10_000_000, Ordering::Relaxed);
        tracing::info!(target: "flyd::test", "stats");
    });
    let lines = capture.lines();
    assert!(
        lines.iter().all(|l| l.0 != Level::ERROR),
        "no ERROR from another crate: {lines:?}"
    );
    let written = lines
        .iter()
        .filter(|l| l.2.starts_with("Dropping client"))
        .count();
    assert_eq!(
        written, 10,
        "a burst of 5 from each of the two callsites in the first second: {lines:?}"
    );
    assert!(
        lines
            .iter()
            .filter(|l| l.2.starts_with("Dropping client"))
            .all(|l| l.2.contains("origin=foxglove::websocket::server")),
        "{lines:?}"
    );
    let summaries: Vec<_> = lines
        .iter()
        .filter(|l| l.2.contains("similar messages suppressed"))
        .collect();
    assert!(summaries.iter().all(|s| s.0 == Level::WARN));
    for why in ["handshake failed", "connection reset"] {
        assert!(
            summaries
                .iter()
                .any(|s| s.2.contains(&format!("x Dropping client … {why}"))),
            "{summaries:?}"
        );
    }
    assert_eq!(written as u64 + suppressed_in(&lines), 1000);
}

#[test]
fn numbers_and_addresses_fold_and_words_stay() {
    assert_eq!(
        fold_numbers("Dropping client 127.0.0.1:38620: handshake failed"),
        "Dropping client … handshake failed"
    );
    assert_eq!(
        fold_numbers("client [::1]:5555 sent 12 bytes"),
        "client … sent … bytes"
    );
    assert_eq!(fold_numbers("a bad face"), "a bad face");
}
