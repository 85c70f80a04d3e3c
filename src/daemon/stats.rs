//! Running statistics for the status frame and the periodic stats event (pure, no allocation
//! after construction).

use std::time::Duration;

/// The last `N` durations, for percentiles (generation time p50/p99).
#[derive(Debug, Clone)]
pub struct SampleWindow {
    samples: Vec<Duration>,
    sorted: Vec<Duration>,
    next: usize,
    filled: bool,
}

impl SampleWindow {
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            samples: vec![Duration::ZERO; capacity],
            sorted: Vec::with_capacity(capacity),
            next: 0,
            filled: false,
        }
    }

    pub fn push(&mut self, d: Duration) {
        self.samples[self.next] = d;
        self.next = (self.next + 1) % self.samples.len();
        self.filled |= self.next == 0;
    }

    pub fn len(&self) -> usize {
        if self.filled {
            self.samples.len()
        } else {
            self.next
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Nearest-rank percentiles (`q` in [0, 1]) of the window, `None` when empty.
    pub fn percentiles<const K: usize>(&mut self, qs: [f64; K]) -> Option<[Duration; K]> {
        let n = self.len();
        if n == 0 {
            return None;
        }
        self.sorted.clear();
        self.sorted.extend_from_slice(&self.samples[..n]);
        self.sorted.sort_unstable();
        Some(qs.map(|q| {
            let rank = (q.clamp(0.0, 1.0) * n as f64).ceil() as usize;
            self.sorted[rank.clamp(1, n) - 1]
        }))
    }
}

/// A rate (events per second) from a monotonically increasing count, over the last interval.
#[derive(Debug, Clone, Copy, Default)]
pub struct RateMeter {
    last: Option<(Duration, u64)>,
    rate: f64,
}

impl RateMeter {
    /// Feeds the count at `now`; updates the rate once at least `min_interval` has passed.
    pub fn update(&mut self, now: Duration, count: u64, min_interval: Duration) -> f64 {
        match self.last {
            None => self.last = Some((now, count)),
            Some((t, c)) => {
                let dt = now.saturating_sub(t);
                if dt >= min_interval && !dt.is_zero() {
                    self.rate = count.saturating_sub(c) as f64 / dt.as_secs_f64();
                    self.last = Some((now, count));
                }
            }
        }
        self.rate
    }

    pub fn rate(&self) -> f64 {
        self.rate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn percentiles_of_the_last_samples() {
        let mut w = SampleWindow::new(100);
        assert_eq!(w.percentiles([0.5]), None);
        for i in 1..=100 {
            w.push(i * MS);
        }
        assert_eq!(
            w.percentiles([0.5, 0.99, 1.0]),
            Some([50 * MS, 99 * MS, 100 * MS])
        );
        // Older samples leave the window.
        for _ in 0..100 {
            w.push(7 * MS);
        }
        assert_eq!(w.percentiles([0.0, 0.99]), Some([7 * MS, 7 * MS]));
        assert_eq!(w.len(), 100);
    }

    #[test]
    fn rate_over_intervals() {
        let mut r = RateMeter::default();
        assert_eq!(r.update(Duration::ZERO, 0, 1000 * MS), 0.0);
        assert_eq!(
            r.update(500 * MS, 15, 1000 * MS),
            0.0,
            "interval not over yet"
        );
        assert_eq!(r.update(1000 * MS, 30, 1000 * MS), 30.0);
        assert_eq!(r.update(3000 * MS, 30, 1000 * MS), 0.0, "stalled");
    }
}
