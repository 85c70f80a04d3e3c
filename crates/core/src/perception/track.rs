//! Debounce over frames: an obstacle is *confirmed* once it was seen on `trigger_frames`
//! consecutive frames, and released once it was missing from `release_frames` consecutive
//! ones (as Nav2's collision monitor and Autoware's AEB debounce their detections).
//!
//! A frame is new evidence; another generation on the same frame is not: the estimates of
//! one frame count once, as the latest of them (the population converges within a frame, so
//! the latest is the best informed). A frame's verdict counts as soon as it is made, so an
//! obstacle seen on two frames is confirmed on the first estimate of the second one.
//! While a confirmed obstacle is missing, the last one seen is held until release.

use serde::{Deserialize, Serialize};

use super::obstacle::{Obstacle, PerceptionParamError};

/// Frames to confirm and to release an obstacle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackConfig {
    /// Consecutive frames with an obstacle that confirm it (1: the first sighting).
    pub trigger_frames: u32,
    /// Consecutive frames without one that release a confirmed obstacle.
    pub release_frames: u32,
}

impl Default for TrackConfig {
    fn default() -> Self {
        Self {
            trigger_frames: 2,
            release_frames: 3,
        }
    }
}

impl TrackConfig {
    pub fn validate(&self) -> Result<(), PerceptionParamError> {
        // More than a few frames to confirm is a pedestrian reached before it is believed.
        PerceptionParamError::check(
            "track.trigger_frames",
            (1..=5).contains(&self.trigger_frames),
            || format!("must be within 1..=5, got {}", self.trigger_frames),
        )?;
        PerceptionParamError::check(
            "track.release_frames",
            (1..=100).contains(&self.release_frames),
            || format!("must be within 1..=100, got {}", self.release_frames),
        )
    }
}

/// The tracker's verdict after an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tracked {
    /// The obstacle of the latest estimate, or, while a confirmed obstacle is missing but not
    /// yet released, the last one seen.
    pub obstacle: Option<Obstacle>,
    /// `obstacle` is confirmed: what the decision acts on.
    pub confirmed: bool,
    /// Consecutive frames with an obstacle, this one included (0 when it has none).
    pub seen_frames: u32,
}

impl Tracked {
    /// The confirmed obstacle, if any.
    pub fn confirmed(&self) -> Option<Obstacle> {
        self.obstacle.filter(|_| self.confirmed)
    }
}

/// The debounce state (see the module docs).
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackConfig,
    frame: Option<u64>,
    /// The verdict on `frame` so far.
    current: Option<Obstacle>,
    /// Consecutive frames before `frame` with (hits) or without (misses) an obstacle.
    hits: u32,
    misses: u32,
    confirmed: bool,
    last_seen: Option<Obstacle>,
}

impl Tracker {
    pub fn new(config: TrackConfig) -> Self {
        Self {
            config,
            frame: None,
            current: None,
            hits: 0,
            misses: 0,
            confirmed: false,
            last_seen: None,
        }
    }

    /// Takes the estimate `seen` made on frame `frame`.
    pub fn update(&mut self, frame: u64, seen: Option<Obstacle>) -> Tracked {
        if self.frame.is_some_and(|f| f != frame) {
            // The previous frame's verdict is final.
            if self.current.is_some() {
                self.hits = self.hits.saturating_add(1);
                self.misses = 0;
            } else {
                self.misses = self.misses.saturating_add(1);
                self.hits = 0;
            }
        }
        self.frame = Some(frame);
        self.current = seen;
        let (seen_frames, missing_frames) = match seen {
            Some(_) => (self.hits.saturating_add(1), 0),
            None => (0, self.misses.saturating_add(1)),
        };
        if seen.is_some() {
            self.last_seen = seen;
            if seen_frames >= self.config.trigger_frames {
                self.confirmed = true;
            }
        } else if self.confirmed && missing_frames >= self.config.release_frames {
            self.confirmed = false;
        }
        let obstacle = match seen {
            Some(o) => Some(o),
            None if self.confirmed => self.last_seen,
            None => None,
        };
        Tracked {
            obstacle,
            confirmed: self.confirmed,
            seen_frames,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(distance: f64) -> Option<Obstacle> {
        Some(Obstacle {
            distance,
            lateral: 0.0,
            bottom: 0.3,
            top: 1.7,
            flies: 20,
            cells: 9,
            confidence: 60.0,
        })
    }

    #[test]
    fn two_frames_confirm_three_release() {
        let mut t = Tracker::new(TrackConfig::default());
        // Several estimates on frame 1: one frame, however many generations.
        for _ in 0..5 {
            let r = t.update(1, at(4.0));
            assert!(!r.confirmed && r.seen_frames == 1, "{r:?}");
        }
        let r = t.update(2, at(3.9));
        assert!(r.confirmed && r.seen_frames == 2, "{r:?}");
        assert_eq!(r.confirmed().map(|o| o.distance), Some(3.9));
        // Missing on frames 3 and 4: held at the last distance seen.
        for f in [3, 4] {
            let r = t.update(f, None);
            assert!(r.confirmed, "frame {f}: {r:?}");
            assert_eq!(r.obstacle.map(|o| o.distance), Some(3.9));
        }
        let r = t.update(5, None);
        assert!(!r.confirmed && r.obstacle.is_none(), "{r:?}");
    }

    #[test]
    fn a_frame_counts_as_its_latest_estimate() {
        let mut t = Tracker::new(TrackConfig::default());
        t.update(1, at(4.0));
        // Frame 1 ends without the obstacle: no streak.
        t.update(1, None);
        let r = t.update(2, at(4.0));
        assert!(!r.confirmed && r.seen_frames == 1, "{r:?}");
    }

    #[test]
    fn one_stray_frame_confirms_nothing() {
        let mut t = Tracker::new(TrackConfig::default());
        for f in 0..20 {
            let seen = if f % 2 == 0 { at(10.0) } else { None };
            assert!(!t.update(f, seen).confirmed, "frame {f}");
        }
    }
}
