//! Per-frame preparation: everything the fitness function needs that depends only on the image.
//!
//! A [`PreparedImage`] is built once per captured frame (in the daemon: by the capture thread), so
//! the evolution only reads it. Layout, chosen for the fitness kernel:
//! - 4 bytes per pixel `[c0, c1, c2, g]`: the colour channels (RGB, or grey in `c0` with `c1 = c2 =
//!   0`) and `g`, the Sobel gradient norm of the luma quantised to a byte (`|grad| / 4`, saturating
//!   at 255). Putting the gradient beside the colour means one cache line serves both the
//!   numerator and the neighbourhood of the fitness.
//! - A border of [`PAD`] pixels on every side, replicated from the edge, so a neighbourhood window
//!   (and the kernel's 16/32-byte loads) never leaves the buffer: the kernel has no bounds logic.
//!
//! Preparation never allocates once the image exists ([`PreparedImage::prepare`] refills in
//! place); a frame of the wrong size is an error, not a panic.

use crate::isa::{Isa, dispatch};

mod prepare;

/// Border, in pixels, around the image (>= the largest neighbourhood radius plus the kernel's
/// over-read).
pub const PAD: usize = 8;
/// Bytes per pixel in a prepared image.
pub const BPP: usize = 4;
/// The gradient norm is stored divided by this (Sobel of an 8-bit luma reaches ~1442).
pub const GRADIENT_SCALE: f32 = 4.0;

/// Mean of every colour channel after photometric normalisation.
pub const NORMALISED_MEAN: f64 = 128.0;
/// Standard deviation of every colour channel after photometric normalisation.
pub const NORMALISED_STD: f64 = 48.0;

/// Pixel formats a frame can arrive in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 3 bytes per pixel, R G B.
    Rgb8,
    /// 1 byte per pixel.
    Grey8,
}

impl PixelFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 => 3,
            PixelFormat::Grey8 => 1,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("frame of {got} bytes does not match {width}x{height} {format:?} ({expected} bytes)")]
    SizeMismatch {
        width: u32,
        height: u32,
        format: PixelFormat,
        expected: usize,
        got: usize,
    },
    #[error("image {width}x{height} is too small or too large")]
    BadDimensions { width: u32, height: u32 },
}

/// An image ready for fitness evaluation (see the module docs for the layout).
#[derive(Debug, Clone)]
pub struct PreparedImage {
    width: usize,
    height: usize,
    stride: usize,
    /// Colour channels that carry data (3 for RGB, 1 for grey).
    channels: u8,
    data: Vec<u8>,
    /// Scratch luma plane (unpadded) reused across frames.
    luma: Vec<u8>,
    /// One row of gradient bytes (scratch).
    row_scratch: Vec<u8>,
    /// Mean luma of each [`BLOCK`] x [`BLOCK`] block, row-major (what the engine compares
    /// between frames to see where the scene changed).
    block_means: Vec<u8>,
    /// Each colour channel's mean and standard deviation as captured, before normalisation
    /// (what the sensor checks of [`crate::sensor`] judge contrast and exposure on).
    raw: RawStats,
    /// The packed pixels of the last [`PreparedImage::prepare`], kept only when
    /// [`PreparedImage::retain_pixels`] asked for them (a recorder copies them out).
    pixels: Option<RetainedPixels>,
    /// Vertical shift applied by every prepare, 1/256 px ([`PreparedImage::with_row_shift`]).
    row_shift_q8: i32,
    /// One row of the padded buffer (scratch of the row shift; empty without one).
    shift_scratch: Vec<u8>,
}

/// What a retained frame was prepared from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Retained<'a> {
    /// Its packed pixels.
    Raw(PixelFormat, &'a [u8]),
    /// The JPEG its pixels were decoded from (RGB).
    Jpeg(&'a [u8]),
}

/// The last prepared frame's packed pixels: `buffer[..len]` (sized for RGB at the start, so
/// that neither a refill nor a clone of the image reallocates it).
#[derive(Debug, Clone)]
struct RetainedPixels {
    format: PixelFormat,
    /// `buffer[..len]` holds the frame's JPEG (what [`PreparedImage::retain_encoded`] kept)
    /// instead of its pixels.
    jpeg: bool,
    len: usize,
    buffer: Vec<u8>,
}

/// A frame's channels as captured (before photometric normalisation): mean and standard
/// deviation per channel, grey levels, and the gain normalisation applied to each.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RawStats {
    pub mean: [f32; 3],
    pub std: [f32; 3],
    pub gain: [f32; 3],
    /// Channels that carry data (3 for RGB, 1 for grey).
    pub channels: u8,
    /// What raw black (0) and white (255) of channel 0 became in the prepared image: a pixel
    /// clipped by the sensor.
    pub black: u8,
    pub white: u8,
}

impl RawStats {
    /// BT.601 luma of the channel means (the grey mean for a grey frame).
    pub fn luma_mean(&self) -> f32 {
        self.weighted(self.mean)
    }

    /// Standard deviation of the luma, approximated from the channels' (exact when they are
    /// proportional, as on grey scenes; an upper bound otherwise).
    pub fn luma_std(&self) -> f32 {
        self.weighted(self.std)
    }

    /// The gain normalisation applied to the luma (the channels' gains, weighted).
    pub fn luma_gain(&self) -> f32 {
        self.weighted(self.gain)
    }

    fn weighted(&self, v: [f32; 3]) -> f32 {
        if self.channels == 3 {
            0.299 * v[0] + 0.587 * v[1] + 0.114 * v[2]
        } else {
            v[0]
        }
    }
}

/// Side of the blocks of [`PreparedImage::block_means`], pixels.
pub const BLOCK: usize = 16;

/// The largest vertical shift [`PreparedImage::with_row_shift`] applies, pixels.
pub const MAX_ROW_SHIFT: f64 = 4.0;

impl PreparedImage {
    /// An all-black image of the given size.
    pub fn new(width: u32, height: u32) -> Result<Self, FrameError> {
        if !(8..=8192).contains(&width) || !(8..=8192).contains(&height) {
            return Err(FrameError::BadDimensions { width, height });
        }
        let (w, h) = (width as usize, height as usize);
        let stride = (w + 2 * PAD) * BPP;
        Ok(Self {
            width: w,
            height: h,
            stride,
            channels: 3,
            data: vec![0; stride * (h + 2 * PAD)],
            luma: vec![0; w * h],
            row_scratch: vec![0; w],
            block_means: vec![0; w.div_ceil(BLOCK) * h.div_ceil(BLOCK)],
            raw: RawStats::default(),
            pixels: None,
            row_shift_q8: 0,
            shift_scratch: vec![0; w * BPP],
        })
    }

    /// Row `y` of every later prepare shows row `y + px` of the pixels it is given (linear
    /// interpolation between rows, edge rows repeated): how a rectified pair's residual
    /// vertical misalignment is corrected on the right image ([`crate::rectification`]).
    /// `px` is clamped to +-[`MAX_ROW_SHIFT`] and kept to 1/256 px; 0 (the default) leaves
    /// the pixels as they are.
    pub fn with_row_shift(mut self, px: f64) -> Self {
        self.set_row_shift(px);
        self
    }

    /// [`Self::with_row_shift`] on an image in use, for the prepares after it (no allocation:
    /// a capture thread applies a new correction with it).
    pub fn set_row_shift(&mut self, px: f64) {
        let px = if px.is_finite() { px } else { 0.0 };
        self.row_shift_q8 = (px.clamp(-MAX_ROW_SHIFT, MAX_ROW_SHIFT) * 256.0).round() as i32;
    }

    /// Makes this image a copy of `other`'s prepared pixels (colour, gradient, channels, and
    /// the row shift they were prepared with),
    /// without allocating, when both are the same size; returns whether it did. (What a
    /// worker off the real-time path measures on.)
    pub fn copy_from(&mut self, other: &PreparedImage) -> bool {
        if (self.width, self.height) != (other.width, other.height) {
            return false;
        }
        self.data.copy_from_slice(&other.data);
        self.channels = other.channels;
        self.raw = other.raw;
        self.row_shift_q8 = other.row_shift_q8;
        true
    }

    /// The vertical shift of [`Self::with_row_shift`], pixels.
    pub fn row_shift(&self) -> f64 {
        f64::from(self.row_shift_q8) / 256.0
    }

    /// Keeps a copy of the packed pixels each [`PreparedImage::prepare`] is given (what a
    /// recording stores, so that a replay prepares the very same image); the buffer is sized
    /// here, once, for RGB. Off by default: the copy costs a memcpy of the frame.
    pub fn retain_pixels(mut self) -> Self {
        self.pixels = Some(RetainedPixels {
            format: PixelFormat::Rgb8,
            jpeg: false,
            len: 0,
            buffer: vec![0; self.width * self.height * 3],
        });
        self
    }

    /// [`PreparedImage::retain_pixels`] when `retain` (a recording runs), else `self`.
    pub fn retain_pixels_if(self, retain: bool) -> Self {
        if retain { self.retain_pixels() } else { self }
    }

    /// What the last prepare was made from, when retained ([`PreparedImage::retain_pixels`]):
    /// its packed pixels, or the JPEG they were decoded from ([`Self::retain_encoded`]).
    pub fn pixels(&self) -> Option<Retained<'_>> {
        self.pixels.as_ref().map(|p| {
            let bytes = &p.buffer[..p.len.min(p.buffer.len())];
            if p.jpeg {
                Retained::Jpeg(bytes)
            } else {
                Retained::Raw(p.format, bytes)
            }
        })
    }

    /// After a prepare from the pixels decoded from `jpeg` (an MJPEG camera's frame): keeps
    /// `jpeg` instead of those pixels, when pixels are retained and it fits their buffer (a
    /// JPEG larger than the raw frame keeps the pixels). Returns whether it was kept.
    pub fn retain_encoded(&mut self, jpeg: &[u8]) -> bool {
        let Some(kept) = self.pixels.as_mut() else {
            return false;
        };
        let Some(to) = kept.buffer.get_mut(..jpeg.len()) else {
            return false;
        };
        to.copy_from_slice(jpeg);
        kept.len = jpeg.len();
        kept.jpeg = true;
        true
    }

    /// Prepares a new image from packed pixels.
    pub fn from_pixels(
        width: u32,
        height: u32,
        format: PixelFormat,
        pixels: &[u8],
    ) -> Result<Self, FrameError> {
        let mut img = Self::new(width, height)?;
        img.prepare(format, pixels)?;
        Ok(img)
    }

    pub fn width(&self) -> u32 {
        self.width as u32
    }
    pub fn height(&self) -> u32 {
        self.height as u32
    }
    /// Colour channels that carry data: 3 (RGB) or 1 (grey, in channel 0).
    pub fn channels(&self) -> u8 {
        self.channels
    }
    /// Bytes between vertically adjacent pixels.
    pub fn stride(&self) -> usize {
        self.stride
    }
    /// The padded buffer.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// Byte offset of pixel `(x, y)`; valid for `-PAD <= x < width + PAD` (same for y).
    #[inline]
    pub fn offset(&self, x: isize, y: isize) -> usize {
        ((y + PAD as isize) as usize) * self.stride + ((x + PAD as isize) as usize) * BPP
    }
    /// [`Self::offset`] in 32-bit arithmetic (what the vectorised evaluation computes); wraps
    /// instead of failing outside the valid range, so callers bounds-check the result.
    #[inline(always)]
    pub fn offset32(&self, x: i32, y: i32) -> u32 {
        let pad = PAD as i32;
        (y.wrapping_add(pad).wrapping_mul(self.stride as i32))
            .wrapping_add(x.wrapping_add(pad).wrapping_mul(BPP as i32)) as u32
    }
    /// Colour channels of pixel `(x, y)` (inside the image).
    pub fn colour(&self, x: u32, y: u32) -> [u8; 3] {
        let o = self.offset(x as isize, y as isize);
        [self.data[o], self.data[o + 1], self.data[o + 2]]
    }
    /// Mean luma per 16x16 block, row-major, `width.div_ceil(16)` blocks a row.
    pub fn block_means(&self) -> &[u8] {
        &self.block_means
    }

    /// The frame's channels as captured, before normalisation.
    pub fn raw_stats(&self) -> RawStats {
        self.raw
    }

    /// Quantised gradient norm of pixel `(x, y)` (inside the image).
    pub fn gradient(&self, x: u32, y: u32) -> u8 {
        self.data[self.offset(x as isize, y as isize) + 3]
    }

    /// Refills this image from packed pixels of the same size, without allocating.
    pub fn prepare(&mut self, format: PixelFormat, pixels: &[u8]) -> Result<(), FrameError> {
        let (w, h) = (self.width, self.height);
        let expected = w * h * format.bytes_per_pixel();
        if pixels.len() != expected {
            return Err(FrameError::SizeMismatch {
                width: w as u32,
                height: h as u32,
                format,
                expected,
                got: pixels.len(),
            });
        }
        if let Some(kept) = self.pixels.as_mut()
            && let Some(to) = kept.buffer.get_mut(..pixels.len())
        {
            // `pixels` is at most w * h * 3 bytes (checked above): the buffer's size.
            to.copy_from_slice(pixels);
            kept.len = pixels.len();
            kept.format = format;
            kept.jpeg = false;
        }
        self.channels = match format {
            PixelFormat::Rgb8 => 3,
            PixelFormat::Grey8 => 1,
        };
        self.prepare_on(Isa::detect(), format, pixels);
        Ok(())
    }

    dispatch! {
        /// [`Self::prepare`]'s work on a chosen instruction set (all give the same bytes):
        /// with AVX2 the compiler vectorises its loops 32 bytes wide and can shuffle the
        /// 3-byte pixels into the 4-byte layout.
        fn prepare_on(self: &mut PreparedImage, format: PixelFormat, pixels: &[u8]);
        up to Avx2 => PreparedImage::prepare_with
    }
}

/// A left/right pair ready for evaluation, with an identity so the engine knows when it changed.
#[derive(Debug, Clone)]
pub struct StereoFrame {
    pub left: PreparedImage,
    pub right: PreparedImage,
    /// Changes whenever the pair's content changes (e.g. the capture sequence number).
    pub id: u64,
}

impl StereoFrame {
    pub fn new(left: PreparedImage, right: PreparedImage, id: u64) -> Self {
        Self { left, right, id }
    }
}

#[cfg(test)]
mod tests;
