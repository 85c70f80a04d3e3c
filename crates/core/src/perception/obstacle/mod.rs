//! The nearest obstacle in the vehicle's corridor, in metres, from flies whose match is unique.
//!
//! Which flies count ([`ObstacleFinder::find`]):
//! 1. **Candidates**: flies with a positive fitness (after the region of interest, before
//!    sharing) inside the corridor: at most `corridor_half_width` off the vehicle's predicted
//!    path ([`PredictedPath`]: the arc of its trusted speed and yaw rate, straight ahead
//!    without them), `min_height..=max_height` above the measured road, at most
//!    `max_distance` along the path. Flies on the road, above the vehicle or off the corridor
//!    are no obstacle; an obstacle's distance is along the path, its lateral offset from it.
//! 2. **A sample** of them, met in a fixed stride order over the population (unrelated to
//!    position or fitness), until `candidates` needed a measurement: a fly measured on this
//!    frame that has not moved since (a survivor) is taken from a memo at no cost, so the
//!    sample holds up to 4 x `candidates` flies. This generation's immigrants are not in it:
//!    drawn at random an instant ago, most match nothing (on KITTI's seq12 frame 11 they were
//!    177 of the 321 corridor flies, 133 of them nearer than 2 m with a fitness of 0.01-0.04
//!    against 0.16-0.9 on the car 13.6 m ahead, and took half of every sample's
//!    measurements); one that found something survives or breeds and is sampled on the next
//!    generation. The fittest flies are not the ones to take.
//!    The paper's fitness rewards gradients, and the strongest gradients are the horizontal
//!    edges (a head's top, a roof, a bumper) whose match is the most ambiguous: on hw-mock's
//!    pedestrian the 200 fittest corridor flies were all ambiguous while 72 % of the corridor
//!    flies on it were unique.
//! 3. **Unique matches** only: the fly's fitness against the best of its left pixel at 2 and 4
//!    pixels of disparity nearer and farther ([`Engine::ambiguity`], as SGBM's
//!    `uniquenessRatio`) is at most `max_ambiguity`. A fly on a horizontal edge or a repeated
//!    texture matches at many depths and proves nothing at its own.
//! 4. **The nearest cluster**: scanning the unique flies by depth, the first window of
//!    `max(min_cluster_depth, cluster_disparity_px z^2 / (f B))` metres (two pixels of
//!    disparity: what stereo resolves at that depth) holding at least `min_flies` of them
//!    within `cluster_width` of one another laterally (a handful of chance matches scattered
//!    over the image at one depth is no object; on hw-mock's drive, 8 of them over 480 px
//!    made one at 1.7 m), in
//!    at least `min_cells` distinct `cell_px`-pixel squares of the left image, over at least
//!    two rows of them, and `MIN_WIDTH_PX` columns and `min_width` metres wide (4 median
//!    absolute deviations of its cells' positions, each cell once: the width of a uniform
//!    spread, robust to a few strays and to flies piled on one feature).
//!    An obstacle is seen in several places of the
//!    image, across and up; a false match is one place, however many flies crowd on it (on
//!    KITTI 2015 #0, 12 flies on one lane-marking tip, 4.7 px of disparity off the truth, made
//!    a 0.4 m "obstacle" at 18.8 m; 7 on one facade window at 1.1 m), or one vertical edge (on
//!    hw-mock's empty road, the end of one roadside wall matched with the end of the next one,
//!    102-118 px of disparity off, made a 1.3-1.5 m "obstacle" 1 cm wide; on hw-mock's drive,
//!    a row of identical trees on the horizon matched a tree off, one at 2.1 m). A real
//!    obstacle near the vehicle is large in the image. The price: an object narrower than
//!    0.1 m, or than 4 px (a 0.1 m pole beyond 13 m at 640 px), may not be reported.
//!    And it **reaches down to the road**: its lowest fly at most `max_bottom` (1.2 m) above
//!    it. What a vehicle hits stands on the road or hangs low (a bumper is 0.3-0.6 m up, an
//!    underrun guard at most 0.55 m, a barrier arm ~1 m; the cars of KITTI's seq12 and
//!    000151 had their lowest fly 0.30-0.49 m up). Near the top of the corridor, above the
//!    cameras, a ray crosses the corridor only close to the vehicle and sees what is far
//!    beyond it: on KITTI odometry 00 frame 1 a tree trunk 22-35 m away matched with the
//!    next one of the row made a cluster at 8.1 m, 1.6-1.95 m up, unique, verified along the
//!    line and by the dense check, on 1-4 of 100 seeds. The price: an overhang with nothing
//!    of it lower than 1.2 m in the corridor (a branch, a load at head height) is not
//!    reported.
//!
//! 5. **Verified along the line**: the `verify_flies` fittest flies of the cluster are
//!    compared with the best match of their left pixel, and of their right pixel, along the
//!    whole epipolar line ([`Engine::line_ambiguity`], every `line_step_px`): a repeated
//!    structure matches a period away (on hw-mock's empty road, 30 flies on one pole matched
//!    with the next pole 102 px of disparity off made a 1.5 m "obstacle" unique within 4 px).
//!    Each of them holds when it is unique there too (ambiguity at most `max_line_ambiguity`)
//!    and, where the line offers it a rival, a larger window does not prefer another disparity
//!    ([`super::dense`]). Unless half of them hold, the cluster is dropped and the next one
//!    looked at (at most `MAX_VERIFIED` an estimate). A vote per fly: one fly at a silhouette,
//!    whose larger window sees the background, does not drop a cluster.
//!    Verdicts are kept for the frame: a cluster at the same depth on the same frame is not
//!    verified again. (The fittest flies of hw-mock's pedestrian measure 0.002-0.1 along the
//!    line, those of its car 0.25-0.95: the car's texture is mostly horizontal lines.)
//!
//! The obstacle is that cluster: its near face (the first quartile of its flies' distances) and
//! lateral offset, the heights of its lowest and highest fly above the road, its size, and a
//! confidence that grows with it (100 % at four times `min_flies`). Whether it persisted over
//! frames is the [`super::track::Tracker`]'s. No allocation: every buffer is sized in
//! [`ObstacleFinder::new`].

use serde::Serialize;

use crate::engine::{Engine, EngineError};
use crate::frame::StereoFrame;
use crate::path::PredictedPath;
use crate::road_plane::RoadPlane;

mod cluster;
mod config;

use cluster::{CellSet, Unique, cell_centre, nearest_cluster, reaches_the_road, stride_for};
pub use config::{ObstacleConfig, PathKind, PerceptionParamError};

/// The nearest obstacle in the corridor, vehicle frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Obstacle {
    /// Ahead, metres along the vehicle's predicted path (straight: vehicle z): the cluster's
    /// near face, the first quartile of its flies' distances (its median read ~1 m long on
    /// hw-mock's pedestrian at 23 m, where a pixel of disparity is 3.4 m).
    pub distance: f64,
    /// The nearest it may be, metres: `distance` with `disparity_error_px` more disparity.
    /// What the decision judges it at (the stopping distance is a bound, and the depth of a
    /// few pixels of disparity is uncertain by metres).
    pub near: f64,
    /// Where the cluster is along the path, metres, each cell of the left image counted once
    /// (the median of its cells' median distances): what its track's motion is fitted to
    /// ([`super::track`]). Flies pile on a few features of an obstacle, each pile at its own
    /// sub-pixel error (on hw-mock's car followed 13.7 m ahead, its left edge read 13.0 m, its
    /// right 14.2 m, its plate 13.6-14.0 m), and `distance`, a quartile of the flies a sample
    /// met, jumped 0.7 m between frames as the sample met one pile more than another: a
    /// car followed at a steady gap read 1-2 m/s closing.
    pub centre: f64,
    /// Lateral offset from the predicted path, metres (straight: vehicle x), positive right:
    /// the cluster's median (beside the corridor, [`ObstacleFinder::watching`]: its quartile
    /// nearest the path).
    pub lateral: f64,
    /// Height above the road of the cluster's lowest fly, metres.
    pub bottom: f64,
    /// ... and of its highest.
    pub top: f64,
    /// Unique flies in the cluster.
    pub flies: usize,
    /// Distinct `cell_px` squares of the left image they lie in.
    pub cells: usize,
    /// 0..=100 %: grows with `flies`, 100 at four times `min_flies`.
    pub confidence: f64,
}

/// One estimate's look at the corridor, whether or not it found an obstacle (for logs and
/// traces).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct CorridorCounts {
    /// Flies in the corridor (step 1), estimated from the share of the population scanned.
    pub candidates: usize,
    /// Of which measured (step 2).
    pub sampled: usize,
    /// Of which unique (step 3).
    pub unique: usize,
}

/// The obstacle stage, with its buffers (see the module docs).
#[derive(Debug, Clone)]
pub struct ObstacleFinder {
    config: ObstacleConfig,
    /// The corridor's centre line: the vehicle's predicted path (straight unless set).
    path: PredictedPath,
    /// A fly is in the corridor only if it is also this close to this path (the arc the
    /// vehicle is turning on now, while it has not held it: [`crate::path::PathEstimate`]).
    gate: PredictedPath,
    /// Instead of the path: the fan of every path up to this curvature either way, 1/m
    /// (a motion fault: [`ObstacleConfig::fault_yaw_rate`]).
    fan: Option<f64>,
    /// Instead of the corridor: the flies this far off the path, metres (signed, positive
    /// right; [`ObstacleFinder::watching`]); none on a fan.
    band: Option<(f32, f32)>,
    /// Disparity (pixels) per m^-1 of inverse depth: f B.
    pixels_per_inverse_depth: f64,
    /// The sampled flies (what the stage needs of each, read once from the population) and
    /// their ambiguities.
    sample: Vec<Unique>,
    ambiguity: Vec<f32>,
    /// Per fly of the population: the position (bits) its ambiguity was measured at, on the
    /// frame of epoch `epoch`, and that ambiguity. A fly that survived selection unmoved on
    /// the same frame has the same ambiguity: it is not measured again (23 of the 151
    /// flies of a sample on hw-mock's `pedestrian-4m`, `flyd bench`). A new frame starts a
    /// new epoch (no pass over the memo).
    memo: Vec<Memo>,
    memo_frame: u64,
    epoch: u32,
    /// The sampled flies not in the memo, where they are in the sample, their positions
    /// (bits), their ambiguities.
    todo: Vec<u32>,
    todo_at: Vec<u32>,
    todo_at_position: Vec<[u32; 3]>,
    todo_out: Vec<f32>,
    /// (depth, left-image cell, index) of the unique flies.
    unique: Vec<Unique>,
    scratch: Vec<f32>,
    cells: CellSet,
    counts: CorridorCounts,
    /// The flies of the cluster being looked at.
    members: Vec<Unique>,
    /// The flies of a cluster being verified, and their line ambiguities.
    verify: Vec<u32>,
    verify_out: Vec<f32>,
    /// Verdicts on this frame's clusters: (frame, nearest depth, farthest depth, genuine).
    verdicts: [(u64, f32, f32, bool); MAX_VERIFIED * 2],
    verdict_next: usize,
}

/// An ambiguity measured: at which position (bits), on which frame (epoch).
#[derive(Debug, Clone, Copy)]
struct Memo {
    at: [u32; 3],
    epoch: u32,
    ambiguity: f32,
}

impl Memo {
    /// No position: `u32::MAX` bits are a NaN, which no fly in the corridor has.
    const EMPTY: Self = Self {
        at: [u32::MAX; 3],
        epoch: 0,
        ambiguity: f32::NAN,
    };
}

/// The sample holds at most this many flies per `candidates` (the rest from the memo).
const SAMPLE_PER_CANDIDATE: usize = 4;

/// A verified fly whose best match elsewhere on the line is more than this share of its own
/// fitness has a rival there: the dense window arbitrates (see [`super::dense`]).
const DENSE_RIVAL: f64 = 0.5;

/// Beside the corridor an obstacle's lateral offset is its inner edge: the first of this many
/// quantiles of its flies' offsets, from the path. With the quartile, the flies on a car
/// parked beside the lane on hw-mock (`between-parked-cars-30kmh`, watch zones 3 m wide)
/// read 2.13-2.9 m off the path for its inner side at 2.25 m, and their drift inwards as more
/// of it was found was taken for someone walking in: a STOP on both seeds; with the decile,
/// on one.
const INNER_OF: usize = 10;

/// Clusters verified along the line per estimate, at most.
pub const MAX_VERIFIED: usize = 3;

impl ObstacleFinder {
    /// Buffers for `flies` flies, for a rig of `pixels_per_inverse_depth` = f B whose left
    /// images are `image` (width, height) pixels.
    pub fn new(
        config: ObstacleConfig,
        flies: usize,
        pixels_per_inverse_depth: f64,
        image: (u32, u32),
    ) -> Self {
        let k = config.candidates;
        Self {
            config,
            path: PredictedPath::STRAIGHT,
            gate: PredictedPath::STRAIGHT,
            fan: None,
            band: None,
            pixels_per_inverse_depth,
            sample: Vec::with_capacity(SAMPLE_PER_CANDIDATE * k),
            ambiguity: vec![0.0; SAMPLE_PER_CANDIDATE * k],
            memo: vec![Memo::EMPTY; flies],
            memo_frame: u64::MAX,
            epoch: 0,
            todo: Vec::with_capacity(k),
            todo_at: Vec::with_capacity(k),
            todo_at_position: Vec::with_capacity(k),
            todo_out: vec![0.0; k],
            unique: Vec::with_capacity(SAMPLE_PER_CANDIDATE * k),
            scratch: Vec::with_capacity(SAMPLE_PER_CANDIDATE * k),
            cells: CellSet::new(image, config.cell_px),
            counts: CorridorCounts::default(),
            members: Vec::with_capacity(SAMPLE_PER_CANDIDATE * k),
            verify: Vec::with_capacity(SAMPLE_PER_CANDIDATE * k),
            verify_out: vec![0.0; 32],
            verdicts: [(u64::MAX, 0.0, 0.0, false); MAX_VERIFIED * 2],
            verdict_next: 0,
        }
    }

    pub fn config(&self) -> &ObstacleConfig {
        &self.config
    }

    /// This finder looks beside the corridor instead of in it: at the flies from `inner` to
    /// `outer` metres off the path (signed, positive right: `1.2, 4.0` is the band right of
    /// a 1.2 m half-width corridor), everything else as in the corridor; on a fan (an
    /// untrusted motion) it finds nothing. What [`super::crossing`] watches.
    pub fn watching(self, inner: f64, outer: f64) -> Self {
        let (lo, hi) = if inner <= outer {
            (inner, outer)
        } else {
            (outer, inner)
        };
        Self {
            band: Some((lo as f32, hi as f32)),
            ..self
        }
    }

    /// The corridor follows `path` from the next [`ObstacleFinder::find`] on: a fly's
    /// distance is along it, its lateral position is its offset from it.
    pub fn set_path(&mut self, path: PredictedPath) {
        self.set_paths(path, path);
    }

    /// As [`ObstacleFinder::set_path`], and a fly must also be within the corridor's
    /// half-width of `gate` (an obstacle on both paths; `gate == path`: no second test).
    pub fn set_paths(&mut self, path: PredictedPath, gate: PredictedPath) {
        self.path = path;
        self.gate = gate;
        self.fan = None;
    }

    /// The corridor covers every path bending up to `max_curvature` (1/m) either way from the
    /// next [`ObstacleFinder::find`] on, until [`ObstacleFinder::set_paths`]: a fly's distance
    /// is along the nearest of those paths, its offset from it ([`crate::path::nearest_in_fan`]).
    pub fn set_fan(&mut self, max_curvature: f64) {
        self.set_paths(PredictedPath::STRAIGHT, PredictedPath::STRAIGHT);
        self.fan = (max_curvature != 0.0).then_some(max_curvature.abs());
    }

    /// The fan the corridor covers (its largest curvature, 1/m), if it does.
    pub fn fan(&self) -> Option<f64> {
        self.fan
    }

    /// Looks `max_distance` metres ahead along the path from the next
    /// [`ObstacleFinder::find`] on (the configured `max_distance` unless set:
    /// [`crate::perception::range`]).
    pub fn set_max_distance(&mut self, max_distance: f64) {
        self.config.max_distance = max_distance;
    }

    /// The path the corridor follows.
    pub fn path(&self) -> PredictedPath {
        self.path
    }

    /// What the latest [`ObstacleFinder::find`] looked at.
    pub fn counts(&self) -> CorridorCounts {
        self.counts
    }

    /// The left-image pixels and depths of the latest estimate's unique corridor flies:
    /// where something in the corridor was seen, whether or not it made an obstacle.
    pub fn unique_pixels(&self) -> impl Iterator<Item = (f32, f32, f32)> + '_ {
        self.unique.iter().map(|u| (u.u, u.v, u.z))
    }

    /// The nearest obstacle in the corridor of `engine`'s population above `road`; `frame` is
    /// that of the engine's latest step.
    pub fn find(
        &mut self,
        engine: &mut Engine,
        frame: &StereoFrame,
        road: &RoadPlane,
    ) -> Result<Option<Obstacle>, EngineError> {
        let c = self.config;
        if self.band.is_some() && self.fan.is_some() {
            self.unique.clear();
            self.counts = CorridorCounts::default();
            return Ok(None);
        }
        let pop = engine.population();
        // The band off the path a fly must be in: the corridor, or the one watched.
        let (band_lo, band_hi) = self
            .band
            .unwrap_or((-c.corridor_half_width as f32, c.corridor_half_width as f32));
        let (half, lo, hi, far) = (
            band_lo.abs().max(band_hi.abs()),
            c.min_height as f32,
            c.max_height as f32,
            c.max_distance as f32,
        );
        let [r0, rz, rx] = road.coefficients();
        // The sample: the corridor flies met in a stride order over the population (a fixed
        // permutation unrelated to position or fitness), until `candidates` of them needed a
        // measurement. A fly measured on this frame that has not moved since (a survivor) is
        // taken from the memo at no cost, so the sample grows over a frame's generations.
        // Scanning stops there: a full pass over 5000 flies cost ~25 us, more than the rest.
        let len = pop.len();
        if self.memo_frame != frame.id || self.memo.len() < len {
            self.memo_frame = frame.id;
            self.epoch = self.epoch.wrapping_add(1);
            if self.epoch == 0 || self.memo.len() < len {
                // Every 2^32 frames (and if the population grew): a memo of no epoch.
                self.epoch = 1;
                self.memo.clear();
                self.memo.resize(len, Memo::EMPTY);
            }
        }
        let stride = stride_for(len);
        // This generation's immigrants (the population's last slots) are not sampled: see the
        // module docs, step 2.
        let immigrants_from = len - engine.params().immigrants().min(len);
        let wanted = c.candidates.min(engine.ambiguity_capacity());
        let most = self.ambiguity.len();
        self.sample.clear();
        self.todo.clear();
        self.todo_at.clear();
        self.todo_at_position.clear();
        let cell_px = c.cell_px.max(1) as f32;
        let mut i = 0usize;
        let mut scanned = 0;
        let fan = self.fan;
        let paths = crate::path::PathEstimate {
            held: self.path,
            now: self.gate,
        };
        while scanned < len && self.todo.len() < wanted && self.sample.len() < most {
            let (x, y, z) = (pop.x[i], pop.y[i], pop.z[i]);
            let h = y - (r0 + rz * z + rx * x);
            // Where it is along the predicted path and off it (straight: z and x), if it is
            // in the corridor.
            let located = if let Some(k) = fan.filter(|_| z > 0.0) {
                let (along, off) = crate::path::nearest_in_fan(k, x, z).locate(x, z);
                (off.abs() <= half).then_some((along, off))
            } else {
                paths
                    .locate_in(x, z, half)
                    .filter(|&(_, off)| (band_lo..=band_hi).contains(&off))
            };
            let inside = i < immigrants_from
                && pop.raw_fitness[i] > 0.0
                && (lo..=hi).contains(&h)
                && z > 0.0
                && located.is_some_and(|(along, _)| along <= far);
            if let (true, Some((along, off))) = (inside, located) {
                let m = self.memo[i];
                let at = [x.to_bits(), y.to_bits(), z.to_bits()];
                if m.epoch == self.epoch && m.at == at {
                    self.ambiguity[self.sample.len()] = m.ambiguity;
                } else {
                    self.todo.push(i as u32);
                    self.todo_at.push(self.sample.len() as u32);
                    self.todo_at_position.push(at);
                }
                // Inside the image (the fly has a fitness): u, v >= -0.5.
                let (u, v) = (pop.u_left[i], pop.v_left[i]);
                let (cu, cv) = (((u + 0.5) / cell_px) as u32, ((v + 0.5) / cell_px) as u32);
                self.sample.push(Unique {
                    z,
                    along,
                    cell: (cv << 16) | (cu & 0xFFFF),
                    u,
                    v,
                    x: off,
                    h,
                    index: i as u32,
                });
            }
            scanned += 1;
            // (i + stride) % len, without a division: stride < len.
            i += stride;
            if i >= len {
                i -= len;
            }
        }
        let k = self.sample.len();
        // Corridor flies in the population, estimated from the scanned share.
        let n = (k * len).checked_div(scanned).unwrap_or(0);
        let measured = self.measure(engine, frame)?;
        self.unique.clear();
        self.unique.extend(
            self.sample[..measured]
                .iter()
                .zip(&self.ambiguity[..measured])
                .filter(|&(_, &a)| f64::from(a) <= c.max_ambiguity)
                .map(|(u, _)| *u),
        );
        self.counts = CorridorCounts {
            candidates: n,
            sampled: measured,
            unique: self.unique.len(),
        };
        // By depth, then index: one integer per fly (a sample's depths are positive, where
        // the bits of an f32 sort as its value).
        self.unique
            .sort_unstable_by_key(|u| (u64::from(u.z.to_bits()) << 32) | u64::from(u.index));
        let mut start = 0;
        let mut found = None;
        for _ in 0..MAX_VERIFIED {
            let Some((to, cells)) = nearest_cluster(
                &self.unique[start..],
                &c,
                self.pixels_per_inverse_depth,
                &mut self.cells,
                &mut self.members,
            ) else {
                break;
            };
            if reaches_the_road(&self.members, &c) && self.genuine(engine, frame)? {
                found = Some(cells);
                break;
            }
            start += to;
        }
        let Some(cells) = found else {
            return Ok(None);
        };
        let centre = f64::from(cell_centre(&mut self.members, &mut self.scratch));
        let cluster = &self.members;
        let quantile = |scratch: &mut Vec<f32>, f: fn(&Unique) -> f32, q: usize| {
            quantile_of(cluster, scratch, f, q, 4)
        };
        // The near face (the first quartile of depth): what braking must stop before, along
        // the path (straight: the depth).
        let depth = quantile(&mut self.scratch, |u| u.z, 1);
        // Across: the median in the corridor; beside it, the decile nearest the path (its
        // inner edge, [`INNER_OF`]). A car parked beside the lane shows more of its side as
        // the vehicle nears it, and its flies' median drifts towards the path (0.4-1.4 m/s on
        // hw-mock's parked cars); its inner edge stays where it is, and a pedestrian's moves
        // with them.
        let lateral = across(cluster, self.band, &mut self.scratch);
        let f_b = self.pixels_per_inverse_depth;
        // Half a pixel of disparity nearer: in depth, then along the path by as much.
        let near_depth = f_b / (f_b / depth + c.disparity_error_px);
        let (distance, near) = if self.path.is_straight() && self.fan.is_none() {
            (depth, near_depth)
        } else {
            let along = quantile(&mut self.scratch, |u| u.along, 1);
            (along, along - (depth - near_depth))
        };
        let (bottom, top) = cluster
            .iter()
            .fold((f32::MAX, f32::MIN), |(b, t), u| (b.min(u.h), t.max(u.h)));
        let flies = cluster.len();
        Ok(Some(Obstacle {
            distance,
            near,
            centre,
            lateral,
            bottom: f64::from(bottom),
            top: f64::from(top),
            flies,
            cells,
            confidence: (100.0 * flies as f64 / (4 * c.min_flies) as f64).min(100.0),
        }))
    }
}

/// The `q`-th of `of` quantiles of `f` over `cluster` (not empty), through `scratch`.
fn quantile_of(
    cluster: &[Unique],
    scratch: &mut Vec<f32>,
    f: fn(&Unique) -> f32,
    q: usize,
    of: usize,
) -> f64 {
    scratch.clear();
    scratch.extend(cluster.iter().map(f));
    let at = (scratch.len() * q / of).min(scratch.len().saturating_sub(1));
    f64::from(*scratch.select_nth_unstable_by(at, f32::total_cmp).1)
}

/// Where `cluster` (not empty) is across the path, metres: its median in the corridor
/// (`band` none); in a band beside it, its inner edge ([`INNER_OF`]).
fn across(cluster: &[Unique], band: Option<(f32, f32)>, scratch: &mut Vec<f32>) -> f64 {
    match band {
        Some((lo, _)) if lo >= 0.0 => quantile_of(cluster, scratch, |u| u.x, 1, INNER_OF),
        Some(_) => quantile_of(cluster, scratch, |u| u.x, INNER_OF - 1, INNER_OF),
        None => quantile_of(cluster, scratch, |u| u.x, 2, 4),
    }
}

impl ObstacleFinder {
    /// The ambiguities of the sample's flies not in the memo (`todo`) into `ambiguity` and
    /// the memo; how many of the sample have one.
    fn measure(&mut self, engine: &mut Engine, frame: &StereoFrame) -> Result<usize, EngineError> {
        let n = self.todo.len();
        let measured = engine.ambiguity(frame, &self.todo, &mut self.todo_out[..n])?;
        for (((&i, &j), &at), &a) in self
            .todo
            .iter()
            .zip(&self.todo_at)
            .zip(&self.todo_at_position)
            .zip(&self.todo_out[..measured])
        {
            self.ambiguity[j as usize] = a;
            self.memo[i as usize] = Memo {
                at,
                epoch: self.epoch,
                ambiguity: a,
            };
        }
        // The sample is at most the engine's capacity: every fly was measured.
        Ok(if measured == n { self.sample.len() } else { 0 })
    }

    /// Whether the cluster in `members` holds up along the epipolar line (see the module
    /// docs, step 5); the verdict is kept for the frame.
    fn genuine(&mut self, engine: &mut Engine, frame: &StereoFrame) -> Result<bool, EngineError> {
        let c = self.config;
        let cluster = &self.members;
        let (near, far) = cluster
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), u| (a.min(u.z), b.max(u.z)));
        if c.verify_flies == 0 {
            return Ok(true);
        }
        let known = self
            .verdicts
            .iter()
            .find(|&&(f, lo, hi, _)| f == frame.id && near <= hi && far >= lo);
        if let Some(&(_, _, _, genuine)) = known {
            return Ok(genuine);
        }
        let k = c.verify_flies.min(cluster.len());
        // The fittest of the cluster: a genuine obstacle's best matches are its surest.
        self.verify.clear();
        self.verify.extend(cluster.iter().map(|u| u.index));
        let fitness = &engine.population().raw_fitness;
        let by_fitness = |a: &u32, b: &u32| {
            fitness[*b as usize]
                .total_cmp(&fitness[*a as usize])
                .then(a.cmp(b))
        };
        if k < self.verify.len() {
            self.verify.select_nth_unstable_by(k - 1, by_fitness);
            self.verify.truncate(k);
        }
        let out = &mut self.verify_out[..k];
        engine.line_ambiguity(frame, &self.verify, c.line_step_px as f32, out)?;
        // Each verified fly votes (`holds`); the cluster is genuine when half of them hold.
        let pop = engine.population();
        let params = engine.params();
        let f_b = self.pixels_per_inverse_depth;
        let range = (
            (f_b / params.max_depth).floor().max(0.0) as u32,
            (f_b / params.min_depth).ceil().max(0.0) as u32,
        );
        let mut hold = 0usize;
        for (&i, &a) in self.verify.iter().zip(out.iter()) {
            let i = i as usize;
            let dense = || {
                super::dense::agrees(
                    &frame.left,
                    &frame.right,
                    (pop.u_left[i], pop.v_left[i]),
                    (pop.u_right[i], pop.v_right[i]),
                    range,
                )
            };
            hold += usize::from(holds(f64::from(a), &c, dense));
        }
        let genuine = 2 * hold >= k;
        self.verdicts[self.verdict_next] = (frame.id, near, far, genuine);
        self.verdict_next = (self.verdict_next + 1) % self.verdicts.len();
        Ok(genuine)
    }
}

/// One verified fly's vote (step 5): it holds when it is unique along the epipolar line
/// (`line_ambiguity` at most `max_line_ambiguity`) and, where the line offers it a rival
/// (above [`DENSE_RIVAL`]), the dense window does not prefer another disparity (`dense`,
/// asked only then; `None`, a window it cannot judge, leaves the line's verdict). A fly
/// unique along the whole line has nothing for a larger window to arbitrate, and at an
/// object's silhouette that window sees mostly what is behind it.
fn holds(line_ambiguity: f64, c: &ObstacleConfig, dense: impl FnOnce() -> Option<bool>) -> bool {
    line_ambiguity <= c.max_line_ambiguity
        && !(c.dense_check && line_ambiguity > DENSE_RIVAL && dense() == Some(false))
}

#[cfg(test)]
mod tests;
