//! The per-frame work of [`PreparedImage::prepare`], done once on the capture thread: colour
//! normalisation (16.16 fixed point, the same bytes on every instruction set), luma, the
//! right image's row shift, Sobel gradient norms, the replicated border and the block means.

use super::{
    BLOCK, BPP, GRADIENT_SCALE, NORMALISED_MEAN, NORMALISED_STD, PAD, PixelFormat, PreparedImage,
    RawStats,
};
use crate::isa::Isa;

/// The stored gradient byte of Sobel responses `gx`, `gy`: `round(|g| / 4)`, saturating.
#[inline(always)]
pub(super) fn quantise(gx: i32, gy: i32) -> u8 {
    quantise_sq(gx * gx + gy * gy)
}

/// [`quantise`] of a squared norm `gx^2 + gy^2`.
#[inline(always)]
pub(super) fn quantise_sq(sq: i32) -> u8 {
    // sq >= 0 (a sum of squares under 2^22), so `q` is finite and in [0.5, 255].
    let q = ((sq.max(0) as f32).sqrt() / GRADIENT_SCALE + 0.5).min(255.0);
    // SAFETY: `q` is finite and in [0.5, 255] (above), so it fits an i32. The unchecked
    // conversion vectorises; a saturating `as` is scalarised lane by lane.
    unsafe { q.to_int_unchecked::<i32>() as u8 }
}

/// One channel's normalisation `v -> clamp((v * gain + offset) >> 16, 0, 255)`, 16.16 fixed
/// point: integer arithmetic vectorises (a 256-entry table lookup per byte does not), and is the
/// same on every instruction set. Within one grey level of the exact
/// `round((v - mean) * std_gain + NORMALISED_MEAN)` (equal but for values within ~0.004 of a
/// rounding tie).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Affine {
    pub(super) gain: i32,
    pub(super) offset: i32,
}

impl Affine {
    const IDENTITY: Self = Self {
        gain: 1 << 16,
        offset: 0,
    };

    /// The map that takes a channel of this mean and variance to the normalised statistics.
    /// A flat image keeps its contrast (there is nothing to stretch): the gain is at most 4, so
    /// `v * gain + offset` stays far inside i32.
    pub(super) fn normalising(mean: f64, var: f64) -> Self {
        let gain = NORMALISED_STD / var.max(0.0).sqrt().max(NORMALISED_STD / 4.0);
        Self {
            gain: (gain * 65536.0).round() as i32,
            offset: ((NORMALISED_MEAN - mean * gain) * 65536.0 + 32768.0).round() as i32,
        }
    }

    #[inline(always)]
    pub(super) fn apply(self, v: u8) -> i32 {
        ((i32::from(v) * self.gain + self.offset) >> 16).clamp(0, 255)
    }
}

impl PreparedImage {
    /// Colour normalisation, luma, Sobel, border and block means. `pixels` has the right size.
    #[inline(always)]
    pub(super) fn prepare_with(&mut self, _: Isa, format: PixelFormat, pixels: &[u8]) {
        let (w, h) = (self.width, self.height);
        let ([n0, n1, n2], raw) = self.normalisation(format, pixels);
        self.raw = raw;
        // Colour (normalised) and luma.
        for y in 0..h {
            let row = self.offset(0, y as isize);
            let dst = &mut self.data[row..row + w * BPP];
            let luma = &mut self.luma[y * w..(y + 1) * w];
            match format {
                PixelFormat::Rgb8 => {
                    let src = &pixels[y * w * 3..(y + 1) * w * 3];
                    for ((d, s), l) in dst
                        .chunks_exact_mut(BPP)
                        .zip(src.chunks_exact(3))
                        .zip(luma.iter_mut())
                    {
                        let (r, g, b) = (n0.apply(s[0]), n1.apply(s[1]), n2.apply(s[2]));
                        // One 4-byte store (the gradient byte is written later).
                        let px = (r | g << 8 | b << 16) as u32;
                        d.copy_from_slice(&px.to_le_bytes());
                        // ITU-R BT.601 weights in 8-bit fixed point.
                        *l = ((77 * r + 150 * g + 29 * b) >> 8) as u8;
                    }
                }
                PixelFormat::Grey8 => {
                    let src = &pixels[y * w..(y + 1) * w];
                    for ((d, &s), l) in dst.chunks_exact_mut(BPP).zip(src).zip(luma.iter_mut()) {
                        let v = n0.apply(s) as u8;
                        d[0] = v;
                        d[1] = 0;
                        d[2] = 0;
                        *l = v;
                    }
                }
            }
        }
        if self.row_shift_q8 != 0 {
            self.shift_rows();
        }
        self.fill_gradient();
        self.replicate_border();
        self.fill_block_means();
    }

    /// Resamples the colour rows and the luma plane in place by the row shift: row `y`
    /// becomes `(1 - a) row(y + k) + a row(y + k + 1)` with `k + a` the shift (source rows
    /// clamped to the image). A non-negative `k` reads rows at or below `y` only, so the rows
    /// are visited top down; a negative one bottom up. No allocation.
    pub(super) fn shift_rows(&mut self) {
        let (w, h, stride) = (self.width, self.height, self.stride);
        let k = self.row_shift_q8.div_euclid(256) as isize;
        let a = self.row_shift_q8.rem_euclid(256) as u16;
        let src = |y: usize, d: isize| (y as isize + d).clamp(0, h as isize - 1) as usize;
        let row = |y: usize| (y + PAD) * stride + PAD * BPP;
        let n = w * BPP;
        let Self {
            data,
            luma,
            shift_scratch,
            ..
        } = self;
        // Sized by `new` (one padded row); the lengths below hold for any image of this size.
        shift_scratch.resize(n, 0);
        // Blends two rows into the scratch (straight-line code the compiler vectorises).
        let blend = |out: &mut [u8], p: &[u8], q: &[u8]| {
            for ((o, &p), &q) in out.iter_mut().zip(p).zip(q) {
                *o = ((u16::from(p) * (256 - a) + u16::from(q) * a + 128) >> 8) as u8;
            }
        };
        for i in 0..h {
            let y = if k >= 0 { i } else { h - 1 - i };
            let (y0, y1) = (src(y, k), src(y, k + 1));
            blend(
                &mut shift_scratch[..n],
                &data[row(y0)..row(y0) + n],
                &data[row(y1)..row(y1) + n],
            );
            data[row(y)..row(y) + n].copy_from_slice(&shift_scratch[..n]);
            blend(
                &mut shift_scratch[..w],
                &luma[y0 * w..(y0 + 1) * w],
                &luma[y1 * w..(y1 + 1) * w],
            );
            luma[y * w..(y + 1) * w].copy_from_slice(&shift_scratch[..w]);
        }
    }

    /// Per-channel affine maps that give each channel of this frame the same mean
    /// ([`NORMALISED_MEAN`]) and standard deviation ([`NORMALISED_STD`]).
    ///
    /// Two real cameras never agree on gain and offset (exposure, white balance, vignetting), and
    /// the fitness compares raw colour differences: with a 20-grey-level exposure difference the
    /// true match of a Middlebury pair has an SSD as large as many wrong ones. Normalising each
    /// image on its own removes a global gain/offset difference without either capture thread
    /// needing the other camera's frame. Built from exact integer sums of v and v^2 (one vectorised
    /// pass): no allocation.
    #[inline(always)]
    pub(super) fn normalisation(
        &self,
        format: PixelFormat,
        pixels: &[u8],
    ) -> ([Affine; 3], RawStats) {
        let channels = format.bytes_per_pixel();
        // Exact integer sums of v and v^2 per channel. 48 lanes (16 RGB pixels, 48 grey ones)
        // keep each lane on one channel and let the compiler vectorise; lanes are u32 within a
        // row (at most 65025 x width / 16 per lane) and folded into u64 after each row.
        const LANES: usize = 48;
        let (mut sum, mut sq) = ([0u64; 3], [0u64; 3]);
        let row_len = self.width * channels;
        for row in pixels.chunks_exact(row_len) {
            let (mut s1, mut s2) = ([0u32; LANES], [0u32; LANES]);
            let mut chunks = row.chunks_exact(LANES);
            for c in &mut chunks {
                for k in 0..LANES {
                    let v = u32::from(c[k]);
                    s1[k] += v;
                    s2[k] += v * v;
                }
            }
            for (k, &v) in chunks.remainder().iter().enumerate() {
                let v = u32::from(v);
                s1[k] += v;
                s2[k] += v * v;
            }
            for k in 0..LANES {
                sum[k % channels] += u64::from(s1[k]);
                sq[k % channels] += u64::from(s2[k]);
            }
        }
        let n = (self.width * self.height) as f64;
        let mut maps = [Affine::IDENTITY; 3];
        let mut raw = RawStats {
            channels: channels as u8,
            ..RawStats::default()
        };
        for c in 0..channels {
            let mean = sum[c] as f64 / n;
            let var = (sq[c] as f64 / n - mean * mean).max(0.0);
            maps[c] = Affine::normalising(mean, var);
            raw.mean[c] = mean as f32;
            raw.std[c] = var.sqrt() as f32;
            raw.gain[c] = maps[c].gain as f32 / 65536.0;
        }
        raw.black = maps[0].apply(0) as u8;
        raw.white = maps[0].apply(255) as u8;
        (maps, raw)
    }

    #[inline(always)]
    pub(super) fn fill_block_means(&mut self) {
        let (w, h) = (self.width, self.height);
        let cols = w.div_ceil(BLOCK);
        for (b, mean) in self.block_means.iter_mut().enumerate() {
            let (bx, by) = ((b % cols) * BLOCK, (b / cols) * BLOCK);
            let (x1, y1) = ((bx + BLOCK).min(w), (by + BLOCK).min(h));
            let mut sum = 0u32;
            for y in by..y1 {
                sum += self.luma[y * w + bx..y * w + x1]
                    .iter()
                    .map(|&v| v as u32)
                    .sum::<u32>();
            }
            *mean = (sum / ((x1 - bx) * (y1 - by)) as u32) as u8;
        }
    }

    /// Sobel gradient norm of the luma, with the image edge replicated. Rows are computed into
    /// a scratch row with straight-line loops over three row slices (the compiler vectorises
    /// them), then spread into the gradient bytes.
    #[inline(always)]
    pub(super) fn fill_gradient(&mut self) {
        let (w, h) = (self.width, self.height);
        let mut row_norms = std::mem::take(&mut self.row_scratch);
        row_norms.resize(w, 0);
        for y in 0..h {
            let (ym, yp) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let (r0, r1, r2) = (
                &self.luma[ym * w..(ym + 1) * w],
                &self.luma[y * w..(y + 1) * w],
                &self.luma[yp * w..(yp + 1) * w],
            );
            let norm = |xm: usize, x: usize, xp: usize| -> u8 {
                let at = |r: &[u8], i: usize| r[i] as i32;
                let gx = (at(r0, xp) + 2 * at(r1, xp) + at(r2, xp))
                    - (at(r0, xm) + 2 * at(r1, xm) + at(r2, xm));
                let gy = (at(r2, xm) + 2 * at(r2, x) + at(r2, xp))
                    - (at(r0, xm) + 2 * at(r0, x) + at(r0, xp));
                quantise(gx, gy)
            };
            row_norms[0] = norm(0, 0, 1.min(w - 1));
            row_norms[w - 1] = norm(w.saturating_sub(2), w - 1, w - 1);
            if w > 2 {
                let n = w - 2;
                let (a0, b0, c0) = (&r0[..n], &r0[1..n + 1], &r0[2..n + 2]);
                let (a1, c1) = (&r1[..n], &r1[2..n + 2]);
                let (a2, b2, c2) = (&r2[..n], &r2[1..n + 2 - 1], &r2[2..n + 2]);
                let out = &mut row_norms[1..n + 1];
                for i in 0..n {
                    let gx = (c0[i] as i32 + 2 * c1[i] as i32 + c2[i] as i32)
                        - (a0[i] as i32 + 2 * a1[i] as i32 + a2[i] as i32);
                    let gy = (a2[i] as i32 + 2 * b2[i] as i32 + c2[i] as i32)
                        - (a0[i] as i32 + 2 * b0[i] as i32 + c0[i] as i32);
                    out[i] = quantise(gx, gy);
                }
            }
            let row = self.offset(0, y as isize);
            for (px, &g) in self.data[row..row + w * BPP]
                .chunks_exact_mut(BPP)
                .zip(row_norms.iter())
            {
                px[3] = g;
            }
        }
        self.row_scratch = row_norms;
    }

    #[inline(always)]
    pub(super) fn replicate_border(&mut self) {
        let (w, h, stride) = (self.width, self.height, self.stride);
        let row_bytes = w * BPP;
        for y in 0..h {
            let start = (y + PAD) * stride;
            let first = start + PAD * BPP;
            let last = first + row_bytes - BPP;
            for p in 0..PAD {
                self.data.copy_within(first..first + BPP, start + p * BPP);
                let right = first + row_bytes + p * BPP;
                self.data.copy_within(last..last + BPP, right);
            }
        }
        for p in 0..PAD {
            self.data
                .copy_within(PAD * stride..(PAD + 1) * stride, p * stride);
            let src = (PAD + h - 1) * stride;
            self.data
                .copy_within(src..src + stride, (PAD + h + p) * stride);
        }
    }
}
