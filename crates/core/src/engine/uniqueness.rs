//! How unique a fly's match is along the epipolar line.
//!
//! A fly on a horizontal edge, or on a repeated texture, matches at many depths: the paper's
//! fitness is as high a few pixels of disparity away as at the fly's own. Such a fly proves no
//! surface at its depth, so it must not count as evidence of an obstacle (nor of the road). As
//! SGBM's `uniquenessRatio` compares a pixel's best matching cost with its best elsewhere on
//! the line, [`Engine::ambiguity`] compares a fly's fitness with the best fitness of the same
//! left pixel at `SHIFTS` pixels of disparity nearer and farther: a ratio near 1 (or above)
//! means an ambiguous match, a small one a unique one. A fly whose own windows do not match
//! (per-sample SSD over a quarter of that of unrelated windows, the engine's `matched` test:
//! scene- and camera-independent) is no evidence at all, its ambiguity infinite: weak chance
//! matches of immigrants are unique within 4 px as often as not. The shifted points are
//! evaluated on the current frame without the region of interest (a shifted point below the
//! road still shows whether the images match there). This room owns the batch of shifted
//! points.

use super::fitness::Kernel;
use super::{Engine, EngineError, Population};
use crate::frame::StereoFrame;
use crate::road_plane::RoadPlane;

/// Disparity offsets (pixels) at which a fly's left pixel is compared again.
pub const SHIFTS: [f32; 4] = [-4.0, -2.0, 2.0, 4.0];

/// Points evaluated per fly: its shifts (whether it matches itself is known from its own
/// evaluation, [`Population::matched`]). All four in one batch: their windows share the
/// image rows a fly's cache misses bring in (two passes, the farther shifts only for the
/// flies the nearer ones left unique, evaluated 20 % fewer points in 30 % more time).
const PER_FLY: usize = SHIFTS.len();

/// The shifted copies of the flies whose ambiguity is asked for, sized once.
#[derive(Debug, Clone)]
pub(super) struct Uniqueness {
    batch: Population,
    /// For each fly's points in the batch, which of the asked flies (`k`) it is.
    owner: Vec<u32>,
    /// Disparity (pixels) per unit of inverse depth along the left camera's axis: the right
    /// camera's focal length times the baseline.
    pixels_per_inverse_depth: f32,
}

impl Uniqueness {
    /// Room for `flies` flies at a time, for a rig whose disparity is `pixels_per_inverse_depth`
    /// pixels per m^-1.
    pub(super) fn new(flies: usize, pixels_per_inverse_depth: f64) -> Self {
        Self {
            // Room for the points of a line too (Engine::line_ambiguity): five per fly.
            batch: Population::with_len(flies * (PER_FLY + 1)),
            owner: vec![0; flies],
            pixels_per_inverse_depth: pixels_per_inverse_depth as f32,
        }
    }

    /// Flies at a time.
    pub(super) fn capacity(&self) -> usize {
        self.owner.len()
    }
}

impl Engine {
    /// For each fly `flies[k]` of the population, `out[k]` = the best fitness of its left pixel
    /// at the [`SHIFTS`] divided by its own fitness (see the module docs): small for a unique
    /// match, near or above 1 for an ambiguous one, infinite for a fly with no fitness or
    /// whose windows do not match (not evaluated). `frame` must be the frame of the latest
    /// [`Engine::step`]. At most [`Engine::ambiguity_capacity`] flies are looked at (the rest
    /// of `out` is left as it is); returns how many were.
    pub fn ambiguity(
        &mut self,
        frame: &StereoFrame,
        flies: &[u32],
        out: &mut [f32],
    ) -> Result<usize, EngineError> {
        self.check_frame(frame)?;
        let n = flies.len().min(out.len()).min(self.uniqueness.capacity());
        let last = self.pop.len().saturating_sub(1);
        let (pop, u, sampler) = (&self.pop, &mut self.uniqueness, &self.setup.sampler);
        let k = u.pixels_per_inverse_depth;
        let mut filled = 0;
        for (j, (o, &i)) in out[..n].iter_mut().zip(&flies[..n]).enumerate() {
            let i = (i as usize).min(last);
            // A fly with no fitness, or whose windows do not match, is no evidence.
            if !(pop.raw_fitness[i] > 0.0 && pop.matched[i]) {
                *o = f32::INFINITY;
                continue;
            }
            let p = [pop.x[i], pop.y[i], pop.z[i]];
            let depth = sampler.depth_of(&p);
            for (m, s) in SHIFTS.iter().enumerate() {
                // Disparity + s along the left pixel's ray: 1/depth + s/k.
                let inv = 1.0 / depth + s / k;
                let scale = if depth > 0.0 && inv > 0.0 {
                    1.0 / (inv * depth)
                } else {
                    f32::NAN
                };
                let q = sampler.along_ray(&p, scale);
                let at = filled * PER_FLY + m;
                (u.batch.x[at], u.batch.y[at], u.batch.z[at]) = (q[0], q[1], q[2]);
            }
            u.owner[filled] = j as u32;
            filled += 1;
        }
        let kernel = Kernel::new(frame, &self.setup.params, &RoadPlane::FLAT).without_roi();
        kernel.evaluate(
            self.isa,
            &self.setup.left,
            &self.setup.right,
            &mut u.batch,
            0..filled * PER_FLY,
            &self.sharing,
            &mut self.scratch,
        );
        for (f, &j) in u.owner[..filled].iter().enumerate() {
            let own = self.pop.raw_fitness[(flies[j as usize] as usize).min(last)];
            let shifted = &u.batch.raw_fitness[f * PER_FLY..(f + 1) * PER_FLY];
            let best = shifted.iter().copied().fold(0.0f32, f32::max);
            out[j as usize] = best / own;
        }
        Ok(n)
    }

    /// For each fly `flies[k]`, `out[k]` = the best fitness along the whole epipolar line, of
    /// its left pixel and of its right pixel (every `step_px` pixels of disparity over the
    /// search range, except within 2 px of its own), over its own fitness. Where
    /// [`Engine::ambiguity`] looks 2 and 4 px away, this finds the match a repeated structure
    /// offers a period away (a pole matched with the next pole, a fence, a facade's windows);
    /// from the right pixel, it is the left-right consistency check of stereo matchers (a
    /// right pixel whose own best match is another left pixel). Costs two evaluations per
    /// `step_px` of the search range's disparity span per fly. `frame` must be the frame of
    /// the latest [`Engine::step`].
    pub fn line_ambiguity(
        &mut self,
        frame: &StereoFrame,
        flies: &[u32],
        step_px: f32,
        out: &mut [f32],
    ) -> Result<(), EngineError> {
        self.check_frame(frame)?;
        let kernel = Kernel::new(frame, &self.setup.params, &RoadPlane::FLAT).without_roi();
        let (u, sampler) = (&mut self.uniqueness, &self.setup.sampler);
        let k = u.pixels_per_inverse_depth;
        let (d0, d1) = (sampler.inv_depth.0 * k, sampler.inv_depth.1 * k);
        let step = step_px.max(0.25);
        let cap = u.batch.len();
        for (o, &i) in out.iter_mut().zip(flies) {
            let i = (i as usize).min(self.pop.len().saturating_sub(1));
            let p = [self.pop.x[i], self.pop.y[i], self.pop.z[i]];
            let own = self.pop.raw_fitness[i];
            let depth = sampler.depth_of(&p);
            let (ur, vr) = (self.pop.u_right[i], self.pop.v_right[i]);
            if !(own > 0.0 && depth > 0.0) {
                *o = f32::INFINITY;
                continue;
            }
            // The right pixel's ray: its points at depth 1 and 0 (the centre), in the vehicle
            // frame; the point at depth t is c + (p1 - c) t (rectified: one depth for both).
            let right_ray = self
                .setup
                .right_camera
                .vehicle_from_pixel_depth(f64::from(ur), f64::from(vr), 1.0)
                .map(|p1| {
                    let c = self.setup.right_camera.centre();
                    (
                        [c.x as f32, c.y as f32, c.z as f32],
                        [p1.x as f32, p1.y as f32, p1.z as f32],
                    )
                });
            let d = k / depth;
            let mut n = 0;
            let mut disparity = d0;
            while disparity <= d1 && n + 2 <= cap {
                if (disparity - d).abs() > 2.0 {
                    // Depth k / disparity on the left pixel's ray: `depth` scaled.
                    let q = sampler.along_ray(&p, d / disparity);
                    (u.batch.x[n], u.batch.y[n], u.batch.z[n]) = (q[0], q[1], q[2]);
                    n += 1;
                    if let Some((c, p1)) = right_ray {
                        let t = k / disparity;
                        let q = [0, 1, 2].map(|a| c[a] + (p1[a] - c[a]) * t);
                        (u.batch.x[n], u.batch.y[n], u.batch.z[n]) = (q[0], q[1], q[2]);
                        n += 1;
                    }
                }
                disparity += step;
            }
            kernel.evaluate(
                self.isa,
                &self.setup.left,
                &self.setup.right,
                &mut u.batch,
                0..n,
                &self.sharing,
                &mut self.scratch,
            );
            let best = u.batch.raw_fitness[..n]
                .iter()
                .copied()
                .fold(0.0f32, f32::max);
            *o = best / own;
        }
        Ok(())
    }

    /// How many flies one [`Engine::ambiguity`] call looks at.
    pub fn ambiguity_capacity(&self) -> usize {
        self.uniqueness.capacity()
    }
}
