//! One step of the perception, written once: a pair arrives (the vehicle's motion since the
//! previous one, its images' health) -> a generation of the engine and the perception stages
//! -> the sensor faults and what the decider is given.
//!
//! The daemon's evolution thread, `flyd replay` (a pair, a scenario, a sequence) and
//! `flyd replay --mcap` (a recording's frames again) all drive a [`FrameStep`]: the order in
//! which the motion, the sensor checks, the engine, the road, the obstacle stage and the
//! blindness debounce see a pair is this module's, so a replay is the daemon's perception bit
//! for bit. Threads, clocks, rings and files stay with the callers; what goes in (frames,
//! motion, health) is passed in and what comes out is returned. The command period's input
//! and the decider are [`crate::policy`]'s.

use crate::decision::DecisionInput;
use crate::engine::{EngineError, GenerationStats};
use crate::frame::StereoFrame;
use crate::kinematics::VehicleMotion;
use crate::perception::{Perception, PerceptionReport};
use crate::policy::{BlindDebounce, Blindness, camera_error};
use crate::sensor::{ImageHealth, SensorConfig, SensorFaults, SensorMonitor, SensorVerdict};

/// What a [`FrameStep`] is set up with besides its [`Perception`] (whose warm-up it takes).
#[derive(Debug, Clone, Copy)]
pub struct StepConfig {
    /// The blindness debounce (`evolution.blind_matched`, `evolution.blind_pairs`).
    pub blind_matched: f64,
    pub blind_pairs: u32,
    /// The image checks' thresholds (`[sensor]`).
    pub sensor: SensorConfig,
    /// Move the flies with the vehicle (`vehicle.predict_flies`); else only the corridor
    /// follows its path.
    pub predict_flies: bool,
    /// The speed a motion fault's fan covers, m/s (`vehicle.assumed_speed_kmh`).
    pub assumed_speed: f64,
}

/// What arrives with a new pair.
#[derive(Debug, Clone, Copy, Default)]
pub struct NewPair {
    /// How the vehicle moved since the previous pair: `None` when there is nothing to move
    /// by (the first pair, no motion source); `Some((None, _))` a motion fault (the corridor
    /// becomes the fan of every path at the assumed speed); `Some((Some(m), dt))` its
    /// motion over `dt` seconds.
    pub moved: Option<(Option<VehicleMotion>, f64)>,
    /// Both images' health ([`crate::sensor::ImageCheck`]); `None`: not checked (a
    /// recording's replay takes the recorded decisions' faults).
    pub health: Option<[ImageHealth; 2]>,
}

/// What one generation found, with the sensor faults at it.
#[derive(Debug, Clone, Copy)]
pub struct Outcome {
    pub report: PerceptionReport,
    /// The population still warms up: the decider is not given this generation.
    pub warming_up: bool,
    /// The blindness debounce after this generation (whether it changed: a log line).
    pub blindness: Blindness,
    /// The pairs' sensor verdict, BLIND included.
    pub sensor: SensorVerdict,
}

impl Outcome {
    /// What the decider is given from this generation at `speed` (m/s), its evidence
    /// `latency` seconds old, with CAMERA_ERROR when a sensor check failed.
    pub fn decision_input(&self, speed: f64, latency: f64) -> DecisionInput {
        self.report.tracked.credit(DecisionInput {
            global_warning: self.report.stats.global_warning,
            obstacle: self.report.tracked.decision_distance(),
            latency,
            faults: camera_error(self.sensor.faults),
            ..DecisionInput::at_speed(None, speed)
        })
    }
}

/// The perception of a stereo pair stream, one pair and one generation at a time (see the
/// module docs).
pub struct FrameStep {
    perception: Perception,
    config: StepConfig,
    sensor: SensorMonitor,
    verdict: SensorVerdict,
    blindness: BlindDebounce,
}

impl FrameStep {
    pub fn new(perception: Perception, config: StepConfig) -> Self {
        Self {
            perception,
            sensor: SensorMonitor::new(config.sensor),
            verdict: SensorVerdict::default(),
            blindness: BlindDebounce::new(config.blind_matched, config.blind_pairs),
            config,
        }
    }

    /// A new pair: the flies and the corridor moved with the vehicle, the images' health
    /// debounced into sensor faults. Returns the verdict before and after (what to log).
    pub fn pair(&mut self, pair: &NewPair) -> (SensorVerdict, SensorVerdict) {
        if let Some((motion, dt)) = pair.moved {
            let c = self.config;
            self.perception
                .vehicle_moved(motion, dt, c.predict_flies, c.assumed_speed);
        }
        let was = self.verdict;
        if let Some([left, right]) = &pair.health {
            self.verdict = self.sensor.observe(left, right);
        }
        (was, self.verdict)
    }

    /// One generation of the engine on `frame` (the pair's, new or not).
    pub fn evolve(&mut self, frame: &StereoFrame) -> Result<GenerationStats, EngineError> {
        self.perception.evolve(frame)
    }

    /// After [`FrameStep::evolve`]: the road and the obstacle stage, then the blindness and
    /// the sensor faults of this generation.
    pub fn observe(&mut self, frame: &StereoFrame) -> Result<Outcome, EngineError> {
        let report = *self.perception.observe(frame)?;
        let stats = report.stats;
        // The perception's own warm-up (`Perception::with_warmup`): one number for both.
        let warming_up = stats.generation < self.perception.warmup();
        let blindness = self
            .blindness
            .observe(warming_up, stats.matched, stats.new_frame);
        let mut sensor = self.verdict;
        sensor.faults.set(SensorFaults::BLIND, blindness.blind);
        Ok(Outcome {
            report,
            warming_up,
            blindness,
            sensor,
        })
    }

    /// [`FrameStep::evolve`] then [`FrameStep::observe`].
    pub fn generation(&mut self, frame: &StereoFrame) -> Result<Outcome, EngineError> {
        self.evolve(frame)?;
        self.observe(frame)
    }

    pub fn perception(&self) -> &Perception {
        &self.perception
    }

    pub fn perception_mut(&mut self) -> &mut Perception {
        &mut self.perception
    }

    /// The perception, the step done with (a replay's last frame is read from it).
    pub fn into_perception(self) -> Perception {
        self.perception
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::EngineParams;
    use crate::frame::{PixelFormat, PreparedImage};
    use crate::geometry::Distortion;
    use crate::perception::PerceptionConfig;
    use crate::status::FaultBits;
    use crate::test_support::{small_rig, xorshift32};

    /// A textured pair, the right image the left shifted by 6 px.
    fn frame(id: u64) -> StereoFrame {
        let (w, h) = (160usize, 120usize);
        let mut next = xorshift32(0x1234_5678);
        let left: Vec<u8> = (0..w * h).map(|_| (next() % 200) as u8 + 20).collect();
        let right: Vec<u8> = (0..w * h)
            .map(|i| left[(i / w) * w + (i % w + 6).min(w - 1)])
            .collect();
        let mut l = PreparedImage::new(w as u32, h as u32).expect("image");
        let mut r = PreparedImage::new(w as u32, h as u32).expect("image");
        l.prepare(PixelFormat::Grey8, &left).expect("left");
        r.prepare(PixelFormat::Grey8, &right).expect("right");
        StereoFrame::new(l, r, id)
    }

    fn perception() -> Perception {
        let params = EngineParams {
            flies: 400,
            ..EngineParams::default()
        };
        Perception::new(
            &small_rig(Distortion::default()),
            params,
            PerceptionConfig::default(),
        )
        .expect("perception")
        .with_warmup(3)
    }

    #[test]
    fn a_step_is_the_perceptions_generation_with_the_sensor_faults_of_its_pairs() {
        let config = StepConfig {
            blind_matched: 0.0,
            blind_pairs: 2,
            sensor: SensorConfig::default(),
            predict_flies: true,
            assumed_speed: 8.0,
        };
        let mut step = FrameStep::new(perception(), config);
        let mut bare = perception();
        let uniform = ImageHealth {
            mean: 128.0,
            contrast: 0.0,
            textured: 0.0,
            unchanged: None,
        };
        let mut faults = Vec::new();
        for id in 0..8u64 {
            let f = frame(id);
            step.pair(&NewPair {
                moved: None,
                health: Some([uniform; 2]),
            });
            let outcome = step.generation(&f).expect("generation");
            // The same generation as the perception's own step, bit for bit.
            let report = *bare.step(&f).expect("step");
            assert_eq!(outcome.report, report, "pair {id}");
            assert_eq!(outcome.warming_up, report.stats.generation < 3);
            faults.push(outcome.sensor.faults);
            let input = outcome.decision_input(10.0, 0.1);
            assert_eq!(input.global_warning, report.stats.global_warning);
            assert_eq!(input.obstacle, report.tracked.decision_distance());
            assert_eq!((input.speed, input.latency), (10.0, 0.1));
            let camera_error = !outcome.sensor.faults.is_empty();
            assert_eq!(input.faults == FaultBits::CAMERA_ERROR, camera_error);
        }
        // Uniform images raise UNIFORM once debounced, and it stays.
        let first = faults
            .iter()
            .position(|f| f.contains(SensorFaults::UNIFORM))
            .expect("UNIFORM raised");
        assert!(first > 0, "debounced: {faults:?}");
        assert!(
            faults[first..]
                .iter()
                .all(|f| f.contains(SensorFaults::UNIFORM))
        );
        // A pair without health (a recording's replay) keeps the verdict.
        let (was, now) = step.pair(&NewPair::default());
        assert_eq!(was, now);
    }
}
