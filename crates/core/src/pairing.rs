//! Left/right pairing by capture timestamp (pure: no clock, no threads): what the daemon's
//! evolution thread pairs its cameras' frames with.
//!
//! The evolution thread offers each camera's newest frame as it fetches it from the ring; the
//! pairer holds at most one candidate per side (the frame the ring reader holds) and answers
//! [`Pairer::try_pair`]:
//!
//! - both candidates within `tolerance` of each other: a [`PairOutcome::Paired`] pair, and both
//!   candidates are used up;
//! - further apart: the **older** candidate is rejected ([`PairOutcome::Rejected`], counted).
//!   Timestamps of one camera only grow, so no later frame of the other camera could ever be
//!   closer to it; the newer candidate waits for its partner;
//! - otherwise (a side has no candidate): [`PairOutcome::Waiting`].
//!
//! A candidate replaced before it was paired or rejected (its camera runs faster than the pairs
//! are taken, or the other camera is stalled) is counted as `superseded`, not as a reject: a
//! stalled camera is the stale-camera fault's business, not a stereo skew.
//!
//! `consecutive_rejects` (reset by a pair) is what the stereo-skew fault is raised on.

use std::time::Duration;

/// Which camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    pub fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

/// What a source knows about a frame it delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameMeta {
    /// Capture time on CLOCK_MONOTONIC.
    pub timestamp: Duration,
    /// Sequence number from the device (gaps mean the driver dropped frames).
    pub sequence: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairOutcome {
    /// Use these two frames; `skew` = |left - right| capture time.
    Paired {
        left: FrameMeta,
        right: FrameMeta,
        skew: Duration,
    },
    /// The `side` candidate was dropped: `skew` older than the other camera's newest frame.
    Rejected {
        side: Side,
        skew: Duration,
    },
    Waiting,
}

/// Counts since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PairCounts {
    pub paired: u64,
    pub rejected: u64,
    pub superseded: u64,
    /// Rejects since the last pair.
    pub consecutive_rejects: u64,
    /// Skew of the last pair or reject.
    pub last_skew: Duration,
}

#[derive(Debug, Clone)]
pub struct Pairer {
    tolerance: Duration,
    left: Option<FrameMeta>,
    right: Option<FrameMeta>,
    counts: PairCounts,
}

impl Pairer {
    pub fn new(tolerance: Duration) -> Self {
        Self {
            tolerance,
            left: None,
            right: None,
            counts: PairCounts::default(),
        }
    }

    /// A new newest frame of `side` (replaces that side's candidate).
    pub fn offer(&mut self, side: Side, meta: FrameMeta) {
        let slot = match side {
            Side::Left => &mut self.left,
            Side::Right => &mut self.right,
        };
        if slot.replace(meta).is_some() {
            self.counts.superseded += 1;
        }
    }

    /// Pairs the candidates if they are close enough (see the module docs).
    pub fn try_pair(&mut self) -> PairOutcome {
        let (Some(left), Some(right)) = (self.left, self.right) else {
            return PairOutcome::Waiting;
        };
        let skew = left.timestamp.abs_diff(right.timestamp);
        self.counts.last_skew = skew;
        if skew <= self.tolerance {
            self.left = None;
            self.right = None;
            self.counts.paired += 1;
            self.counts.consecutive_rejects = 0;
            return PairOutcome::Paired { left, right, skew };
        }
        let side = if left.timestamp < right.timestamp {
            self.left = None;
            Side::Left
        } else {
            self.right = None;
            Side::Right
        };
        self.counts.rejected += 1;
        self.counts.consecutive_rejects += 1;
        PairOutcome::Rejected { side, skew }
    }

    pub fn counts(&self) -> PairCounts {
        self.counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use PairOutcome::{Paired, Rejected, Waiting};

    fn meta(ms: u64, sequence: u64) -> FrameMeta {
        FrameMeta {
            timestamp: Duration::from_millis(ms),
            sequence,
        }
    }

    /// Feeds `(side, ms)` frames in order, calling `try_pair` after each, and compares the
    /// outcomes written as "P" (paired), "RL"/"RR" (rejected left/right), "-" (waiting).
    fn check(tolerance_ms: u64, frames: &[(Side, u64)], expected: &str) -> PairCounts {
        let mut p = Pairer::new(Duration::from_millis(tolerance_ms));
        let got: Vec<&str> = frames
            .iter()
            .enumerate()
            .map(|(i, &(side, ms))| {
                p.offer(side, meta(ms, i as u64));
                match p.try_pair() {
                    Paired { .. } => "P",
                    Rejected {
                        side: Side::Left, ..
                    } => "RL",
                    Rejected {
                        side: Side::Right, ..
                    } => "RR",
                    Waiting => "-",
                }
            })
            .collect();
        assert_eq!(got.join(" "), expected);
        p.counts()
    }

    use Side::{Left as L, Right as R};

    #[test]
    fn synchronised_cameras_pair_every_frame() {
        let c = check(
            5,
            &[(L, 0), (R, 1), (L, 33), (R, 33), (R, 67), (L, 66)],
            "- P - P - P",
        );
        assert_eq!((c.paired, c.rejected, c.superseded), (3, 0, 0));
    }

    #[test]
    fn tolerance_is_inclusive() {
        check(5, &[(L, 100), (R, 105)], "- P");
        check(5, &[(L, 100), (R, 106)], "- RL");
    }

    #[test]
    fn the_older_frame_is_rejected_and_the_newer_waits() {
        // Right lags 20 ms behind left: each new frame finds its partner too old.
        let c = check(
            10,
            &[(L, 0), (R, 20), (L, 33), (R, 53), (L, 66)],
            "- RL RR RL RR",
        );
        assert_eq!(c.rejected, 4);
        assert_eq!(c.consecutive_rejects, 4);
        assert_eq!(c.last_skew, Duration::from_millis(13));
    }

    #[test]
    fn a_pair_resets_consecutive_rejects() {
        let c = check(10, &[(L, 0), (R, 20), (L, 21)], "- RL P");
        assert_eq!((c.rejected, c.consecutive_rejects, c.paired), (1, 0, 1));
    }

    #[test]
    fn a_stalled_camera_supersedes_rather_than_rejects() {
        // Right delivers once, then stalls: its frame is rejected once, the left frames that
        // follow wait and replace each other.
        let c = check(5, &[(R, 0), (L, 33), (L, 66), (L, 100)], "- RR - -");
        assert_eq!((c.rejected, c.superseded, c.consecutive_rejects), (1, 2, 1));
    }

    #[test]
    fn paired_frames_carry_their_metadata() {
        let mut p = Pairer::new(Duration::from_millis(2));
        p.offer(Side::Right, meta(1001, 7));
        p.offer(Side::Left, meta(1000, 9));
        assert_eq!(
            p.try_pair(),
            Paired {
                left: meta(1000, 9),
                right: meta(1001, 7),
                skew: Duration::from_millis(1)
            }
        );
        assert_eq!(p.try_pair(), Waiting, "both candidates are used up");
    }
}
