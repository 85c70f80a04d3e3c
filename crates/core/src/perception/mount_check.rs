//! The declared mount checked against the road flyd measures.
//!
//! The road plane is fitted in the vehicle frame the calibration's mount defines
//! ([`super::road_estimator`]): on a level road under a correctly declared mount it is
//! `y = 0`. A camera declared at the wrong height puts the road at `y = declared - true`; one
//! pitched further down than declared makes the road rise ahead by the tangent of the
//! difference; one rolled, bank across. The estimator bounds what it uses to
//! `max_height_change` (0.3 m) and `max_slope` around the mount, so a larger error leaves every
//! height flyd measures off by the rest: a camera declared 1.2 m up that is 1.65 m up (the
//! KITTI car's, imported without a mount) put a car 12.4 m ahead below the bounded road, and
//! flyd said CLEAR.
//!
//! [`MountCheck`] averages each frame's fit as measured ([`RoadEstimate::fitted`], before the
//! bounds and the smoothing) over the last [`WINDOW`] measured frames and says where the road
//! lies from the declared mount: its height, the rise ahead (pitch) and across (roll). A real
//! road's grade and bank look the same as a pitch or a roll; averaged over a drive they are
//! small, on one frame they are not, so the bounds on the angles are wider than the grades
//! flyd meets on its data (`docs/perception.md`, "The mount checked against the road").

use serde::Serialize;

use super::road_estimator::RoadEstimate;

/// Frames the check averages over (older ones fade out): 10 s at 30 fps.
pub const WINDOW: f64 = 300.0;
/// The mount disagrees with the road when the road measured lies further than this above or
/// below it, metres. On the KITTI pairs and drive of `eval/real.toml` with their true mount the
/// road lies within 0.10 m of it (hw-mock's ramp-30, 0.145 m); with the mount 0.3 m too low
/// or too high, 0.20-0.75 m.
pub const HEIGHT_TOLERANCE: f64 = 0.17;
/// ... or rises ahead by more than this, degrees. Real roads rise up to 2.0 degrees on those
/// pairs under their true mount: on one frame a camera's pitch is not told from the road's
/// grade, so only a larger one is said.
pub const PITCH_TOLERANCE_DEG: f64 = 2.5;
/// ... or across, degrees (KITTI 2012 #1 banks 4.5 degrees).
pub const ROLL_TOLERANCE_DEG: f64 = 5.5;
/// Measured frames before the daemon takes a disagreement for a fault ([`MountReport::hides`]).
pub const FAULT_FRAMES: u32 = 30;

named_enum! {
    /// What the road says about the declared mount.
    pub enum MountVerdict {
        /// No frame measured the road (no road, too few matches, or road measurement off).
        Unmeasured = 0 => "UNMEASURED",
        /// Within the tolerances.
        Agrees = 1 => "AGREES",
        /// Beyond at least one of them ([`MountReport::height_off`] and the others say which).
        Disagrees = 2 => "DISAGREES",
    }
}

impl Serialize for MountVerdict {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// Where the road lies from the declared mount, averaged over the frames that measured it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MountReport {
    pub verdict: MountVerdict,
    /// Frames that measured the road.
    pub frames: u32,
    /// The road's height in the declared frame under the left camera, metres: the camera is
    /// this much lower above the road than declared (negative: higher).
    pub road_height: f64,
    /// The road's rise ahead, degrees: the camera looks this much further down than declared
    /// (or the road climbs).
    pub road_pitch_deg: f64,
    /// ... and to the right, degrees (a roll of the mount, or a banked road).
    pub road_roll_deg: f64,
    /// Each one's standard deviation from frame to frame (NaN before two frames).
    pub height_sd: f64,
    pub pitch_sd_deg: f64,
    pub roll_sd_deg: f64,
    /// Which are beyond their tolerance.
    pub height_off: bool,
    pub pitch_off: bool,
    pub roll_off: bool,
}

impl MountReport {
    /// Whether the mount is off by more than the road estimator absorbs, `max_height_change`
    /// metres (`perception.road.max_height_change`), over at least [`FAULT_FRAMES`] measured
    /// frames: every height flyd measures is then off by the rest, and an obstacle may sink
    /// below the road or float above the corridor's reach. The daemon's fault (`INTERNAL`,
    /// the safe command).
    pub fn hides(&self, max_height_change: f64) -> bool {
        self.frames >= FAULT_FRAMES && self.road_height.abs() > max_height_change
    }

    /// What a person reading a log needs: the declared camera height `declared_height`
    /// (metres) and what the road says, with the key to fix; none when it agrees or was not
    /// measured.
    pub fn advice(&self, declared_height: f64) -> Option<String> {
        if self.verdict != MountVerdict::Disagrees {
            return None;
        }
        let mut parts = Vec::new();
        if self.height_off {
            parts.push(format!(
                "the left camera is {:.2} m above the road, not {:.2} m as declared \
                 ([mount] position, its second value)",
                declared_height - self.road_height,
                declared_height
            ));
        }
        if self.pitch_off {
            parts.push(format!(
                "the road rises {:.1} degrees ahead: the camera looks {:.1} degrees further {} \
                 than declared ([mount] pitch_deg, positive down), or the road climbs",
                self.road_pitch_deg,
                self.road_pitch_deg.abs(),
                if self.road_pitch_deg > 0.0 {
                    "down"
                } else {
                    "up"
                }
            ));
        }
        if self.roll_off {
            parts.push(format!(
                "the road rises {:.1} degrees to the right ([mount] roll_deg), or it is banked",
                self.road_roll_deg
            ));
        }
        Some(format!(
            "the mount disagrees with the road measured over {} frames: {}",
            self.frames,
            parts.join("; ")
        ))
    }
}

/// The running average of the road's fits (see the module docs).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MountCheck {
    frames: u32,
    /// Height (m), rise ahead and to the right (degrees): mean and variance.
    mean: [f64; 3],
    var: [f64; 3],
}

impl MountCheck {
    /// Takes a frame's road estimate: its fit as measured, if any.
    pub fn add(&mut self, road: &RoadEstimate) {
        let Some(p) = road.fitted else {
            return;
        };
        let x = [p.height, p.pitch_deg(), p.roll_deg()];
        if !x.iter().all(|v| v.is_finite()) {
            return;
        }
        self.frames = self.frames.saturating_add(1);
        // A plain mean over the first WINDOW frames, then an exponential one.
        let a = 1.0 / f64::from(self.frames).min(WINDOW);
        for ((x, mean), var) in x.iter().zip(&mut self.mean).zip(&mut self.var) {
            let d = x - *mean;
            *mean += a * d;
            *var = (1.0 - a) * (*var + a * d * d);
        }
    }

    pub fn report(&self) -> MountReport {
        let [h, pitch, roll] = self.mean;
        let sd = |i: usize| {
            if self.frames >= 2 {
                self.var[i].sqrt()
            } else {
                f64::NAN
            }
        };
        let measured = self.frames > 0;
        let height_off = measured && h.abs() > HEIGHT_TOLERANCE;
        let pitch_off = measured && pitch.abs() > PITCH_TOLERANCE_DEG;
        let roll_off = measured && roll.abs() > ROLL_TOLERANCE_DEG;
        let verdict = if !measured {
            MountVerdict::Unmeasured
        } else if height_off || pitch_off || roll_off {
            MountVerdict::Disagrees
        } else {
            MountVerdict::Agrees
        };
        let nan_unless = |v: f64| if measured { v } else { f64::NAN };
        MountReport {
            verdict,
            frames: self.frames,
            road_height: nan_unless(h),
            road_pitch_deg: nan_unless(pitch),
            road_roll_deg: nan_unless(roll),
            height_sd: sd(0),
            pitch_sd_deg: sd(1),
            roll_sd_deg: sd(2),
            height_off,
            pitch_off,
            roll_off,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::road_plane::RoadPlane;

    fn measured(height: f64, slope_z: f64, slope_x: f64) -> RoadEstimate {
        RoadEstimate {
            fitted: Some(RoadPlane {
                height,
                slope_z,
                slope_x,
            }),
            ..RoadEstimate::prior(RoadPlane::FLAT)
        }
    }

    #[test]
    fn a_camera_declared_too_low_is_named_with_its_height_and_the_key() {
        let mut c = MountCheck::default();
        assert_eq!(c.report().verdict, MountVerdict::Unmeasured);
        // Declared 1.2 m up, really 1.65 m: the road lies 0.45 m below the declared one.
        for i in 0..30 {
            c.add(&measured(-0.45 + 0.01 * f64::from(i % 3), 0.0, 0.0));
        }
        let r = c.report();
        assert_eq!(r.verdict, MountVerdict::Disagrees);
        assert!(r.height_off && !r.pitch_off && !r.roll_off, "{r:?}");
        assert!((r.road_height + 0.44).abs() < 0.01, "{r:?}");
        let advice = r.advice(1.2).expect("advice");
        assert!(
            advice.contains("1.64 m above the road, not 1.20 m"),
            "{advice}"
        );
        assert!(advice.contains("[mount] position"), "{advice}");
        // 0.45 m is more than the road estimator's 0.3 m absorbs: the daemon's fault, once
        // 30 frames say so.
        assert!(r.hides(0.3) && !r.hides(0.5), "{r:?}");
        let few = {
            let mut c = MountCheck::default();
            (0..29).for_each(|_| c.add(&measured(-0.45, 0.0, 0.0)));
            c.report()
        };
        assert!(!few.hides(0.3), "{few:?}");
    }

    #[test]
    fn a_pitch_is_told_from_the_road_rising_ahead_and_noise_is_not() {
        let mut c = MountCheck::default();
        // 3 degrees further down: the road rises tan(3 deg) per metre ahead.
        c.add(&measured(0.0, 3f64.to_radians().tan(), 0.0));
        let r = c.report();
        assert!(r.pitch_off && !r.height_off, "{r:?}");
        assert!((r.road_pitch_deg - 3.0).abs() < 1e-9, "{r:?}");
        assert!(r.advice(1.65).is_some_and(|a| a.contains("further down")));
        // A right mount on a road that wanders by a few centimetres and a degree of grade:
        // agrees. Frames without a measurement change nothing.
        let mut ok = MountCheck::default();
        for i in 0..50 {
            let w = f64::from(i % 5) - 2.0;
            ok.add(&measured(0.03 * w, 0.01 * w, 0.03 * w));
            ok.add(&RoadEstimate::prior(RoadPlane::FLAT));
        }
        let r = ok.report();
        assert_eq!((r.verdict, r.frames), (MountVerdict::Agrees, 50), "{r:?}");
        assert_eq!(r.advice(1.65), None);
    }
}
