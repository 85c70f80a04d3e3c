//! The vehicle's predicted path on the road: the arc its speed and yaw rate describe, from
//! where it is now, tangent to its heading (what an AEB function checks obstacles along, as
//! Autoware's `autonomous_emergency_braking` does). The obstacle stage locates each fly in
//! the path's coordinates: its distance along the path and its offset from it.
//!
//! Vehicle frame: x right, z ahead; yaw rate positive turning left ([`VehicleMotion`]).

use crate::kinematics::VehicleMotion;

/// The tightest the path bends, 1/m: a 5 m radius, about a car's turning circle. A larger
/// curvature (a yaw rate at walking pace, a noisy one at standstill) is clamped to it.
pub const MAX_CURVATURE: f64 = 0.2;

/// Below this speed (m/s, either way) the path is straight: the yaw rate over a near-zero
/// speed says nothing of where the vehicle goes over its (short) stopping distance.
pub const MIN_SPEED: f64 = 1.0;

/// The fastest a predicted path's curvature changes, 1/m per metre: from straight to
/// [`MAX_CURVATURE`] over 10 m.
pub const MAX_RATE: f64 = 0.02;

/// A path from the vehicle frame's origin, tangent to +z: an arc of constant curvature, or
/// (a `rate`) a clothoid whose curvature changes linearly with the distance travelled, as a
/// road's entries and exits are built and as a driver steers into and out of a bend.
///
/// The extrapolated curvature `curvature + rate s` never changes sign (a bend being left
/// ends straight: an S-bend's other half is not guessed), never exceeds [`MAX_CURVATURE`],
/// and changes only over the first [`CLOTHOID_REACH`] metres (a steering input is not
/// extrapolated for ever).
///
/// Where a clothoid's point is, off it and along it, is taken from the arc of the same
/// lateral displacement at that distance ([`PredictedPath::effective_curvature`]): exact
/// for an arc, within centimetres of the clothoid over the distances flyd decides at.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct PredictedPath {
    /// 1/m at the vehicle, positive turning left; 0 (and no rate): straight ahead.
    pub curvature: f64,
    /// 1/m^2: how the curvature changes per metre travelled (0: an arc).
    pub rate: f64,
}

/// Over how many metres a clothoid's curvature keeps changing ([`PredictedPath`]).
pub const CLOTHOID_REACH: f64 = 30.0;

impl PredictedPath {
    pub const STRAIGHT: Self = Self {
        curvature: 0.0,
        rate: 0.0,
    };

    /// The arc of curvature `curvature` (1/m).
    pub const fn arc(curvature: f64) -> Self {
        Self {
            curvature,
            rate: 0.0,
        }
    }

    /// Where the curvature stops changing, metres along: at [`CLOTHOID_REACH`], where it
    /// reaches 0 (a bend's exit) or [`MAX_CURVATURE`].
    fn rate_ends(&self) -> f64 {
        let (k, r) = (self.curvature, self.rate);
        if r == 0.0 {
            return 0.0;
        }
        let mut end = CLOTHOID_REACH;
        // Towards 0 (r and k of opposite signs), or away towards the bound.
        let limit = if k * r < 0.0 {
            0.0
        } else {
            MAX_CURVATURE.copysign(r)
        };
        let to_limit = (limit - k) / r;
        if to_limit.is_finite() && to_limit >= 0.0 {
            end = end.min(to_limit);
        }
        end
    }

    /// The curvature `along` metres ahead (1/m).
    pub fn curvature_at(&self, along: f64) -> f64 {
        let s = along.max(0.0).min(self.rate_ends());
        self.curvature + self.rate * s
    }

    /// The curvature of the arc that is as far sideways `along` metres ahead as the path:
    /// `2 / s^2` times the lateral displacement `int_0^s (s - u) k(u) du` (small angles),
    /// `curvature + rate s / 3` while the curvature changes. An arc's own curvature.
    pub fn effective_curvature(&self, along: f64) -> f64 {
        let (k0, r) = (self.curvature, self.rate);
        if r == 0.0 {
            return k0;
        }
        let s = along.max(0.0);
        let u1 = self.rate_ends();
        if s <= u1 {
            return k0 + r * s / 3.0;
        }
        let k1 = k0 + r * u1;
        let lateral = s * (k0 * u1 + r * u1 * u1 / 2.0)
            - (k0 * u1 * u1 / 2.0 + r * u1 * u1 * u1 / 3.0)
            + k1 * (s - u1) * (s - u1) / 2.0;
        2.0 * lateral / (s * s)
    }

    /// The arc that stands for the path `along` metres ahead ([`PredictedPath::effective_curvature`]).
    fn arc_at(&self, along: f64) -> Self {
        Self::arc(self.effective_curvature(along))
    }

    /// The path `motion` describes: curvature = yaw rate / speed, within
    /// `-MAX_CURVATURE..=MAX_CURVATURE`; straight below [`MIN_SPEED`] or for a non-finite
    /// motion.
    pub fn of_motion(motion: VehicleMotion) -> Self {
        let k = motion.yaw_rate / motion.speed;
        if motion.speed.abs() < MIN_SPEED || !k.is_finite() {
            return Self::STRAIGHT;
        }
        Self::arc(k.clamp(-MAX_CURVATURE, MAX_CURVATURE))
    }

    /// The clothoid of `motion` whose curvature changes by `rate` 1/m per metre (see
    /// [`PredictedPath`]): straight as [`PredictedPath::of_motion`] is.
    pub fn clothoid(motion: VehicleMotion, rate: f64) -> Self {
        let arc = Self::of_motion(motion);
        let known = motion.speed.abs() >= MIN_SPEED && (motion.yaw_rate / motion.speed).is_finite();
        if !known || !rate.is_finite() {
            return arc;
        }
        Self {
            rate: rate.clamp(-MAX_RATE, MAX_RATE),
            ..arc
        }
    }

    /// Whether the path is straight ahead (then [`PredictedPath::locate`] is `(z, x)` exactly).
    pub fn is_straight(&self) -> bool {
        self.curvature == 0.0 && self.rate == 0.0
    }

    /// The path's point `along` metres from the vehicle (x, z).
    pub fn point(&self, along: f64) -> (f64, f64) {
        if self.rate != 0.0 {
            return self.arc_at(along).point(along);
        }
        let k = self.curvature;
        if k == 0.0 {
            return (0.0, along);
        }
        let (sin, cos) = (k * along).sin_cos();
        // Left (k > 0) bends towards -x.
        (-(1.0 - cos) / k, sin / k)
    }

    /// The point `along` metres along the path and `offset` metres right of it (x, z): the
    /// path's point moved along its right normal there.
    pub fn point_at(&self, along: f64, offset: f64) -> (f64, f64) {
        if self.rate != 0.0 {
            return self.arc_at(along).point_at(along, offset);
        }
        let (px, pz) = self.point(along);
        let heading = self.curvature * along;
        (px + offset * heading.cos(), pz + offset * heading.sin())
    }

    /// A vehicle-frame point `(x, z)` in the path's coordinates: `(along, offset)`, its
    /// distance along the path to where it is abreast (metres; the arc's length to the foot
    /// of the point's radius) and its signed offset from the path (metres, positive right).
    /// Straight: `(z, x)`, bit for bit.
    ///
    /// Written without the radius (infinite for a straight path): with `k` the curvature,
    /// `offset = (2x + k (x^2 + z^2)) / (1 + hypot(1 + k x, k z))` (the distance to the
    /// circle's centre minus its radius, rationalised) and `along = atan2(|k| z, 1 + k x) / |k|`.
    pub fn locate(&self, x: f32, z: f32) -> (f32, f32) {
        if self.rate != 0.0 {
            // The arc of the path's displacement where the point is abreast: found from the
            // depth, then once more from the distance along.
            let first = self.arc_at(f64::from(z)).locate(x, z).0;
            return self.arc_at(f64::from(first)).locate(x, z);
        }
        let k = self.curvature;
        if k == 0.0 {
            return (z, x);
        }
        let (x, z) = (f64::from(x), f64::from(z));
        let offset = (2.0 * x + k * (x * x + z * z)) / (1.0 + (1.0 + k * x).hypot(k * z));
        let along = (k.abs() * z).atan2(1.0 + k * x) / k.abs();
        (along as f32, offset as f32)
    }
}

/// The fan of every path bending at most `max_curvature` either way (1/m): the arc of it
/// nearest to the vehicle-frame point `(x, z)`, ahead (`z > 0`). The arc through the point
/// has curvature `-2x / (x^2 + z^2)`; within the fan the point is on a path (offset 0),
/// outside it the fan's edge on its side is the nearest. What the vehicle could reach when its
/// yaw rate is not known; the straight path is always in it.
pub fn nearest_in_fan(max_curvature: f64, x: f32, z: f32) -> PredictedPath {
    let (x, z) = (f64::from(x), f64::from(z));
    let r2 = x * x + z * z;
    let k = if r2 > 0.0 { -2.0 * x / r2 } else { 0.0 };
    let max = max_curvature.abs().min(MAX_CURVATURE);
    PredictedPath::arc(if k.is_finite() {
        k.clamp(-max, max)
    } else {
        0.0
    })
}

/// The paths the obstacle stage's corridor follows ([`PathEstimator::update`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct PathEstimate {
    /// The corridor's centre line, distances along it: the clothoid of the vehicle's motion
    /// ([`PathModel::Clothoid`]), or the curvature it has held ([`PathModel::Held`]).
    pub held: PredictedPath,
    /// A fly must be in this path's corridor too (the same path: no second test). With
    /// [`PathModel::Held`], the curvature of the moment ([`PredictedPath::of_motion`]):
    /// while a turn has not been held (a lane change, a bend being entered, a correction),
    /// what is ahead on one path only is left out.
    pub now: PredictedPath,
}

impl PathEstimate {
    pub const STRAIGHT: Self = Self {
        held: PredictedPath::STRAIGHT,
        now: PredictedPath::STRAIGHT,
    };

    /// How far apart the two paths are `along` metres ahead, metres: how unsure the corridor
    /// is of where the vehicle goes there (0 where they agree, and for a straight box).
    pub fn spread(&self, along: f64) -> f64 {
        let (a, b) = (self.held.point(along), self.now.point(along));
        (a.0 - b.0).hypot(a.1 - b.1)
    }

    /// Where the vehicle-frame point `(x, z)` is in the corridor `half_width` metres either
    /// side of the paths: `(along, offset)` on [`PathEstimate::held`] when it is within
    /// `half_width` of both paths, else `None`. What the obstacle stage and `flyd bench
    /// --path` call a point in the corridor.
    pub fn locate_in(&self, x: f32, z: f32, half_width: f32) -> Option<(f32, f32)> {
        let (along, off) = if !self.held.is_straight() && z > 0.0 {
            self.held.locate(x, z)
        } else {
            (z, x)
        };
        let gate = || {
            self.now == self.held
                || (if !self.now.is_straight() && z > 0.0 {
                    self.now.locate(x, z).1
                } else {
                    x
                })
                .abs()
                    <= half_width
        };
        (off.abs() <= half_width && gate()).then_some((along, off))
    }
}

/// How the path is predicted from the vehicle's motion ([`PathEstimator`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case", tag = "model")]
pub enum PathModel {
    /// The curvature of the moment and how it changed over the last `window` seconds,
    /// extrapolated as a clothoid ([`PredictedPath::clothoid`]); `window` 0: the arc of the
    /// moment.
    Clothoid { window: f64 },
    /// The clothoid, and a fly must also be in the corridor of the arc of the moment: on
    /// both the path where the curvature keeps changing and the one where it stops now.
    ClothoidGated { window: f64 },
    /// The smallest curvature kept the same way over the last `hold` seconds (else
    /// straight), gated by the arc of the moment.
    Held { hold: f64 },
}

/// Most motion samples a [`PathEstimator`] keeps: 5 s (the longest hold its configuration
/// allows) at 100 Hz.
const HELD_SAMPLES: usize = 512;
/// Samples each half of the rate window needs before the two halves are compared.
const HALF_SAMPLES: usize = 3;

/// The vehicle's path from its motion, sample by sample ([`PathModel`]).
///
/// **Clothoid** (the default): a driver steering into a bend, out of it, or along an
/// on-ramp that opens up changes the curvature steadily; the yaw rate of the moment says
/// where the vehicle goes for about a second, its change over the last few tenths of a
/// second where it goes in the next. Measured on 38 minutes of real KITTI trajectories
/// (`flyd bench --path`, docs/path.md): at the STOP distance the clothoid's corridor keeps
/// an object on the real path more often and one beside it out more often than the arc of
/// the moment's or the held curvature's.
///
/// **Held**: the curvature its motion has kept, the same way, for at least `hold` seconds
/// (the smallest over that time), else straight, gated by the arc of the moment: what a
/// brief yaw rate (a lane change, a heading correction) points at is left out, at the cost
/// of a straight corridor over the first `hold` seconds of a bend.
///
/// Fixed capacity: no allocation per update.
#[derive(Debug, Clone)]
pub struct PathEstimator {
    model: PathModel,
    /// (seconds the sample's motion was held, its curvature, metres travelled), oldest first
    /// from `head`.
    samples: Box<[(f64, f64, f64); HELD_SAMPLES]>,
    head: usize,
    len: usize,
    /// Seconds the kept samples cover.
    covered: f64,
}

impl PathEstimator {
    /// An estimator that extrapolates a curvature held for `hold` seconds (0: the curvature
    /// of the moment, [`PredictedPath::of_motion`]).
    pub fn new(hold: f64) -> Self {
        Self::with_model(PathModel::Held { hold })
    }

    /// An estimator of the `model`'s paths.
    pub fn with_model(model: PathModel) -> Self {
        let seconds = |t: f64| if t.is_finite() { t.max(0.0) } else { 0.0 };
        Self {
            model: match model {
                PathModel::Held { hold } => PathModel::Held {
                    hold: seconds(hold),
                },
                PathModel::Clothoid { window } => PathModel::Clothoid {
                    window: seconds(window),
                },
                PathModel::ClothoidGated { window } => PathModel::ClothoidGated {
                    window: seconds(window),
                },
            },
            samples: Box::new([(0.0, 0.0, 0.0); HELD_SAMPLES]),
            head: 0,
            len: 0,
            covered: 0.0,
        }
    }

    /// Forgets the motion seen (a frame without trusted motion interrupts the hold).
    pub fn reset(&mut self) {
        self.head = 0;
        self.len = 0;
        self.covered = 0.0;
    }

    /// Takes the motion held over the last `dt` seconds and returns the paths to follow.
    pub fn update(&mut self, motion: VehicleMotion, dt: f64) -> PathEstimate {
        let now = PredictedPath::of_motion(motion);
        match self.model {
            PathModel::Held { hold } => PathEstimate {
                held: self.held(now, dt, motion.speed, hold),
                now,
            },
            PathModel::Clothoid { window } | PathModel::ClothoidGated { window } => {
                let path = if window == 0.0 {
                    now
                } else {
                    self.keep(now, dt, motion.speed, window);
                    PredictedPath::clothoid(motion, self.rate(window))
                };
                let gated = matches!(self.model, PathModel::ClothoidGated { .. });
                PathEstimate {
                    held: path,
                    now: if gated { now } else { path },
                }
            }
        }
    }

    /// Keeps the sample, and the newest ones that cover `window` seconds.
    fn keep(&mut self, now: PredictedPath, dt: f64, speed: f64, window: f64) {
        let dt = if dt.is_finite() { dt.max(0.0) } else { 0.0 };
        let ds = if speed.is_finite() {
            speed.abs() * dt
        } else {
            0.0
        };
        if self.len == HELD_SAMPLES {
            self.drop_oldest();
        }
        self.samples[(self.head + self.len) % HELD_SAMPLES] = (dt, now.curvature, ds);
        self.len += 1;
        self.covered += dt;
        while self.len > 1 && self.covered - self.samples[self.head].0 >= window {
            self.drop_oldest();
        }
    }

    /// How the curvature changed per metre over the kept samples (least squares), 0 until
    /// they cover `window` seconds and half a metre.
    fn rate(&self, window: f64) -> f64 {
        if self.covered < window * (1.0 - 1e-9) && self.len < HELD_SAMPLES {
            return 0.0;
        }
        // A steady change shows in both halves of the window; a step (a bend of constant
        // curvature entered without a transition, a glitch of the yaw rate) in one only. The
        // smaller of the two halves' rates, 0 when they disagree in sign. A half needs three
        // samples to hold a rate: with two (a 10 Hz feed over 0.3 s) each half's rate is one
        // difference of two noisy curvatures, and taking the smaller of two such made a real
        // drive (KITTI odometry 06, eval/real.toml) SLOW for nothing on 5 of seeds 1-8, against
        // 0 with the least squares over the whole window.
        let half = self.len / 2;
        if half + 1 < HALF_SAMPLES || self.len - half < HALF_SAMPLES {
            return self.fit(0, self.len, 0.5).unwrap_or(0.0);
        }
        let first = self.fit(0, half + 1, 0.25);
        let second = self.fit(half, self.len, 0.25);
        match (first, second) {
            (Some(a), Some(b)) if a * b > 0.0 => {
                if a.abs() < b.abs() {
                    a
                } else {
                    b
                }
            }
            _ => 0.0,
        }
    }

    /// The least-squares rate of the kept samples `from..to` (their curvature against the
    /// distance travelled), `None` over less than `min_distance` metres.
    fn fit(&self, from: usize, to: usize, min_distance: f64) -> Option<f64> {
        let (mut n, mut sum_s, mut sum_k, mut sum_ss, mut sum_sk) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut s = 0.0;
        for i in from..to {
            let (_, k, ds) = self.samples[(self.head + i) % HELD_SAMPLES];
            if i > from {
                s += ds;
            }
            n += 1.0;
            sum_s += s;
            sum_k += k;
            sum_ss += s * s;
            sum_sk += s * k;
        }
        let var = n * sum_ss - sum_s * sum_s;
        if s < min_distance || var <= 0.0 {
            return None;
        }
        let rate = (n * sum_sk - sum_s * sum_k) / var;
        rate.is_finite().then_some(rate)
    }

    /// The held path, `now` being the motion's.
    fn held(&mut self, now: PredictedPath, dt: f64, speed: f64, hold: f64) -> PredictedPath {
        if hold == 0.0 {
            return now;
        }
        self.keep(now, dt, speed, hold);
        // Rounding in `covered` must not deny a hold the samples do cover.
        if self.covered < hold * (1.0 - 1e-9) && self.len < HELD_SAMPLES {
            return PredictedPath::STRAIGHT;
        }
        let mut held = now.curvature;
        for i in 0..self.len {
            let k = self.samples[(self.head + i) % HELD_SAMPLES].1;
            if k * now.curvature <= 0.0 {
                return PredictedPath::STRAIGHT;
            }
            if k.abs() < held.abs() {
                held = k;
            }
        }
        PredictedPath::arc(held)
    }

    fn drop_oldest(&mut self) {
        self.covered -= self.samples[self.head].0;
        self.head = (self.head + 1) % HELD_SAMPLES;
        self.len -= 1;
    }
}

#[cfg(test)]
mod tests;
