//! The road surface as flyd measures it: a plane in the vehicle frame.
//!
//! The calibration places the cameras above a road at y = 0 (the prior). Real roads slope
//! (0.5-2.5 % on the KITTI pairs) and bank (1-4 %), which lifts the road 0.1-0.3 m above that
//! plane 10-15 m ahead: road a fixed model would call an obstacle. So heights, for the region
//! of interest and for obstacles, are measured from a [`RoadPlane`] that the road estimator
//! ([`crate::perception`]) fits to the scene on every frame, within bounds around the prior.

use serde::Serialize;

/// The road surface: its height `y = height + slope_z z + slope_x x` (metres) at vehicle-frame
/// point (x, z). The prior, [`RoadPlane::FLAT`], is y = 0.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RoadPlane {
    /// Height of the road under the vehicle origin, metres.
    pub height: f64,
    /// Rise per metre ahead (a 2 % climb is 0.02).
    pub slope_z: f64,
    /// Rise per metre to the right (banking).
    pub slope_x: f64,
}

impl RoadPlane {
    /// The calibration's road: y = 0.
    pub const FLAT: RoadPlane = RoadPlane {
        height: 0.0,
        slope_z: 0.0,
        slope_x: 0.0,
    };

    /// The road's height at (x, z), metres.
    #[inline]
    pub fn road_y(&self, x: f64, z: f64) -> f64 {
        self.height + self.slope_z * z + self.slope_x * x
    }

    /// How high vehicle-frame point (x, y, z) is above this road, metres.
    #[inline]
    pub fn height_above(&self, x: f64, y: f64, z: f64) -> f64 {
        y - self.road_y(x, z)
    }

    /// The road's pitch (positive: it rises ahead), degrees.
    pub fn pitch_deg(&self) -> f64 {
        self.slope_z.atan().to_degrees()
    }

    /// The road's roll (positive: it rises to the right), degrees.
    pub fn roll_deg(&self) -> f64 {
        self.slope_x.atan().to_degrees()
    }

    /// The plane as f32 coefficients `[height, slope_z, slope_x]` (what the engine evaluates).
    pub(crate) fn coefficients(&self) -> [f32; 3] {
        [self.height as f32, self.slope_z as f32, self.slope_x as f32]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heights_are_measured_from_the_plane() {
        let road = RoadPlane {
            height: 0.05,
            slope_z: 0.02,
            slope_x: -0.01,
        };
        assert!((road.road_y(1.0, 10.0) - 0.24).abs() < 1e-12);
        assert!((road.height_above(1.0, 1.24, 10.0) - 1.0).abs() < 1e-12);
        assert!((road.pitch_deg() - 1.1457628).abs() < 1e-6);
        assert_eq!(RoadPlane::FLAT.height_above(3.0, 0.7, 40.0), 0.7);
    }
}
