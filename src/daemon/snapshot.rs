//! What the evolution thread tells the control thread after each generation.
//!
//! A [`Snapshot`] is small and `Copy`: it goes through a bounded channel without allocating.
//! It carries the population's summary, not the flies themselves (5000 flies x 10 floats per
//! generation would be 200 kB of copying for a control thread that needs a dozen numbers).
//!
//! The nearest-obstacle estimate ([`ObstacleEstimator`]) looks at the fittest flies inside the
//! vehicle's lane (|x| <= lane half-width; the engine's road region of interest has already
//! zeroed the fitness of flies on the road and above the vehicle): among the
//! `best` fittest in-lane flies with a positive fitness, the distance is the 25th percentile of
//! their depths (the near edge of the cluster, robust to a few stray flies), the lateral offset
//! the mean x of those within 10 % of that depth, and the confidence the share of the `best`
//! flies that agree with it (within 10 %). With fewer than `min_flies` candidates there is no
//! obstacle. No allocation: the index buffer is sized once.

use std::time::Duration;

use crate::source::FrameMeta;
use flyd_core::can::messages::ObstacleMsg;
use flyd_core::engine::Population;

/// The nearest obstacle in the lane, vehicle frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleEstimate {
    /// Ahead, metres (vehicle z).
    pub distance: f64,
    /// Lateral, metres (vehicle x, positive right).
    pub lateral: f64,
    /// 0..=100 %.
    pub confidence: f64,
    /// Flies it was estimated from.
    pub flies: usize,
}

impl ObstacleEstimate {
    pub fn to_msg(estimate: Option<Self>) -> ObstacleMsg {
        match estimate {
            Some(e) => ObstacleMsg {
                valid: true,
                distance: e.distance,
                lateral: e.lateral,
                confidence: e.confidence,
            },
            None => ObstacleMsg::NONE,
        }
    }
}

/// One generation's outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    /// Engine generation number.
    pub generation: u64,
    /// The paper's global warning (mean fly warning): what the decision thresholds compare.
    pub global_warning: f64,
    /// Where the evidence is, m^-3 (diagnostic, see the engine docs).
    pub danger: f64,
    /// Fraction of the flies evaluated in the generation whose windows match (see
    /// [`flyd_core::engine::GenerationStats`]): what `blind` is judged on, logged with the stats.
    pub matched: f64,
    /// On the last `blind_pairs` new pairs, fewer than `blind_matched` of the flies matched:
    /// the images match nowhere, so a low warning proves nothing (CAMERA_ERROR).
    pub blind: bool,
    pub visible: usize,
    /// The generation saw a new pair (the population was re-evaluated).
    pub new_frame: bool,
    pub obstacle: Option<ObstacleEstimate>,
    /// Wall time of `engine.step` plus the estimate.
    pub generation_time: Duration,
    /// `generation_time` over the configured maximum.
    pub overrun: bool,
    /// The pair evaluated, and its identity (`StereoFrame::id`).
    pub left: FrameMeta,
    pub right: FrameMeta,
    pub pair_id: u64,
    /// Pairing counters of the evolution thread.
    pub pairs: u64,
    pub pair_rejects: u64,
    /// Too many consecutive rejected candidates (STEREO_SKEW).
    pub skew_fault: bool,
    /// The population has not run `warmup_generations` yet: its danger is not trusted.
    pub warming_up: bool,
    /// When the generation finished (daemon clock).
    pub taken_at: Duration,
}

impl Snapshot {
    /// Capture time of the older frame of the pair.
    pub fn capture_time(&self) -> Duration {
        self.left.timestamp.min(self.right.timestamp)
    }
}

/// The nearest-obstacle estimate (see the module docs), with its preallocated scratch.
#[derive(Debug, Clone)]
pub struct ObstacleEstimator {
    lane_half_width: f32,
    best: usize,
    min_flies: usize,
    scratch: Vec<u32>,
}

/// Depths within this fraction of the estimate agree with it.
const AGREEMENT: f32 = 0.1;

impl ObstacleEstimator {
    pub fn new(population: usize, lane_half_width: f64, best: usize, min_flies: usize) -> Self {
        Self {
            lane_half_width: lane_half_width as f32,
            best: best.max(1),
            min_flies: min_flies.max(1),
            scratch: Vec::with_capacity(population),
        }
    }

    pub fn estimate(&mut self, pop: &Population) -> Option<ObstacleEstimate> {
        self.scratch.clear();
        let lane = self.lane_half_width;
        self.scratch.extend(
            (0..pop.len())
                .filter(|&i| pop.fitness[i] > 0.0 && pop.x[i].abs() <= lane && pop.z[i] > 0.0)
                .map(|i| i as u32),
        );
        if self.scratch.len() < self.min_flies {
            return None;
        }
        let fitness = &pop.fitness;
        let by_fitness = |a: &u32, b: &u32| {
            fitness[*b as usize]
                .total_cmp(&fitness[*a as usize])
                .then(a.cmp(b))
        };
        let k = self.best.min(self.scratch.len());
        if k < self.scratch.len() {
            self.scratch.select_nth_unstable_by(k - 1, by_fitness);
        }
        let top = &mut self.scratch[..k];
        top.sort_unstable_by(|a, b| pop.z[*a as usize].total_cmp(&pop.z[*b as usize]));
        let distance = pop.z[top[k / 4] as usize];
        let (mut agree, mut sum_x) = (0usize, 0.0f64);
        for &i in top.iter() {
            if (pop.z[i as usize] - distance).abs() <= AGREEMENT * distance {
                agree += 1;
                sum_x += f64::from(pop.x[i as usize]);
            }
        }
        Some(ObstacleEstimate {
            distance: f64::from(distance),
            lateral: sum_x / agree.max(1) as f64,
            confidence: 100.0 * agree as f64 / self.best as f64,
            flies: k,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn population(flies: &[(f32, f32, f32)]) -> Population {
        let mut p = Population::default();
        for &(x, z, f) in flies {
            p.x.push(x);
            p.y.push(1.0);
            p.z.push(z);
            p.fitness.push(f);
        }
        p
    }

    #[test]
    fn nearest_cluster_in_the_lane() {
        let mut flies = vec![];
        // A pedestrian at 4 m, slightly left; the fittest flies.
        for i in 0..20 {
            flies.push((-0.3 + 0.01 * i as f32, 4.0 + 0.01 * i as f32, 10.0));
        }
        // A closer but weak cluster, and a strong one outside the lane.
        for _ in 0..20 {
            flies.push((0.0, 2.0, 0.1));
            flies.push((3.0, 1.5, 50.0));
        }
        let mut e = ObstacleEstimator::new(flies.len(), 1.0, 20, 5);
        let o = e.estimate(&population(&flies)).expect("obstacle");
        assert!((o.distance - 4.05).abs() < 0.06, "{o:?}");
        assert!((o.lateral - -0.2).abs() < 0.05, "{o:?}");
        assert_eq!(o.confidence, 100.0);
        assert_eq!(o.flies, 20);
    }

    #[test]
    fn too_few_fit_flies_is_no_obstacle() {
        let flies = [(0.0, 3.0, 1.0), (0.1, 3.0, 1.0), (0.2, 3.0, 0.0)];
        let mut e = ObstacleEstimator::new(3, 1.0, 10, 3);
        assert_eq!(e.estimate(&population(&flies)), None);
        assert_eq!(ObstacleEstimate::to_msg(None), ObstacleMsg::NONE);
    }

    #[test]
    fn scattered_flies_give_low_confidence() {
        let flies: Vec<_> = (0..40).map(|i| (0.0, 2.0 + i as f32, 1.0)).collect();
        let mut e = ObstacleEstimator::new(flies.len(), 1.0, 40, 5);
        let o = e.estimate(&population(&flies)).expect("obstacle");
        assert_eq!(o.distance, 12.0);
        assert!(o.confidence < 10.0, "{o:?}");
    }
}
