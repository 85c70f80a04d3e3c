//! A plane sweep along a grid of rays: for left-image blocks spread over a band of heights
//! (the road's), the fittest depth of each ray and how unique it is.
//!
//! The population goes where the fitness is high, and the paper's fitness rewards strong
//! edges: a population evolved on the road settles on lane-marking tips and shadow edges and
//! leaves the asphalt bare, so a plane fitted to it follows a few places, some of them false
//! matches. The sweep instead looks at every part of the band evenly: the 16x16 blocks of the
//! left image whose centre ray crosses the band inside the depth range and the lateral bound
//! are taken evenly (at most `rays` of them); in each, the strongest gradient of four points
//! gives the ray; `steps` depths spread evenly in disparity over the ray's span of the band
//! are evaluated, then 8 more over the two steps around the fittest. Its ambiguity, as for
//! flies ([`super::uniqueness`]), is the best fitness more than 2 pixels of disparity away
//! over its own. This room owns the batch of probes.

use super::fitness::Kernel;
use super::immigration::Context;
use super::sampler::lerp;
use super::{Engine, EngineError, Population};
use crate::frame::StereoFrame;
use crate::road_plane::RoadPlane;

/// What to sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sweep {
    /// The band: heights above `road`, metres.
    pub heights: (f64, f64),
    pub road: RoadPlane,
    /// Depths along the left camera's axis, metres.
    pub depths: (f64, f64),
    /// Rays whose point at the middle of their span lies farther from the centre line than
    /// this are not swept, metres.
    pub half_width: f64,
    /// Rays at most.
    pub rays: usize,
    /// Depths per ray in the first stage.
    pub steps: usize,
}

/// The fittest point of one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepPoint {
    /// Vehicle frame, metres.
    pub point: [f32; 3],
    /// Its fitness (the paper's, no region of interest).
    pub fitness: f32,
    /// The best fitness more than 2 px of disparity away, over `fitness` (infinite when it
    /// has none).
    pub ambiguity: f32,
    /// Its left-image projection, pixels.
    pub u: f32,
    pub v: f32,
}

/// Second-stage depths around the fittest of the first.
const REFINE: usize = 8;
/// Disparity within which another depth is the same match.
const SAME_MATCH_PX: f32 = 2.0;

/// The batch of probes, sized once.
#[derive(Debug, Clone)]
pub(super) struct Sweeps {
    batch: Population,
    /// Per ray: normalised left coordinates, inverse-depth span.
    rays: Vec<[f32; 4]>,
    /// Blocks whose centre ray crosses the band (indices into the sampler's blocks).
    eligible: Vec<u32>,
    pixels_per_inverse_depth: f32,
}

impl Sweeps {
    /// Room for `points` probes at a time over `blocks` blocks of the left image, for a rig
    /// of `pixels_per_inverse_depth` = f B.
    pub(super) fn new(points: usize, blocks: usize, pixels_per_inverse_depth: f64) -> Self {
        Self {
            batch: Population::with_len(points),
            rays: Vec::with_capacity(points / REFINE),
            eligible: Vec::with_capacity(blocks),
            pixels_per_inverse_depth: pixels_per_inverse_depth as f32,
        }
    }

    pub(super) fn capacity(&self) -> usize {
        self.batch.len()
    }
}

impl Engine {
    /// Sweeps `sweep`'s band on `frame` (the frame of the latest [`Engine::step`]) and puts
    /// one point per swept ray into `out` (cleared first; it allocates only if its capacity
    /// is below `sweep.rays`). At most [`Engine::sweep_capacity`] probes are evaluated at once:
    /// `rays * steps` beyond it sweeps fewer rays.
    pub fn sweep(
        &mut self,
        frame: &StereoFrame,
        sweep: &Sweep,
        out: &mut Vec<SweepPoint>,
    ) -> Result<(), EngineError> {
        self.check_frame(frame)?;
        out.clear();
        let steps = sweep.steps.max(2);
        let s = &mut self.sweeps;
        let wanted = sweep.rays.min(s.capacity() / steps).min(s.rays.capacity());
        let sampler = &self.setup.sampler;
        let inv = (1.0 / sweep.depths.1 as f32, 1.0 / sweep.depths.0 as f32);
        let heights = Some((sweep.heights.0 as f32, sweep.heights.1 as f32));
        let road = sweep.road.coefficients();
        let half = sweep.half_width as f32;
        let eligible = |b: &[f32; 4]| {
            let (xn, yn) = ((b[0] + b[1]) / 2.0, (b[2] + b[3]) / 2.0);
            let span = sampler.ray_range_in(xn, yn, inv, heights, road)?;
            let mid = sampler.at(xn, yn, 1.0 / lerp(span, 0.5));
            (mid[0].abs() <= half).then_some(span)
        };
        // The eligible blocks, once; then `k` of them evenly, each through its strongest
        // gradient.
        s.eligible.clear();
        s.eligible.extend(
            sampler
                .blocks
                .iter()
                .enumerate()
                .filter(|(_, b)| eligible(b).is_some())
                .map(|(i, _)| i as u32),
        );
        let n = s.eligible.len();
        if n == 0 || wanted == 0 {
            return Ok(());
        }
        let kernel = Kernel::new(frame, &self.setup.params, &RoadPlane::FLAT).without_roi();
        s.rays.clear();
        let k = wanted.min(n);
        for j in 0..k {
            let Some(b) = sampler.blocks.get(s.eligible[j * n / k] as usize) else {
                continue;
            };
            let mut best = (0u8, (b[0] + b[1]) / 2.0, (b[2] + b[3]) / 2.0);
            for (fx, fy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                let (xn, yn) = (lerp((b[0], b[1]), fx), lerp((b[2], b[3]), fy));
                let p = sampler.at(xn, yn, 1.0);
                let g = self
                    .setup
                    .left
                    .project(p[0], p[1], p[2])
                    .map_or(0, |(u, v)| kernel.left_gradient(u, v));
                if g > best.0 {
                    best = (g, xn, yn);
                }
            }
            let (_, xn, yn) = best;
            if let Some((i0, i1)) = sampler.ray_range_in(xn, yn, inv, heights, road) {
                s.rays.push([xn, yn, i0, i1]);
            }
        }
        let rays = s.rays.len();
        // Stage 1: `steps` depths per ray, evenly in inverse depth (in disparity).
        for (j, &[xn, yn, i0, i1]) in s.rays.iter().enumerate() {
            for q in 0..steps {
                let t = (q as f32 + 0.5) / steps as f32;
                let p = sampler.at(xn, yn, 1.0 / lerp((i0, i1), t));
                let at = j * steps + q;
                (s.batch.x[at], s.batch.y[at], s.batch.z[at]) = (p[0], p[1], p[2]);
            }
        }
        let at = Context::of(&self.setup, &self.change, &self.sharing, &kernel, self.isa);
        at.evaluate(&mut s.batch, 0..rays * steps, &mut self.scratch);
        // Per ray: the fittest step, its ambiguity against the steps more than 2 px away.
        for (j, &[_, _, i0, i1]) in s.rays.iter().enumerate() {
            let fit = &s.batch.raw_fitness[j * steps..(j + 1) * steps];
            let (best, f) = fit
                .iter()
                .enumerate()
                .fold((0, 0.0f32), |a, (q, &v)| if v > a.1 { (q, v) } else { a });
            let step_px = (i1 - i0) / steps as f32 * s.pixels_per_inverse_depth;
            let apart = (SAME_MATCH_PX / step_px.max(1e-6)).ceil() as usize;
            let other = fit
                .iter()
                .enumerate()
                .filter(|&(q, _)| q.abs_diff(best) > apart)
                .fold(0.0f32, |a, (_, &v)| a.max(v));
            let ambiguity = if f > 0.0 { other / f } else { f32::INFINITY };
            let at = j * steps + best;
            out.push(SweepPoint {
                point: [s.batch.x[at], s.batch.y[at], s.batch.z[at]],
                fitness: f,
                ambiguity,
                u: s.batch.u_left[at],
                v: s.batch.v_left[at],
            });
        }
        // Stage 2, over the two steps around each ray's fittest (once every ray's stage 1 was
        // read: the slots are reused).
        for (j, &[xn, yn, i0, i1]) in s.rays.iter().enumerate() {
            let best_t = {
                let p = &out[j].point;
                let d = sampler.depth_of(p);
                let inv_d = if d > 0.0 { 1.0 / d } else { i0 };
                ((inv_d - i0) / (i1 - i0).max(1e-12)).clamp(0.0, 1.0)
            };
            for q in 0..REFINE {
                let t = best_t + ((q as f32 + 0.5) / REFINE as f32 - 0.5) * 2.0 / steps as f32;
                let p = sampler.at(xn, yn, 1.0 / lerp((i0, i1), t.clamp(0.0, 1.0)));
                let at = j * REFINE + q;
                (s.batch.x[at], s.batch.y[at], s.batch.z[at]) = (p[0], p[1], p[2]);
            }
        }
        at.evaluate(&mut s.batch, 0..rays * REFINE, &mut self.scratch);
        for (j, o) in out.iter_mut().enumerate() {
            let fit = &s.batch.raw_fitness[j * REFINE..(j + 1) * REFINE];
            let (best, f) = fit
                .iter()
                .enumerate()
                .fold((0, 0.0f32), |a, (q, &v)| if v > a.1 { (q, v) } else { a });
            if f > o.fitness {
                let at = j * REFINE + best;
                o.ambiguity *= o.fitness / f;
                o.fitness = f;
                o.point = [s.batch.x[at], s.batch.y[at], s.batch.z[at]];
                (o.u, o.v) = (s.batch.u_left[at], s.batch.v_left[at]);
            }
        }
        Ok(())
    }

    /// The paper's fitness (no region of interest) of vehicle-frame `points` on `frame` (the
    /// frame of the latest [`Engine::step`]) into `out`, at most [`Engine::sweep_capacity`] of
    /// them; returns how many. For measurements (where a predicted point matches best); the
    /// population is not touched.
    pub fn evaluate_points(
        &mut self,
        frame: &StereoFrame,
        points: &[[f32; 3]],
        out: &mut [f32],
    ) -> Result<usize, EngineError> {
        self.check_frame(frame)?;
        let s = &mut self.sweeps;
        let n = points.len().min(out.len()).min(s.capacity());
        for (k, p) in points[..n].iter().enumerate() {
            (s.batch.x[k], s.batch.y[k], s.batch.z[k]) = (p[0], p[1], p[2]);
        }
        let kernel = Kernel::new(frame, &self.setup.params, &RoadPlane::FLAT).without_roi();
        let at = Context::of(&self.setup, &self.change, &self.sharing, &kernel, self.isa);
        at.evaluate(&mut s.batch, 0..n, &mut self.scratch);
        out[..n].copy_from_slice(&s.batch.raw_fitness[..n]);
        Ok(n)
    }

    /// Probes one [`Engine::sweep`] evaluates at once, at most.
    pub fn sweep_capacity(&self) -> usize {
        self.sweeps.capacity()
    }
}
