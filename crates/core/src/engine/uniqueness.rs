//! How unique a fly's match is along the epipolar line.
//!
//! A fly on a horizontal edge, or on a repeated texture, matches at many depths: the paper's
//! fitness is as high a few pixels of disparity away as at the fly's own. Such a fly proves no
//! surface at its depth, so it must not count as evidence of an obstacle (nor of the road). As
//! SGBM's `uniquenessRatio` compares a pixel's best matching cost with its best elsewhere on
//! the line, [`Engine::ambiguity`] compares a fly's fitness with the best fitness of the same
//! left pixel at `SHIFTS` pixels of disparity nearer and farther: a ratio near 1 (or above)
//! means an ambiguous match, a small one a unique one. The shifted points are evaluated on the
//! current frame without the region of interest (a shifted point below the road still shows
//! whether the images match there). This room owns the batch of shifted points.

use super::fitness::Kernel;
use super::{Engine, EngineError, Population};
use crate::frame::StereoFrame;
use crate::road::RoadPlane;

/// Disparity offsets (pixels) at which a fly's left pixel is compared again.
pub const SHIFTS: [f32; 4] = [-4.0, -2.0, 2.0, 4.0];

/// The shifted copies of the flies whose ambiguity is asked for, sized once.
#[derive(Debug, Clone)]
pub(super) struct Uniqueness {
    batch: Population,
    /// Disparity (pixels) per unit of inverse depth along the left camera's axis: the right
    /// camera's focal length times the baseline.
    pixels_per_inverse_depth: f32,
}

impl Uniqueness {
    /// Room for `flies` flies at a time, for a rig whose disparity is `pixels_per_inverse_depth`
    /// pixels per m^-1.
    pub(super) fn new(flies: usize, pixels_per_inverse_depth: f64) -> Self {
        Self {
            batch: Population::with_len(flies * SHIFTS.len()),
            pixels_per_inverse_depth: pixels_per_inverse_depth as f32,
        }
    }

    /// Flies at a time.
    pub(super) fn capacity(&self) -> usize {
        self.batch.len() / SHIFTS.len()
    }
}

impl Engine {
    /// For each fly `flies[k]` of the population, `out[k]` = the best fitness of its left pixel
    /// at the [`SHIFTS`] divided by its own fitness (see the module docs): small for a unique
    /// match, near or above 1 for an ambiguous one, infinite for a fly with no fitness. `frame`
    /// must be the frame of the latest [`Engine::step`]. At most [`Engine::ambiguity_capacity`]
    /// flies are looked at (the rest of `out` is left as it is); returns how many were.
    pub fn ambiguity(
        &mut self,
        frame: &StereoFrame,
        flies: &[u32],
        out: &mut [f32],
    ) -> Result<usize, EngineError> {
        self.check_frame(frame)?;
        let n = flies.len().min(out.len()).min(self.uniqueness.capacity());
        let (pop, u, sampler) = (&self.pop, &mut self.uniqueness, &self.setup.sampler);
        let k = u.pixels_per_inverse_depth;
        let mut filled = 0;
        for &i in &flies[..n] {
            let i = (i as usize).min(pop.len().saturating_sub(1));
            let p = [pop.x[i], pop.y[i], pop.z[i]];
            let depth = sampler.depth_of(&p);
            for (j, s) in SHIFTS.iter().enumerate() {
                // Disparity + s along the left pixel's ray: 1/depth + s/k.
                let inv = 1.0 / depth + s / k;
                let scale = if depth > 0.0 && inv > 0.0 {
                    1.0 / (inv * depth)
                } else {
                    f32::NAN
                };
                let q = sampler.along_ray(&p, scale);
                let at = filled * SHIFTS.len() + j;
                (u.batch.x[at], u.batch.y[at], u.batch.z[at]) = (q[0], q[1], q[2]);
            }
            filled += 1;
        }
        let kernel = Kernel::new(frame, &self.setup.params, &RoadPlane::FLAT).without_roi();
        kernel.evaluate(
            self.isa,
            &self.setup.left,
            &self.setup.right,
            &mut u.batch,
            0..filled * SHIFTS.len(),
            &self.sharing,
            &mut self.scratch,
        );
        for (k, &i) in flies[..n].iter().enumerate() {
            let own = self.pop.raw_fitness[(i as usize).min(self.pop.len().saturating_sub(1))];
            let shifted = &u.batch.raw_fitness[k * SHIFTS.len()..(k + 1) * SHIFTS.len()];
            let best = shifted.iter().copied().fold(0.0f32, f32::max);
            out[k] = if own > 0.0 { best / own } else { f32::INFINITY };
        }
        Ok(n)
    }

    /// How many flies one [`Engine::ambiguity`] call looks at.
    pub fn ambiguity_capacity(&self) -> usize {
        self.uniqueness.capacity()
    }
}
