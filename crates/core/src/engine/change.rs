//! Where the left image changed between frames: the map guided immigration draws from.
//!
//! The paper's immigration explores the whole search space uniformly, so a pedestrian stepping
//! into a converged scene is found only by chance (about one useful immigrant per generation at
//! 5000 flies). An obstacle that appears changes the image where it appears, so immigrants are
//! drawn preferentially in the 16x16 blocks whose mean luma changed by more than the sensor
//! noise. The evidence decays by half per frame, so a change keeps attracting immigrants for a
//! few frames. With no change (a static scene, a still frame) the map is empty and immigration
//! is uniform. O(blocks) per frame, O(log blocks) per draw, no allocation.

use crate::frame::BLOCK;

/// Mean-luma change below this (grey levels of the normalised image) is noise.
const NOISE: f32 = 3.0;
/// Fraction of the change evidence kept from one frame to the next.
const DECAY: f32 = 0.5;

#[derive(Debug, Clone)]
pub(crate) struct ChangeMap {
    previous: Vec<u8>,
    weight: Vec<f32>,
    cdf: Vec<f32>,
    pub(crate) total: f32,
    primed: bool,
    /// Blocks per row.
    wide: usize,
}

impl ChangeMap {
    pub(crate) fn new(width: u32, height: u32) -> Self {
        let blocks = (width as usize).div_ceil(BLOCK) * (height as usize).div_ceil(BLOCK);
        Self {
            previous: vec![0; blocks],
            weight: vec![0.0; blocks],
            cdf: vec![0.0; blocks],
            total: 0.0,
            primed: false,
            wide: (width as usize).div_ceil(BLOCK),
        }
    }

    /// Takes the block means of a new left frame.
    pub(crate) fn update(&mut self, means: &[u8]) {
        if means.len() != self.previous.len() {
            return;
        }
        let mut acc = 0.0;
        for ((w, c), (&now, prev)) in self
            .weight
            .iter_mut()
            .zip(self.cdf.iter_mut())
            .zip(means.iter().zip(self.previous.iter_mut()))
        {
            let d = if self.primed {
                ((now as f32 - *prev as f32).abs() - NOISE).max(0.0)
            } else {
                0.0
            };
            *w = d.max(*w * DECAY);
            if *w < 0.5 {
                *w = 0.0;
            }
            acc += *w;
            *c = acc;
            *prev = now;
        }
        self.total = acc;
        self.primed = true;
    }

    /// Whether left pixel `(u, v)` lies in a block that changed (false outside the image or for
    /// NaN).
    #[inline]
    pub(crate) fn changed_at(&self, u: f32, v: f32) -> bool {
        if !(u >= 0.0 && v >= 0.0) {
            return false;
        }
        let (bx, by) = (u as usize / BLOCK, v as usize / BLOCK);
        bx < self.wide
            && self
                .weight
                .get(by * self.wide + bx)
                .is_some_and(|&w| w > 0.0)
    }

    /// A block drawn in proportion to its change weight, from `u` uniform in [0, 1).
    pub(crate) fn pick(&self, u: f32) -> usize {
        let target = u * self.total;
        self.cdf
            .partition_point(|&c| c <= target)
            .min(self.cdf.len().saturating_sub(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_only_where_the_image_changed_then_forgets() {
        let mut m = ChangeMap::new(64, 32); // 4 x 2 blocks
        m.update(&[100; 8]);
        assert_eq!(m.total, 0.0, "the first frame has nothing to compare with");
        let mut next = [100u8; 8];
        next[5] = 140;
        next[2] = 101; // below the noise
        m.update(&next);
        assert!(m.total > 0.0);
        for k in 0..100 {
            assert_eq!(m.pick(k as f32 / 100.0), 5);
        }
        // Unchanged frames: the evidence halves each frame, then is gone.
        for _ in 0..8 {
            m.update(&next);
        }
        assert_eq!(m.total, 0.0);
    }
}
