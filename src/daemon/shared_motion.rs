//! The vehicle's motion as the control thread trusts it, for the evolution thread: one atomic
//! word (speed and yaw rate as two `f32`), written every control turn, read on each new pair.
//! Lock-free: neither thread ever waits for the other.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use flyd_core::kinematics::VehicleMotion;

/// The word of "not known" (a NaN speed).
const UNKNOWN: u64 = (f32::NAN.to_bits() as u64) << 32;

/// The latest trusted motion, or none.
#[derive(Debug, Clone)]
pub struct SharedMotion(Arc<AtomicU64>);

impl Default for SharedMotion {
    fn default() -> Self {
        Self(Arc::new(AtomicU64::new(UNKNOWN)))
    }
}

impl SharedMotion {
    pub fn publish(&self, motion: Option<VehicleMotion>) {
        let word = motion.map_or(UNKNOWN, |m| {
            (u64::from((m.speed as f32).to_bits()) << 32) | u64::from((m.yaw_rate as f32).to_bits())
        });
        self.0.store(word, Ordering::Relaxed);
    }

    pub fn get(&self) -> Option<VehicleMotion> {
        let word = self.0.load(Ordering::Relaxed);
        let speed = f32::from_bits((word >> 32) as u32);
        let yaw_rate = f32::from_bits(word as u32);
        (speed.is_finite() && yaw_rate.is_finite()).then(|| VehicleMotion {
            speed: f64::from(speed),
            yaw_rate: f64::from(yaw_rate),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publishes_and_forgets() {
        let s = SharedMotion::default();
        assert_eq!(s.get(), None);
        s.publish(Some(VehicleMotion {
            speed: 8.25,
            yaw_rate: -0.125,
        }));
        assert_eq!(
            s.clone().get(),
            Some(VehicleMotion {
                speed: 8.25,
                yaw_rate: -0.125
            })
        );
        s.publish(None);
        assert_eq!(s.get(), None);
    }
}
