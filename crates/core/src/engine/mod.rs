//! The Fly Algorithm (Pauplin, Louchet, Lutton, Parent): a population of 3-D points evolved
//! against a calibrated stereo pair.
//!
//! # Contract
//! - Pure: takes [`StereoFrame`]s, returns a population. No device, thread, clock or I/O.
//! - Deterministic: the same [`EngineParams`] (seed included), rig and frames give a bit-identical
//!   population ([`Engine::population`]), generation after generation.
//! - No allocation per generation: every buffer is sized in [`Engine::new`].
//! - After every [`Engine::step`] the whole population is evaluated against the newest frame:
//!   when a new pair arrives every fly, survivors included, is re-evaluated (a stored fitness goes
//!   stale on video); otherwise only the offspring are.
//!
//! # One generation ([`Engine::step`]), room by room
//! 1. **Refresh** (`refresh`): on the first generation of a new frame, the flies whose left
//!    projection lies where the image changed (`change`: 16x16 blocks whose mean luma moved
//!    beyond the noise; after [`Engine::predict`], the road's blocks compared with where that
//!    road was before the vehicle moved) are re-evaluated first: their stale fitness is the one that no longer
//!    holds (a fly that a new obstacle hides).
//! 2. **Selection** (`select`, elitist, deterministic): the best `survival_rate` of the flies
//!    by shared fitness are kept, found in O(N) with a radix selection (not a sort), and
//!    compacted to the front.
//! 3. **Breeding** (`breeding`): barycentric crossover `OF = l OF1 + (1-l) OF2` of two
//!    survivors, l uniform in \[0, 1); the first parent, with probability `guided_breeding`,
//!    the fittest before sharing of `breeding_tournament` survivors drawn where the left image
//!    changed (when there are some), else one drawn from all survivors; the second from the
//!    first one's sharing cell with probability `local_mating`, else from all survivors.
//! 4. **Mutation** (`mutation`): each coordinate with probability `mutation_rate`, by a normal
//!    of sigma `mutation_sigma * max(z, 1 m)`.
//! 5. **Immigration** (`immigration`): the last `immigration_rate` of the population are drawn
//!    like the initial flies (`sampler`), except that `guided_immigration` of them go where
//!    the left image changed: each takes the strongest gradient of a few points of a changed
//!    block and keeps the fittest of `immigrant_probes` depths along that ray (one per stratum
//!    of inverse depth), then of two refinement stages of 8 around the fittest so far.
//! 6. **Evaluation** (`fitness`, `windows`): `F = g_L g_R / (SSD + floor)` at the two
//!    projections, multiplied by `roi.penalty` outside the road region of interest (paper 5.1).
//! 7. **Sharing** (`sharing`): F is divided by `n^sharing_exponent`, n being the number of
//!    flies whose left projection falls in the same `sharing_cell_px` square: O(N) with a grid.
//! 8. **Warnings**: `w = F / (max(|x|, 0.5)^2 * max(z, 1))` for every fly, F being the fly's
//!    fitness after the region of interest and *before* sharing. Sharing is a device of
//!    selection (diversity); dividing the evidence of an obstacle by the number of flies that
//!    found it made a pedestrian at 4 m only ~5x as alarming as an empty road in hw-mock,
//!    against >20x without. The paper's global warning is the mean warning; the engine also
//!    reports the *danger* `sum(w) / sum(F)`, the fitness-weighted mean of
//!    `1 / (max(|x|,.5)^2 max(z,1))` in m^-3: where the evidence is, not how much there is (on
//!    an empty road a few weak matches near the vehicle give it a high value). The daemon logs
//!    it and decides on neither of them alone (see `flyd::daemon::control`).
//!
//! Each room owns its buffers; only the population, the random generator and the
//! evaluation's scratch go from one phase to the next. The hot loops run on the instruction
//! set the engine detected ([`crate::isa`]; every set gives the same bits).
//!
//! Initial and immigrant flies are drawn uniformly over the left image and uniformly in inverse
//! depth within `[min_depth, max_depth]` (uniform in disparity, the quantity stereo resolves
//! uniformly), and kept only if both cameras see them: uniform inside the intersection of the
//! two fields of view, in the projective measure of the stereo pair.

mod breeding;
mod change;
mod fitness;
mod immigration;
mod lists;
mod mutation;
mod params;
pub mod phase;
mod population;
mod projector;
mod refresh;
mod sampler;
mod select;
mod sharing;
mod sweep;
mod trunc;
mod uniqueness;
mod windows;

pub use params::{EngineParams, ParamError, RoadRoi};
pub use population::Population;
pub use sampler::Corridor;
pub use sweep::{Sweep, SweepPoint};
pub use uniqueness::SHIFTS as AMBIGUITY_SHIFTS;

use crate::frame::StereoFrame;
use crate::geometry::StereoRig;
use crate::isa::{Isa, dispatch};
use crate::kinematics::{EgoTransform, VehicleMotion};
use crate::road_plane::RoadPlane;
use breeding::Breeder;
use change::{ChangeMap, EgoFlow};
use fitness::{Kernel, Scratch};
pub use immigration::MAX_FOCUS;
use immigration::{Context, Immigration};
use mutation::Mutation;
use phase::Phase;
use projector::Projector;
use rand::SeedableRng;
use rand::rngs::Xoshiro256PlusPlus;
use refresh::Refresh;
use sampler::Sampler;
use select::Survival;
use sharing::{Grid, Mates};
use sweep::Sweeps;
use uniqueness::Uniqueness;

/// Why an engine cannot be built or run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EngineError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("the depth range [{min}, {max}] m is not visible by both cameras")]
    NoCommonView { min: f64, max: f64 },
    #[error("the left camera's model cannot be inverted at the image border")]
    NotInvertible,
    #[error("frame {which} is {got_w}x{got_h} but the calibration expects {want_w}x{want_h}")]
    FrameSize {
        which: &'static str,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
}

/// Figures of the latest generation.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct GenerationStats {
    /// Generations run so far.
    pub generation: u64,
    /// Mean warning of the population (the paper's global warning).
    pub global_warning: f64,
    /// `sum(warning) / sum(fitness)`, m^-3: contrast-independent danger (see module docs).
    pub danger: f64,
    /// Mean raw fitness (after the region of interest, before sharing): how well the stereo
    /// pair matches where the flies are. Collapses to that of random flies when the images
    /// match nowhere (a camera delivering noise or covered, a calibration that no longer fits).
    pub mean_fitness: f64,
    /// Fraction of the flies evaluated in this generation (all of them on a new frame) whose
    /// two windows match: per-sample SSD under a quarter of that of two unrelated windows of
    /// normalised images. Independent of camera and scene; ~0 when the images match nowhere
    /// (a camera delivering noise or covered).
    pub matched: f64,
    /// Flies evaluated in this generation.
    pub evaluated: usize,
    /// Depth probes of guided immigrants evaluated in this generation (`immigrant_probes` + 16
    /// each).
    pub probes: usize,
    /// Flies re-evaluated before selection because the image changed where they project
    /// (first generation on a new frame only).
    pub refreshed: usize,
    /// Flies whose projection falls inside both images.
    pub visible: usize,
    /// Whether this generation saw a new frame.
    pub new_frame: bool,
    /// Evidence of change of the newest frame against the previous one (sum over the 16x16
    /// blocks of the mean-luma change above the noise, decaying by half per frame); 0 when
    /// nothing moved.
    pub change: f32,
}

/// [`Engine::predict`] leaves one fly in this many where it was (the hypothesis that what it
/// found moves with the vehicle). Measured on hw-mock's 30 and 40 km/h approaches: every
/// other fly unmoved delayed the first STOP by a frame on some seeds (half the population
/// left on a scene that flows).
const STAY_EVERY: usize = 4;

/// Where an obstacle that moves is, in the vehicle frame, and how far it travels ahead over
/// the prediction's interval ([`Engine::predict_around`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingRegion {
    /// Lateral (x) and depth (z) bounds, metres.
    pub x: (f32, f32),
    pub z: (f32, f32),
    /// The obstacle's own travel along the vehicle's heading, metres.
    pub travelled: f64,
}

impl MovingRegion {
    fn contains(&self, x: f32, z: f32) -> bool {
        (self.x.0..=self.x.1).contains(&x) && (self.z.0..=self.z.1).contains(&z)
    }
}

/// Flies one [`Engine::ambiguity`] call looks at, at most.
const AMBIGUITY_FLIES: usize = 512;
/// Probes one [`Engine::sweep`] evaluates at once, at most.
const SWEEP_POINTS: usize = 4096;

/// What an engine is built with: the parameters, the cameras' projections and the domain new
/// flies are drawn from. Only the setters change it: the road and the corridor new flies are
/// drawn in, and how far the search reaches ([`Engine::set_reach`]).
struct Setup {
    params: EngineParams,
    /// `max_depth` and `roi.max_ahead` as configured: the reach never searches less.
    configured_far: (f64, Option<f64>),
    left: Projector,
    right: Projector,
    sampler: Sampler,
    /// The right camera's model (rays from its pixels).
    right_camera: crate::geometry::Camera,
}

/// The evolving population and everything needed to run a generation without allocating.
/// Each phase's buffers belong to that phase's room (module); only the population, the
/// generator and the evaluation's scratch go from one phase to the next.
pub struct Engine {
    setup: Setup,
    pop: Population,
    rng: Xoshiro256PlusPlus,
    /// Per-fly intermediates of one evaluation (population or probes, whichever is larger).
    scratch: Scratch,
    /// Instruction set of the vectorised passes (detected once; the same bits on each).
    isa: Isa,
    change: ChangeMap,
    /// Where the road of each block was one vehicle motion ago (the change map's
    /// compensation).
    flow: EgoFlow,
    /// The motion [`Engine::predict`] applied since the last new frame (metres, radians).
    pending_motion: Option<(f64, f64)>,
    sharing: Grid,
    refresh: Refresh,
    survival: Survival,
    mates: Mates,
    breeder: Breeder,
    mutation: Mutation,
    immigration: Immigration,
    uniqueness: Uniqueness,
    sweeps: Sweeps,
    frame_size: (u32, u32, u32, u32),
    /// The road the region of interest's heights are measured from.
    road: RoadPlane,
    /// Id of the frame the population was last evaluated against.
    frame_id: Option<u64>,
    /// Flies from this index on have not been evaluated since they were created.
    unevaluated_from: usize,
    stats: GenerationStats,
}

impl Engine {
    /// A population of random flies over `rig`'s common field of view.
    pub fn new(rig: &StereoRig, params: EngineParams) -> Result<Self, EngineError> {
        params.validate()?;
        let n = params.flies;
        let (w, h) = (rig.left.width(), rig.left.height());
        let setup = Setup {
            sampler: Sampler::new(rig, &params)?,
            left: Projector::new(&rig.left),
            right: Projector::new(&rig.right),
            right_camera: rig.right.clone(),
            configured_far: (params.max_depth, params.roi.map(|r| r.max_ahead)),
            params,
        };
        let params = &setup.params;
        let cell_px = params.sharing_cell_px;
        let mut engine = Self {
            sharing: Grid::new(w, h, cell_px, params.sharing_exponent, n),
            rng: Xoshiro256PlusPlus::seed_from_u64(params.seed),
            scratch: Scratch::new(
                Immigration::probe_capacity(params)
                    .max(AMBIGUITY_FLIES * (AMBIGUITY_SHIFTS.len() + 1))
                    .max(SWEEP_POINTS),
            ),
            isa: Isa::detect(),
            pop: Population::with_len(n),
            change: ChangeMap::new(w, h),
            flow: EgoFlow::new(&rig.left, &ChangeMap::new(w, h)),
            pending_motion: None,
            refresh: Refresh::new(n),
            survival: Survival::new(n),
            mates: Mates::new(w, h, cell_px, n),
            breeder: Breeder::new(n),
            mutation: Mutation::new(n),
            immigration: Immigration::new(params),
            uniqueness: Uniqueness::new(
                AMBIGUITY_FLIES,
                rig.right.intrinsics().fx * rig.baseline(),
            ),
            sweeps: Sweeps::new(
                SWEEP_POINTS,
                setup.sampler.blocks.len(),
                rig.right.intrinsics().fx * rig.baseline(),
            ),
            frame_size: (w, h, rig.right.width(), rig.right.height()),
            road: RoadPlane::FLAT,
            frame_id: None,
            unevaluated_from: 0,
            stats: GenerationStats::default(),
            setup,
        };
        let mut visible = 0;
        let Setup {
            sampler,
            left,
            right,
            params,
            ..
        } = &engine.setup;
        for i in 0..n {
            let (p, ok) = sampler.sample_fly(&mut engine.rng, left, right);
            visible += ok as usize;
            engine.pop.x[i] = p[0];
            engine.pop.y[i] = p[1];
            engine.pop.z[i] = p[2];
        }
        if visible == 0 {
            return Err(EngineError::NoCommonView {
                min: params.min_depth,
                max: params.max_depth,
            });
        }
        Ok(engine)
    }

    /// Where something was seen in the corridor (left-image pixels and depths, at most
    /// [`MAX_FOCUS`] kept): `focus_immigrants` immigrants a generation look around those
    /// blocks and depths ([`EngineParams::focus_immigrants`]), until the next call. No
    /// allocation.
    pub fn set_focus(&mut self, pixels: impl Iterator<Item = (f32, f32, f32)>) {
        let (w, h, _, _) = self.frame_size;
        self.immigration.set_focus(pixels, w, h);
    }

    /// The corridor `corridor_immigrants` immigrants a generation scan from now on
    /// ([`EngineParams::corridor_immigrants`]); `None`: none.
    pub fn set_corridor(&mut self, corridor: Option<Corridor>) {
        self.setup.sampler.corridor = corridor;
    }

    pub fn params(&self) -> &EngineParams {
        &self.setup.params
    }

    /// Searches as far as `far` metres ahead from now on, never less than the configured
    /// `max_depth` and `roi.max_ahead` (a `far` within them, or not finite, restores them):
    /// new flies are drawn, and flies are judged in the region of interest, up to the
    /// farther of the two. The caller caps `far` at what the rig resolves
    /// ([`crate::perception::range::SearchReach`]). No allocation.
    pub fn set_reach(&mut self, far: f64) {
        let far = if far.is_finite() { far } else { 0.0 };
        let (depth, ahead) = self.setup.configured_far;
        let params = &mut self.setup.params;
        params.max_depth = depth.max(far);
        if let (Some(roi), Some(ahead)) = (params.roi.as_mut(), ahead) {
            roi.max_ahead = ahead.max(far);
        }
        self.setup.sampler.set_far(params);
    }

    pub fn population(&self) -> &Population {
        &self.pop
    }

    pub fn stats(&self) -> GenerationStats {
        self.stats
    }

    /// The instruction set the hot loops run on (the best this CPU has, unless set).
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// Runs the hot loops on `isa` instead (for benchmarks: every instruction set gives the
    /// same population; an [`Isa`] is always one this CPU has).
    pub fn set_isa(&mut self, isa: Isa) {
        self.isa = isa;
    }

    /// The road the region of interest's heights are measured from.
    pub fn road(&self) -> &RoadPlane {
        &self.road
    }

    /// Measures the region of interest's heights from `road` from now on (new flies are drawn
    /// above it, flies are judged against it at their next evaluation).
    pub fn set_road(&mut self, road: RoadPlane) {
        self.road = road;
        self.setup.sampler.road = road.coefficients();
    }

    /// Moves every fly where the vehicle's own motion puts it: a static point seen at `p` is,
    /// `dt` seconds later, at `R(-yaw) (p - t)` in the new vehicle frame, the vehicle having
    /// driven `speed dt` along an arc turning `yaw_rate dt` (chord at half the turn; about the
    /// vehicle frame's origin). Call it between two frames, before the next [`Engine::step`]:
    /// the flies on static surfaces land on them again in the new images (their re-evaluation
    /// keeps them), and only what moved in the world must be found again. No motion (or a
    /// non-finite one) leaves the population untouched, bit for bit.
    ///
    /// One fly in four is not moved; the others are. The world
    /// is not all static: a car ahead driving at the vehicle's speed stays where it was in the
    /// vehicle frame, and a motion that does not fit the images (a wrong speed on the bus)
    /// would otherwise move every fly off what it found. Selection keeps whichever of the two
    /// hypotheses the new images confirm.
    pub fn predict(&mut self, motion: VehicleMotion, dt: f64) {
        self.predict_around(motion, dt, None);
    }

    /// [`Engine::predict`], but the flies in `moving` (an obstacle whose motion is measured)
    /// are moved as that obstacle moves relative to the vehicle: by the vehicle's motion less
    /// the obstacle's travel ahead ("Dynamic Flies", Boumaza and Louchet 2001, with the
    /// velocity from the obstacle's track instead of evolved per fly). A car followed at the
    /// vehicle's speed keeps its flies; moved as the static world, three in four fell off it
    /// every frame and the car was lost on 23-44 % of hw-mock's frames.
    pub fn predict_around(&mut self, motion: VehicleMotion, dt: f64, moving: Option<MovingRegion>) {
        let travelled = motion.speed * dt;
        let turned = motion.yaw_rate * dt;
        if !(travelled.is_finite() && turned.is_finite()) || (travelled == 0.0 && turned == 0.0) {
            return;
        }
        let ego = EgoTransform::new(travelled, turned);
        let (d0, t0) = self.pending_motion.unwrap_or((0.0, 0.0));
        self.pending_motion = Some((d0 + travelled, t0 + turned));
        let region = moving.filter(|m| m.travelled.is_finite());
        let relative = region.map(|m| (m, EgoTransform::new(travelled - m.travelled, turned)));
        let p = &mut self.pop;
        for (i, (x, z)) in p.x.iter_mut().zip(p.z.iter_mut()).enumerate() {
            if i % STAY_EVERY == STAY_EVERY - 1 {
                continue;
            }
            (*x, *z) = match relative {
                Some((m, rel)) if m.contains(*x, *z) => rel.apply(*x, *z),
                _ => ego.apply(*x, *z),
            };
        }
    }

    /// Runs one generation against `frame` (see the module docs for the steps).
    pub fn step(&mut self, frame: &StereoFrame) -> Result<GenerationStats, EngineError> {
        self.check_frame(frame)?;
        let new_frame = self.frame_id != Some(frame.id);
        let mut refreshed = 0;
        if new_frame {
            // Before reproduction, so this generation's immigrants already go where it changed.
            match self.pending_motion.take() {
                Some((travelled, turned)) => {
                    let left = &self.setup.left;
                    let predicted = self.flow.predict(
                        &self.change,
                        self.road.coefficients(),
                        travelled,
                        turned,
                        |x, y, z| left.project(x, y, z),
                    );
                    self.change
                        .update_from(frame.left.block_means(), Some(predicted));
                }
                None => self.change.update(frame.left.block_means()),
            }
        }
        let kernel = Kernel::new(frame, &self.setup.params, &self.road);
        self.immigration.probed = 0;
        if self.frame_id.is_some() {
            if new_frame {
                let _t = phase::start(Phase::Refresh);
                let at = Context::of(&self.setup, &self.change, &self.sharing, &kernel, self.isa);
                if let Some(m) = self.refresh.run(&mut self.pop, &at, &mut self.scratch) {
                    refreshed = m;
                    self.sharing.apply_on(self.isa, &mut self.pop);
                }
            }
            self.reproduce(&kernel);
        }
        if new_frame {
            self.unevaluated_from = 0;
            self.frame_id = Some(frame.id);
        }
        let from = self.unevaluated_from;
        let n = self.pop.len();
        let t = phase::start(Phase::Evaluate);
        let at = Context::of(&self.setup, &self.change, &self.sharing, &kernel, self.isa);
        let matches = at.evaluate(&mut self.pop, from..n, &mut self.scratch);
        self.unevaluated_from = n;
        t.stop();
        let t = phase::start(Phase::Share);
        self.sharing.apply_on(self.isa, &mut self.pop);
        t.stop();
        let t = phase::start(Phase::Warnings);
        let (min_x, min_z) = (
            self.setup.params.warning_min_abs_x as f32,
            self.setup.params.warning_min_z as f32,
        );
        let (global_warning, danger, mean_fitness, visible) =
            warnings_on(self.isa, &mut self.pop, min_x, min_z);
        t.stop();

        self.stats = GenerationStats {
            generation: self.stats.generation + 1,
            global_warning,
            danger,
            mean_fitness,
            matched: if matches.visible > 0 {
                f64::from(matches.matched) / f64::from(matches.visible)
            } else {
                0.0
            },
            evaluated: n - from,
            probes: self.immigration.probed,
            refreshed,
            visible,
            new_frame,
            change: self.change.total,
        };
        Ok(self.stats)
    }

    fn check_frame(&self, frame: &StereoFrame) -> Result<(), EngineError> {
        let (lw, lh, rw, rh) = self.frame_size;
        for (which, img, w, h) in [
            ("left", &frame.left, lw, lh),
            ("right", &frame.right, rw, rh),
        ] {
            if img.width() != w || img.height() != h {
                return Err(EngineError::FrameSize {
                    which,
                    got_w: img.width(),
                    got_h: img.height(),
                    want_w: w,
                    want_h: h,
                });
            }
        }
        Ok(())
    }

    /// Selection and genetic operators: survivors move to `0..keep` (in place), offspring fill
    /// `keep..`, immigrants last.
    fn reproduce(&mut self, kernel: &Kernel) {
        let params = &self.setup.params;
        let n = self.pop.len();
        let keep = params.survivors();
        let immigrants_from = n - params.immigrants();
        self.survival.run(self.isa, &mut self.pop, keep);
        let t = phase::start(Phase::Mates);
        if params.local_mating > 0.0 {
            self.mates.index_on(self.isa, &self.pop.cell[..keep]);
        }
        t.stop();
        let t = phase::start(Phase::Breed);
        let children = keep..immigrants_from;
        let mates = self.mates.picker();
        let (pop, rng) = (&mut self.pop, &mut self.rng);
        self.breeder.run(
            self.isa,
            pop,
            children.clone(),
            &self.change,
            mates,
            params,
            rng,
        );
        t.stop();
        let t = phase::start(Phase::Mutate);
        // Mutation decisions use 16-bit chunks of one draw: P(mutate) = round(rate * 65536) / 65536.
        let threshold = (params.mutation_rate * 65536.0).round() as u32;
        let sigma = params.mutation_sigma as f32;
        let r = children;
        let coords = [&mut pop.x[r.clone()], &mut pop.y[r.clone()], &mut pop.z[r]];
        self.mutation.run(
            self.isa,
            coords,
            self.breeder.coins(),
            rng,
            threshold,
            sigma,
        );
        t.stop();
        let _t = phase::start(Phase::Immigrate);
        let at = Context::of(&self.setup, &self.change, &self.sharing, kernel, self.isa);
        self.immigration
            .immigrate(pop, immigrants_from, &at, rng, &mut self.scratch);
        self.unevaluated_from = keep;
    }
}

dispatch! {
    /// [`warnings`] on instruction set `isa` (AVX2: 8 divisions at a time; the same bits).
    fn warnings_on(p: &mut Population, min_x: f32, min_z: f32) -> (f64, f64, f64, usize);
    up to Avx2 => warnings
}

/// The warnings step: the warning of every fly of `p`; returns (mean warning, danger, mean
/// fitness, visible flies).
#[inline(always)]
fn warnings(_: Isa, p: &mut Population, min_x: f32, min_z: f32) -> (f64, f64, f64, usize) {
    // The fly's own evidence (after the region of interest, before sharing): sharing is a
    // device of selection, and must not make an obstacle look less dangerous because many
    // flies found it.
    let (raw, xs, zs) = (&p.raw_fitness, &p.x, &p.z);
    for (((w, &f), &x), &z) in p.warning.iter_mut().zip(raw).zip(xs).zip(zs) {
        *w = warning(f, x, z, min_x, min_z);
    }
    // Sums in f32 blocks of 64 (exact enough: < 1e-5 relative), accumulated in f64.
    let sum = |v: &[f32]| -> f64 {
        v.chunks(64)
            .map(|c| {
                // Lane j takes elements j, j + 8, ...: eight independent sums that
                // vectorise.
                let mut lanes = [0.0f32; 8];
                let mut eights = c.chunks_exact(8);
                for q in &mut eights {
                    for j in 0..8 {
                        lanes[j] += q[j];
                    }
                }
                for (j, x) in eights.remainder().iter().enumerate() {
                    lanes[j] += x;
                }
                lanes.iter().map(|&x| x as f64).sum::<f64>()
            })
            .sum()
    };
    let (sum_w, sum_f) = (sum(&p.warning), sum(&p.raw_fitness));
    let visible = p.cell.iter().filter(|&&c| c != u32::MAX).count();
    let danger = if sum_f > 0.0 { sum_w / sum_f } else { 0.0 };
    let n = p.len() as f64;
    (sum_w / n, danger, sum_f / n, visible)
}

/// The paper's warning of one fly, with its clamps.
#[inline]
pub fn warning(fitness: f32, x: f32, z: f32, min_abs_x: f32, min_z: f32) -> f32 {
    let ax = x.abs().max(min_abs_x);
    fitness / (ax * ax * z.max(min_z))
}

#[cfg(test)]
mod tests;
