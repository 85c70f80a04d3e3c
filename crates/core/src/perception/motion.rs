//! How a tracked obstacle moves over the ground: a straight line fitted to its sightings.
//!
//! Each sighting of a track is put in a frame fixed to the ground along the vehicle's path:
//! its distance plus the vehicle's travel since the tracker started (the odometer the
//! vehicle's motion gives), its lateral offset, at the frame's time. Over the last
//! [`WINDOW`] sightings, least squares give the speed over the ground along the path and
//! across it, and their standard errors from the scatter about the line, at least what the
//! sightings' own depth noise gives (each sighting's, given by the tracker: a quarter of a
//! pixel of disparity at its distance, [`DEPTH_FLOOR`] at the least; across,
//! [`LATERAL_FLOOR`]). The floor matters: the
//! flies an obstacle is built from persist from frame to frame, so a sighting's error does
//! too, and sightings that line up are not independent. Without it, a stopped car approached
//! at 20 km/h from 29 m on the mock rig (a pixel of disparity is 3-5 m there) read 3 m/s
//! away at its 16th sighting with a standard error of 0.6 m/s. The closing speed is the
//! vehicle's speed less the obstacle's.
//!
//! The motion is *established* once [`MIN_SAMPLES`] sightings span [`MIN_SPAN`] seconds and
//! the speed's standard error is below [`MAX_SIGMA`]: at 30 fps about a quarter of a second
//! after the track starts, at 10 fps about 0.7 s. Until then the obstacle counts as still
//! (the conservative rule). The fit assumes a constant velocity over the window (0.5 s at
//! 30 fps): an obstacle that brakes shows as its mean speed over the window, late by about
//! half of it.

use serde::Serialize;

/// Sightings the fit uses, newest first out.
pub const WINDOW: usize = 16;
/// Sightings, time span (s) and speed standard error (m/s) an established motion needs.
pub const MIN_SAMPLES: usize = 8;
pub const MIN_SPAN: f64 = 0.2;
pub const MAX_SIGMA: f64 = 1.0;
/// The fastest an obstacle is taken to move over the ground, m/s: a motion beyond it moves
/// neither a held track nor the flies on it by more.
pub const MAX_SPEED: f64 = 40.0;
/// Sightings older than this before the newest are not fitted, seconds: the fit assumes a
/// constant velocity over what it takes, and a track resumed after a loss ([`super::track`])
/// holds sightings seconds old. Fitted over 2 s, a car braking at 6 m/s^2 from 12 m ahead
/// read 13.5 m/s with a standard error of 0.07 while it slowed, and was hit at 43 km/h
/// (hw-mock, 50 km/h, seed 1). A resumed track is only associated by its older sightings
/// ([`History::along_at`]).
pub const MAX_AGE: f64 = 0.6;
/// The least depth noise a sighting is assumed to have, metres.
pub const DEPTH_FLOOR: f64 = 0.05;
/// The least noise of a sighting's lateral offset, metres: a cluster's quartile moves with the
/// flies it is built from (on hw-mock's parked cars 0.1-0.3 m from frame to frame), and its
/// errors persist as the depth's do.
pub const LATERAL_FLOOR: f64 = 0.15;

/// How an obstacle moves, as its sightings show.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ObstacleMotion {
    /// Speed over the ground along the vehicle's path, m/s (positive: the vehicle's way).
    pub speed: f64,
    /// Its standard error, m/s.
    pub speed_sigma: f64,
    /// Speed across the path, m/s (positive: to the right).
    pub lateral_speed: f64,
    pub lateral_sigma: f64,
    /// Sightings fitted, and the time they span, seconds.
    pub samples: u32,
    pub span: f64,
    /// Enough sightings over long enough, and precise enough, to be used.
    pub established: bool,
}

/// A track's last sightings in the ground frame: (time s, along m, lateral m), and each
/// one's depth noise (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct History {
    samples: [(f64, f64, f64); WINDOW],
    noise: [f64; WINDOW],
    len: usize,
    /// Index of the oldest.
    start: usize,
}

impl Default for History {
    fn default() -> Self {
        Self {
            samples: [(0.0, 0.0, 0.0); WINDOW],
            noise: [DEPTH_FLOOR; WINDOW],
            len: 0,
            start: 0,
        }
    }
}

impl History {
    /// This history and a newer sighting whose depth is uncertain by `noise` metres (at
    /// least [`DEPTH_FLOOR`]; the oldest dropped when full; a sighting not finite, or not
    /// later than the newest, is ignored).
    pub fn with(mut self, time: f64, along: f64, lateral: f64, noise: f64) -> Self {
        if !(time.is_finite() && along.is_finite() && lateral.is_finite()) {
            return self;
        }
        if self.len > 0 && time <= self.sample(self.len - 1).0 {
            return self;
        }
        let noise = if noise.is_finite() {
            noise.max(DEPTH_FLOOR)
        } else {
            DEPTH_FLOOR
        };
        let slot = if self.len < WINDOW {
            self.len += 1;
            (self.start + self.len - 1) % WINDOW
        } else {
            let oldest = self.start;
            self.start = (self.start + 1) % WINDOW;
            oldest
        };
        self.samples[slot] = (time, along, lateral);
        self.noise[slot] = noise;
        self
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The newest sighting: (time, along, lateral).
    pub fn newest(&self) -> Option<(f64, f64, f64)> {
        (self.len > 0).then(|| self.sample(self.len - 1))
    }

    /// Where the obstacle of these sightings is along the path at `time`, as its motion
    /// carries its newest sighting on, and how uncertain that is from the motion's speed
    /// (two standard errors over the time since), metres; none before a motion.
    pub fn along_at(&self, time: f64) -> Option<(f64, f64)> {
        let m = self.fit(0)?;
        let (t, along, _) = self.newest()?;
        let dt = (time - t).max(0.0);
        Some((along + m.speed * dt, 2.0 * m.speed_sigma * dt))
    }

    /// The `i`th oldest sighting.
    fn sample(&self, i: usize) -> (f64, f64, f64) {
        self.samples[(self.start + i) % WINDOW]
    }

    /// The motion its sightings of the last [`MAX_AGE`] seconds show; none with fewer than
    /// three.
    pub fn motion(&self) -> Option<ObstacleMotion> {
        let newest = self.newest()?.0;
        let first = (0..self.len)
            .find(|&i| newest - self.sample(i).0 <= MAX_AGE)
            .unwrap_or(self.len);
        self.fit(first)
    }

    /// The line through its sightings from the `first`th oldest on; none with fewer than
    /// three.
    fn fit(&self, first: usize) -> Option<ObstacleMotion> {
        let n = self.len.saturating_sub(first);
        if n < 3 {
            return None;
        }
        let nf = n as f64;
        let (mut st, mut sa, mut sl) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let (t, a, l) = self.sample(first + i);
            st += t;
            sa += a;
            sl += l;
        }
        let (mt, ma, ml) = (st / nf, sa / nf, sl / nf);
        let (mut stt, mut sta, mut stl) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let (t, a, l) = self.sample(first + i);
            let dt = t - mt;
            stt += dt * dt;
            sta += dt * (a - ma);
            stl += dt * (l - ml);
        }
        if stt <= 0.0 {
            return None;
        }
        let (speed, lateral_speed) = (sta / stt, stl / stt);
        let (mut ra, mut rl) = (0.0, 0.0);
        for i in 0..n {
            let (t, a, l) = self.sample(first + i);
            let dt = t - mt;
            ra += (a - ma - speed * dt).powi(2);
            rl += (l - ml - lateral_speed * dt).powi(2);
        }
        // The sightings' own noise: the mean of their variances (the along axis), at least
        // the floor (across).
        let own = (0..n)
            .map(|i| self.noise[(self.start + first + i) % WINDOW].powi(2))
            .sum::<f64>()
            / nf;
        let sigma = |residuals: f64, floor: f64| ((residuals / (nf - 2.0)).max(floor) / stt).sqrt();
        let (speed_sigma, lateral_sigma) =
            (sigma(ra, own), sigma(rl, LATERAL_FLOOR * LATERAL_FLOOR));
        let span = self.sample(first + n - 1).0 - self.sample(first).0;
        Some(ObstacleMotion {
            speed,
            speed_sigma,
            lateral_speed,
            lateral_sigma,
            samples: n as u32,
            span,
            established: n >= MIN_SAMPLES && span >= MIN_SPAN && speed_sigma <= MAX_SIGMA,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sightings at 30 fps of an obstacle at `speed` along and `lateral` across, with
    /// alternating depth noise of `noise` metres.
    fn history(frames: usize, speed: f64, lateral: f64, noise: f64) -> History {
        (0..frames).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            let jitter = if k % 2 == 0 { noise } else { -noise };
            h.with(t, 20.0 + speed * t + jitter, 0.5 + lateral * t, DEPTH_FLOOR)
        })
    }

    #[test]
    fn a_steady_obstacle_is_measured_and_established_after_enough_sightings() {
        let m = history(12, 8.0, -1.0, 0.0).motion().expect("a motion");
        assert!((m.speed - 8.0).abs() < 1e-9, "{}", m.speed);
        assert!((m.lateral_speed + 1.0).abs() < 1e-9);
        assert!(m.established);
        assert_eq!(m.samples, 12);
        // The floor: sightings on an exact line are not taken as certain.
        assert!(m.speed_sigma > 0.1, "{}", m.speed_sigma);
        // Too few, or over too short a time: not established.
        let early = history(5, 8.0, 0.0, 0.0).motion().expect("a motion");
        assert!(!early.established);
        assert!(history(2, 8.0, 0.0, 0.0).motion().is_none());
    }

    #[test]
    fn noisy_sightings_give_a_wider_error_and_the_window_keeps_the_newest() {
        let quiet = history(16, 0.0, 0.0, 0.05).motion().expect("a motion");
        let noisy = history(16, 0.0, 0.0, 1.0).motion().expect("a motion");
        assert!(noisy.speed_sigma > 3.0 * quiet.speed_sigma);
        assert!(!noisy.established, "{}", noisy.speed_sigma);
        // 60 sightings: the last 16 (the last half second) are fitted.
        let h = (0..60).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            // Standing for a second, then driving off at 5 m/s.
            let a = if t < 1.0 {
                20.0
            } else {
                20.0 + 5.0 * (t - 1.0)
            };
            h.with(t, a, 0.0, 0.0)
        });
        assert_eq!(h.len(), WINDOW);
        let m = h.motion().expect("a motion");
        assert!((m.speed - 5.0).abs() < 1e-9, "{}", m.speed);
        // Not later than the newest, or not finite: ignored.
        assert_eq!(h.with(0.5, 1.0, 0.0, 0.0), h);
        assert_eq!(h.with(f64::NAN, 1.0, 0.0, 0.0), h);
    }

    /// A track resumed after a loss: its sightings before the loss are not fitted, so a car
    /// that slowed meanwhile is measured at its speed now, not at its mean over seconds.
    #[test]
    fn only_the_last_sightings_are_fitted() {
        let before = (0..8).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            h.with(t, 20.0 + 13.0 * t, 0.0, DEPTH_FLOOR)
        });
        let h = (0..8).fold(before, |h, k| {
            let t = 1.8 + k as f64 / 30.0;
            h.with(t, 40.0 + 7.0 * (t - 1.8), 0.0, DEPTH_FLOOR)
        });
        let m = h.motion().expect("a motion");
        assert_eq!(m.samples, 8);
        assert!((m.speed - 7.0).abs() < 1e-9, "{m:?}");
        // Where it is expected later still comes from all of them.
        let (at, _) = h.along_at(2.5).expect("a position");
        assert!(at > 40.0, "{at}");
    }

    /// Sightings on an exact line but each uncertain by a metre (a pixel of disparity at
    /// 25 m on a short baseline): the line is not taken as certain.
    #[test]
    fn the_sightings_own_noise_bounds_the_error_from_below() {
        let far = (0..16).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            h.with(t, 25.0 + 3.0 * t, 0.0, 1.0)
        });
        let m = far.motion().expect("a motion");
        assert!((m.speed - 3.0).abs() < 1e-9);
        assert!(m.speed_sigma > 1.5 && !m.established, "{m:?}");
    }
}
