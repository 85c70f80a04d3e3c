//! Sensor plausibility: the camera faults that would otherwise read as a clear road.
//!
//! A stereo matcher sees nothing in an image without texture, and nothing new in an image that
//! does not change: a black, saturated, covered or defocused camera, or one that repeats its
//! last frame with fresh timestamps, gives a population with no evidence of an obstacle, which
//! the decision would take for a clear road. These checks look at the images themselves, in
//! raw grey levels (before the photometric normalisation that would stretch a black frame's
//! noise into texture), and say when the perception cannot be trusted:
//!
//! | fault | judged on | raised | cleared |
//! |---|---|---|---|
//! | `UNIFORM` | a camera's luma contrast (standard deviation) under `min_contrast`, or fewer than `min_textured` of its pixels with a gradient of at least [`TEXTURE_GRADIENT`] raw Sobel units | `raise_frames` consecutive frames | `clear_frames` consecutive healthy frames |
//! | `FROZEN` | at least `frozen_unchanged` of a camera's sampled pixels (those not clipped at black or white) identical to the previous frame's: a live sensor's noise changes most of them | `frozen_frames` consecutive frames | `clear_frames` |
//! | `MISMATCH` | the two cameras' mean grey levels more than `mismatch_mean` apart, or their contrasts more than `mismatch_contrast` times apart: far beyond the gain and exposure differences of a working pair | `raise_frames` consecutive pairs | `clear_frames` |
//! | `BLIND` | the engine's `matched` (flies whose windows match on texture) under the daemon's `blind_matched` | the daemon's `blind_pairs` | the flies match again |
//!
//! [`ImageCheck`] measures one camera's frames ([`ImageHealth`], no allocation per frame: the
//! capture thread runs it after preparing each frame); [`SensorMonitor`] debounces the pairs'
//! health into [`SensorFaults`]. The thresholds' defaults were measured on hw-mock's scenarios and
//! on the real KITTI frames of the test fixtures (none faulty: see `docs/tuning.md`).

use serde::{Deserialize, Serialize};

use crate::frame::{BPP, PreparedImage};

/// Raw Sobel magnitude (grey levels; a step of `s` levels gives `4 s`) from which a pixel counts
/// as textured: a 12-level edge. A sensor's noise of 2-3 grey levels stays under it (a Sobel of
/// noise of standard deviation `s` has a Rayleigh magnitude of scale ~3.5 `s`).
pub const TEXTURE_GRADIENT: f32 = 48.0;

/// Pixels between two samples of [`ImageCheck`], in both directions.
pub const SAMPLE_STEP: usize = 4;

/// One frame of one camera, as the checks see it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImageHealth {
    /// Mean luma as captured, grey levels.
    pub mean: f32,
    /// Standard deviation of the luma as captured, grey levels.
    pub contrast: f32,
    /// Fraction of the sampled pixels with a raw gradient of at least [`TEXTURE_GRADIENT`].
    pub textured: f32,
    /// Fraction of the sampled, unclipped pixels identical to the previous frame's; `None` for
    /// the first frame, or when every sample is clipped.
    pub unchanged: Option<f32>,
}

/// Measures each frame of one camera against the previous one: sized once for an image size.
#[derive(Debug, Clone)]
pub struct ImageCheck {
    width: usize,
    height: usize,
    previous: Vec<u8>,
    current: Vec<u8>,
    have_previous: bool,
}

impl ImageCheck {
    pub fn new(width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        let n = w.div_ceil(SAMPLE_STEP) * h.div_ceil(SAMPLE_STEP);
        Self {
            width: w,
            height: h,
            previous: vec![0; n],
            current: vec![0; n],
            have_previous: false,
        }
    }

    /// Health of `img`, the camera's next frame (a frame of another size resets the check).
    pub fn observe(&mut self, img: &PreparedImage) -> ImageHealth {
        let (w, h) = (img.width() as usize, img.height() as usize);
        if (w, h) != (self.width, self.height) {
            *self = Self::new(img.width(), img.height());
        }
        let raw = img.raw_stats();
        // The stored gradient byte is the normalised Sobel magnitude / GRADIENT_SCALE, the
        // normalised image being the raw one times the luma gain.
        let gain = raw.luma_gain().max(f32::MIN_POSITIVE);
        let min_byte = (TEXTURE_GRADIENT * gain / crate::frame::GRADIENT_SCALE).ceil();
        let min_byte = min_byte.clamp(1.0, 255.0) as u8;
        let (data, stride) = (img.data(), img.stride());
        let (mut n, mut textured, mut unclipped, mut same) = (0u32, 0u32, 0u32, 0u32);
        let mut k = 0;
        for y in (0..h).step_by(SAMPLE_STEP) {
            let row = img.offset(0, y as isize);
            debug_assert!(row + w * BPP <= data.len() && stride >= w * BPP);
            for x in (0..w).step_by(SAMPLE_STEP) {
                let o = row + x * BPP;
                let (v, g) = (data[o], data[o + 3]);
                n += 1;
                textured += u32::from(g >= min_byte);
                let live = v != raw.black && v != raw.white;
                unclipped += u32::from(live);
                same += u32::from(live && v == self.previous[k]);
                self.current[k] = v;
                k += 1;
            }
        }
        let unchanged =
            (self.have_previous && unclipped > 0).then(|| same as f32 / unclipped as f32);
        std::mem::swap(&mut self.previous, &mut self.current);
        self.have_previous = true;
        ImageHealth {
            mean: raw.luma_mean(),
            contrast: raw.luma_std(),
            textured: if n > 0 {
                textured as f32 / n as f32
            } else {
                0.0
            },
            unchanged,
        }
    }
}

bit_set! {
    /// The sensor faults, one bit each (the `SensorFaults` signal of `FLYD_Status`; any of
    /// them also sets `CAMERA_ERROR`).
    pub struct SensorFaults(mask 0x0F) {
        /// bit 0: a camera's image is uniform or has too little texture (dark, saturated,
        /// covered, defocused).
        const UNIFORM = 0 => "UNIFORM";
        /// bit 1: a camera repeats the same image (frozen sensor, stuck driver buffer).
        const FROZEN = 1 => "FROZEN";
        /// bit 2: the two cameras' exposures differ far beyond a working pair's.
        const MISMATCH = 2 => "MISMATCH";
        /// bit 3: the stereo pair matches nowhere (noise, covered, calibration no longer fits).
        const BLIND = 3 => "BLIND";
    }
}

/// Thresholds and debouncing of [`SensorMonitor`] (see the module docs): the `[sensor]`
/// settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Luma standard deviation, grey levels, under which an image is uniform.
    pub min_contrast: f32,
    /// Fraction of textured pixels under which an image is uniform.
    pub min_textured: f32,
    /// Fraction of unchanged unclipped pixels from which a frame repeats the previous one.
    pub frozen_unchanged: f32,
    /// Consecutive repeated frames before FROZEN.
    pub frozen_frames: u32,
    /// Mean grey levels between the cameras beyond which they mismatch.
    pub mismatch_mean: f32,
    /// Ratio of the cameras' contrasts beyond which they mismatch.
    pub mismatch_contrast: f32,
    /// Consecutive faulty frames (pairs) before UNIFORM or MISMATCH.
    pub raise_frames: u32,
    /// Consecutive healthy frames (pairs) before a fault clears.
    pub clear_frames: u32,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            min_contrast: 6.0,
            min_textured: 0.01,
            frozen_unchanged: 0.95,
            frozen_frames: 3,
            mismatch_mean: 100.0,
            mismatch_contrast: 5.0,
            raise_frames: 2,
            clear_frames: 3,
        }
    }
}

/// A [`SensorConfig`] key out of its range.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{key} must be within {range}")]
pub struct SensorConfigError {
    pub key: &'static str,
    pub range: &'static str,
}

impl SensorConfig {
    /// Every threshold within what still detects its fault (none can be set so that it never
    /// fires, or fires on every healthy frame).
    pub fn validate(&self) -> Result<(), SensorConfigError> {
        let within = |v: f32, lo: f32, hi: f32| v.is_finite() && (lo..=hi).contains(&v);
        let checks = [
            (
                within(self.min_contrast, 0.5, 64.0),
                "min_contrast",
                "0.5..=64",
            ),
            (
                within(self.min_textured, 0.0001, 0.5),
                "min_textured",
                "0.0001..=0.5",
            ),
            (
                within(self.frozen_unchanged, 0.5, 1.0),
                "frozen_unchanged",
                "0.5..=1",
            ),
            (
                (1..=30).contains(&self.frozen_frames),
                "frozen_frames",
                "1..=30",
            ),
            (
                within(self.mismatch_mean, 16.0, 255.0),
                "mismatch_mean",
                "16..=255",
            ),
            (
                within(self.mismatch_contrast, 1.5, 64.0),
                "mismatch_contrast",
                "1.5..=64",
            ),
            (
                (1..=30).contains(&self.raise_frames),
                "raise_frames",
                "1..=30",
            ),
            (
                (1..=300).contains(&self.clear_frames),
                "clear_frames",
                "1..=300",
            ),
        ];
        match checks.into_iter().find(|(ok, _, _)| !ok) {
            Some((_, key, range)) => Err(SensorConfigError { key, range }),
            None => Ok(()),
        }
    }
}

/// Which camera a sensor fault was seen on (for the logs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sides {
    pub left: bool,
    pub right: bool,
}

impl Sides {
    pub fn name(self) -> &'static str {
        match (self.left, self.right) {
            (true, true) => "both",
            (true, false) => "left",
            (false, true) => "right",
            (false, false) => "none",
        }
    }
}

/// A fault raised after `raise` consecutive bad observations and cleared after `clear`
/// consecutive good ones.
#[derive(Debug, Clone, Copy, Default)]
struct Debounce {
    bad: u32,
    good: u32,
    on: bool,
}

impl Debounce {
    fn update(&mut self, bad: bool, raise: u32, clear: u32) -> bool {
        if bad {
            self.bad = self.bad.saturating_add(1);
            self.good = 0;
            self.on |= self.bad >= raise;
        } else {
            self.good = self.good.saturating_add(1);
            self.bad = 0;
            self.on &= self.good < clear;
        }
        self.on
    }
}

/// What [`SensorMonitor::observe`] concluded on a pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SensorVerdict {
    pub faults: SensorFaults,
    pub uniform: Sides,
    pub frozen: Sides,
}

/// Debounces the health of each new pair into [`SensorFaults`] (BLIND is the caller's: the
/// daemon judges it on the engine's statistics).
#[derive(Debug, Clone)]
pub struct SensorMonitor {
    config: SensorConfig,
    uniform: [Debounce; 2],
    frozen: [Debounce; 2],
    mismatch: Debounce,
}

impl SensorMonitor {
    pub fn new(config: SensorConfig) -> Self {
        Self {
            config,
            uniform: [Debounce::default(); 2],
            frozen: [Debounce::default(); 2],
            mismatch: Debounce::default(),
        }
    }

    /// Whether `h` alone shows too little texture to match on.
    pub fn is_uniform(&self, h: &ImageHealth) -> bool {
        let c = &self.config;
        let textured = h.contrast >= c.min_contrast && h.textured >= c.min_textured;
        !textured
    }

    /// Whether `h` repeats its camera's previous frame.
    pub fn is_repeated(&self, h: &ImageHealth) -> bool {
        h.unchanged
            .is_some_and(|u| u >= self.config.frozen_unchanged)
    }

    /// Whether the two cameras' exposures are beyond what a working pair differs by.
    pub fn is_mismatched(&self, l: &ImageHealth, r: &ImageHealth) -> bool {
        let c = &self.config;
        let (lo, hi) = if l.contrast < r.contrast {
            (l.contrast, r.contrast)
        } else {
            (r.contrast, l.contrast)
        };
        let contrast = hi > c.mismatch_contrast * lo.max(0.5);
        // NaN (never from a prepared image) counts as a mismatch.
        let means_close = (l.mean - r.mean).abs() <= c.mismatch_mean;
        !means_close || contrast
    }

    /// The faults after one more pair.
    pub fn observe(&mut self, left: &ImageHealth, right: &ImageHealth) -> SensorVerdict {
        let c = self.config;
        let mut v = SensorVerdict::default();
        let mut side = |i: usize, h: &ImageHealth| {
            let u = self.uniform[i].update(self.is_uniform(h), c.raise_frames, c.clear_frames);
            let repeated = self.is_repeated(h);
            let f = self.frozen[i].update(repeated, c.frozen_frames, c.clear_frames);
            (u, f)
        };
        let (lu, lf) = side(0, left);
        let (ru, rf) = side(1, right);
        v.uniform = Sides {
            left: lu,
            right: ru,
        };
        v.frozen = Sides {
            left: lf,
            right: rf,
        };
        // A uniform image says nothing about exposure: its mismatch is already a fault.
        let mismatched = !(lu || ru) && self.is_mismatched(left, right);
        let m = self
            .mismatch
            .update(mismatched, c.raise_frames, c.clear_frames);
        v.faults.set(SensorFaults::UNIFORM, lu || ru);
        v.faults.set(SensorFaults::FROZEN, lf || rf);
        v.faults.set(SensorFaults::MISMATCH, m);
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::PixelFormat;

    fn hash(a: u64, b: u64, c: u64) -> u64 {
        let mut z = a
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(b.wrapping_mul(0xBF58_476D_1CE4_E5B9))
            .wrapping_add(c.wrapping_mul(0x94D0_49BB_1331_11EB));
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> PreparedImage {
        let mut px = Vec::with_capacity((w * h * 3) as usize);
        for y in 0..h {
            for x in 0..w {
                px.extend_from_slice(&f(x, y));
            }
        }
        PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, &px).expect("image")
    }

    /// A textured scene with sensor noise of about `noise` grey levels, different per `frame`.
    fn scene(frame: u64, noise: u64, gain: f32) -> PreparedImage {
        image(96, 64, |x, y| {
            let base = if (x / 8 + y / 8) % 2 == 0 {
                60.0
            } else {
                180.0
            };
            let n = hash(frame, u64::from(x), u64::from(y)) % (2 * noise + 1);
            let v = ((base + n as f32 - noise as f32) * gain).clamp(0.0, 255.0) as u8;
            [v, v, v]
        })
    }

    fn flat(v: u8) -> PreparedImage {
        image(96, 64, |_, _| [v, v, v])
    }

    #[test]
    fn a_textured_noisy_scene_is_healthy_and_changes() {
        let mut check = ImageCheck::new(96, 64);
        let first = check.observe(&scene(0, 3, 1.0));
        assert_eq!(first.unchanged, None);
        let h = check.observe(&scene(1, 3, 1.0));
        let m = SensorMonitor::new(SensorConfig::default());
        assert!(!m.is_uniform(&h), "{h:?}");
        assert!(!m.is_repeated(&h), "{h:?}");
        assert!(h.textured > 0.1 && h.contrast > 50.0, "{h:?}");
    }

    #[test]
    fn black_white_grey_and_noise_only_images_are_uniform() {
        let m = SensorMonitor::new(SensorConfig::default());
        let mut check = ImageCheck::new(96, 64);
        for v in [0, 128, 255] {
            let h = check.observe(&flat(v));
            assert!(m.is_uniform(&h), "{v}: {h:?}");
        }
        // A covered lens: black with 2 grey levels of noise.
        let dark = image(96, 64, |x, y| {
            let n = (hash(7, u64::from(x), u64::from(y)) % 5) as u8;
            [n + 3, n + 3, n + 3]
        });
        let h = check.observe(&dark);
        assert!(m.is_uniform(&h), "{h:?}");
    }

    #[test]
    fn a_repeated_frame_is_frozen_whatever_else() {
        let m = SensorMonitor::new(SensorConfig::default());
        let mut check = ImageCheck::new(96, 64);
        let img = scene(4, 3, 1.0);
        check.observe(&img);
        let h = check.observe(&img);
        assert_eq!(h.unchanged, Some(1.0));
        assert!(m.is_repeated(&h));
        // Clipped pixels do not count: a live frame half black (night, a tunnel's wall) is
        // judged on its other half, whose noise changes.
        let mut check = ImageCheck::new(96, 64);
        for frame in 0..2 {
            let h = check.observe(&image(96, 64, |x, y| {
                let noise = (hash(frame, x.into(), y.into()) % 7) as u8;
                let v = if x < 48 {
                    0
                } else {
                    60 + 120 * (((x / 8) + (y / 8)) % 2) as u8 + noise
                };
                [v, v, v]
            }));
            if frame == 1 {
                assert!(h.unchanged.is_some_and(|u| u < 0.5), "{h:?}");
                assert!(!m.is_repeated(&h));
            }
        }
    }

    #[test]
    fn exposures_far_apart_mismatch_but_gain_differences_do_not() {
        let m = SensorMonitor::new(SensorConfig::default());
        let (mut a, mut b) = (ImageCheck::new(96, 64), ImageCheck::new(96, 64));
        let l = a.observe(&scene(0, 3, 1.0));
        let r = b.observe(&scene(0, 3, 1.3));
        assert!(!m.is_mismatched(&l, &r), "{l:?} {r:?}");
        let r = b.observe(&scene(1, 3, 0.1));
        assert!(m.is_mismatched(&l, &r), "{l:?} {r:?}");
    }

    #[test]
    fn faults_are_raised_after_their_frames_and_cleared_after_healthy_ones() {
        let c = SensorConfig::default();
        let mut m = SensorMonitor::new(c);
        let mut l = ImageCheck::new(96, 64);
        let mut r = ImageCheck::new(96, 64);
        let mut frame = 0;
        let mut pair = |m: &mut SensorMonitor, left_black: bool, right_frozen: bool| {
            frame += 1;
            let li = if left_black {
                flat(0)
            } else {
                scene(frame, 3, 1.0)
            };
            let ri = scene(if right_frozen { 0 } else { frame }, 3, 1.0);
            m.observe(&l.observe(&li), &r.observe(&ri))
        };
        for _ in 0..5 {
            assert!(pair(&mut m, false, false).faults.is_empty());
        }
        for k in 1..=c.raise_frames {
            let v = pair(&mut m, true, false);
            assert_eq!(
                v.faults.contains(SensorFaults::UNIFORM),
                k >= c.raise_frames
            );
        }
        let v = pair(&mut m, true, false);
        assert_eq!(
            v.uniform,
            Sides {
                left: true,
                right: false
            }
        );
        assert!(
            !v.faults.contains(SensorFaults::MISMATCH),
            "uniform is not also a mismatch"
        );
        for k in 1..=c.clear_frames {
            let v = pair(&mut m, false, false);
            assert_eq!(v.faults.is_empty(), k >= c.clear_frames, "{k}: {v:?}");
        }
        // The right camera repeats one frame: the first repeat is a comparison, so FROZEN
        // follows `frozen_frames` repeats.
        pair(&mut m, false, true);
        for k in 1..=c.frozen_frames {
            let v = pair(&mut m, false, true);
            assert_eq!(
                v.faults.contains(SensorFaults::FROZEN),
                k >= c.frozen_frames,
                "{k}"
            );
            assert!(!v.frozen.left);
        }
    }

    #[test]
    fn validation_rejects_thresholds_that_detect_nothing() {
        assert_eq!(SensorConfig::default().validate(), Ok(()));
        for bad in [
            SensorConfig {
                min_contrast: 0.0,
                ..SensorConfig::default()
            },
            SensorConfig {
                min_textured: f32::NAN,
                ..SensorConfig::default()
            },
            SensorConfig {
                frozen_unchanged: 1.5,
                ..SensorConfig::default()
            },
            SensorConfig {
                frozen_frames: 0,
                ..SensorConfig::default()
            },
            SensorConfig {
                mismatch_mean: 1e30,
                ..SensorConfig::default()
            },
            SensorConfig {
                clear_frames: 0,
                ..SensorConfig::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn fault_names() {
        let f = SensorFaults::UNIFORM | SensorFaults::BLIND;
        assert_eq!(f.to_string(), "UNIFORM|BLIND");
        assert_eq!(SensorFaults::from_bits(0xFF).bits(), 0x0F);
    }
}
