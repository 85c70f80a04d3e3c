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
//! # One generation ([`Engine::step`])
//! 1. **Selection** (elitist, deterministic): the best `survival_rate` of the flies by shared
//!    fitness are kept, found in O(N) with a selection (not a sort). On the first generation of
//!    a new frame, the flies whose left projection lies where the image changed are
//!    re-evaluated first: their stale fitness is the one that no longer holds (a fly that a new
//!    obstacle hides).
//! 2. **Operators** fill the rest: barycentric crossover `OF = l OF1 + (1-l) OF2` of two survivors
//!    (l ~ U[0,1]; the first parent, with probability `guided_breeding`, the fittest before
//!    sharing of `breeding_tournament` survivors drawn in blocks where the left image changed
//!    ([`change`]) when there are some, one drawn from all survivors otherwise; the second from
//!    the first one's sharing cell with probability `local_mating`, from all survivors
//!    otherwise), then Gaussian mutation of each coordinate
//!    with probability `mutation_rate`, sigma = `mutation_sigma * max(z, 1 m)`; the last
//!    `immigration_rate` of the population are immigrants drawn like the initial flies, except
//!    that `guided_immigration` of them go where the left image changed since the previous
//!    frame ([`change`]): each takes the strongest gradient of a few points of a changed block
//!    and keeps the fittest of `immigrant_probes` depths along that ray (one per stratum of
//!    inverse depth), then of two refinement stages of 8 around the fittest so far (over one
//!    stratum, then over a quarter of that), evaluated on the current frame.
//! 3. **Evaluation** ([`fitness`]): `F = g_L g_R / (SSD + floor)` at the two projections.
//! 4. **Road region of interest** (paper 5.1): outside it, F is multiplied by `roi.penalty`.
//! 5. **Sharing** ([`sharing`]): F is divided by `n^sharing_exponent`, n being the number of flies
//!    whose left projection falls in the same `sharing_cell_px` square: O(N) with a grid.
//! 6. **Warnings**: `w = F / (max(|x|, 0.5)^2 * max(z, 1))` for every fly, F being the fly's
//!    fitness after the region of interest and *before* sharing. Sharing is a device of
//!    selection (diversity); dividing the evidence of an obstacle by the number of flies that
//!    found it made a pedestrian at 4 m only ~5x as alarming as an empty road in hw-mock,
//!    against >20x without. The paper's global warning is the mean warning. Its scale depends
//!    on image contrast, camera gain and window size, so the engine also reports the *danger*
//!    `sum(w) / sum(F)`: the fitness-weighted mean of `1 / (max(|x|,.5)^2 max(z,1))`, in m^-3,
//!    which does not. Thresholds written in danger carry over between scenes and cameras
//!    (4 = all evidence at 1 m dead ahead, 1 = at 4 m, 0.06 = at 4 m but 2 m to the side).
//!
//! Initial and immigrant flies are drawn uniformly over the left image and uniformly in inverse
//! depth within `[min_depth, max_depth]` (uniform in disparity, the quantity stereo resolves
//! uniformly), and kept only if both cameras see them: uniform inside the intersection of the
//! two fields of view, in the projective measure of the stereo pair.

mod change;
mod fitness;
mod params;
pub mod phase;
mod projector;
mod select;
mod sharing;

pub use params::{EngineParams, ParamError, RoadRoi};

use crate::frame::{BLOCK, StereoFrame};
use crate::geometry::StereoRig;
use crate::isa::{Isa, Level, dispatch};
use fitness::Kernel;
use phase::Phase;
use projector::Projector;
use rand::rngs::Xoshiro256PlusPlus;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use std::ops::Range;

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

/// The flies, structure-of-arrays: the hot loops stream over one field at a time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Population {
    /// Vehicle-frame coordinates, metres.
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    /// Fitness after the region of interest, before sharing.
    pub raw_fitness: Vec<f32>,
    /// Fitness after sharing: what selection ranks by.
    pub fitness: Vec<f32>,
    /// `raw_fitness / (max(|x|,.5)^2 max(z,1))`.
    pub warning: Vec<f32>,
    /// Projections (continuous pixel coordinates); NaN when the fly is outside an image.
    pub u_left: Vec<f32>,
    pub v_left: Vec<f32>,
    pub u_right: Vec<f32>,
    pub v_right: Vec<f32>,
    /// Sharing cell of the left projection, `u32::MAX` when outside.
    cell: Vec<u32>,
}

impl Population {
    fn with_len(n: usize) -> Self {
        Self {
            x: vec![0.0; n],
            y: vec![0.0; n],
            z: vec![0.0; n],
            raw_fitness: vec![0.0; n],
            fitness: vec![0.0; n],
            warning: vec![0.0; n],
            u_left: vec![f32::NAN; n],
            v_left: vec![f32::NAN; n],
            u_right: vec![f32::NAN; n],
            v_right: vec![f32::NAN; n],
            cell: vec![u32::MAX; n],
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Moves fly `from` into slot `to` (the state that survives a generation).
    #[inline]
    fn move_fly(&mut self, to: usize, from: usize) {
        self.x[to] = self.x[from];
        self.y[to] = self.y[from];
        self.z[to] = self.z[from];
        self.raw_fitness[to] = self.raw_fitness[from];
        self.u_left[to] = self.u_left[from];
        self.v_left[to] = self.v_left[from];
        self.u_right[to] = self.u_right[from];
        self.v_right[to] = self.v_right[from];
        self.cell[to] = self.cell[from];
    }

    /// Projects flies `r` into both images (NaN where a fly is outside one). Inlined, so the
    /// AVX2 evaluation compiles it 8 flies wide.
    #[inline(always)]
    fn project(&mut self, left: &Projector, right: &Projector, r: Range<usize>) {
        let (x, y, z) = (&self.x[r.clone()], &self.y[r.clone()], &self.z[r.clone()]);
        left.project_batch(
            x,
            y,
            z,
            &mut self.u_left[r.clone()],
            &mut self.v_left[r.clone()],
        );
        right.project_batch(x, y, z, &mut self.u_right[r.clone()], &mut self.v_right[r]);
    }

    /// [`Population::project`] on instruction set `isa` (the same bits on each; AVX2 projects
    /// 8 flies at a time instead of 4).
    fn project_on(&mut self, isa: Isa, left: &Projector, right: &Projector, r: Range<usize>) {
        project_on(isa, self, left, right, r);
    }

    #[inline(always)]
    fn project_at(_: Level, pop: &mut Self, left: &Projector, right: &Projector, r: Range<usize>) {
        pop.project(left, right, r);
    }

    /// Indices of the `k` fittest flies, best first (for display and evaluation; allocates).
    pub fn best(&self, k: usize) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.len()).collect();
        idx.sort_by(|&a, &b| self.fitness[b].total_cmp(&self.fitness[a]).then(a.cmp(&b)));
        idx.truncate(k);
        idx
    }
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

/// Left-camera sampling domain for new flies.
#[derive(Debug, Clone)]
struct Sampler {
    /// Undistorted normalised bounds of the left image.
    xn: (f32, f32),
    yn: (f32, f32),
    /// Inverse depth range.
    inv_depth: (f32, f32),
    /// Undistorted normalised bounds (x0, x1, y0, y1) of each 16x16 block of the left image.
    blocks: Vec<[f32; 4]>,
    /// Road region of interest as (min height, max height): new flies are drawn inside it.
    heights: Option<(f32, f32)>,
    /// Vehicle from left camera: `p_vehicle = m * p_cam + c`.
    m: [f32; 9],
    c: [f32; 3],
}

/// Second-stage depth probes of a guided immigrant, around its best first-stage probe.
const REFINE_PROBES: usize = 8;
/// Refinement stages after the first one (see [`Engine::immigrate`]).
const REFINE_STAGES: usize = 2;

/// Index and value of the first of the fittest (deterministic); (0, 0) if none is positive.
fn first_fittest(fit: &[f32]) -> (usize, f32) {
    fit.iter().enumerate().fold(
        (0, 0.0f32),
        |acc, (s, &v)| if v > acc.1 { (s, v) } else { acc },
    )
}

/// Points of a changed block looked at to place one guided immigrant.
const PIXEL_CANDIDATES: usize = 8;

/// Attempts to draw a fly visible in both images before giving up on that slot.
const SAMPLE_ATTEMPTS: usize = 16;

/// The evolving population and everything needed to run a generation without allocating.
pub struct Engine {
    params: EngineParams,
    left: Projector,
    right: Projector,
    sampler: Sampler,
    pop: Population,
    selector: select::Selector,
    mates: sharing::Mates,
    change: change::ChangeMap,
    /// Survivor flags of the current selection.
    chosen: Vec<bool>,
    /// Compaction scratch: non-survivor slots below `survivors()`, survivors above it.
    holes: Vec<u32>,
    movers: Vec<u32>,
    /// Survivors in changed blocks: the first parents of guided breeding.
    breeders: Vec<u32>,
    /// Their fitness before sharing (the breeding tournament's key).
    breeder_fitness: Vec<f32>,
    /// Mutation coin tosses of each offspring (16 bits a coordinate) and, per coordinate, the
    /// offspring its mutation moves (three lists, 3 slots a fly: see [`mutate`]).
    masks: Vec<u64>,
    hits: Vec<u32>,
    /// Depth probes of the guided immigrants: `immigrant_probes` consecutive flies each, then
    /// the refinement stages; also the flies refreshed before selection.
    probe: Population,
    /// Inverse-depth parameter of each first-stage probe along its ray.
    probe_t: Vec<f32>,
    /// Ray (normalised left coordinates) and inverse-depth range of each probed immigrant.
    probe_ray: Vec<[f32; 4]>,
    /// Population slot of each probed immigrant.
    probe_slot: Vec<u32>,
    /// Best probe of each probed immigrant so far: (inverse-depth parameter, fitness, index).
    probe_best: Vec<(f32, f32, u32)>,
    /// Probes evaluated in the latest generation.
    probed: usize,
    /// Flies re-evaluated before selection in the latest generation ([`Engine::refresh_changed`]).
    refreshed: usize,
    sharing: sharing::Grid,
    /// Per-fly intermediates of an evaluation (population or probes, whichever is larger).
    scratch: fitness::Scratch,
    /// Instruction set of the vectorised passes (detected once; the same bits on each).
    isa: Isa,
    rng: Xoshiro256PlusPlus,
    frame_size: (u32, u32, u32, u32),
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
        let sampler = Sampler::new(rig, &params)?;
        let left = Projector::new(&rig.left);
        let right = Projector::new(&rig.right);
        // The probe buffer: the guided immigrants' probes, or every fly refreshed before
        // selection; the evaluation scratch is sized for it (it is at least the population).
        let probes = n.max(
            params.immigrants()
                * (params.immigrant_probes as usize + REFINE_STAGES * REFINE_PROBES),
        );
        let mut engine = Self {
            sharing: sharing::Grid::new(
                rig.left.width(),
                rig.left.height(),
                params.sharing_cell_px,
                params.sharing_exponent,
                n,
            ),
            rng: Xoshiro256PlusPlus::seed_from_u64(params.seed),
            scratch: fitness::Scratch::new(probes),
            isa: Isa::detect(),
            left,
            right,
            sampler,
            pop: Population::with_len(n),
            selector: select::Selector::new(n),
            change: change::ChangeMap::new(rig.left.width(), rig.left.height()),
            mates: sharing::Mates::new(
                rig.left.width(),
                rig.left.height(),
                params.sharing_cell_px,
                n,
            ),
            chosen: vec![false; n],
            holes: vec![0; n],
            movers: vec![0; n],
            breeders: vec![0; n],
            breeder_fitness: vec![0.0; n],
            masks: vec![0; n],
            hits: vec![0; 3 * n],
            probe: Population::with_len(probes),
            probe_t: vec![0.0; params.immigrants() * params.immigrant_probes as usize],
            probe_ray: vec![[0.0; 4]; params.immigrants()],
            probe_slot: vec![0; params.immigrants()],
            probe_best: vec![(0.0, 0.0, 0); params.immigrants()],
            probed: 0,
            refreshed: 0,
            frame_size: (
                rig.left.width(),
                rig.left.height(),
                rig.right.width(),
                rig.right.height(),
            ),
            frame_id: None,
            unevaluated_from: 0,
            stats: GenerationStats::default(),
            params,
        };
        let mut visible = 0;
        for i in 0..n {
            let (p, ok) = engine.sample_fly();
            visible += ok as usize;
            engine.pop.x[i] = p[0];
            engine.pop.y[i] = p[1];
            engine.pop.z[i] = p[2];
        }
        if visible == 0 {
            return Err(EngineError::NoCommonView {
                min: engine.params.min_depth,
                max: engine.params.max_depth,
            });
        }
        Ok(engine)
    }

    pub fn params(&self) -> &EngineParams {
        &self.params
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

    /// Runs one generation against `frame` (see the module docs for the steps).
    pub fn step(&mut self, frame: &StereoFrame) -> Result<GenerationStats, EngineError> {
        self.check_frame(frame)?;
        let new_frame = self.frame_id != Some(frame.id);
        self.refreshed = 0;
        if new_frame {
            // Before reproduction, so this generation's immigrants already go where it changed.
            self.change.update(frame.left.block_means());
        }
        let kernel = Kernel::new(frame, &self.params, self.isa);
        if self.frame_id.is_some() {
            if new_frame {
                let _t = phase::start(Phase::Refresh);
                self.refresh_changed(&kernel);
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
        let matches = kernel.evaluate(
            &self.left,
            &self.right,
            &mut self.pop,
            from..n,
            &self.sharing,
            &mut self.scratch,
        );
        self.unevaluated_from = n;
        t.stop();
        let t = phase::start(Phase::Share);
        self.sharing.apply_on(self.isa, &mut self.pop);
        t.stop();
        let t = phase::start(Phase::Warnings);
        let (global_warning, danger, mean_fitness, visible) = self.warnings();
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
            probes: self.probed,
            refreshed: self.refreshed,
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

    /// Warnings of every fly; returns (mean warning, danger, mean fitness, visible flies).
    fn warnings(&mut self) -> (f64, f64, f64, usize) {
        let (min_x, min_z) = (
            self.params.warning_min_abs_x as f32,
            self.params.warning_min_z as f32,
        );
        warnings_on(self.isa, &mut self.pop, min_x, min_z)
    }

    /// Re-evaluates, before selection, the flies whose left projection lies where the image
    /// changed: there the previous frame's fitness is the one that is wrong (a fly on the
    /// background that an obstacle now hides would survive, and parent the guided breeding,
    /// on evidence that is gone). Elsewhere the stale fitness still ranks the flies as the new
    /// frame would. Evaluated in the probe buffer, so the population's slots are untouched.
    fn refresh_changed(&mut self, kernel: &Kernel) {
        if self.change.total <= 0.0 {
            return;
        }
        let n = self.pop.len();
        let (change, pop) = (&self.change, &self.pop);
        let changed = (0..n).map(|i| change.changed_at(pop.u_left[i], pop.v_left[i]));
        // The breeders' buffer holds the indices for now (reproduction refills it); the probe
        // buffer has room for the whole population.
        let m = gather(changed, 0, &mut self.breeders).min(self.probe.len());
        for (k, &i) in self.breeders[..m].iter().enumerate() {
            let i = i as usize;
            self.probe.x[k] = self.pop.x[i];
            self.probe.y[k] = self.pop.y[i];
            self.probe.z[k] = self.pop.z[i];
        }
        kernel.evaluate(
            &self.left,
            &self.right,
            &mut self.probe,
            0..m,
            &self.sharing,
            &mut self.scratch,
        );
        for (k, &i) in self.breeders[..m].iter().enumerate() {
            self.pop.raw_fitness[i as usize] = self.probe.raw_fitness[k];
        }
        self.refreshed = m;
        self.sharing.apply_on(self.isa, &mut self.pop);
    }

    /// Selection and genetic operators: survivors move to `0..keep` (in place), offspring fill
    /// `keep..`, immigrants last.
    fn reproduce(&mut self, kernel: &Kernel) {
        let n = self.pop.len();
        let keep = self.params.survivors();
        let immigrants_from = n - self.params.immigrants();
        let t = phase::start(Phase::Select);
        self.selector
            .select_on(self.isa, &self.pop.fitness, keep, &mut self.chosen);
        t.stop();
        let t = phase::start(Phase::Compact);
        // Compact: each non-survivor slot below `keep` takes a survivor from above it, the k-th
        // hole the k-th such survivor. There are exactly as many of one as of the other.
        // Survivors already below `keep` (the usual case for long-lived flies) do not move. The
        // two lists are built without branches (a survivor flag is a coin toss to a predictor).
        let holes = gather_flags(self.isa, &self.chosen[..keep], false, 0, &mut self.holes);
        let movers = gather_flags(
            self.isa,
            &self.chosen[keep..n],
            true,
            keep,
            &mut self.movers,
        );
        for k in 0..holes.min(movers) {
            self.pop
                .move_fly(self.holes[k] as usize, self.movers[k] as usize);
        }
        t.stop();
        let t = phase::start(Phase::Mates);
        if self.params.local_mating > 0.0 {
            self.mates.index_on(self.isa, &self.pop.cell[..keep]);
        }
        t.stop();
        let t = phase::start(Phase::Breed);
        // Survivors where the image changed (none on a static scene: then no extra draws).
        let breeders = if self.params.guided_breeding > 0.0 && self.change.total > 0.0 {
            let (change, pop) = (&self.change, &self.pop);
            let changed = (0..keep).map(|i| change.changed_at(pop.u_left[i], pop.v_left[i]));
            gather(changed, 0, &mut self.breeders)
        } else {
            0
        };
        let tournament = self.params.breeding_tournament as usize;
        if tournament > 1 {
            for (f, &i) in self
                .breeder_fitness
                .iter_mut()
                .zip(&self.breeders[..breeders])
            {
                *f = self.pop.raw_fitness[i as usize];
            }
        }
        // Mutation decisions use 16-bit chunks of one draw: P(mutate) = round(rate * 65536) / 65536.
        let threshold = (self.params.mutation_rate * 65536.0).round() as u32;
        let sigma = self.params.mutation_sigma as f32;
        let pop = &mut self.pop;
        breed(
            self.isa,
            &Breeding {
                guided: unit_threshold(self.params.guided_breeding),
                local: unit_threshold(self.params.local_mating),
                tournament,
                breeders: &self.breeders[..breeders],
                breeder_fitness: &self.breeder_fitness[..breeders],
                mates: self.mates.picker(),
                cell: &pop.cell[..keep],
            },
            [&mut pop.x, &mut pop.y, &mut pop.z],
            keep..immigrants_from,
            &mut self.masks,
            &mut self.rng,
        );
        t.stop();
        let t = phase::start(Phase::Mutate);
        let r = keep..immigrants_from;
        mutate_on(
            self.isa,
            [
                &mut self.pop.x[r.clone()],
                &mut self.pop.y[r.clone()],
                &mut self.pop.z[r],
            ],
            &self.masks,
            &mut self.hits,
            &mut self.rng,
            threshold,
            sigma,
        );
        t.stop();
        let _t = phase::start(Phase::Immigrate);
        self.immigrate(immigrants_from, kernel);
        self.unevaluated_from = keep;
    }

    /// Replaces flies `from..` with new random flies. Candidates are drawn in bulk and checked
    /// with the vectorised projection; those outside an image or the road band (about a third)
    /// are drawn again, in batches ([`Engine::redraw_outsiders`]).
    /// Guided immigrants (drawn where the image changed) probe `immigrant_probes` depths along
    /// their ray against the current frame and keep the fittest.
    fn immigrate(&mut self, from: usize, kernel: &Kernel) {
        let guided = unit_threshold(self.params.guided_immigration);
        let k = self.params.immigrant_probes as usize;
        self.probed = 0;
        let mut probing = 0;
        for i in from..self.pop.len() {
            let p = if self.change.total > 0.0 && self.rng.next_u32() < guided {
                let b = self.change.pick(unit_f32(self.rng.next_u32()));
                let ray = self.strongest_in_block(b, kernel);
                match ray.and_then(|(xn, yn)| Some((xn, yn, self.sampler.ray_range(xn, yn)?))) {
                    Some((xn, yn, inv)) if k > 1 => {
                        let base = probing * k;
                        for s in 0..k {
                            // One probe per stratum of the ray's inverse-depth range.
                            let t = (s as f32 + unit_f32(self.rng.next_u32())) / k as f32;
                            let p = self.sampler.at(xn, yn, 1.0 / lerp(inv, t));
                            self.probe.x[base + s] = p[0];
                            self.probe.y[base + s] = p[1];
                            self.probe.z[base + s] = p[2];
                            self.probe_t[base + s] = t;
                        }
                        self.probe_slot[probing] = i as u32;
                        self.probe_ray[probing] = [xn, yn, inv.0, inv.1];
                        probing += 1;
                        self.sampler.at(xn, yn, 1.0 / lerp(inv, 0.5))
                    }
                    Some((xn, yn, inv)) => {
                        self.sampler
                            .at(xn, yn, 1.0 / lerp(inv, unit_f32(self.rng.next_u32())))
                    }
                    None => self.sampler.candidate_in_block(&mut self.rng, b),
                }
            } else {
                self.sampler.candidate(&mut self.rng)
            };
            self.pop.x[i] = p[0];
            self.pop.y[i] = p[1];
            self.pop.z[i] = p[2];
        }
        if probing > 0 {
            self.probed = probing * k;
            kernel.evaluate(
                &self.left,
                &self.right,
                &mut self.probe,
                0..probing * k,
                &self.sharing,
                &mut self.scratch,
            );
            // Best probe of each immigrant so far: (t, fitness, probe index).
            for j in 0..probing {
                let (b, f) = first_fittest(&self.probe.raw_fitness[j * k..(j + 1) * k]);
                self.probe_best[j] = (self.probe_t[j * k + b], f, (j * k + b) as u32);
            }
            // Refinement: each stage spreads REFINE_PROBES depths evenly around the best probe
            // so far, the first over one stratum, each next over two spacings of the previous.
            // A stratum spans several pixels of disparity while the fitness peaks within a
            // fraction of one, so the first stage finds the right stratum more often than the
            // right depth.
            let mut width = 1.0 / k as f32;
            // Offset of refinement probe q from the centre, in units of the stage's width.
            let offset = |q: usize| (q as f32 + 0.5) / REFINE_PROBES as f32 - 0.5;
            for stage in 0..REFINE_STAGES {
                let fine = probing * (k + stage * REFINE_PROBES);
                for j in 0..probing {
                    let t0 = self.probe_best[j].0;
                    let [xn, yn, i0, i1] = self.probe_ray[j];
                    for q in 0..REFINE_PROBES {
                        let t = t0 + offset(q) * width;
                        let p = self
                            .sampler
                            .at(xn, yn, 1.0 / lerp((i0, i1), t.clamp(0.0, 1.0)));
                        let at = fine + j * REFINE_PROBES + q;
                        self.probe.x[at] = p[0];
                        self.probe.y[at] = p[1];
                        self.probe.z[at] = p[2];
                    }
                }
                self.probed += probing * REFINE_PROBES;
                kernel.evaluate(
                    &self.left,
                    &self.right,
                    &mut self.probe,
                    fine..fine + probing * REFINE_PROBES,
                    &self.sharing,
                    &mut self.scratch,
                );
                for j in 0..probing {
                    let r = fine + j * REFINE_PROBES;
                    let (b, f) = first_fittest(&self.probe.raw_fitness[r..r + REFINE_PROBES]);
                    if f > self.probe_best[j].1 {
                        let t = self.probe_best[j].0 + offset(b) * width;
                        self.probe_best[j] = (t.clamp(0.0, 1.0), f, (r + b) as u32);
                    }
                }
                width *= 2.0 / REFINE_PROBES as f32;
            }
            for (j, &slot) in self.probe_slot[..probing].iter().enumerate() {
                let (_, f, q) = self.probe_best[j];
                // The middle probe stays if all fail.
                if f > 0.0 {
                    let (i, q) = (slot as usize, q as usize);
                    self.pop.x[i] = self.probe.x[q];
                    self.pop.y[i] = self.probe.y[q];
                    self.pop.z[i] = self.probe.z[q];
                }
            }
        }
        let n = self.pop.len();
        self.pop
            .project_on(self.isa, &self.left, &self.right, from..n);
        self.redraw_outsiders(from);
    }

    /// Redraws the flies of `from..` (projected) that lie outside an image or the region of
    /// interest: each becomes what [`Engine::sample_fly`] would draw for it, one after the
    /// other (the same draws, the same flies, the generator left in the same state), but the
    /// candidates are checked in batches with the vectorised projection. One by one, a
    /// candidate rejected a third of the time made a chain of mispredicted branches and
    /// divisions (~160 cycles a candidate, ~6 us a generation).
    /// Returns how many candidates it drew.
    fn redraw_outsiders(&mut self, from: usize) -> usize {
        let n = self.pop.len();
        let (pop, sampler) = (&self.pop, &self.sampler);
        let outside = (from..n).map(|i| {
            pop.u_left[i].is_nan()
                | pop.u_right[i].is_nan()
                | !sampler.in_roi(&[pop.x[i], pop.y[i], pop.z[i]])
        });
        // Compaction is over: its scratch is free.
        let count = gather(outside, from, &mut self.holes);
        if count == 0 {
            return 0;
        }
        let start = self.rng.clone();
        let cap = self.probe.len();
        // Outsiders placed, candidates consumed, attempts spent on the current outsider.
        let (mut k, mut used, mut attempts) = (0, 0, 0);
        while k < count && cap > 0 {
            // About 1.5 candidates an outsider are needed: a batch rarely falls short.
            let batch = cap.min(2 * (count - k) + 16);
            for j in 0..batch {
                let p = self.sampler.candidate(&mut self.rng);
                (self.probe.x[j], self.probe.y[j], self.probe.z[j]) = (p[0], p[1], p[2]);
            }
            self.probe
                .project_on(self.isa, &self.left, &self.right, 0..batch);
            for j in 0..batch {
                if k == count {
                    break;
                }
                let (probe, i) = (&self.probe, self.holes[k] as usize);
                let p = [probe.x[j], probe.y[j], probe.z[j]];
                let seen = !probe.u_left[j].is_nan() && !probe.u_right[j].is_nan();
                used += 1;
                attempts += 1;
                if (seen && self.sampler.in_roi(&p)) || attempts == SAMPLE_ATTEMPTS {
                    (self.pop.x[i], self.pop.y[i], self.pop.z[i]) = (p[0], p[1], p[2]);
                    k += 1;
                    attempts = 0;
                }
            }
        }
        // Where the one-by-one draws would have left the generator: `used` candidates on.
        self.rng = start;
        for _ in 0..used {
            Sampler::skip_candidate(&mut self.rng);
        }
        used
    }

    /// The left-image ray (normalised coordinates) through the strongest gradient of
    /// `PIXEL_CANDIDATES` random points of block `b`: the fitness is proportional to the
    /// gradients, so an obstacle is found first where it has contrast.
    fn strongest_in_block(&mut self, b: usize, kernel: &Kernel) -> Option<(f32, f32)> {
        let mut best: Option<(f32, f32, u8)> = None;
        for _ in 0..PIXEL_CANDIDATES {
            let (xn, yn) = self.sampler.in_block(&mut self.rng, b)?;
            let p = self.sampler.at(xn, yn, 1.0);
            let g = self
                .left
                .project(p[0], p[1], p[2])
                .map_or(0, |(u, v)| kernel.left_gradient(u, v));
            if best.is_none_or(|(_, _, bg)| g > bg) {
                best = Some((xn, yn, g));
            }
        }
        best.map(|(xn, yn, _)| (xn, yn))
    }

    /// A new random fly (see the module docs); the flag says whether both cameras see it.
    fn sample_fly(&mut self) -> ([f32; 3], bool) {
        let mut p = [0.0; 3];
        for _ in 0..SAMPLE_ATTEMPTS {
            p = self.sampler.candidate(&mut self.rng);
            if self.sampler.in_roi(&p)
                && self.left.project(p[0], p[1], p[2]).is_some()
                && self.right.project(p[0], p[1], p[2]).is_some()
            {
                return (p, true);
            }
        }
        (p, false)
    }
}

dispatch! {
    /// [`warnings`] on instruction set `isa` (AVX2: 8 divisions at a time; the same bits).
    fn warnings_on(p: &mut Population, min_x: f32, min_z: f32) -> (f64, f64, f64, usize);
    up to Avx2 => warnings
}

dispatch! {
    fn project_on(pop: &mut Population, left: &Projector, right: &Projector, r: Range<usize>);
    up to Avx2 => Population::project_at
}

/// The body of [`Engine::warnings`]: the warning of every fly of `p` and the sums.
#[inline(always)]
fn warnings(_: Level, p: &mut Population, min_x: f32, min_z: f32) -> (f64, f64, f64, usize) {
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

/// What the offspring loop reads besides the parents' coordinates.
struct Breeding<'a> {
    /// `bits < guided`: the first parent comes from the breeders (a tournament among them).
    guided: u32,
    /// `bits < local`: the second parent comes from the first one's cell.
    local: u32,
    tournament: usize,
    /// Survivors where the image changed, and their fitness (before sharing).
    breeders: &'a [u32],
    breeder_fitness: &'a [f32],
    mates: sharing::Picker<'a>,
    /// Sharing cell of each parent.
    cell: &'a [u32],
}

dispatch! {
    /// [`breed_with`] compiled for instruction set `isa` (the same offspring on each: integer
    /// and f32 arithmetic only; AVX2 brings BMI2's shifts and rotations for the generator, and
    /// wider registers).
    fn breed(
        b: &Breeding,
        coords: [&mut [f32]; 3],
        children: Range<usize>,
        masks: &mut [u64],
        generator: &mut Xoshiro256PlusPlus,
    );
    up to Avx2 => breed_with
}

/// Writes one crossover offspring into each fly of `children` (of the coordinates `[x, y, z]`)
/// from the survivors `0..children.start`, and its mutation coins to `masks` (from 0). A
/// function of its own over disjoint slices, so the loop keeps the slices' pointers in
/// registers (through `&mut self`, every store could have moved them); parents and children
/// are read and written through one slice a coordinate, which keeps three pointers fewer.
#[inline(always)]
fn breed_with(
    _: Level,
    b: &Breeding,
    coords: [&mut [f32]; 3],
    children: Range<usize>,
    masks: &mut [u64],
    generator: &mut Xoshiro256PlusPlus,
) {
    // A static scene has no breeders: its loop carries none of the tournament's state.
    if b.breeders.is_empty() || b.breeder_fitness.is_empty() {
        breed_loop::<false>(b, coords, children, masks, generator);
    } else {
        breed_loop::<true>(b, coords, children, masks, generator);
    }
}

#[inline(always)]
fn breed_loop<const GUIDED: bool>(
    b: &Breeding,
    [x, y, z]: [&mut [f32]; 3],
    children: Range<usize>,
    masks: &mut [u64],
    generator: &mut Xoshiro256PlusPlus,
) {
    let n = x.len().min(y.len()).min(z.len());
    let keep = children.start.min(b.cell.len()).min(n);
    let end = children.end.min(n);
    let breeders = b.breeders.len().min(b.breeder_fitness.len());
    let fit = &b.breeder_fitness[..breeders];
    let (cell, mates) = (&b.cell[..keep], b.mates);
    if keep == 0 {
        return;
    }
    // A local copy: the generator's state stays in registers (through the reference, each
    // store to a child could have changed it, so it went through memory on every draw).
    let mut rng = generator.clone();
    for i in keep..end {
        let r = rng.next_u64();
        let mut a = lemire(r as u32, keep);
        if GUIDED {
            let g = rng.next_u64();
            if (g as u32) < b.guided {
                // Tournament: the fittest of `tournament` draws, two per random word.
                let mut best = lemire((g >> 32) as u32, breeders);
                let mut best_f = fit[best];
                let mut bits = 0;
                for k in 1..b.tournament {
                    if k % 2 == 1 {
                        bits = rng.next_u64();
                    }
                    let c = lemire((bits >> (32 * (k % 2))) as u32, breeders);
                    if fit[c] > best_f {
                        (best, best_f) = (c, fit[c]);
                    }
                }
                a = (b.breeders[best] as usize).min(keep - 1);
            }
        }
        let r2 = rng.next_u64();
        let m = if (r2 as u32) < b.local {
            mates
                .pick(cell[a], (r2 >> 32) as u32)
                .unwrap_or(a)
                .min(keep - 1)
        } else {
            lemire((r >> 32) as u32, keep)
        };
        let l = unit_f32(rng.next_u32());
        let c = crossover([x[a], y[a], z[a]], [x[m], y[m], z[m]], l);
        (x[i], y[i], z[i]) = (c[0], c[1], c[2]);
        if let Some(w) = masks.get_mut(i - keep) {
            *w = rng.next_u64();
        }
    }
    *generator = rng;
}

/// Barycentric crossover: `l * a + (1 - l) * b`.
#[inline]
pub fn crossover(a: [f32; 3], b: [f32; 3], l: f32) -> [f32; 3] {
    [
        l * a[0] + (1.0 - l) * b[0],
        l * a[1] + (1.0 - l) * b[1],
        l * a[2] + (1.0 - l) * b[2],
    ]
}

dispatch! {
    /// [`mutate`] compiled for instruction set `isa` (the same flies on each, as for
    /// [`breed`]), the coins' lists made 8 (AVX2) or 16 (AVX-512) coins at a time.
    fn mutate_on(
        coords: [&mut [f32]; 3],
        masks: &[u64],
        hits: &mut [u32],
        generator: &mut Xoshiro256PlusPlus,
        threshold: u32,
        sigma: f32,
    );
    up to Avx512 => mutate_at
}

#[inline(always)]
fn mutate_at(
    level: Level,
    coords: [&mut [f32]; 3],
    masks: &[u64],
    hits: &mut [u32],
    generator: &mut Xoshiro256PlusPlus,
    threshold: u32,
    sigma: f32,
) {
    let lists = |m: &[u64], t: u64, l: [&mut [u32]; 3]| match level {
        // SAFETY: the level is AVX-512 only in `mutate_on`'s AVX-512 function.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { coin_lists_avx512(m, t, l) },
        // SAFETY: as above, for AVX2.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { coin_lists_avx2(m, t, l) },
        _ => coin_lists(m, t, l, 0, [0; 3]),
    };
    mutate_with(coords, masks, hits, generator, threshold, sigma, lists);
}

/// Gaussian mutation of flies `[x, y, z]`: coordinate k of fly j moves with probability
/// `threshold / 65536` (bits 16k..16k+16 of `masks[j]` below it) by rand_distr's
/// `StandardNormal` times `sigma * max(z, 1)`, z before the mutation. A coin toss per coordinate
/// is a branch no predictor guesses, so the mutation is done in two passes: one pass over the
/// coins gathers, without branches, the indices of the flies each coordinate moves (into
/// `hits`, three lists of up to n: `hits` holds 3 per fly), then only those draw a normal,
/// coordinate by coordinate. Flies beyond `masks` or a third of `hits` are left as they are.
#[inline(always)]
pub fn mutate<R: Rng + Clone>(
    coords: [&mut [f32]; 3],
    masks: &[u64],
    hits: &mut [u32],
    generator: &mut R,
    threshold: u32,
    sigma: f32,
) {
    let lists = |m: &[u64], t: u64, l: [&mut [u32]; 3]| coin_lists(m, t, l, 0, [0; 3]);
    mutate_with(coords, masks, hits, generator, threshold, sigma, lists);
}

/// [`mutate`], the coins' lists made by `lists` (a [`coin_lists`] from 0).
#[inline(always)]
fn mutate_with<R: Rng + Clone>(
    [x, y, z]: [&mut [f32]; 3],
    masks: &[u64],
    hits: &mut [u32],
    generator: &mut R,
    threshold: u32,
    sigma: f32,
    lists: impl FnOnce(&[u64], u64, [&mut [u32]; 3]) -> [usize; 3],
) {
    // `hits` holds three lists of up to n indices, one per coordinate.
    let n = x
        .len()
        .min(y.len())
        .min(z.len())
        .min(masks.len())
        .min(hits.len() / 3);
    let (hx, rest) = hits.split_at_mut(n);
    let (hy, hz) = rest.split_at_mut(n);
    // One pass over the coins fills the three lists, without branches.
    let t = u64::from(threshold);
    let [cx, cy, cz] = lists(&masks[..n], t, [&mut *hx, &mut *hy, &mut *hz]);
    // z is mutated last: every coordinate's scale is the depth before the mutation. One loop
    // a coordinate, drawing from a local copy of the generator (see `breed`): a loop choosing
    // its coordinate per draw, through the reference, kept its state and half its values on
    // the stack.
    let (x, y, z) = (&mut x[..n], &mut y[..n], &mut z[..n]);
    let mut rng = generator.clone();
    for &j in &hx[..cx.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        x[j] += sigma * z[j].max(1.0) * g;
    }
    for &j in &hy[..cy.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        y[j] += sigma * z[j].max(1.0) * g;
    }
    for &j in &hz[..cz.min(n)] {
        let j = j as usize;
        let g: f32 = StandardNormal.sample(&mut rng);
        z[j] += sigma * z[j].max(1.0) * g;
    }
    *generator = rng;
}

/// The mutation's three lists (see [`mutate`]): into `lists[k]`, from `counts[k]` on, the index
/// (`base` + position) of every coin of `masks` whose chunk k is below `t`; returns the new
/// counts. Each list must have room for `counts[k] + masks.len()` entries (entries past the
/// count are scratch).
#[inline(always)]
fn coin_lists(
    masks: &[u64],
    t: u64,
    [hx, hy, hz]: [&mut [u32]; 3],
    base: usize,
    [mut cx, mut cy, mut cz]: [usize; 3],
) -> [usize; 3] {
    for (j, &m) in masks.iter().enumerate() {
        let j32 = (base + j) as u32;
        if let (Some(a), Some(b), Some(c)) = (hx.get_mut(cx), hy.get_mut(cy), hz.get_mut(cz)) {
            (*a, *b, *c) = (j32, j32, j32);
        }
        cx += usize::from(m & 0xffff < t);
        cy += usize::from((m >> 16) & 0xffff < t);
        cz += usize::from((m >> 32) & 0xffff < t);
    }
    [cx, cy, cz]
}

/// [`coin_lists`] from 0 with AVX-512: 16 coins at a time, compared in 64-bit lanes, their
/// indices compressed into each list with one masked store (a branch-free scalar pass cost
/// ~3 us a generation).
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
unsafe fn coin_lists_avx512(masks: &[u64], t: u64, lists: [&mut [u32]; 3]) -> [usize; 3] {
    use std::arch::x86_64::*;
    let n = masks
        .len()
        .min(lists[0].len())
        .min(lists[1].len())
        .min(lists[2].len());
    let full = n / 16 * 16;
    let mut counts = [0usize; 3];
    // SAFETY: the loads read 16 u64 at `j < full <= masks.len() - 16`; list k's store writes
    // the `popcount` lanes of a mask below 2^popcount at `counts[k]`, and counts[k] + popcount
    // <= j + 16 <= n <= the list's length (a list gets at most one entry per coin).
    unsafe {
        let tv = _mm512_set1_epi64(t as i64);
        let chunk = _mm512_set1_epi64(0xffff);
        for j in (0..full).step_by(16) {
            let m0 = _mm512_loadu_si512(masks.as_ptr().add(j).cast());
            let m1 = _mm512_loadu_si512(masks.as_ptr().add(j + 8).cast());
            let below = |a: __m512i, b: __m512i| {
                let lo = _mm512_cmplt_epu64_mask(_mm512_and_si512(a, chunk), tv);
                let hi = _mm512_cmplt_epu64_mask(_mm512_and_si512(b, chunk), tv);
                u16::from(lo) | (u16::from(hi) << 8)
            };
            let flags = [
                below(m0, m1),
                below(_mm512_srli_epi64::<16>(m0), _mm512_srli_epi64::<16>(m1)),
                below(_mm512_srli_epi64::<32>(m0), _mm512_srli_epi64::<32>(m1)),
            ];
            for (k, &f) in flags.iter().enumerate() {
                counts[k] += compress16(f, j, lists[k].as_mut_ptr().add(counts[k]));
            }
        }
    }
    let [hx, hy, hz] = lists;
    coin_lists(&masks[full..n], t, [hx, hy, hz], full, counts)
}

/// Writes `base + j` for every j whose flag is set to the front of `out` and returns how many
/// (at most `out.len()`). Without branches: every index is written and the cursor advances on a
/// set flag, so flags that are coin tosses cost no mispredictions.
#[inline]
fn gather(flags: impl Iterator<Item = bool>, base: usize, out: &mut [u32]) -> usize {
    let mut count = 0;
    for (j, f) in flags.enumerate() {
        if let Some(slot) = out.get_mut(count) {
            *slot = (base + j) as u32;
        }
        count += usize::from(f);
    }
    count.min(out.len())
}

dispatch! {
    /// [`gather`] of the flags equal to `set`, on instruction set `isa` (the same list on
    /// each).
    fn gather_flags(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize;
    up to Avx512 => gather_flags_at
}

#[inline(always)]
fn gather_flags_at(level: Level, flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    match level {
        // SAFETY: the level is AVX-512 only in `gather_flags`'s AVX-512 function.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { gather_flags_avx512(flags, set, base, out) },
        // SAFETY: as above, for AVX2.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { gather_flags_avx2(flags, set, base, out) },
        _ => gather(flags.iter().map(|&f| f == set), base, out),
    }
}

/// Writes the indices `base + lane` of the set bits of `mask` (16 lanes) at `out`, compressed
/// to the front with one masked store (only the count is written), and returns the count.
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL; `popcount(mask)` u32 must be writable at `out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
#[inline]
unsafe fn compress16(mask: u16, base: usize, out: *mut u32) -> usize {
    use std::arch::x86_64::*;
    let c = mask.count_ones();
    // SAFETY: the store writes the `c` lanes of a mask below 2^c; the caller guarantees them.
    unsafe {
        let idx = _mm512_add_epi32(
            _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
            _mm512_set1_epi32(base as i32),
        );
        let packed = _mm512_maskz_compress_epi32(mask, idx);
        _mm512_mask_storeu_epi32(out.cast(), ((1u32 << c) - 1) as u16, packed);
    }
    c as usize
}

/// For each 8-bit mask, the lanes of its set bits packed to the front (then zeros): the
/// permutation that compresses 8 lanes with AVX2, which has no compress instruction.
#[cfg(target_arch = "x86_64")]
static LEFT_PACK: [[u32; 8]; 256] = {
    let mut t = [[0u32; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let (mut lane, mut k) = (0, 0);
        while lane < 8 {
            if m & (1 << lane) != 0 {
                t[m][k] = lane as u32;
                k += 1;
            }
            lane += 1;
        }
        m += 1;
    }
    t
};

/// Writes the indices `base + lane` of the set bits of `mask` (8 lanes) at `out`, all 8 lanes
/// (those past the count are scratch), and returns the count.
///
/// # Safety
/// The CPU must support AVX2; 8 u32 must be writable at `out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
#[inline]
unsafe fn left_pack8(mask: u32, base: usize, out: *mut u32) -> usize {
    use std::arch::x86_64::*;
    let m = (mask & 0xff) as usize;
    // SAFETY: the table row is 8 u32; the caller guarantees the store.
    unsafe {
        let perm = _mm256_loadu_si256(LEFT_PACK[m].as_ptr().cast());
        let idx = _mm256_add_epi32(
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
            _mm256_set1_epi32(base as i32),
        );
        _mm256_storeu_si256(out.cast(), _mm256_permutevar8x32_epi32(idx, perm));
    }
    m.count_ones() as usize
}

/// [`gather_flags`] with AVX2: 8 flags at a time, packed with a permutation from
/// [`LEFT_PACK`] and stored whole (the lanes past the count are overwritten next).
///
/// # Safety
/// The CPU must support AVX2 (and BMI1/BMI2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
unsafe fn gather_flags_avx2(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let n = flags.len().min(out.len());
    let full = n / 8 * 8;
    let mut count = 0usize;
    // SAFETY: each load reads 8 bools at `j < full <= flags.len() - 8`; the store writes 8
    // lanes at `count <= j`, so up to j + 8 <= n <= out.len().
    unsafe {
        let want = _mm_set1_epi8(i8::from(set));
        for j in (0..full).step_by(8) {
            let f = _mm_loadl_epi64(flags.as_ptr().add(j).cast());
            let m = _mm_movemask_epi8(_mm_cmpeq_epi8(f, want)) as u32;
            count += left_pack8(m, base + j, out.as_mut_ptr().add(count));
        }
    }
    let tail = flags[full..n].iter().map(|&f| f == set);
    count + gather(tail, base + full, &mut out[count..])
}

/// [`coin_lists`] from 0 with AVX2: 8 coins at a time, compared in 64-bit lanes (the 16-bit
/// chunks and the threshold are far inside a signed compare), packed with [`left_pack8`].
///
/// # Safety
/// The CPU must support AVX2 (and BMI1/BMI2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
unsafe fn coin_lists_avx2(masks: &[u64], t: u64, lists: [&mut [u32]; 3]) -> [usize; 3] {
    use std::arch::x86_64::*;
    let n = masks
        .len()
        .min(lists[0].len())
        .min(lists[1].len())
        .min(lists[2].len());
    let full = n / 8 * 8;
    let mut counts = [0usize; 3];
    // SAFETY: the loads read 8 u64 at `j < full <= masks.len() - 8`; list k's store writes 8
    // lanes at `counts[k] <= j`, so up to j + 8 <= n <= the list's length.
    unsafe {
        // Chunks are below 2^16: a threshold clamped to 2^20 compares the same, signed.
        let tv = _mm256_set1_epi64x(t.min(1 << 20) as i64);
        let chunk = _mm256_set1_epi64x(0xffff);
        for j in (0..full).step_by(8) {
            let m0 = _mm256_loadu_si256(masks.as_ptr().add(j).cast());
            let m1 = _mm256_loadu_si256(masks.as_ptr().add(j + 4).cast());
            let below = |a: __m256i, b: __m256i| {
                let lo = _mm256_cmpgt_epi64(tv, _mm256_and_si256(a, chunk));
                let hi = _mm256_cmpgt_epi64(tv, _mm256_and_si256(b, chunk));
                let lo = _mm256_movemask_pd(_mm256_castsi256_pd(lo)) as u32;
                let hi = _mm256_movemask_pd(_mm256_castsi256_pd(hi)) as u32;
                lo | (hi << 4)
            };
            let flags = [
                below(m0, m1),
                below(_mm256_srli_epi64::<16>(m0), _mm256_srli_epi64::<16>(m1)),
                below(_mm256_srli_epi64::<32>(m0), _mm256_srli_epi64::<32>(m1)),
            ];
            for (k, &f) in flags.iter().enumerate() {
                let at = lists[k].as_mut_ptr().add(counts[k]);
                counts[k] += left_pack8(f, j, at);
            }
        }
    }
    let [hx, hy, hz] = lists;
    coin_lists(&masks[full..n], t, [hx, hy, hz], full, counts)
}

/// [`gather_flags`] with AVX-512: 16 flags at a time, their indices compressed into `out`
/// with one masked store.
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
unsafe fn gather_flags_avx512(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let n = flags.len().min(out.len());
    let full = n / 16 * 16;
    let mut count = 0usize;
    // SAFETY: each load reads 16 bools at `j < full <= flags.len() - 16`; the store writes the
    // `popcount` lanes of a mask below 2^popcount at `count`, and count + popcount <= j + 16
    // <= n <= out.len().
    unsafe {
        let want = _mm_set1_epi8(i8::from(set));
        for j in (0..full).step_by(16) {
            let f = _mm_loadu_si128(flags.as_ptr().add(j).cast());
            let m = _mm_cmpeq_epi8_mask(f, want);
            count += compress16(m, base + j, out.as_mut_ptr().add(count));
        }
    }
    let tail = flags[full..n].iter().map(|&f| f == set);
    count + gather(tail, base + full, &mut out[count..])
}

/// Probability `p` in [0, 1] as a threshold on 32 random bits: `bits < threshold` with
/// probability `p` (to within 2^-32).
#[inline]
fn unit_threshold(p: f64) -> u32 {
    (p * 4_294_967_296.0).min(u32::MAX as f64) as u32
}

/// Lemire's multiply-shift: 32 random bits to `0..n`, unbiased to within n / 2^32.
#[inline]
fn lemire(bits: u32, n: usize) -> usize {
    ((u64::from(bits) * n as u64) >> 32) as usize
}

/// The paper's warning of one fly, with its clamps.
#[inline]
pub fn warning(fitness: f32, x: f32, z: f32, min_abs_x: f32, min_z: f32) -> f32 {
    let ax = x.abs().max(min_abs_x);
    fitness / (ax * ax * z.max(min_z))
}

/// A uniform f32 in [0, 1) from 24 random bits.
#[inline]
fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[inline]
fn lerp((a, b): (f32, f32), t: f32) -> f32 {
    a + (b - a) * t
}

impl Sampler {
    /// Whether a new fly at `p` lies in the region of interest (always true without one).
    #[inline]
    fn in_roi(&self, p: &[f32; 3]) -> bool {
        self.heights.is_none_or(|(lo, hi)| p[1] >= lo && p[1] <= hi)
    }

    #[inline]
    fn point<R: Rng>(&self, xn: f32, yn: f32, rng: &mut R) -> [f32; 3] {
        self.at(xn, yn, 1.0 / lerp(self.inv_depth, unit_f32(rng.next_u32())))
    }

    /// A point in left-image block `b` (uniform over its normalised bounds), uniform in inverse
    /// depth.
    #[inline]
    fn candidate_in_block<R: Rng>(&self, rng: &mut R, b: usize) -> [f32; 3] {
        match self.in_block(rng, b) {
            Some((xn, yn)) => self.point(xn, yn, rng),
            None => self.candidate(rng),
        }
    }

    /// A point of left-image block `b`, uniform over its normalised bounds.
    #[inline]
    fn in_block<R: Rng>(&self, rng: &mut R, b: usize) -> Option<(f32, f32)> {
        let &[x0, x1, y0, y1] = self.blocks.get(b)?;
        let r = rng.next_u64();
        Some((
            lerp((x0, x1), unit_f32(r as u32)),
            lerp((y0, y1), unit_f32((r >> 32) as u32)),
        ))
    }

    /// The inverse-depth range of the left camera's ray through normalised `(xn, yn)` inside
    /// the search range and the road region of interest; `None` when no point qualifies.
    #[inline]
    fn ray_range(&self, xn: f32, yn: f32) -> Option<(f32, f32)> {
        let (mut near, mut far) = (1.0 / self.inv_depth.1, 1.0 / self.inv_depth.0);
        if let Some((lo, hi)) = self.heights {
            // Height along the ray: y(d) = c_y + d * k.
            let k = self.m[3] * xn + self.m[4] * yn + self.m[5];
            let c = self.c[1];
            if k.abs() < 1e-6 {
                if c < lo || c > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - c) / k, (hi - c) / k);
                near = near.max(a.min(b));
                far = far.min(a.max(b));
            }
        }
        (near < far).then(|| (1.0 / far, 1.0 / near))
    }

    /// The point at depth `d` along the left camera's ray through normalised `(xn, yn)`.
    #[inline]
    fn at(&self, xn: f32, yn: f32, d: f32) -> [f32; 3] {
        let cam = [xn * d, yn * d, d];
        let m = &self.m;
        [
            m[0] * cam[0] + m[1] * cam[1] + m[2] * cam[2] + self.c[0],
            m[3] * cam[0] + m[4] * cam[1] + m[5] * cam[2] + self.c[1],
            m[6] * cam[0] + m[7] * cam[1] + m[8] * cam[2] + self.c[2],
        ]
    }

    /// A point uniform over the left image's normalised bounds and uniform in inverse depth
    /// (possibly outside one of the images: callers check).
    #[inline]
    fn candidate<R: Rng>(&self, rng: &mut R) -> [f32; 3] {
        let r = rng.next_u64();
        let xn = lerp(self.xn, unit_f32(r as u32));
        let yn = lerp(self.yn, unit_f32((r >> 32) as u32));
        self.point(xn, yn, rng)
    }

    /// Advances `rng` past the draws of one [`Sampler::candidate`] (tested to agree).
    #[inline]
    fn skip_candidate<R: Rng>(rng: &mut R) {
        rng.next_u64();
        rng.next_u32();
    }

    fn new(rig: &StereoRig, params: &EngineParams) -> Result<Self, EngineError> {
        let cam = &rig.left;
        let (w, h) = (cam.width() as f64, cam.height() as f64);
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        // The undistorted image of the border bounds the left field of view.
        let steps = 64;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            for (u, v) in [
                (t * (w - 1.0), 0.0),
                (t * (w - 1.0), h - 1.0),
                (0.0, t * (h - 1.0)),
                (w - 1.0, t * (h - 1.0)),
            ] {
                let (xn, yn) = cam
                    .normalised_from_pixel(u, v)
                    .ok_or(EngineError::NotInvertible)?;
                x0 = x0.min(xn);
                x1 = x1.max(xn);
                y0 = y0.min(yn);
                y1 = y1.max(yn);
            }
        }
        let cols = (w as usize).div_ceil(BLOCK);
        let rows = (h as usize).div_ceil(BLOCK);
        let mut blocks = Vec::with_capacity(cols * rows);
        for by in 0..rows {
            for bx in 0..cols {
                let (u0, v0) = ((bx * BLOCK) as f64 - 0.5, (by * BLOCK) as f64 - 0.5);
                let (u1, v1) = (
                    (u0 + BLOCK as f64).min(w - 0.5),
                    (v0 + BLOCK as f64).min(h - 0.5),
                );
                let (mut b, mut ok) = ([f32::MAX, f32::MIN, f32::MAX, f32::MIN], true);
                for (u, v) in [(u0, v0), (u1, v0), (u0, v1), (u1, v1)] {
                    match cam.normalised_from_pixel(u, v) {
                        Some((xn, yn)) => {
                            b = [
                                b[0].min(xn as f32),
                                b[1].max(xn as f32),
                                b[2].min(yn as f32),
                                b[3].max(yn as f32),
                            ]
                        }
                        None => ok = false,
                    }
                }
                // A block the model cannot invert falls back to the whole image.
                blocks.push(if ok {
                    b
                } else {
                    [x0 as f32, x1 as f32, y0 as f32, y1 as f32]
                });
            }
        }
        // With a road region of interest, new flies are drawn inside it: flies outside it get
        // the penalised fitness anyway, so drawing them there only wastes evaluations.
        let far = match &params.roi {
            Some(roi) => params.max_depth.min(roi.max_ahead),
            None => params.max_depth,
        };
        let heights = params
            .roi
            .map(|roi| (roi.min_height as f32, roi.max_height as f32));
        let origin = cam.vehicle_from_camera(&nalgebra::Point3::origin());
        let ex = cam.vehicle_from_camera(&nalgebra::Point3::new(1.0, 0.0, 0.0)) - origin;
        let ey = cam.vehicle_from_camera(&nalgebra::Point3::new(0.0, 1.0, 0.0)) - origin;
        let ez = cam.vehicle_from_camera(&nalgebra::Point3::new(0.0, 0.0, 1.0)) - origin;
        Ok(Self {
            xn: (x0 as f32, x1 as f32),
            yn: (y0 as f32, y1 as f32),
            inv_depth: ((1.0 / far) as f32, (1.0 / params.min_depth) as f32),
            blocks,
            heights,
            m: [
                ex.x as f32,
                ey.x as f32,
                ez.x as f32,
                ex.y as f32,
                ey.y as f32,
                ez.y as f32,
                ex.z as f32,
                ey.z as f32,
                ez.z as f32,
            ],
            c: [origin.x as f32, origin.y as f32, origin.z as f32],
        })
    }
}

#[cfg(test)]
mod tests;
