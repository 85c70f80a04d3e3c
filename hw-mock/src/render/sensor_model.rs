//! The camera's sensor: its radiometric response and noise, applied to a rendered frame.

use super::RenderError;
use crate::noise::{GAUSS_TABLE_LEN, GOLDEN_GAMMA, gaussian_table, splitmix64};

/// Linear radiometric response of one camera: `out = gain * in + offset` (grey levels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Response {
    pub gain: f64,
    pub offset: f64,
}

/// What the simulated image sensors do to the noise-free render.
///
/// Output = clamp(round(gain * clean + offset + noise), 0, 255) per channel, where noise is
/// Gaussian with standard deviation `noise_sigma` grey levels, independent per pixel, channel,
/// frame and camera, and a pure function of (`seed`, frame, camera index, sample index): the same
/// inputs always give the same bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    pub seed: u64,
    /// Standard deviation of the additive noise, grey levels (0 disables noise).
    pub noise_sigma: f64,
    /// Response of camera 0 (left) and camera 1 (right).
    pub response: [Response; 2],
}

impl Default for SensorModel {
    /// ~2 grey levels of noise; the right camera a little brighter than the left (gain 1.06,
    /// offset +5), as two real cameras of the same model differ: matchers must cope with it.
    fn default() -> Self {
        Self {
            seed: 0x5EED_F1E5,
            noise_sigma: 2.0,
            response: [
                Response {
                    gain: 1.0,
                    offset: 0.0,
                },
                Response {
                    gain: 1.06,
                    offset: 5.0,
                },
            ],
        }
    }
}

impl SensorModel {
    /// Identical, noiseless, unit-response cameras: the output is the clean render itself.
    pub fn ideal() -> Self {
        let unit = Response {
            gain: 1.0,
            offset: 0.0,
        };
        Self {
            seed: 0,
            noise_sigma: 0.0,
            response: [unit, unit],
        }
    }

    pub(super) fn check(&self, camera_index: u8) -> Result<Response, RenderError> {
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return Err(RenderError::BadSensor(
                "noise_sigma must be finite and >= 0",
            ));
        }
        let r = *self
            .response
            .get(usize::from(camera_index))
            .ok_or(RenderError::UnknownCamera(camera_index))?;
        if !(r.gain.is_finite() && r.offset.is_finite()) {
            return Err(RenderError::BadSensor("gain and offset must be finite"));
        }
        Ok(r)
    }

    /// Hash key of one camera's frame: every (seed, frame, camera) gets its own noise stream.
    pub(super) fn frame_key(&self, frame: u32, camera_index: u8) -> u64 {
        splitmix64(self.seed ^ splitmix64((u64::from(frame) << 8) | u64::from(camera_index)))
    }
}

/// The response `round(gain * v + offset)`, saturated to a byte, for every input level.
pub(super) fn response_table(r: Response) -> [u8; 256] {
    let mut t = [0; 256];
    for (v, e) in t.iter_mut().enumerate() {
        *e = (r.gain * v as f64 + r.offset).round().clamp(0.0, 255.0) as u8;
    }
    t
}

/// Samples in a noise field: a power of two above the samples of a 1280x1024 RGB frame.
pub(super) const FIELD_BITS: u32 = 22;
pub(super) const FIELD_LEN: usize = 1 << FIELD_BITS;

/// A field of Gaussian noise in grey levels, N(0, sigma^2) rounded to integers and saturated
/// to +-127: quantiles of the normal distribution (a 4096-entry table) drawn by a fixed
/// splitmix64 stream. Built once per camera and sigma; each frame reads it from its own
/// offset (see [`apply_sensor`]).
pub(super) fn noise_field(sigma: f64) -> Vec<i8> {
    let unit = gaussian_table();
    let mut levels = [0i8; GAUSS_TABLE_LEN];
    for (l, u) in levels.iter_mut().zip(unit.iter()) {
        *l = (u * sigma).round().clamp(-127.0, 127.0) as i8;
    }
    let mut field = vec![0i8; FIELD_LEN];
    let mut stream: u64 = 0x6e6f_6973_655f_6669; // "noise_fi": any fixed seed
    // Five 12-bit draws per hash.
    for five in field.chunks_mut(5) {
        let h = splitmix64(stream);
        stream = stream.wrapping_add(GOLDEN_GAMMA);
        for (k, f) in five.iter_mut().enumerate() {
            *f = levels[((h >> (12 * k)) as usize) & (GAUSS_TABLE_LEN - 1)];
        }
    }
    field
}

/// Applies the sensor noise to an image already through the camera's response (`sensed`):
/// sample `k` gets `field[(offset + k) mod FIELD_LEN]`, the offset drawn from `key` (every
/// seed, frame and camera gets its own). Frames see the same noise sequence shifted by a
/// random offset: independent for the flies, which never compare a frame with another at the
/// same offset difference, and one saturating byte add per sample (SIMD).
pub(super) fn apply_sensor(sensed: &[u8], out: &mut [u8], field: Option<&[i8]>, key: u64) {
    let Some(field) = field else {
        out.copy_from_slice(sensed);
        return;
    };
    let mut at = (splitmix64(key) as usize) & (FIELD_LEN - 1);
    for (src, dst) in sensed.chunks(FIELD_LEN).zip(out.chunks_mut(FIELD_LEN)) {
        // At most two contiguous runs of the field per chunk (it wraps once).
        let first = src.len().min(FIELD_LEN - at);
        let (s0, s1) = src.split_at(first);
        let (d0, d1) = dst.split_at_mut(first);
        for (s, d, run) in [(s0, d0, at), (s1, d1, 0)] {
            for ((o, &c), &n) in d.iter_mut().zip(s).zip(&field[run..]) {
                *o = (i16::from(c) + i16::from(n)).clamp(0, 255) as u8;
            }
        }
        at = (at + src.len()) & (FIELD_LEN - 1);
    }
}
