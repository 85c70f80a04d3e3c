//! The vehicle's own motion, as kinematics: its speed and yaw rate ([`VehicleMotion`]) and how
//! a static point moves in the vehicle frame while it drives ([`EgoTransform`]), what the
//! engine's prediction and the obstacle tracking need.
//!
//! Where the motion comes from is not this module's concern: the vehicle's `VCU_Motion` frames
//! are decoded and checked before they are trusted in [`crate::can::motion_monitor`].

/// The vehicle's motion in flyd's vehicle frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleMotion {
    /// Forward speed, m/s (negative = reversing).
    pub speed: f64,
    /// Yaw rate, rad/s, positive turning left.
    pub yaw_rate: f64,
}

impl VehicleMotion {
    pub const STANDSTILL: Self = Self {
        speed: 0.0,
        yaw_rate: 0.0,
    };
}

/// How a static point moves in the vehicle frame when the vehicle drives `travelled` metres
/// along an arc turning `turned` radians (left positive): `p' = R(-turned) (p - t)`, `t` the
/// chord at half the turn. Rotation about the vehicle frame's vertical axis through its origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EgoTransform {
    tx: f32,
    tz: f32,
    sin: f32,
    cos: f32,
}

impl EgoTransform {
    pub fn new(travelled: f64, turned: f64) -> Self {
        let (half_sin, half_cos) = (0.5 * turned).sin_cos();
        let (sin, cos) = turned.sin_cos();
        Self {
            tx: (-travelled * half_sin) as f32,
            tz: (travelled * half_cos) as f32,
            sin: sin as f32,
            cos: cos as f32,
        }
    }

    /// Where static point (x, z) is after the motion.
    #[inline]
    pub fn apply(&self, x: f32, z: f32) -> (f32, f32) {
        let (qx, qz) = (x - self.tx, z - self.tz);
        (qx * self.cos + qz * self.sin, qz * self.cos - qx * self.sin)
    }

    /// Where point (x, z) was before the motion.
    #[inline]
    pub fn invert(&self, x: f32, z: f32) -> (f32, f32) {
        let (qx, qz) = (x * self.cos - z * self.sin, x * self.sin + z * self.cos);
        (qx + self.tx, qz + self.tz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ego_transform_inverts() {
        let t = EgoTransform::new(1.5, 0.2);
        let (x, z) = t.apply(2.0, 10.0);
        let (bx, bz) = t.invert(x, z);
        assert!((bx - 2.0).abs() < 1e-5 && (bz - 10.0).abs() < 1e-5);
        // Straight on: 1.5 m nearer.
        assert_eq!(EgoTransform::new(1.5, 0.0).apply(0.0, 10.0), (0.0, 8.5));
    }
}
