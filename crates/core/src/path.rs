//! The vehicle's predicted path on the road: the arc its speed and yaw rate describe, from
//! where it is now, tangent to its heading (what an AEB function checks obstacles along, as
//! Autoware's `autonomous_emergency_braking` does). The obstacle stage locates each fly in
//! the path's coordinates: its distance along the path and its offset from it.
//!
//! Vehicle frame: x right, z ahead; yaw rate positive turning left ([`VehicleMotion`]).

use crate::motion::VehicleMotion;

/// The tightest the path bends, 1/m: a 5 m radius, about a car's turning circle. A larger
/// curvature (a yaw rate at walking pace, a noisy one at standstill) is clamped to it.
pub const MAX_CURVATURE: f64 = 0.2;

/// Below this speed (m/s, either way) the path is straight: the yaw rate over a near-zero
/// speed says nothing of where the vehicle goes over its (short) stopping distance.
pub const MIN_SPEED: f64 = 1.0;

/// An arc of constant curvature from the vehicle frame's origin, tangent to +z.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct PredictedPath {
    /// 1/m, positive turning left; 0: straight ahead.
    pub curvature: f64,
}

impl PredictedPath {
    pub const STRAIGHT: Self = Self { curvature: 0.0 };

    /// The path `motion` describes: curvature = yaw rate / speed, within
    /// `-MAX_CURVATURE..=MAX_CURVATURE`; straight below [`MIN_SPEED`] or for a non-finite
    /// motion.
    pub fn of_motion(motion: VehicleMotion) -> Self {
        let k = motion.yaw_rate / motion.speed;
        if motion.speed.abs() < MIN_SPEED || !k.is_finite() {
            return Self::STRAIGHT;
        }
        Self {
            curvature: k.clamp(-MAX_CURVATURE, MAX_CURVATURE),
        }
    }

    /// Whether the path is straight ahead (then [`PredictedPath::locate`] is `(z, x)` exactly).
    pub fn is_straight(&self) -> bool {
        self.curvature == 0.0
    }

    /// The path's point `along` metres from the vehicle (x, z).
    pub fn point(&self, along: f64) -> (f64, f64) {
        let k = self.curvature;
        if k == 0.0 {
            return (0.0, along);
        }
        let (sin, cos) = (k * along).sin_cos();
        // Left (k > 0) bends towards -x.
        (-(1.0 - cos) / k, sin / k)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_straight_path_is_the_vehicle_frame_bit_for_bit() {
        let p = PredictedPath::STRAIGHT;
        for (x, z) in [(0.3f32, 12.7f32), (-1.1, 0.5), (0.0, 40.0), (1e-7, 3.3)] {
            let (along, offset) = p.locate(x, z);
            assert_eq!(
                (along.to_bits(), offset.to_bits()),
                (z.to_bits(), x.to_bits())
            );
        }
        assert_eq!(p.point(7.0), (0.0, 7.0));
    }

    #[test]
    fn points_on_and_beside_an_arc_are_located_on_it() {
        // A left bend of 50 m radius and a right one of 120 m.
        for k in [0.02, -1.0 / 120.0] {
            let p = PredictedPath { curvature: k };
            for s in [0.5, 10.0, 23.0, 41.0] {
                let (x, z) = p.point(s);
                let (along, offset) = p.locate(x as f32, z as f32);
                assert!((f64::from(along) - s).abs() < 1e-3, "k {k}: {along} vs {s}");
                assert!(offset.abs() < 1e-3, "k {k} at {s}: offset {offset}");
                // 1.5 m to the right of the path, along its normal: the heading there is
                // (-sin, cos) of k s, its right (cos, sin).
                let (sin, cos) = (k * s).sin_cos();
                let (xr, zr) = (x + 1.5 * cos, z + 1.5 * sin);
                let (along, offset) = p.locate(xr as f32, zr as f32);
                assert!((f64::from(along) - s).abs() < 1e-3, "k {k}: {along} vs {s}");
                assert!((offset - 1.5).abs() < 1e-3, "k {k} at {s}: offset {offset}");
            }
        }
    }

    #[test]
    fn on_a_bend_the_straight_box_and_the_path_disagree() {
        // 20 m ahead on a 100 m left bend the path is 2 m left of the straight line: a car
        // there is on the path, what stands straight ahead is 2 m right of it.
        let p = PredictedPath { curvature: 0.01 };
        let (x, z) = p.point(20.0);
        assert!(
            (x + 2.0).abs() < 0.05 && (z - 19.87).abs() < 0.05,
            "{x} {z}"
        );
        let (_, offset) = p.locate(0.0, 20.0);
        assert!((offset - 2.0).abs() < 0.05, "{offset}");
    }

    #[test]
    fn the_path_of_a_motion() {
        let m = |speed, yaw_rate| PredictedPath::of_motion(VehicleMotion { speed, yaw_rate });
        assert_eq!(m(10.0, 0.1).curvature, 0.01);
        assert_eq!(m(10.0, -0.1).curvature, -0.01);
        assert_eq!(m(10.0, 0.0), PredictedPath::STRAIGHT);
        // Walking pace, standstill, nonsense: straight.
        assert_eq!(m(0.5, 0.3), PredictedPath::STRAIGHT);
        assert_eq!(m(0.0, 0.3), PredictedPath::STRAIGHT);
        assert_eq!(m(f64::NAN, 0.1), PredictedPath::STRAIGHT);
        assert_eq!(m(10.0, f64::INFINITY), PredictedPath::STRAIGHT);
        // Never tighter than a car turns.
        assert_eq!(m(2.0, 1.0).curvature, MAX_CURVATURE);
        assert_eq!(m(2.0, -1.0).curvature, -MAX_CURVATURE);
    }
}
