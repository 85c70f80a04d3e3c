//! The road, measured: a plane fitted on every frame to points that match on the road.
//!
//! On each new frame, a plane sweep ([`Engine::sweep`]) looks along `rays` rays spread evenly
//! over the band `band` metres either side of the current road estimate, `min_distance..
//! max_distance` ahead and within `half_width` of the centre line, `steps` depths each: the
//! fittest depth of each ray whose match is unique (its ambiguity at most `max_ambiguity`)
//! is a point of the road. (A population evolved on the band, tried first, settled on a few
//! lane-marking tips and shadow edges, some of them false matches 4-5 px of disparity off,
//! and left the asphalt bare: its planes were off by up to 3 % of bank on KITTI.) A robust
//! fit of `y = height + slope_z z + slope_x x` on them (iteratively reweighted least
//! squares, Tukey's biweight with a scale shrinking from 0.4 to `inlier_tolerance` m, started
//! from the current estimate, so kerbs, a car's lower part and stray matches weigh nothing)
//! is the measurement. It is bounded around the prior (the calibration's mount): height within
//! `max_height_change`, slopes within `max_slope` (rise per metre); a fit outside is clamped to
//! the bounds and says so. Then the estimate moves `gain` of the way to the measurement (a
//! frame's fit is noisy; the road changes over metres, not frames).
//!
//! Fewer than `min_inliers` points within `inlier_tolerance` of the fit (an untextured road,
//! night, a camera covered) is no measurement: the estimate falls back to the prior, and says
//! so (source `PRIOR_FALLBACK`).

use serde::{Deserialize, Serialize};

use super::obstacle::PerceptionParamError;
use crate::engine::{Engine, EngineError, Sweep, SweepPoint};
use crate::frame::StereoFrame;
use crate::road_plane::RoadPlane;

/// The road estimator's settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RoadConfig {
    /// Measure the road (false: the prior, always).
    pub enabled: bool,
    /// Half-height of the swept band around the estimate, metres.
    pub band: f64,
    /// Road points are looked for this far ahead, metres.
    pub min_distance: f64,
    pub max_distance: f64,
    /// ... and within this lateral distance of the centre line, metres.
    pub half_width: f64,
    /// Rays swept per frame.
    pub rays: usize,
    /// Depths per ray.
    pub steps: usize,
    /// A ray's match is unique when its ambiguity is at most this.
    pub max_ambiguity: f64,
    /// Points within `inlier_tolerance` of the fit that make a measurement.
    pub min_inliers: usize,
    /// Distance to the plane of an inlier, metres (the fit's final scale).
    pub inlier_tolerance: f64,
    /// Bound of the road's height change from the prior, metres.
    pub max_height_change: f64,
    /// Bound of the road's slope change from the prior, rise per metre (0.08 = 4.6 degrees: KITTI 2012 #1 banks 6.2 %).
    pub max_slope: f64,
    /// Share of the way the estimate moves to a frame's measurement, (0, 1].
    pub gain: f64,
}

impl Default for RoadConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            band: 0.5,
            min_distance: 4.0,
            max_distance: 30.0,
            half_width: 4.0,
            rays: 128,
            steps: 12,
            max_ambiguity: 0.5,
            min_inliers: 12,
            inlier_tolerance: 0.1,
            max_height_change: 0.3,
            max_slope: 0.08,
            gain: 0.5,
        }
    }
}

impl RoadConfig {
    pub fn validate(&self) -> Result<(), PerceptionParamError> {
        let positive = |key, v: f64| {
            PerceptionParamError::check(key, v.is_finite() && v > 0.0, || {
                format!("must be > 0, got {v}")
            })
        };
        positive("road.band", self.band)?;
        positive("road.min_distance", self.min_distance)?;
        positive("road.half_width", self.half_width)?;
        positive("road.max_ambiguity", self.max_ambiguity)?;
        positive("road.inlier_tolerance", self.inlier_tolerance)?;
        positive("road.max_height_change", self.max_height_change)?;
        positive("road.max_slope", self.max_slope)?;
        // A road allowed to move further takes a low obstacle for the road itself.
        PerceptionParamError::check(
            "road.max_height_change",
            self.max_height_change <= 1.0,
            || format!("must be within (0, 1] m, got {}", self.max_height_change),
        )?;
        PerceptionParamError::check("road.max_slope", self.max_slope <= 0.2, || {
            format!("must be within (0, 0.2], got {}", self.max_slope)
        })?;
        PerceptionParamError::check(
            "road.max_distance",
            self.max_distance.is_finite() && self.max_distance > self.min_distance,
            || {
                format!(
                    "must be greater than road.min_distance ({})",
                    self.min_distance
                )
            },
        )?;
        PerceptionParamError::check("road.gain", self.gain > 0.0 && self.gain <= 1.0, || {
            format!("must be within (0, 1], got {}", self.gain)
        })?;
        PerceptionParamError::check("road.steps", (8..=64).contains(&self.steps), || {
            format!("must be within 8..=64, got {}", self.steps)
        })?;
        PerceptionParamError::check(
            "road.rays",
            (16..=512).contains(&self.rays) && self.rays * self.steps <= 4096,
            || {
                format!(
                    "must be within 16..=512 with road.rays x road.steps <= 4096, got {} x {}",
                    self.rays, self.steps
                )
            },
        )?;
        PerceptionParamError::check(
            "road.min_inliers",
            (3..=self.rays).contains(&self.min_inliers),
            || format!("must be within 3..=road.rays, got {}", self.min_inliers),
        )
    }
}

named_enum! {
    /// Where the road estimate comes from.
    pub enum RoadSource {
        /// The calibration's mount: road measurement off, or before the first frame.
        Prior = 0 => "PRIOR",
        /// Fitted to the road flies of the latest frame.
        Measured = 1 => "MEASURED",
        /// Fitted, but outside the bounds around the prior: clamped to them.
        Bounded = 2 => "BOUNDED",
        /// Too few road flies matched uniquely on the latest frame: the prior.
        PriorFallback = 3 => "PRIOR_FALLBACK",
    }
}

impl Serialize for RoadSource {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// The road as flyd uses it, and how it got it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RoadEstimate {
    pub plane: RoadPlane,
    pub source: RoadSource,
    /// Points of the latest fit within `inlier_tolerance` of it.
    pub inliers: usize,
    /// Their RMS distance to the fitted plane, metres (NaN without a fit).
    pub rms: f64,
    /// The latest frame's fit as measured, before the bounds and the smoothing (none: no
    /// measurement): what the mount is checked against ([`super::mount_check`]).
    pub fitted: Option<RoadPlane>,
}

impl RoadEstimate {
    /// The prior, unmeasured.
    pub fn prior(plane: RoadPlane) -> Self {
        Self {
            plane,
            source: RoadSource::Prior,
            inliers: 0,
            rms: f64::NAN,
            fitted: None,
        }
    }

    /// Whether the plane comes from a measurement (bounded or not).
    pub fn measured(&self) -> bool {
        matches!(self.source, RoadSource::Measured | RoadSource::Bounded)
    }
}

/// The fit's buffers and the estimate it keeps.
#[derive(Debug, Clone)]
pub struct RoadEstimator {
    config: RoadConfig,
    prior: RoadPlane,
    estimate: RoadEstimate,
    swept: Vec<SweepPoint>,
    points: Vec<[f64; 3]>,
}

impl RoadEstimator {
    pub fn new(config: RoadConfig, prior: RoadPlane) -> Self {
        let k = config.rays;
        Self {
            config,
            prior,
            estimate: RoadEstimate::prior(prior),
            swept: Vec::with_capacity(k),
            points: Vec::with_capacity(k),
        }
    }

    pub fn estimate(&self) -> RoadEstimate {
        self.estimate
    }

    /// The points of the latest measurement (for diagnostics and figures).
    pub fn swept(&self) -> &[SweepPoint] {
        &self.swept
    }

    /// Measures the road on `frame` (the engine's latest step), updates the estimate and
    /// returns it (see the module docs).
    pub fn update(
        &mut self,
        engine: &mut Engine,
        frame: &StereoFrame,
    ) -> Result<RoadEstimate, EngineError> {
        let c = self.config;
        let sweep = Sweep {
            heights: (-c.band, c.band),
            road: self.estimate.plane,
            depths: (c.min_distance, c.max_distance),
            half_width: c.half_width,
            rays: c.rays,
            steps: c.steps,
        };
        engine.sweep(frame, &sweep, &mut self.swept)?;
        self.points.clear();
        self.points.extend(
            self.swept
                .iter()
                .filter(|p| p.fitness > 0.0 && f64::from(p.ambiguity) <= c.max_ambiguity)
                .map(|p| p.point.map(f64::from)),
        );
        self.estimate = self.next(fit(&self.points, &self.estimate.plane, c.inlier_tolerance));
        Ok(self.estimate)
    }

    /// The estimate after a frame whose fit is `fit`.
    fn next(&self, fit: Option<Fit>) -> RoadEstimate {
        let c = self.config;
        let Some(fit) = fit.filter(|f| f.inliers >= c.min_inliers) else {
            return RoadEstimate {
                source: RoadSource::PriorFallback,
                inliers: fit.map_or(0, |f| f.inliers),
                rms: fit.map_or(f64::NAN, |f| f.rms),
                plane: self.prior,
                fitted: None,
            };
        };
        let p = self.prior;
        let clamp = |v: f64, around: f64, by: f64| v.clamp(around - by, around + by);
        let bounded = RoadPlane {
            height: clamp(fit.plane.height, p.height, c.max_height_change),
            slope_z: clamp(fit.plane.slope_z, p.slope_z, c.max_slope),
            slope_x: clamp(fit.plane.slope_x, p.slope_x, c.max_slope),
        };
        let source = if bounded == fit.plane {
            RoadSource::Measured
        } else {
            RoadSource::Bounded
        };
        // From the prior after a fallback, else from the previous estimate.
        let from = if self.estimate.measured() {
            self.estimate.plane
        } else {
            p
        };
        let toward = |a: f64, b: f64| a + c.gain * (b - a);
        RoadEstimate {
            plane: RoadPlane {
                height: toward(from.height, bounded.height),
                slope_z: toward(from.slope_z, bounded.slope_z),
                slope_x: toward(from.slope_x, bounded.slope_x),
            },
            source,
            inliers: fit.inliers,
            rms: fit.rms,
            fitted: Some(fit.plane),
        }
    }
}

/// A robust plane fit.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fit {
    plane: RoadPlane,
    inliers: usize,
    rms: f64,
}

/// Tukey-weighted least squares of `y = h + sz z + sx x` on `points` ([x, y, z]), started from
/// `start`, the scale shrinking from 0.4 m to `tolerance` (see the module docs). `None` when
/// the points do not determine a plane (fewer than 3, or all on a line).
fn fit(points: &[[f64; 3]], start: &RoadPlane, tolerance: f64) -> Option<Fit> {
    const SCALES: [f64; 6] = [0.4, 0.3, 0.2, 0.15, 0.0, 0.0];
    let mut plane = *start;
    for scale in SCALES {
        let c = if scale > tolerance { scale } else { tolerance } * 2.0;
        // Normal equations of the weighted fit, unknowns [h, sz, sx].
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut b = nalgebra::Vector3::<f64>::zeros();
        for &[x, y, z] in points {
            let r = y - plane.road_y(x, z);
            let u = r / c;
            if u.abs() >= 1.0 {
                continue;
            }
            let w = (1.0 - u * u).powi(2);
            let row = nalgebra::Vector3::new(1.0, z, x);
            a += w * row * row.transpose();
            b += w * y * row;
        }
        // A plane needs points that span it: three or more, not on one line.
        let eigen = a.symmetric_eigen().eigenvalues;
        let spans = eigen.min() > 1e-9 * eigen.max().max(1e-300);
        if !spans {
            return None;
        }
        let solved = a.lu().solve(&b)?;
        if !solved.iter().all(|v| v.is_finite()) {
            return None;
        }
        plane = RoadPlane {
            height: solved[0],
            slope_z: solved[1],
            slope_x: solved[2],
        };
    }
    let (mut inliers, mut sum) = (0usize, 0.0);
    for &[x, y, z] in points {
        let r = y - plane.road_y(x, z);
        if r.abs() <= tolerance {
            inliers += 1;
            sum += r * r;
        }
    }
    Some(Fit {
        plane,
        inliers,
        rms: if inliers > 0 {
            (sum / inliers as f64).sqrt()
        } else {
            f64::NAN
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::xorshift64;

    /// Points of `road` over 5-30 m ahead, +-3 m across, with uniform noise of +-`noise` m.
    fn road_points(road: &RoadPlane, n: usize, noise: f64, seed: u64) -> Vec<[f64; 3]> {
        let mut next = xorshift64(seed);
        let mut unit = || (next() >> 11) as f64 / (1u64 << 53) as f64;
        (0..n)
            .map(|_| {
                let (x, z) = (-3.0 + 6.0 * unit(), 5.0 + 25.0 * unit());
                [x, road.road_y(x, z) + noise * (2.0 * unit() - 1.0), z]
            })
            .collect()
    }

    #[test]
    fn a_sloping_banked_road_is_fitted_through_outliers() {
        let road = RoadPlane {
            height: 0.05,
            slope_z: 0.02,
            slope_x: -0.03,
        };
        let mut points = road_points(&road, 150, 0.03, 7);
        // A car's lower part at 12 m (0.2-0.5 m above the road) and stray matches.
        points
            .extend((0..40).map(|i| [0.5, road.road_y(0.5, 12.0) + 0.2 + 0.0075 * i as f64, 12.0]));
        points.extend([[0.0, -0.45, 20.0], [1.0, 0.48, 8.0], [-2.0, 0.4, 25.0]]);
        let f = fit(&points, &RoadPlane::FLAT, 0.1).expect("fit");
        assert!((f.plane.height - road.height).abs() < 0.03, "{f:?}");
        assert!((f.plane.slope_z - road.slope_z).abs() < 0.003, "{f:?}");
        assert!((f.plane.slope_x - road.slope_x).abs() < 0.01, "{f:?}");
        assert!((145..=160).contains(&f.inliers), "{f:?}");
    }

    #[test]
    fn too_few_points_fall_back_to_the_prior_and_say_so() {
        let prior = RoadPlane {
            height: 0.01,
            ..RoadPlane::FLAT
        };
        let e = RoadEstimator::new(RoadConfig::default(), prior);
        let few = road_points(&RoadPlane::FLAT, 10, 0.01, 3);
        let next = e.next(fit(&few, &prior, 0.1));
        assert_eq!(next.source, RoadSource::PriorFallback);
        assert_eq!(next.plane, prior);
        assert_eq!(next.inliers, 10);
        assert_eq!(e.next(None).source, RoadSource::PriorFallback);
        assert_eq!(fit(&few[..2], &prior, 0.1), None);
    }

    #[test]
    fn a_fit_beyond_the_bounds_is_clamped_and_smoothed() {
        let mut e = RoadEstimator::new(RoadConfig::default(), RoadPlane::FLAT);
        // A 12 % climb: beyond the 8 % bound.
        let steep = RoadPlane {
            slope_z: 0.12,
            ..RoadPlane::FLAT
        };
        let points = road_points(&steep, 100, 0.0, 11);
        let first = e.next(fit(&points, &steep, 0.1));
        assert_eq!(first.source, RoadSource::Bounded);
        // Half of the way from the prior to the bound.
        assert!((first.plane.slope_z - 0.04).abs() < 1e-9, "{first:?}");
        e.estimate = first;
        let second = e.next(fit(&points, &steep, 0.1));
        assert!((second.plane.slope_z - 0.06).abs() < 1e-9, "{second:?}");
    }

    #[test]
    fn a_config_that_cannot_work_is_named() {
        let bad = RoadConfig {
            gain: 0.0,
            ..RoadConfig::default()
        };
        assert_eq!(bad.validate().map_err(|e| e.key), Err("road.gain"));
        assert_eq!(RoadConfig::default().validate(), Ok(()));
    }
}
