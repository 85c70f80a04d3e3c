//! Immigration: the last `immigration_rate` of the population, new flies every generation.
//!
//! Uniform immigrants are drawn like the initial flies ([`super::sampler`]); those outside an
//! image or the road band (about a third) are redrawn in batches checked with the vectorised
//! projection. Guided immigrants (`guided_immigration` of them, on a frame that changed) go
//! where the left image changed ([`super::change`]): each takes the strongest gradient of a few
//! points of a changed block and probes depths along that ray against the current frame, one
//! per stratum of inverse depth, then two refinement stages around the fittest so far; the
//! fittest probe joins. This room owns the probes and the outsiders' list.

use super::Population;
use super::breeding::unit_threshold;
use super::change::ChangeMap;
use super::fitness::{Kernel, Matches, Scratch};
use super::lists::gather;
use super::params::EngineParams;
use super::projector::Projector;
use super::sampler::{Corridor, SAMPLE_ATTEMPTS, Sampler, lerp, unit_f32};
use super::sharing::Grid;
use crate::isa::Isa;
use rand::Rng;
use rand::rngs::Xoshiro256PlusPlus;
use std::ops::Range;

/// What the phases of a generation read from the engine (the frame's kernel included).
pub(super) struct Context<'a> {
    pub(super) params: &'a EngineParams,
    pub(super) sampler: &'a Sampler,
    pub(super) change: &'a ChangeMap,
    pub(super) left: &'a Projector,
    pub(super) right: &'a Projector,
    pub(super) sharing: &'a Grid,
    pub(super) kernel: &'a Kernel<'a>,
    pub(super) isa: Isa,
}

impl Context<'_> {
    pub(super) fn of<'a>(
        setup: &'a super::Setup,
        change: &'a ChangeMap,
        sharing: &'a Grid,
        kernel: &'a Kernel<'a>,
        isa: Isa,
    ) -> Context<'a> {
        Context {
            params: &setup.params,
            sampler: &setup.sampler,
            left: &setup.left,
            right: &setup.right,
            change,
            sharing,
            kernel,
            isa,
        }
    }

    /// Evaluates flies `range` of `pop` on the kernel's frame (projections, sharing cells,
    /// raw fitness; [`Kernel::evaluate`]).
    #[inline(always)]
    pub(super) fn evaluate(
        &self,
        pop: &mut Population,
        range: Range<usize>,
        scratch: &mut Scratch,
    ) -> Matches {
        self.kernel.evaluate(
            self.isa,
            self.left,
            self.right,
            pop,
            range,
            self.sharing,
            scratch,
        )
    }
}

/// Second-stage depth probes of a guided immigrant, around its best first-stage probe.
pub(super) const REFINE_PROBES: usize = 8;
/// Refinement stages after the first one (see [`Immigration::immigrate`]).
pub(super) const REFINE_STAGES: usize = 2;

/// Index and value of the first of the fittest (deterministic); (0, 0) if none is positive.
pub(super) fn first_fittest(fit: &[f32]) -> (usize, f32) {
    fit.iter().enumerate().fold(
        (0, 0.0f32),
        |acc, (s, &v)| if v > acc.1 { (s, v) } else { acc },
    )
}

/// Points of a changed block looked at to place one guided immigrant.
const PIXEL_CANDIDATES: usize = 8;

/// The immigration and its buffers, sized once.
#[derive(Debug, Clone)]
pub(super) struct Immigration {
    /// Depth probes of the guided immigrants: `immigrant_probes` consecutive flies each, then
    /// the refinement stages; also the candidates of the outsiders' redraws.
    pub(super) probe: Population,
    /// Inverse-depth parameter of each first-stage probe along its ray.
    probe_t: Vec<f32>,
    /// Ray (normalised left coordinates) and inverse-depth range of each probed immigrant.
    pub(super) probe_ray: Vec<[f32; 4]>,
    /// Population slot of each probed immigrant.
    probe_slot: Vec<u32>,
    /// Where each probed immigrant's first-stage probes are, and how many.
    probe_span: Vec<(u32, u32)>,
    /// Best probe of each probed immigrant so far: (inverse-depth parameter, fitness, index).
    pub(super) probe_best: Vec<(f32, f32, u32)>,
    /// Immigrants outside an image or the road band, to redraw.
    outsiders: Vec<u32>,
    /// Probes evaluated in the latest generation.
    pub(super) probed: usize,
    /// Blocks where the obstacle stage last saw something, and the inverse depth it was seen
    /// at ([`super::Engine::set_focus`]).
    focus: Vec<(u32, f32)>,
}

/// A focused immigrant probes this share of the inverse depth either side of what was seen
/// (15 %: 4 px of disparity on a car 13.8 m ahead of KITTI's rig).
const FOCUS_DEPTH: f32 = 0.15;

/// Focus blocks kept, at most.
pub const MAX_FOCUS: usize = 64;

impl Immigration {
    /// Buffers for `params` (validated).
    pub(super) fn new(params: &EngineParams) -> Self {
        let immigrants = params.immigrants();
        let probes = params.immigrant_probes as usize;
        Self {
            probe: Population::with_len(Self::probe_capacity(params)),
            probe_t: vec![0.0; immigrants * probes],
            probe_ray: vec![[0.0; 4]; immigrants],
            probe_slot: vec![0; immigrants],
            probe_span: vec![(0, 0); immigrants],
            probe_best: vec![(0.0, 0.0, 0); immigrants],
            outsiders: vec![0; params.flies],
            probed: 0,
            focus: Vec::with_capacity(MAX_FOCUS),
        }
    }

    /// The blocks of `seen` (left-image pixel and depth; left image `width` x `height`), at
    /// most [`MAX_FOCUS`].
    pub(super) fn set_focus(
        &mut self,
        seen: impl Iterator<Item = (f32, f32, f32)>,
        width: u32,
        height: u32,
    ) {
        self.focus.clear();
        let (w, h) = (width as usize, height as usize);
        let cols = w.div_ceil(crate::frame::BLOCK);
        for (u, v, depth) in seen.take(MAX_FOCUS) {
            let (x, y) = ((u + 0.5).max(0.0) as usize, (v + 0.5).max(0.0) as usize);
            if x < w && y < h && depth > 0.0 {
                let b = (y / crate::frame::BLOCK) * cols + x / crate::frame::BLOCK;
                // The depth ahead (vehicle z) stands for the depth along the left camera's
                // axis: equal for a level camera, a few per cent off for one pitched by a
                // few degrees, well inside the FOCUS_DEPTH window.
                self.focus.push((b as u32, 1.0 / depth));
            }
        }
    }

    /// Flies evaluated at once by the probes (every stage of every guided immigrant), or the
    /// population, whichever is larger: what the evaluation's scratch must hold.
    pub(super) fn probe_capacity(params: &EngineParams) -> usize {
        params.flies.max(
            params.immigrants()
                * (params.immigrant_probes as usize + REFINE_STAGES * REFINE_PROBES),
        )
    }

    /// Replaces flies `from..` with new random flies. Candidates are drawn in bulk and checked
    /// with the vectorised projection; those outside an image or the road band (about a third)
    /// are drawn again, in batches ([`Engine::redraw_outsiders`]).
    /// Guided immigrants (drawn where the image changed) probe `immigrant_probes` depths along
    /// their ray against the current frame and keep the fittest.
    pub(super) fn immigrate(
        &mut self,
        pop: &mut Population,
        from: usize,
        ctx: &Context<'_>,
        rng: &mut Xoshiro256PlusPlus,
        scratch: &mut Scratch,
    ) {
        let guided = unit_threshold(ctx.params.guided_immigration);
        let k = ctx.params.immigrant_probes as usize;
        self.probed = 0;
        let mut probing = 0;
        // First-stage probes placed so far.
        let mut first = 0;
        // The first immigrants look around what the obstacle stage saw (none when it saw
        // nothing), the next ones scan the corridor (none without one).
        let focused = if self.focus.is_empty() {
            from
        } else {
            from + ctx.params.focus_immigrants()
        };
        // Then those that scan the bands watched beside it (none without them).
        let (in_corridor, watching) = match ctx.sampler.corridor {
            Some(c) => (
                focused + ctx.params.corridor_immigrants(),
                if c.watch_half_width > c.half_width {
                    ctx.params.watch_immigrants()
                } else {
                    0
                },
            ),
            None => (focused, 0),
        };
        let scanning = in_corridor + watching;
        // Where a watch immigrant's ray is probed: across the corridor and both bands.
        let wide = ctx.sampler.corridor.map(|c| Corridor {
            half_width: c.watch_half_width.max(c.half_width),
            ..c
        });
        for i in from..pop.len() {
            let focus = i < focused;
            let scan = !focus && i < scanning;
            let beside = i >= in_corridor;
            // A corridor immigrant's block: where a point drawn in the corridor (or beside
            // it) is seen. Near the vehicle much of the corridor is outside the image: drawn
            // again.
            let scanned = if scan {
                (0..SAMPLE_ATTEMPTS).find_map(|_| {
                    let (p, along) = ctx.sampler.corridor_point(rng, beside)?;
                    let (u, v) = ctx.left.project(p[0], p[1], p[2])?;
                    Some((Self::block_of(ctx, u, v)?, along))
                })
            } else {
                None
            };
            let p = if focus
                || scanned.is_some()
                || (!scan && ctx.change.total > 0.0 && rng.next_u32() < guided)
            {
                // A focused immigrant goes around something seen in the corridor: its block
                // or a neighbour, its depth give or take FOCUS_DEPTH.
                let mut around = None;
                let b = if let Some((b, _)) = scanned {
                    b
                } else if focus {
                    let u = unit_f32(rng.next_u32());
                    let n = self.focus.len();
                    let (b, inv) = self.focus[((u * n as f32) as usize).min(n - 1)];
                    around = Some(inv);
                    let (cols, rows) = ctx.change.blocks();
                    let r = rng.next_u32();
                    let (dx, dy) = ((r % 3) as usize, ((r / 3) % 3) as usize);
                    let (bx, by) = (b as usize % cols.max(1), b as usize / cols.max(1));
                    let x = (bx + dx).saturating_sub(1).min(cols.saturating_sub(1));
                    let y = (by + dy).saturating_sub(1).min(rows.saturating_sub(1));
                    y * cols + x
                } else {
                    ctx.change.pick(unit_f32(rng.next_u32()))
                };
                let ray = Self::strongest_in_block(ctx, rng, b);
                let range = |xn: f32, yn: f32| {
                    let box_of = if beside { &wide } else { &ctx.sampler.corridor };
                    if let (Some((_, along)), Some(c)) = (scanned, box_of) {
                        return ctx.sampler.ray_range_in_corridor(xn, yn, c, along);
                    }
                    let (lo, hi) = ctx.sampler.ray_range(xn, yn)?;
                    Some(match around {
                        Some(inv) => {
                            let (a, b) = (
                                lo.max(inv * (1.0 - FOCUS_DEPTH)),
                                hi.min(inv * (1.0 + FOCUS_DEPTH)),
                            );
                            if a < b { (a, b) } else { (lo, hi) }
                        }
                        None => (lo, hi),
                    })
                };
                match ray.and_then(|(xn, yn)| Some((xn, yn, range(xn, yn)?))) {
                    Some((xn, yn, inv)) if k > 1 => {
                        // Fewer first-stage probes over a focused immigrant's narrower range
                        // (~8 px of disparity on a car 13.8 m ahead of KITTI's rig).
                        let n = if around.is_some() {
                            (k / 4).max(2)
                        } else if scanned.is_some() {
                            (k / 2).max(2)
                        } else {
                            k
                        };
                        let base = first;
                        for s in 0..n {
                            // One probe per stratum of the ray's inverse-depth range.
                            let t = (s as f32 + unit_f32(rng.next_u32())) / n as f32;
                            let p = ctx.sampler.at(xn, yn, 1.0 / lerp(inv, t));
                            self.probe.x[base + s] = p[0];
                            self.probe.y[base + s] = p[1];
                            self.probe.z[base + s] = p[2];
                            self.probe_t[base + s] = t;
                        }
                        self.probe_slot[probing] = i as u32;
                        self.probe_ray[probing] = [xn, yn, inv.0, inv.1];
                        self.probe_span[probing] = (base as u32, n as u32);
                        probing += 1;
                        first += n;
                        ctx.sampler.at(xn, yn, 1.0 / lerp(inv, 0.5))
                    }
                    Some((xn, yn, inv)) => {
                        ctx.sampler
                            .at(xn, yn, 1.0 / lerp(inv, unit_f32(rng.next_u32())))
                    }
                    None => ctx.sampler.candidate_in_block(rng, b),
                }
            } else {
                ctx.sampler.candidate(rng)
            };
            pop.x[i] = p[0];
            pop.y[i] = p[1];
            pop.z[i] = p[2];
        }
        if probing > 0 {
            self.probed = first;
            ctx.evaluate(&mut self.probe, 0..first, scratch);
            // Best probe of each immigrant so far: (t, fitness, probe index).
            for j in 0..probing {
                let (start, n) = self.probe_span[j];
                let (start, n) = (start as usize, n as usize);
                let (b, f) = first_fittest(&self.probe.raw_fitness[start..start + n]);
                self.probe_best[j] = (self.probe_t[start + b], f, (start + b) as u32);
            }
            // Refinement: each stage spreads REFINE_PROBES depths evenly around the best probe
            // so far, the first over one stratum, each next over two spacings of the previous.
            // A stratum spans several pixels of disparity while the fitness peaks within a
            // fraction of one, so the first stage finds the right stratum more often than the
            // right depth.
            let mut scale = 1.0;
            // Offset of refinement probe q from the centre, in units of the stage's width.
            let offset = |q: usize| (q as f32 + 0.5) / REFINE_PROBES as f32 - 0.5;
            for stage in 0..REFINE_STAGES {
                let fine = first + probing * stage * REFINE_PROBES;
                for j in 0..probing {
                    let t0 = self.probe_best[j].0;
                    let width = scale / self.probe_span[j].1.max(1) as f32;
                    let [xn, yn, i0, i1] = self.probe_ray[j];
                    for q in 0..REFINE_PROBES {
                        let t = t0 + offset(q) * width;
                        let p = ctx
                            .sampler
                            .at(xn, yn, 1.0 / lerp((i0, i1), t.clamp(0.0, 1.0)));
                        let at = fine + j * REFINE_PROBES + q;
                        self.probe.x[at] = p[0];
                        self.probe.y[at] = p[1];
                        self.probe.z[at] = p[2];
                    }
                }
                self.probed += probing * REFINE_PROBES;
                ctx.evaluate(
                    &mut self.probe,
                    fine..fine + probing * REFINE_PROBES,
                    scratch,
                );
                for j in 0..probing {
                    let r = fine + j * REFINE_PROBES;
                    let (b, f) = first_fittest(&self.probe.raw_fitness[r..r + REFINE_PROBES]);
                    if f > self.probe_best[j].1 {
                        let width = scale / self.probe_span[j].1.max(1) as f32;
                        let t = self.probe_best[j].0 + offset(b) * width;
                        self.probe_best[j] = (t.clamp(0.0, 1.0), f, (r + b) as u32);
                    }
                }
                scale *= 2.0 / REFINE_PROBES as f32;
            }
            for (j, &slot) in self.probe_slot[..probing].iter().enumerate() {
                let (_, f, q) = self.probe_best[j];
                // The middle probe stays if all fail.
                if f > 0.0 {
                    let (i, q) = (slot as usize, q as usize);
                    pop.x[i] = self.probe.x[q];
                    pop.y[i] = self.probe.y[q];
                    pop.z[i] = self.probe.z[q];
                }
            }
        }
        let n = pop.len();
        pop.project_on(ctx.isa, ctx.left, ctx.right, from..n);
        self.redraw_outsiders(pop, from, ctx, rng);
    }

    /// Redraws the flies of `from..` (projected) that lie outside an image or the region of
    /// interest: each becomes what [`Engine::sample_fly`] would draw for it, one after the
    /// other (the same draws, the same flies, the generator left in the same state), but the
    /// candidates are checked in batches with the vectorised projection. One by one, a
    /// candidate rejected a third of the time made a chain of mispredicted branches and
    /// divisions (~160 cycles a candidate, ~6 us a generation).
    /// Returns how many candidates it drew.
    pub(super) fn redraw_outsiders(
        &mut self,
        pop: &mut Population,
        from: usize,
        ctx: &Context<'_>,
        rng: &mut Xoshiro256PlusPlus,
    ) -> usize {
        let n = pop.len();
        let (flies, sampler) = (&*pop, ctx.sampler);
        let outside = (from..n).map(|i| {
            flies.u_left[i].is_nan()
                | flies.u_right[i].is_nan()
                | !sampler.in_roi(&[flies.x[i], flies.y[i], flies.z[i]])
        });
        // Compaction is over: its scratch is free.
        let count = gather(outside, from, &mut self.outsiders);
        if count == 0 {
            return 0;
        }
        let start = rng.clone();
        let cap = self.probe.len();
        // Outsiders placed, candidates consumed, attempts spent on the current outsider.
        let (mut k, mut used, mut attempts) = (0, 0, 0);
        while k < count && cap > 0 {
            // About 1.5 candidates an outsider are needed: a batch rarely falls short.
            let batch = cap.min(2 * (count - k) + 16);
            for j in 0..batch {
                let p = ctx.sampler.candidate(rng);
                (self.probe.x[j], self.probe.y[j], self.probe.z[j]) = (p[0], p[1], p[2]);
            }
            self.probe
                .project_on(ctx.isa, ctx.left, ctx.right, 0..batch);
            for j in 0..batch {
                if k == count {
                    break;
                }
                let (probe, i) = (&self.probe, self.outsiders[k] as usize);
                let p = [probe.x[j], probe.y[j], probe.z[j]];
                let seen = !probe.u_left[j].is_nan() && !probe.u_right[j].is_nan();
                used += 1;
                attempts += 1;
                if (seen && ctx.sampler.in_roi(&p)) || attempts == SAMPLE_ATTEMPTS {
                    (pop.x[i], pop.y[i], pop.z[i]) = (p[0], p[1], p[2]);
                    k += 1;
                    attempts = 0;
                }
            }
        }
        // Where the one-by-one draws would have left the generator: `used` candidates on.
        *rng = start;
        for _ in 0..used {
            Sampler::skip_candidate(rng);
        }
        used
    }

    /// The block of left-image pixel `(u, v)`, if inside the image.
    fn block_of(ctx: &Context<'_>, u: f32, v: f32) -> Option<usize> {
        let (cols, rows) = ctx.change.blocks();
        let (x, y) = ((u + 0.5).floor(), (v + 0.5).floor());
        if x < 0.0 || y < 0.0 {
            return None;
        }
        let (bx, by) = (
            x as usize / crate::frame::BLOCK,
            y as usize / crate::frame::BLOCK,
        );
        (bx < cols && by < rows).then_some(by * cols + bx)
    }

    /// The left-image ray (normalised coordinates) through the strongest gradient of
    /// `PIXEL_CANDIDATES` random points of block `b`: the fitness is proportional to the
    /// gradients, so an obstacle is found first where it has contrast.
    fn strongest_in_block(
        ctx: &Context<'_>,
        rng: &mut Xoshiro256PlusPlus,
        b: usize,
    ) -> Option<(f32, f32)> {
        let mut best: Option<(f32, f32, u8)> = None;
        for _ in 0..PIXEL_CANDIDATES {
            let (xn, yn) = ctx.sampler.in_block(rng, b)?;
            let p = ctx.sampler.at(xn, yn, 1.0);
            let g = ctx
                .left
                .project(p[0], p[1], p[2])
                .map_or(0, |(u, v)| ctx.kernel.left_gradient(u, v));
            if best.is_none_or(|(_, _, bg)| g > bg) {
                best = Some((xn, yn, g));
            }
        }
        best.map(|(xn, yn, _)| (xn, yn))
    }
}
