//! Where the left image changed between frames: the map guided immigration draws from.
//!
//! The paper's immigration explores the whole search space uniformly, so a pedestrian stepping
//! into a converged scene is found only by chance (about one useful immigrant per generation at
//! 5000 flies). An obstacle that appears changes the image where it appears, so immigrants are
//! drawn preferentially in the 16x16 blocks whose mean luma changed by more than the sensor
//! noise. The evidence decays by half per frame, so a change keeps attracting immigrants for a
//! few frames. With no change (a static scene, a still frame) the map is empty and immigration
//! is uniform. O(blocks) per frame, O(log blocks) per draw, no allocation.
//!
//! While the vehicle moves, every block changes: the road flows towards the cameras. With the
//! vehicle's motion between the frames ([`super::Engine::predict`]), each block showing the
//! road ([`EgoFlow`]: its centre's ray meets the road plane) is compared with the previous
//! frame's means where that patch of road was (bilinear between block centres), not with the
//! same block: the road that only moved is no change, what stands on it or crossed it is.
//! Blocks above the road (roadside, sky) are compared in place, as without motion.

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
        self.update_from(means, None);
    }

    /// Blocks per row and per column.
    pub(crate) fn blocks(&self) -> (usize, usize) {
        (self.wide, self.previous.len() / self.wide.max(1))
    }

    /// The previous frame's mean luma at fractional block coordinates (block centres at whole
    /// numbers), `None` outside the grid.
    pub(crate) fn previous_at(&self, bx: f32, by: f32) -> Option<f32> {
        let (wide, high) = self.blocks();
        if !(bx >= 0.0 && by >= 0.0 && self.primed) {
            return None;
        }
        let (x0, y0) = (bx.floor() as usize, by.floor() as usize);
        if x0 + 1 >= wide || y0 + 1 >= high {
            return None;
        }
        let (fx, fy) = (bx - x0 as f32, by - y0 as f32);
        let at = |x: usize, y: usize| f32::from(self.previous[y * wide + x]);
        let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1, y0) * fx;
        let bottom = at(x0, y0 + 1) * (1.0 - fx) + at(x0 + 1, y0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }

    /// [`ChangeMap::update`], each block compared with `predicted[block]` (the previous
    /// frame's mean where its content was) where that is finite.
    pub(crate) fn update_from(&mut self, means: &[u8], predicted: Option<&[f32]>) {
        if means.len() != self.previous.len()
            || predicted.is_some_and(|p| p.len() != self.previous.len())
        {
            return;
        }
        let mut acc = 0.0;
        for (i, ((w, c), (&now, prev))) in self
            .weight
            .iter_mut()
            .zip(self.cdf.iter_mut())
            .zip(means.iter().zip(self.previous.iter_mut()))
            .enumerate()
        {
            let before = predicted
                .map(|p| p[i])
                .filter(|v| v.is_finite())
                .unwrap_or(*prev as f32);
            let d = if self.primed {
                ((now as f32 - before).abs() - NOISE).max(0.0)
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

/// Where each block's content was one vehicle motion ago, for the blocks that show the road:
/// the rays of the block centres (vehicle frame), and the previous means sampled there.
#[derive(Debug, Clone)]
pub(crate) struct EgoFlow {
    rays: Vec<Option<([f32; 3], [f32; 3])>>,
    predicted: Vec<f32>,
}

/// Road farther than this is not compensated (its flow is under a pixel a frame anyway).
const FLOW_MAX_RANGE: f32 = 60.0;

impl EgoFlow {
    /// The rays of `camera`'s block centres.
    pub(crate) fn new(camera: &crate::geometry::Camera, map: &ChangeMap) -> Self {
        let (wide, high) = map.blocks();
        let (w, h) = (camera.width() as f64, camera.height() as f64);
        let mut rays = Vec::with_capacity(wide * high);
        for by in 0..high {
            for bx in 0..wide {
                let u = ((bx * BLOCK) as f64 + 0.5 * BLOCK as f64 - 0.5).min(w - 1.0);
                let v = ((by * BLOCK) as f64 + 0.5 * BLOCK as f64 - 0.5).min(h - 1.0);
                rays.push(camera.ray_from_pixel(u, v).map(|(o, d)| {
                    (
                        [o.x as f32, o.y as f32, o.z as f32],
                        [d.x as f32, d.y as f32, d.z as f32],
                    )
                }));
            }
        }
        Self {
            predicted: vec![f32::NAN; rays.len()],
            rays,
        }
    }

    /// For every block that shows `road`, the previous frame's mean where its patch of road
    /// was before the vehicle drove `travelled` metres turning `turned` radians; NaN for the
    /// others. `project` maps a vehicle-frame point to the left image.
    pub(crate) fn predict(
        &mut self,
        map: &ChangeMap,
        road: [f32; 3],
        travelled: f64,
        turned: f64,
        project: impl Fn(f32, f32, f32) -> Option<(f32, f32)>,
    ) -> &[f32] {
        let [height, slope_z, slope_x] = road;
        let ego = crate::kinematics::EgoTransform::new(travelled, turned);
        let block = BLOCK as f32;
        for (out, ray) in self.predicted.iter_mut().zip(&self.rays) {
            *out = f32::NAN;
            let Some(([ox, oy, oz], [dx, dy, dz])) = *ray else {
                continue;
            };
            // y = height + slope_z z + slope_x x along o + t d.
            let denom = dy - slope_z * dz - slope_x * dx;
            let t = (height + slope_z * oz + slope_x * ox - oy) / denom;
            let (x, y, z) = (ox + t * dx, oy + t * dy, oz + t * dz);
            if !(t > 0.0 && z > 0.0 && z < FLOW_MAX_RANGE) {
                continue;
            }
            // The inverse of Engine::predict: where this point of the road was.
            let (px, pz) = ego.invert(x, z);
            if let Some((u, v)) = project(px, y, pz) {
                *out = map
                    .previous_at((u + 0.5) / block - 0.5, (v + 0.5) / block - 0.5)
                    .unwrap_or(f32::NAN);
            }
        }
        &self.predicted
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

    #[test]
    fn a_block_compared_where_its_content_was_is_no_change() {
        let mut m = ChangeMap::new(64, 48); // 4 x 3 blocks
        let before: Vec<u8> = (0..12).map(|i| 40 + 10 * i as u8).collect();
        m.update(&before);
        // Between block centres: bilinear.
        assert_eq!(m.previous_at(0.5, 0.0), Some(45.0));
        assert_eq!(m.previous_at(1.0, 1.5), Some(110.0));
        assert_eq!(m.previous_at(3.0, 0.0), None, "no right neighbour");
        assert_eq!(m.previous_at(-0.1, 0.0), None);
        // The image shifted by one block to the left: each block shows its right neighbour's
        // content. In place that is change everywhere; compared where it was, none.
        let shifted: Vec<u8> = (0..12)
            .map(|i| if i % 4 == 3 { before[i] } else { before[i + 1] })
            .collect();
        let mut a = m.clone();
        a.update(&shifted);
        assert!(a.total > 0.0);
        let predicted: Vec<f32> = (0..12)
            .map(|i| {
                if i % 4 == 3 {
                    f32::NAN
                } else {
                    f32::from(before[i + 1])
                }
            })
            .collect();
        m.update_from(&shifted, Some(&predicted));
        assert_eq!(m.total, 0.0);
    }
}
