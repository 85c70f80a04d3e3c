//! Tunable parameters of the evolution, with the defaults chosen by measurement (see docs/tuning.md).

use serde::{Deserialize, Serialize};

/// The road region of interest of the paper (section 5.1): flies that cannot be obstacles for the
/// vehicle have their fitness multiplied by `penalty`, so selection removes them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RoadRoi {
    /// Flies higher than this above the road (metres) are penalised (paper: 2 m).
    pub max_height: f64,
    /// Flies lower than this above the road (metres) are penalised: the road itself (paper: 0.1 m).
    pub min_height: f64,
    /// Flies farther ahead than this (metres, vehicle z) are penalised (paper: 16 m).
    pub max_ahead: f64,
    /// Fitness multiplier outside the region, in [0, 1]. 0 makes such flies the worst.
    pub penalty: f64,
}

impl Default for RoadRoi {
    fn default() -> Self {
        Self {
            max_height: 2.0,
            min_height: 0.1,
            max_ahead: 40.0,
            penalty: 0.0,
        }
    }
}

/// Upper bound of [`EngineParams::breeding_tournament`].
pub const MAX_TOURNAMENT: u32 = 64;

/// Upper bound of [`EngineParams::immigrant_probes`].
pub const MAX_PROBES: u32 = 256;

/// Parameters of one fly population. All rates are fractions of the population.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EngineParams {
    /// Population size.
    pub flies: usize,
    /// Fraction of the population kept by elitist selection (paper: ~40 %).
    pub survival_rate: f64,
    /// Fraction of the population replaced by fresh random flies every generation.
    pub immigration_rate: f64,
    /// Fraction of immigrants drawn where the left image changed since the previous frame
    /// (16x16 blocks whose mean luma moved by more than the noise), when something changed.
    /// A new obstacle changes the image where it appears; the rest are drawn uniformly.
    pub guided_immigration: f64,
    /// Depths tried along the ray of each guided immigrant before it joins the population: the
    /// probes are spread over the ray's inverse-depth range inside the search range and the road
    /// region of interest (one per stratum), evaluated on the current frame; then 8 more are
    /// spread over one stratum around the fittest, and 8 more over a quarter of that around the
    /// fittest so far (a stratum spans several pixels of disparity, the fitness peaks within a
    /// fraction of one), and the fittest of all is kept. 1 is the paper's immigrant (one random
    /// depth, no refinement). Costs `probes + 16` evaluations per guided immigrant, only while
    /// the image changes.
    pub immigrant_probes: u32,
    /// Immigrants per generation drawn around what the obstacle stage last saw in the
    /// corridor ([`super::Engine::set_focus`]), whether or not the image changed: each takes
    /// the strongest gradient of the block of a unique corridor fly or a neighbour, probes 8
    /// depths within 15 % of that fly's inverse depth, then the guided ones' refinement, and
    /// joins at the fittest. The paper's uniform immigrants rarely land on the part of an
    /// obstacle inside the corridor (a car crossing 13.8 m ahead on KITTI, 0.7 m of it in the
    /// corridor, had no fly there after 87 generations on half the seeds); these look where
    /// something was seen, so the evidence grows where it started. Part of the
    /// `immigration_rate` (at most a quarter of the immigrants are); 0..=64, 0: none.
    pub focus_immigrants: u32,
    /// Immigrants per generation that scan the vehicle's corridor
    /// ([`super::Engine::set_corridor`]), whether or not the image changed or something was
    /// seen: each draws a point uniformly in the corridor, takes the strongest gradient of
    /// its left-image block, probes `immigrant_probes` depths where that ray crosses the
    /// corridor, then the guided ones' refinement, and joins at the fittest. Uniform
    /// immigrants spend most of their depths off the corridor and guided ones need the image
    /// to change: on a still pair or a steady approach, the part of a car inside the corridor
    /// could go unvisited until a fly happened on it. Part of the `immigration_rate` (at most
    /// a quarter of the immigrants are); 0..=64, 0: none.
    pub corridor_immigrants: u32,
    /// Immigrants per generation that scan the zones watched beside the corridor (a
    /// corridor with a `watch_half_width`, [`super::Corridor`]) as the corridor immigrants
    /// scan the corridor: a point drawn uniformly in the band either side of it. Beside the
    /// corridor the roadside's strong textures hold the flies, and a pedestrian 3 m beside
    /// the lane 17 m ahead had none (hw-mock's Euro NCAP CPNA case at 30 km/h): seen only once
    /// in the corridor, too late to stop ([`crate::perception::crossing`]). 24: with 8 the
    /// same pedestrian was found 9 m ahead on one seed of two at 30 and 40 km/h (contact at
    /// 21 and 15 km/h); with 24 that run STOPped 1.1 s earlier and stopped 4.3 m short. Part of the `immigration_rate` (at most a quarter
    /// of the immigrants are); 0..=64, 0: none.
    pub watch_immigrants: u32,
    /// How far ahead the corridor immigrants scan, metres (and never beyond the obstacle
    /// stage's `max_distance`): where a missed obstacle means STOP. With the decision's
    /// defaults STOP reaches 23 m ahead at 40 km/h. Farther, the flies find obstacles as the
    /// paper's do; scanning to 40 m made flyd SLOW at 30 km/h for a car 36 m ahead (KITTI
    /// 2012 #70) and a sign pole 30.5 m ahead on most seeds.
    pub corridor_scan_distance: f64,
    /// Fraction of crossovers whose second parent is drawn from the first parent's sharing
    /// cell (mating restriction) rather than from all survivors. 0 is the paper's operator; 1
    /// (default) lets a fly found on a new obstacle breed there, which is what makes the
    /// population react in ~10 generations instead of ~150 (see docs/tuning.md).
    pub local_mating: f64,
    /// Fraction of offspring whose first parent is drawn from the survivors in blocks where the
    /// left image changed (see `guided_immigration`), when some survivor is in one; the others
    /// draw it from all survivors (the paper). Guided immigrants find a new obstacle; this
    /// lets the few that did breed faster than the converged flies elsewhere. Inert on a static
    /// scene.
    pub guided_breeding: f64,
    /// A guided offspring's first parent is the fittest (by fitness before sharing) of this many
    /// survivors drawn from the changed blocks; 1 draws one uniformly. The flies there are a
    /// mix of the few that found the new obstacle (fitness ~20-50 in hw-mock) and of background
    /// flies and immigrants at the wrong depth (~1): drawn uniformly, the former parent a few
    /// offspring each. A tournament ranks rather than weighs, so one outlier fitness (a false
    /// match on a periodic texture) cannot take over the breeding as it would under
    /// fitness-proportional choice.
    pub breeding_tournament: u32,
    /// Probability that each coordinate of an offspring is mutated (paper: 40 %).
    pub mutation_rate: f64,
    /// Standard deviation of the Gaussian mutation, relative to the fly's depth: a fly at z metres
    /// moves by N(0, (sigma * max(z, 1 m))^2) on each mutated coordinate. Scaling with depth keeps
    /// the step constant in pixels and in disparity.
    pub mutation_sigma: f64,
    /// Radius of the square neighbourhood N compared by the fitness (1..=3: 3x3 to 7x7 pixels).
    pub neighbourhood_radius: u32,
    /// Compare every `row_step`-th row of the neighbourhood (1 = all of it; 3 with radius 3 =
    /// rows -3, 0, +3). Rows matter less than columns: disparity is along the rows.
    pub neighbourhood_row_step: u32,
    /// Added to the fitness denominator per compared sample (pixels x channels): guards against
    /// division by zero and keeps a perfectly flat match from dominating. Grey levels squared.
    pub ssd_floor: f64,
    /// Side, in left-image pixels, of the cells of the sharing grid.
    pub sharing_cell_px: u32,
    /// Sharing exponent: a fly's fitness is divided by (flies in its cell)^exponent. 0 disables.
    pub sharing_exponent: f64,
    /// Search range: depth along the left camera's optical axis, metres.
    pub min_depth: f64,
    pub max_depth: f64,
    /// Road region of interest; `None` for scenes without a road (datasets).
    pub roi: Option<RoadRoi>,
    /// Warning clamps of the paper: |x| below this counts as this (metres).
    pub warning_min_abs_x: f64,
    /// Warning clamps of the paper: z below this counts as this (metres).
    pub warning_min_z: f64,
    /// Seed of the random generator: same seed + same frames = bit-identical population.
    pub seed: u64,
}

impl Default for EngineParams {
    fn default() -> Self {
        Self {
            flies: 5000,
            survival_rate: 0.4,
            immigration_rate: 0.05,
            guided_immigration: 0.75,
            immigrant_probes: 32,
            focus_immigrants: 16,
            corridor_immigrants: 8,
            watch_immigrants: 24,
            corridor_scan_distance: 25.0,
            local_mating: 1.0,
            guided_breeding: 0.75,
            breeding_tournament: 8,
            mutation_rate: 0.4,
            mutation_sigma: 0.01,
            neighbourhood_radius: 3,
            neighbourhood_row_step: 3,
            ssd_floor: 1.0,
            sharing_cell_px: 6,
            sharing_exponent: 1.5,
            min_depth: 1.0,
            max_depth: 40.0,
            roi: Some(RoadRoi::default()),
            warning_min_abs_x: 0.5,
            warning_min_z: 1.0,
            seed: 1,
        }
    }
}

/// A parameter that cannot work, named as in the configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("engine parameter '{key}': {reason}")]
pub struct ParamError {
    pub key: &'static str,
    pub reason: String,
}

impl EngineParams {
    /// Checks every parameter; the error names the offending key.
    pub fn validate(&self) -> Result<(), ParamError> {
        let err = |key: &'static str, reason: String| Err(ParamError { key, reason });
        let unit = |key: &'static str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                err(key, format!("must be within [0, 1], got {v}"))
            }
        };
        if !(16..=1_000_000).contains(&self.flies) {
            return err(
                "flies",
                format!("must be within 16..=1000000, got {}", self.flies),
            );
        }
        unit("survival_rate", self.survival_rate)?;
        unit("immigration_rate", self.immigration_rate)?;
        unit("mutation_rate", self.mutation_rate)?;
        unit("local_mating", self.local_mating)?;
        unit("guided_immigration", self.guided_immigration)?;
        unit("guided_breeding", self.guided_breeding)?;
        let count = |key: &'static str, v: u32, max: u32| {
            if (1..=max).contains(&v) {
                Ok(())
            } else {
                err(key, format!("must be within 1..={max}, got {v}"))
            }
        };
        count(
            "breeding_tournament",
            self.breeding_tournament,
            MAX_TOURNAMENT,
        )?;
        count("immigrant_probes", self.immigrant_probes, MAX_PROBES)?;
        for (key, v) in [
            ("focus_immigrants", self.focus_immigrants),
            ("corridor_immigrants", self.corridor_immigrants),
            ("watch_immigrants", self.watch_immigrants),
        ] {
            if v > 64 {
                return err(key, format!("must be within 0..=64, got {v}"));
            }
        }
        if !(self.corridor_scan_distance.is_finite()
            && (1.0..=500.0).contains(&self.corridor_scan_distance))
        {
            return err(
                "corridor_scan_distance",
                format!(
                    "must be within 1..=500 m, got {}",
                    self.corridor_scan_distance
                ),
            );
        }
        let keep = self.survivors();
        if keep < 2 {
            return err("survival_rate", "must keep at least 2 flies".into());
        }
        if keep + self.immigrants() > self.flies {
            return err(
                "immigration_rate",
                format!(
                    "survival_rate + immigration_rate must not exceed 1 (got {} + {})",
                    self.survival_rate, self.immigration_rate
                ),
            );
        }
        if !(self.mutation_sigma.is_finite() && self.mutation_sigma >= 0.0) {
            return err(
                "mutation_sigma",
                format!("must be >= 0, got {}", self.mutation_sigma),
            );
        }
        if !(1..=3).contains(&self.neighbourhood_radius) {
            return err(
                "neighbourhood_radius",
                format!("must be 1, 2 or 3, got {}", self.neighbourhood_radius),
            );
        }
        if !(1..=2 * self.neighbourhood_radius + 1).contains(&self.neighbourhood_row_step) {
            return err(
                "neighbourhood_row_step",
                format!(
                    "must be within 1..={} for radius {}, got {}",
                    2 * self.neighbourhood_radius + 1,
                    self.neighbourhood_radius,
                    self.neighbourhood_row_step
                ),
            );
        }
        if !(self.ssd_floor.is_finite() && self.ssd_floor > 0.0) {
            return err("ssd_floor", format!("must be > 0, got {}", self.ssd_floor));
        }
        if !(2..=256).contains(&self.sharing_cell_px) {
            return err(
                "sharing_cell_px",
                format!("must be within 2..=256, got {}", self.sharing_cell_px),
            );
        }
        if !(self.sharing_exponent.is_finite() && (0.0..=4.0).contains(&self.sharing_exponent)) {
            return err(
                "sharing_exponent",
                format!("must be within [0, 4], got {}", self.sharing_exponent),
            );
        }
        if !(self.min_depth.is_finite() && self.min_depth > 0.0) {
            return err("min_depth", format!("must be > 0, got {}", self.min_depth));
        }
        if !(self.max_depth.is_finite() && self.max_depth > self.min_depth) {
            return err(
                "max_depth",
                format!(
                    "must be greater than min_depth ({}), got {}",
                    self.min_depth, self.max_depth
                ),
            );
        }
        if let Some(roi) = &self.roi {
            if !(roi.max_height.is_finite() && roi.max_height > roi.min_height) {
                return err(
                    "roi.max_height",
                    format!("must be greater than roi.min_height ({})", roi.min_height),
                );
            }
            if !(roi.max_ahead.is_finite() && roi.max_ahead > 0.0) {
                return err(
                    "roi.max_ahead",
                    format!("must be > 0, got {}", roi.max_ahead),
                );
            }
            unit("roi.penalty", roi.penalty)?;
        }
        // The paper's clamps of the warning F / (x^2 z): larger ones flatten every warning
        // (1e6 m made a pedestrian 4 m ahead read as nothing).
        if !(self.warning_min_abs_x.is_finite() && (0.01..=2.0).contains(&self.warning_min_abs_x)) {
            return err(
                "warning_min_abs_x",
                format!("must be within 0.01..=2 m, got {}", self.warning_min_abs_x),
            );
        }
        if !(self.warning_min_z.is_finite() && (0.01..=5.0).contains(&self.warning_min_z)) {
            return err(
                "warning_min_z",
                format!("must be within 0.01..=5 m, got {}", self.warning_min_z),
            );
        }
        Ok(())
    }

    /// Number of flies kept by selection.
    pub fn survivors(&self) -> usize {
        ((self.flies as f64 * self.survival_rate).round() as usize).min(self.flies)
    }

    /// Number of immigrants per generation.
    pub fn immigrants(&self) -> usize {
        (self.flies as f64 * self.immigration_rate).round() as usize
    }

    /// The focused immigrants a generation draws when something was seen:
    /// `focus_immigrants`, at most a quarter of the immigrants.
    pub fn focus_immigrants(&self) -> usize {
        (self.focus_immigrants as usize).min(self.immigrants() / 4)
    }

    /// The corridor immigrants a generation draws when a corridor is set:
    /// `corridor_immigrants`, at most a quarter of the immigrants.
    pub fn corridor_immigrants(&self) -> usize {
        (self.corridor_immigrants as usize).min(self.immigrants() / 4)
    }

    /// The watch immigrants a generation draws when the corridor has watch zones:
    /// `watch_immigrants`, at most a quarter of the immigrants.
    pub fn watch_immigrants(&self) -> usize {
        (self.watch_immigrants as usize).min(self.immigrants() / 4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(change: impl FnOnce(&mut EngineParams), key: &str) {
        let mut p = EngineParams::default();
        change(&mut p);
        let e = p.validate().expect_err("should be rejected");
        assert_eq!(e.key, key, "{e}");
    }

    #[test]
    fn defaults_are_valid() {
        EngineParams::default().validate().expect("defaults");
    }

    #[test]
    fn impossible_values_name_their_key() {
        check(|p| p.min_depth = 50.0, "max_depth");
        check(|p| p.min_depth = -1.0, "min_depth");
        check(|p| p.survival_rate = 1.5, "survival_rate");
        check(|p| p.immigration_rate = 0.7, "immigration_rate");
        check(|p| p.neighbourhood_radius = 4, "neighbourhood_radius");
        check(|p| p.mutation_sigma = f64::NAN, "mutation_sigma");
        check(|p| p.flies = 3, "flies");
        check(|p| p.immigrant_probes = 0, "immigrant_probes");
        check(|p| p.breeding_tournament = 0, "breeding_tournament");
        check(|p| p.breeding_tournament = 65, "breeding_tournament");
        check(|p| p.focus_immigrants = 65, "focus_immigrants");
        check(|p| p.corridor_immigrants = 65, "corridor_immigrants");
        check(|p| p.watch_immigrants = 65, "watch_immigrants");
        check(|p| p.corridor_scan_distance = 0.5, "corridor_scan_distance");
        check(
            |p| p.corridor_scan_distance = f64::NAN,
            "corridor_scan_distance",
        );
        check(|p| p.ssd_floor = 0.0, "ssd_floor");
        check(
            |p| {
                p.roi = Some(RoadRoi {
                    min_height: 3.0,
                    ..RoadRoi::default()
                })
            },
            "roi.max_height",
        );
    }
}
