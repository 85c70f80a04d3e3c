//! How a tracked obstacle moves over the ground: a straight line fitted to its sightings.
//!
//! Each sighting of a track is put in a frame fixed to the ground along the vehicle's path:
//! where it is along the path (its cluster's centre, each image cell counted once:
//! [`super::Obstacle::centre`]) plus the vehicle's travel since the tracker started (the
//! odometer the vehicle's motion gives), its lateral offset, at the frame's time. Over the last
//! [`WINDOW`] sightings, least squares give the speed over the ground along the path, the
//! median of the slopes between every two sightings the speed across it (robust to a few
//! frames of the flies missing a watched obstacle's inner edge), and their standard errors
//! from the scatter about the line (across: the spread of those slopes), at least what the
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
//! the speed's standard error is at most [`MAX_SIGMA`]: at 30 fps about a quarter of a second
//! after the track starts, at 10 fps about 0.7 s. Until then the obstacle counts as still
//! (the conservative rule). The decision credits an obstacle its speed less two standard
//! errors, so a wide error credits little; 1.5 m/s lets a car followed 22 m ahead on
//! hw-mock's rig count (1.27 m/s there: a pixel of disparity is 3.3 m), which at 1 m/s
//! counted as still, and was STOPped for at 40 km/h. The fit assumes a constant velocity over the window (0.5 s at
//! 30 fps): an obstacle that brakes shows as its mean speed over the window, late by about
//! half of it.

use serde::Serialize;

/// Sightings the fit uses, newest first out.
pub const WINDOW: usize = 16;
/// Sightings, time span (s) and speed standard error (m/s) an established motion needs.
pub const MIN_SAMPLES: usize = 8;
pub const MIN_SPAN: f64 = 0.2;
pub const MAX_SIGMA: f64 = 1.5;
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
/// A track resumed after a loss of at most this many seconds is measured across it while its
/// sightings since are too few ([`History::motion`]). hw-mock's car followed at 30 km/h was
/// lost for 0.4 s, resumed, and counted as still until eight new sightings: a STOP, obeyed.
pub const MAX_BRIDGE: f64 = 1.0;
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
    /// How near the path the track came before the last [`PROGRESS_S`] seconds: the second
    /// smallest offset from it (metres, unsigned) of its sightings older than that, the
    /// retired ones included; infinite with fewer than two. A watched obstacle that walks
    /// towards the path comes nearer than it ever was ([`super::crossing::entry`]).
    pub closest_before: f64,
}

/// Sightings at least this many seconds older than the newest are "before" for
/// [`ObstacleMotion::closest_before`]: a walk at 1.4 m/s covers 0.35 m in it.
pub const PROGRESS_S: f64 = 0.25;

/// A track's last sightings in the ground frame: (time s, along m, lateral m), and each
/// one's depth noise (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct History {
    samples: [(f64, f64, f64); WINDOW],
    noise: [f64; WINDOW],
    len: usize,
    /// Index of the oldest.
    start: usize,
    /// The two smallest unsigned lateral offsets of the sightings dropped from the window.
    retired: [f64; 2],
}

impl Default for History {
    fn default() -> Self {
        Self {
            samples: [(0.0, 0.0, 0.0); WINDOW],
            noise: [DEPTH_FLOOR; WINDOW],
            len: 0,
            start: 0,
            retired: [f64::INFINITY; 2],
        }
    }
}

/// `two` (ascending) with `x` among them if it is smaller than either.
fn two_smallest(two: [f64; 2], x: f64) -> [f64; 2] {
    if x < two[0] {
        [x, two[0]]
    } else if x < two[1] {
        [two[0], x]
    } else {
        two
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
            self.retired = two_smallest(self.retired, self.samples[oldest].2.abs());
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
        let m = self.fit(0, self.len)?;
        let (t, along, _) = self.newest()?;
        let dt = (time - t).max(0.0);
        Some((along + m.speed * dt, 2.0 * m.speed_sigma * dt))
    }

    /// The `i`th oldest sighting.
    fn sample(&self, i: usize) -> (f64, f64, f64) {
        self.samples[(self.start + i) % WINDOW]
    }

    /// The motion its sightings of the last [`MAX_AGE`] seconds show; none with fewer than
    /// three. A track resumed after a loss of at most [`MAX_BRIDGE`] seconds, with too few
    /// sightings since to be established, is measured across the loss instead
    /// (see `History::bridged`).
    pub fn motion(&self) -> Option<ObstacleMotion> {
        let newest = self.newest()?.0;
        let first = (0..self.len)
            .find(|&i| newest - self.sample(i).0 <= MAX_AGE)
            .unwrap_or(self.len);
        let recent = self.fit(first, self.len);
        let m = if recent.is_some_and(|m| m.established) {
            recent
        } else {
            self.bridged(first, recent).or(recent)
        };
        m.map(|m| ObstacleMotion {
            closest_before: self.closest_before(newest - PROGRESS_S),
            ..m
        })
    }

    /// The second smallest unsigned lateral offset of the sightings older than `time`, the
    /// retired ones included; infinite with fewer than two. The second, not the smallest:
    /// one sighting nearer the path than the obstacle is (flies on the road beside it) is
    /// not where it was.
    fn closest_before(&self, time: f64) -> f64 {
        (0..self.len)
            .map(|i| self.sample(i))
            .take_while(|&(t, _, _)| t < time)
            .fold(self.retired, |two, (_, _, l)| two_smallest(two, l.abs()))[1]
    }

    /// The motion of a track resumed after a loss, from its sightings before the loss (the
    /// oldest `first`, established on their own) and those since. Where the line before
    /// carries the obstacle, it would be at their mean time; as far short of that as it is,
    /// it braked, taken as steadily from its last sighting before the loss (the latest it may
    /// have started: the hardest braking that falls that short), and that braking is carried
    /// on to the newest sighting. One that is farther than the line carries it is credited
    /// its speed before, no more. The error: the sightings' own noise at both ends (not
    /// divided by their number: the errors persist) and the speed before's, over the time
    /// since. Across: the motion of the sightings since, when they have one, else that before.
    /// None when the loss is longer than [`MAX_BRIDGE`]: a car may have done anything
    /// meanwhile.
    fn bridged(&self, first: usize, recent: Option<ObstacleMotion>) -> Option<ObstacleMotion> {
        // The loss: the longest time between two sightings (the latest of equals), when it is
        // at least twice the shortest (a frame or more missed); else, sightings on every
        // frame (at 10 fps the last 0.6 s hold 7), those older than `MAX_AGE`.
        let gap = |i: usize| self.sample(i).0 - self.sample(i - 1).0;
        let longest = (1..self.len).max_by(|&a, &b| gap(a).total_cmp(&gap(b)).then(a.cmp(&b)))?;
        let shortest = (1..self.len).map(gap).fold(f64::INFINITY, f64::min);
        let first = if gap(longest) >= 2.0 * shortest {
            longest
        } else {
            first
        };
        if first == 0 || first >= self.len {
            return None;
        }
        let lost_at = self.sample(first - 1).0;
        let loss = self.sample(first).0 - lost_at;
        if loss.is_nan() || loss > MAX_BRIDGE {
            return None;
        }
        let before = self.fit(0, first).filter(|m| m.established)?;
        let mean = |from: usize, to: usize| {
            let n = (to - from) as f64;
            let (mut t, mut a, mut noise) = (0.0, 0.0, 0.0);
            for i in from..to {
                let (ti, ai, _) = self.sample(i);
                t += ti;
                a += ai;
                noise += self.noise[(self.start + i) % WINDOW].powi(2);
            }
            (t / n, a / n, noise / n)
        };
        let ((tb, ab, nb), (ta, aa, na)) = (mean(0, first), mean(first, self.len));
        let since = ta - lost_at;
        if since.is_nan() || since <= 0.0 {
            return None;
        }
        // Where the line before carries it at `ta`, and how far short of that it is.
        let short = ab + before.speed * (ta - tb) - aa;
        let decel = (2.0 * short / (since * since)).max(0.0);
        let newest = self.sample(self.len - 1).0;
        let braking = newest - lost_at;
        let speed = before.speed - decel * braking;
        let sigma_short = (nb + na + (before.speed_sigma * (ta - tb)).powi(2)).sqrt();
        let sigma_decel = 2.0 * sigma_short / (since * since);
        let speed_sigma = (before.speed_sigma.powi(2) + (sigma_decel * braking).powi(2)).sqrt();
        let lateral = recent.unwrap_or(before);
        let finite = speed.is_finite() && speed_sigma.is_finite();
        Some(ObstacleMotion {
            speed,
            speed_sigma,
            lateral_speed: lateral.lateral_speed,
            lateral_sigma: lateral.lateral_sigma,
            samples: self.len as u32,
            span: newest - self.sample(0).0,
            established: finite && speed_sigma <= MAX_SIGMA,
            closest_before: f64::INFINITY,
        })
        .filter(|_| finite)
    }

    /// The motion across of the `n` sightings from `first` (at least three), robustly: the
    /// median of the slopes between every two of them (Theil and Sen), and its standard error
    /// from their spread (Sen's 95 % interval of the slope, the ranks of its ends from the
    /// normal approximation, divided by 2 x 1.96). The flies a watched obstacle's inner edge
    /// is taken from come and go: on hw-mock's cars parked beside the lane it read 2.9 m off
    /// the path for three frames, then 2.25 m, where its inner side is; least squares made
    /// that 1.3 m/s towards the path, a SLOW, then a STOP. And where they come and go on
    /// most frames, the slopes spread and the speed is not sure.
    fn across(&self, first: usize, n: usize) -> (f64, f64) {
        let mut slopes = [0.0f64; WINDOW * (WINDOW - 1) / 2];
        let mut k = 0;
        for i in 0..n {
            let (ti, _, li) = self.sample(first + i);
            for j in i + 1..n {
                let (tj, _, lj) = self.sample(first + j);
                if tj > ti {
                    slopes[k] = (lj - li) / (tj - ti);
                    k += 1;
                }
            }
        }
        if k == 0 {
            return (f64::NAN, f64::NAN);
        }
        let slopes = &mut slopes[..k];
        let slope = median(slopes);
        // `median` sorted them.
        let nf = n as f64;
        let c = 1.96 * (nf * (nf - 1.0) * (2.0 * nf + 5.0) / 18.0).sqrt();
        let kf = k as f64;
        let lo = (((kf - c) / 2.0).floor() as usize)
            .saturating_sub(1)
            .min(k - 1);
        let hi = (((kf + c) / 2.0).ceil() as usize).min(k - 1);
        (slope, (slopes[hi] - slopes[lo]) / (2.0 * 1.96))
    }

    /// The line through its sightings `from..to` (oldest first); none with fewer than three.
    fn fit(&self, from: usize, to: usize) -> Option<ObstacleMotion> {
        let first = from;
        let n = to.saturating_sub(from);
        if n < 3 {
            return None;
        }
        let nf = n as f64;
        let (mut st, mut sa) = (0.0, 0.0);
        for i in 0..n {
            let (t, a, _) = self.sample(first + i);
            st += t;
            sa += a;
        }
        let (mt, ma) = (st / nf, sa / nf);
        let (mut stt, mut sta) = (0.0, 0.0);
        for i in 0..n {
            let (t, a, _) = self.sample(first + i);
            let dt = t - mt;
            stt += dt * dt;
            sta += dt * (a - ma);
        }
        if stt <= 0.0 {
            return None;
        }
        let speed = sta / stt;
        let mut ra = 0.0;
        for i in 0..n {
            let (t, a, _) = self.sample(first + i);
            let dt = t - mt;
            ra += (a - ma - speed * dt).powi(2);
        }
        let (lateral_speed, lateral_sigma) = self.across(first, n);
        // The sightings' own noise: the mean of their variances (the along axis), at least
        // the floor (across).
        let own = (0..n)
            .map(|i| self.noise[(self.start + first + i) % WINDOW].powi(2))
            .sum::<f64>()
            / nf;
        let sigma = |residuals: f64, floor: f64| ((residuals / (nf - 2.0)).max(floor) / stt).sqrt();
        let speed_sigma = sigma(ra, own);
        // Across: the slopes' own spread, at least what the floor gives.
        let lateral_sigma = lateral_sigma.max(sigma(0.0, LATERAL_FLOOR * LATERAL_FLOOR));
        let span = self.sample(first + n - 1).0 - self.sample(first).0;
        Some(ObstacleMotion {
            speed,
            speed_sigma,
            lateral_speed,
            lateral_sigma,
            samples: n as u32,
            span,
            established: n >= MIN_SAMPLES && span >= MIN_SPAN && speed_sigma <= MAX_SIGMA,
            closest_before: f64::INFINITY,
        })
    }
}

/// The median of `v` (reordered; the mean of the middle two of an even count); NaN when
/// empty.
fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    v.sort_unstable_by(f64::total_cmp);
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
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

    /// Sightings at 30 fps of an obstacle approached at 8.3 m/s from `along` metres, its
    /// lateral offsets `offsets`.
    fn approached(along: f64, offsets: &[f64]) -> History {
        offsets
            .iter()
            .enumerate()
            .fold(History::default(), |h, (k, &l)| {
                let t = k as f64 / 30.0;
                h.with(t, along - 8.3 * t, l, DEPTH_FLOOR)
            })
    }

    #[test]
    fn a_few_sightings_off_the_inner_edge_are_no_motion_across() {
        // A car parked 2.25 m left of the path (hw-mock's between-parked-cars, seed 2): its
        // inner edge read 2.9 m for three frames, then where it is, give or take 0.1 m.
        let offsets = [
            -2.33, -2.91, -2.91, -2.91, -2.25, -2.33, -2.37, -2.32, -2.28, -2.27, -2.33, -2.31,
            -2.25, -2.23, -2.20, -2.26,
        ];
        let h = approached(12.0, &offsets);
        let m = h.motion().expect("a motion");
        // Least squares: 1.04 m/s towards the path; the median slope, 0.43, is the inner
        // edge's own drift as the flies settle on it, and not surely towards the path.
        assert!(m.lateral_speed > 0.3 && m.lateral_speed < 0.5, "{m:?}");
        assert!(m.lateral_speed - 2.0 * m.lateral_sigma < 0.5, "{m:?}");
        // Someone walking in from 4 m left at 5 km/h, read up to 0.1 m either way and 0.6 m
        // farther out on three frames, is measured walking in, surely.
        let walking = (0..16).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            let noise = 0.1 * (2.3 * k as f64).sin();
            let off = if (1..4).contains(&k) { -0.6 } else { 0.0 };
            h.with(
                t,
                12.0 - 8.3 * t,
                -4.0 + 1.39 * t + noise + off,
                DEPTH_FLOOR,
            )
        });
        let w = walking.motion().expect("a motion");
        assert!(w.lateral_speed - 2.0 * w.lateral_sigma >= 0.5, "{w:?}");
    }

    #[test]
    fn a_parked_cars_edge_read_farther_out_then_back_is_no_nearer_than_before() {
        // hw-mock's car parked on a 60 m bend, its near side 1.7 m right of the path
        // (`bend-parked-car-outside`, seed 1, 2.0-2.6 s): read at its side, then 2.3-2.4 m
        // out for 0.3 s, then at its side again.
        let offsets = [
            1.708, 1.74, 1.68, 1.72, 2.379, 2.371, 1.835, 1.937, 2.392, 2.398, 2.265, 2.337, 2.118,
            2.407, 1.681, 1.575, 2.245, 1.723, 1.680, 1.908, 1.653, 1.674, 1.651, 1.697,
        ];
        let h = approached(20.0, &offsets);
        let m = h.motion().expect("a motion");
        // The fit reads it walking in, surely...
        assert!(m.lateral_speed + 2.0 * m.lateral_sigma < -0.5, "{m:?}");
        // ...but it came nearer before: the retired sightings and those 0.25 s old hold
        // 1.575 and 1.68 (the second is what counts).
        assert_eq!(m.closest_before, 1.68);
        assert!(1.697 >= m.closest_before);
        // Someone walking in from 4 m at 5 km/h is nearer than ever on every frame.
        let walking = (0..24).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            h.with(t, 20.0 - 8.3 * t, 4.0 - 1.39 * t, DEPTH_FLOOR)
        });
        let (_, _, now) = walking.newest().expect("sightings");
        let w = walking.motion().expect("a motion");
        assert!(now < w.closest_before, "{now} {w:?}");
        // Fewer than two sightings before: nothing to compare with.
        let young = (0..8).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            h.with(t, 20.0, 4.0 - 1.39 * t, DEPTH_FLOOR)
        });
        assert_eq!(
            young.motion().map(|m| m.closest_before),
            Some(f64::INFINITY)
        );
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

    /// Sightings at 30 fps of a car driving at 8.3 m/s for half a second, lost from 0.5 s for
    /// `loss` seconds, braking at `decel` from 0.5 s on, then seen on `after` frames.
    fn resumed(loss: f64, decel: f64, after: usize) -> (History, f64) {
        let at = |t: f64| {
            // Braking from 0.5 s until it stands.
            let b = (t - 0.5).max(0.0).min(8.3 / decel.max(1e-9));
            20.0 + 8.3 * t.min(0.5) + 8.3 * b - 0.5 * decel * b * b
        };
        let before = (0..15).fold(History::default(), |h, k| {
            let t = k as f64 / 30.0;
            h.with(t, at(t), 0.0, DEPTH_FLOOR)
        });
        let t0 = 14.0 / 30.0 + loss;
        let h = (0..after).fold(before, |h, k| {
            let t = t0 + k as f64 / 30.0;
            h.with(t, at(t), 0.0, DEPTH_FLOOR)
        });
        let newest = t0 + (after - 1) as f64 / 30.0;
        (h, (8.3 - decel * (newest - 0.5).max(0.0)).max(0.0))
    }

    /// A car lost for 0.4 s and seen again on three frames: its motion is measured across the
    /// loss, not taken as still until eight new sightings; one that braked meanwhile is
    /// measured slower, near its speed now.
    #[test]
    fn a_resumed_track_is_measured_across_its_loss() {
        let (steady, truth) = resumed(0.4, 0.0, 3);
        let m = steady.motion().expect("a motion");
        assert!(m.established, "{m:?}");
        assert!((m.speed - truth).abs() < 0.2, "{m:?} vs {truth}");
        // Braking at 6 m/s^2 from the loss on: measured slower, and its speed less the two
        // standard errors the decision credits below its speed now.
        let (braking, truth) = resumed(0.4, 6.0, 3);
        let m = braking.motion().expect("a motion");
        assert!(m.established, "{m:?}");
        assert!(
            m.speed < 7.0 && m.speed - 2.0 * m.speed_sigma < truth,
            "{m:?} vs {truth}"
        );
        // At 10 fps the last 0.6 s hold 7 sightings, too few: the older ones bridge to them.
        let tenth = (0..16).fold(History::default(), |h, k| {
            let t = k as f64 / 10.0;
            h.with(t, 20.0 + 8.3 * t, 0.0, DEPTH_FLOOR)
        });
        let m = tenth.motion().expect("a motion");
        assert!(m.established && (m.speed - 8.3).abs() < 1e-6, "{m:?}");
        // Lost for longer than MAX_BRIDGE: still until its new sightings establish it.
        let (long, _) = resumed(1.5, 0.0, 3);
        assert!(!long.motion().expect("a motion").established);
    }
}
