//! Pure conversions from what a V4L2 camera delivers to the packed RGB8 or grey pixels that
//! [`PreparedImage::prepare`] takes.
//!
//! Everything here is a function of its input bytes: no device, no clock, so every path is tested
//! on this machine. Contract:
//! - Conversions write into buffers sized once (in [`FrameConverter::new`]); our code never
//!   allocates per frame. The MJPEG path calls `zune-jpeg`, which allocates its own working
//!   buffers per decode (bounded by the negotiated size, see below).
//! - A payload shorter than the negotiated format needs is an error ([`ConvertError::Short`]),
//!   never a panic and never a partly stale image. Longer payloads are accepted: drivers may pad.
//! - Garbage in gives an error out. An MJPEG frame must end with its EOI marker and is decoded in
//!   `zune-jpeg`'s strict mode, so a truncated frame is rejected rather than decoded with grey
//!   blocks where its tail was (grey looks like empty road); the decoder is also capped at the
//!   negotiated width and height, so a corrupt header cannot make it allocate a huge image.
//!
//! Colour: YUYV is taken as ITU-R BT.601 limited range ("studio swing", what UVC webcams send);
//! YUYV to grey keeps the Y byte as is (no range expansion: the fitness compares pixels of two
//! cameras treated the same way, and gradients only scale).

use flyd_core::frame::{FrameError, PixelFormat, PreparedImage};
use zune_jpeg::JpegDecoder;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;

/// Pixel formats flyd asks a V4L2 camera for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
pub enum CaptureFormat {
    /// Packed YUV 4:2:2, `Y0 U Y1 V` for each pair of pixels.
    #[serde(rename = "YUYV")]
    Yuyv,
    /// Motion JPEG: one JPEG per frame, often without Huffman tables.
    #[serde(rename = "MJPG", alias = "MJPEG")]
    Mjpg,
    /// 8-bit grey.
    #[serde(rename = "GREY", alias = "GRAY")]
    Grey,
}

impl CaptureFormat {
    /// The V4L2 four-character code.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            CaptureFormat::Yuyv => *b"YUYV",
            CaptureFormat::Mjpg => *b"MJPG",
            CaptureFormat::Grey => *b"GREY",
        }
    }

    /// The format with this four-character code, if flyd handles it.
    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        match &code {
            b"YUYV" => Some(CaptureFormat::Yuyv),
            b"MJPG" => Some(CaptureFormat::Mjpg),
            b"GREY" => Some(CaptureFormat::Grey),
            _ => None,
        }
    }

    /// What a frame becomes when nobody asks for something else: colour for colour formats.
    pub fn natural_output(self) -> PixelFormat {
        match self {
            CaptureFormat::Yuyv | CaptureFormat::Mjpg => PixelFormat::Rgb8,
            CaptureFormat::Grey => PixelFormat::Grey8,
        }
    }

    /// Bytes of one row of `width` pixels, for the uncompressed formats.
    fn packed_row_bytes(self, width: usize) -> Option<usize> {
        match self {
            CaptureFormat::Yuyv => Some(width * 2),
            CaptureFormat::Grey => Some(width),
            CaptureFormat::Mjpg => None,
        }
    }
}

impl std::fmt::Display for CaptureFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(fourcc_str(self.fourcc()).as_str())
    }
}

/// A four-character code as text, with unprintable bytes escaped (codes come from drivers).
pub fn fourcc_str(code: [u8; 4]) -> String {
    code.iter()
        .flat_map(|&b| std::ascii::escape_default(b))
        .map(char::from)
        .collect()
}

/// Why a frame could not be converted.
#[derive(Debug, Clone, thiserror::Error)]
pub enum ConvertError {
    /// The payload is shorter than the negotiated format needs (a short `bytesused`).
    #[error(
        "{format} frame of {got} bytes is shorter than {width}x{height} needs ({expected} bytes)"
    )]
    Short {
        format: CaptureFormat,
        width: u32,
        height: u32,
        expected: usize,
        got: usize,
    },
    /// The negotiated geometry cannot be converted (odd YUYV width, stride too small...).
    #[error("cannot convert {format} {width}x{height}: {reason}")]
    Geometry {
        format: CaptureFormat,
        width: u32,
        height: u32,
        reason: String,
    },
    /// The output buffer does not hold exactly one image (a caller bug, reported not panicked).
    #[error("output buffer of {got} bytes, need {expected}")]
    Output { expected: usize, got: usize },
    /// The MJPEG frame is not a JPEG flyd can decode.
    #[error("bad MJPEG frame: {0}")]
    Jpeg(String),
    /// The JPEG decoder refused the frame.
    #[error("bad MJPEG frame")]
    JpegDecoder(#[source] std::sync::Arc<zune_jpeg::errors::DecodeErrors>),
    /// The MJPEG frame decodes to another size than negotiated.
    #[error("MJPEG frame is {got_width}x{got_height}, expected {width}x{height}")]
    JpegSize {
        width: u32,
        height: u32,
        got_width: usize,
        got_height: usize,
    },
    /// The prepared image has another size than the camera.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

fn short(
    format: CaptureFormat,
    width: usize,
    height: usize,
    expected: usize,
    got: usize,
) -> ConvertError {
    ConvertError::Short {
        format,
        width: width as u32,
        height: height as u32,
        expected,
        got,
    }
}

/// Bytes an uncompressed frame needs: every row at `stride`, except that the last one may stop
/// at its last pixel.
fn needed_bytes(row_bytes: usize, stride: usize, height: usize) -> usize {
    if height == 0 {
        0
    } else {
        stride * (height - 1) + row_bytes
    }
}

fn check_output(dst: &[u8], expected: usize) -> Result<(), ConvertError> {
    if dst.len() != expected {
        return Err(ConvertError::Output {
            expected,
            got: dst.len(),
        });
    }
    Ok(())
}

fn check_uncompressed(
    format: CaptureFormat,
    src: &[u8],
    width: usize,
    height: usize,
    stride: usize,
) -> Result<usize, ConvertError> {
    let row = format.packed_row_bytes(width).unwrap_or(0);
    if format == CaptureFormat::Yuyv && !width.is_multiple_of(2) {
        return Err(ConvertError::Geometry {
            format,
            width: width as u32,
            height: height as u32,
            reason: "YUYV needs an even width".into(),
        });
    }
    if stride < row {
        return Err(ConvertError::Geometry {
            format,
            width: width as u32,
            height: height as u32,
            reason: format!("stride {stride} is shorter than a row ({row} bytes)"),
        });
    }
    let expected = needed_bytes(row, stride, height);
    if src.len() < expected {
        return Err(short(format, width, height, expected, src.len()));
    }
    Ok(row)
}

#[inline]
fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// BT.601 limited range YCbCr to RGB, 8-bit fixed point (the usual 298/409/100/208/516 set).
#[inline]
fn ycbcr_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    let c = 298 * (y as i32 - 16);
    let d = cb as i32 - 128;
    let e = cr as i32 - 128;
    [
        clamp_u8((c + 409 * e + 128) >> 8),
        clamp_u8((c - 100 * d - 208 * e + 128) >> 8),
        clamp_u8((c + 516 * d + 128) >> 8),
    ]
}

/// Where an uncompressed frame's pixels are: `width` x `height`, rows `stride` bytes apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    pub width: usize,
    pub height: usize,
    pub stride: usize,
}

impl Layout {
    pub fn new(width: usize, height: usize, stride: usize) -> Self {
        Self {
            width,
            height,
            stride,
        }
    }

    /// The rows of `src`, a `format` frame of this layout (checked), each with the row of
    /// `dst` it converts to, `out_bpp` bytes a pixel (checked: `dst` holds exactly the image).
    fn rows<'a>(
        self,
        format: CaptureFormat,
        src: &'a [u8],
        dst: &'a mut [u8],
        out_bpp: usize,
    ) -> Result<impl Iterator<Item = (&'a [u8], &'a mut [u8])>, ConvertError> {
        let Layout {
            width,
            height,
            stride,
        } = self;
        let row = check_uncompressed(format, src, width, height, stride)?;
        check_output(dst, width * height * out_bpp)?;
        let rows = dst.chunks_exact_mut((width * out_bpp).max(1)).enumerate();
        Ok(rows.map(move |(y, out)| (&src[y * stride..y * stride + row], out)))
    }
}

/// YUYV to packed RGB8 in `dst` (`width * height * 3` bytes).
pub fn yuyv_to_rgb(src: &[u8], layout: Layout, dst: &mut [u8]) -> Result<(), ConvertError> {
    for (input, output) in layout.rows(CaptureFormat::Yuyv, src, dst, 3)? {
        for (yuyv, rgb) in input.chunks_exact(4).zip(output.chunks_exact_mut(6)) {
            let (y0, u, y1, v) = (yuyv[0], yuyv[1], yuyv[2], yuyv[3]);
            rgb[0..3].copy_from_slice(&ycbcr_to_rgb(y0, u, v));
            rgb[3..6].copy_from_slice(&ycbcr_to_rgb(y1, u, v));
        }
    }
    Ok(())
}

/// Packed RGB8 (`width * height * 3` bytes) to YUYV (`width * height * 2` bytes, BT.601
/// limited range, the inverse of [`yuyv_to_rgb`]): what a camera sends of a rendered frame
/// (the VM suite's feeder, `tests/vm/guest/src/feeder`). Each pair of pixels shares the mean of
/// their chroma; `width` must be even.
pub fn rgb_to_yuyv(rgb: &[u8], width: usize, yuyv: &mut [u8]) -> Result<(), ConvertError> {
    let height = rgb.len() / 3 / width.max(1);
    if !width.is_multiple_of(2) || rgb.len() != width * height * 3 {
        return Err(ConvertError::Geometry {
            format: CaptureFormat::Yuyv,
            width: width as u32,
            height: height as u32,
            reason: format!("{} RGB bytes at an even width", rgb.len()),
        });
    }
    if yuyv.len() != width * height * 2 {
        return Err(ConvertError::Output {
            expected: width * height * 2,
            got: yuyv.len(),
        });
    }
    for (px, out) in rgb.chunks_exact(6).zip(yuyv.chunks_exact_mut(4)) {
        let (y0, u0, v0) = rgb_to_ycbcr(px[0], px[1], px[2]);
        let (y1, u1, v1) = rgb_to_ycbcr(px[3], px[4], px[5]);
        out[0] = y0;
        out[1] = ((u0 + u1 + 1) / 2) as u8;
        out[2] = y1;
        out[3] = ((v0 + v1 + 1) / 2) as u8;
    }
    Ok(())
}

/// BT.601 limited range, 8-bit fixed point: Y in 16..=235, Cb and Cr in 16..=240 (as i32).
fn rgb_to_ycbcr(r: u8, g: u8, b: u8) -> (u8, i32, i32) {
    let (r, g, b) = (i32::from(r), i32::from(g), i32::from(b));
    let y = ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16;
    let cb = ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128;
    let cr = ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128;
    (y as u8, cb, cr)
}

/// YUYV to grey: the Y bytes as they are.
pub fn yuyv_to_grey(src: &[u8], layout: Layout, dst: &mut [u8]) -> Result<(), ConvertError> {
    for (input, output) in layout.rows(CaptureFormat::Yuyv, src, dst, 1)? {
        for (pair, out) in input.chunks_exact(4).zip(output.chunks_exact_mut(2)) {
            out[0] = pair[0];
            out[1] = pair[2];
        }
    }
    Ok(())
}

/// GREY with a stride to packed grey.
pub fn grey_copy(src: &[u8], layout: Layout, dst: &mut [u8]) -> Result<(), ConvertError> {
    for (input, output) in layout.rows(CaptureFormat::Grey, src, dst, 1)? {
        output.copy_from_slice(input);
    }
    Ok(())
}

// --- MJPEG -------------------------------------------------------------------------------------

/// The DHT segment (marker included) with the four Huffman tables of ITU-T T.81 Annex K.3
/// (Tables K.3 to K.6, in the order DC luma, AC luma, DC chroma, AC chroma: class and id, code
/// counts per length 1..=16, symbols). UVC MJPEG frames that carry no DHT segment are coded
/// with these (the AVI1 convention). Data, not code: the tests check its structure and decode
/// frames whose own tables were stripped through it.
pub const STD_DHT_SEGMENT: &[u8; STD_DHT_LEN] = include_bytes!("jpeg_annex_k_dht.bin");

/// Length of the standard DHT segment: marker (2) + length field (2) + 4 x (Tc/Th + 16 counts)
/// + 12 + 12 + 162 + 162 symbols.
const STD_DHT_LEN: usize = 4 + 4 * 17 + 12 + 12 + 162 + 162;

/// Where a DHT segment must be inserted in `jpeg`: `Ok(None)` if it already has Huffman tables
/// before its first scan, `Ok(Some(offset))` of the SOS marker otherwise. Walks the marker
/// segments with bounds checks, so garbage is an error, not a panic.
pub fn dht_insertion_point(jpeg: &[u8]) -> Result<Option<usize>, ConvertError> {
    let bad = |what: &str, at: usize| ConvertError::Jpeg(format!("{what} at byte {at}"));
    if jpeg.len() < 2 || jpeg[0] != 0xFF || jpeg[1] != 0xD8 {
        return Err(ConvertError::Jpeg("no SOI marker at the start".into()));
    }
    let mut pos = 2;
    let mut has_dht = false;
    loop {
        let start = pos;
        if jpeg.get(pos) != Some(&0xFF) {
            return Err(bad("expected a marker", pos));
        }
        // Any number of 0xFF fill bytes may precede a marker.
        while jpeg.get(pos) == Some(&0xFF) {
            pos += 1;
        }
        let Some(&marker) = jpeg.get(pos) else {
            return Err(bad("truncated marker", start));
        };
        pos += 1;
        match marker {
            0xDA => return Ok(if has_dht { None } else { Some(start) }),
            0xD9 => return Err(bad("end of image before any scan", start)),
            0x00 => return Err(bad("stuffed byte where a marker belongs", start)),
            // Markers without a length: TEM, RSTn, a repeated SOI.
            0x01 | 0xD0..=0xD8 => {}
            _ => {
                if marker == 0xC4 {
                    has_dht = true;
                }
                let Some(len) = jpeg.get(pos..pos + 2) else {
                    return Err(bad("truncated segment length", pos));
                };
                let len = u16::from_be_bytes([len[0], len[1]]) as usize;
                if len < 2 {
                    return Err(bad("segment length below 2", pos));
                }
                pos += len;
                if pos > jpeg.len() {
                    return Err(bad("segment runs past the end", start));
                }
            }
        }
    }
}

/// Whether `jpeg` has an EOI marker after offset `from` (the SOS). Entropy-coded data cannot
/// contain `FF D9` (an 0xFF data byte is stuffed as `FF 00`), so this finds the real end of
/// image; drivers may pad the payload after it.
pub fn has_eoi_after(jpeg: &[u8], from: usize) -> bool {
    jpeg.get(from..)
        .is_some_and(|tail| tail.windows(2).rev().any(|w| w == [0xFF, 0xD9]))
}

/// Decodes one MJPEG frame into packed RGB8 or grey, inserting the standard Huffman tables
/// when the frame has none.
#[derive(Debug)]
pub struct MjpegDecoder {
    /// Scratch for a frame with the DHT inserted; sized once, grown only by a larger frame.
    with_dht: Vec<u8>,
}

impl MjpegDecoder {
    /// `max_frame_bytes` is the largest payload expected (the driver's `sizeimage`).
    pub fn new(max_frame_bytes: usize) -> Self {
        Self {
            with_dht: Vec::with_capacity(max_frame_bytes + STD_DHT_LEN),
        }
    }

    /// Decodes `jpeg`, which must be `width` x `height`, into `dst` (`width * height` times the
    /// bytes per pixel of `output`).
    pub fn decode(
        &mut self,
        jpeg: &[u8],
        width: usize,
        height: usize,
        output: PixelFormat,
        dst: &mut [u8],
    ) -> Result<(), ConvertError> {
        check_output(dst, width * height * output.bytes_per_pixel())?;
        let insert_at = dht_insertion_point(jpeg)?;
        // A frame that lost its tail (USB packet loss) still "decodes" in part: refuse it.
        if !has_eoi_after(jpeg, insert_at.unwrap_or(2)) {
            return Err(ConvertError::Jpeg("no EOI marker: truncated frame".into()));
        }
        let data = match insert_at {
            None => jpeg,
            Some(at) => {
                self.with_dht.clear();
                self.with_dht.extend_from_slice(&jpeg[..at]);
                self.with_dht.extend_from_slice(STD_DHT_SEGMENT);
                self.with_dht.extend_from_slice(&jpeg[at..]);
                &self.with_dht
            }
        };
        let colour = match output {
            PixelFormat::Rgb8 => ColorSpace::RGB,
            PixelFormat::Grey8 => ColorSpace::Luma,
        };
        let options = DecoderOptions::new_fast()
            .set_strict_mode(true)
            .set_max_width(width)
            .set_max_height(height)
            .jpeg_set_out_colorspace(colour);
        let mut decoder = JpegDecoder::new_with_options(ZCursor::new(data), options);
        let jpeg_err = |e| ConvertError::JpegDecoder(std::sync::Arc::new(e));
        decoder.decode_headers().map_err(jpeg_err)?;
        let size_err = |(w, h)| ConvertError::JpegSize {
            width: width as u32,
            height: height as u32,
            got_width: w,
            got_height: h,
        };
        let got = decoder.dimensions().unwrap_or((0, 0));
        if got != (width, height) {
            return Err(size_err(got));
        }
        if decoder.output_buffer_size() != Some(dst.len()) {
            return Err(ConvertError::Jpeg(format!(
                "decoder wants {:?} output bytes, have {}",
                decoder.output_buffer_size(),
                dst.len()
            )));
        }
        decoder.decode_into(dst).map_err(jpeg_err)
    }
}

// --- Whole frames ------------------------------------------------------------------------------

/// Turns the payloads of one negotiated stream (format, size, stride) into prepared images,
/// reusing its buffers for every frame.
#[derive(Debug)]
pub struct FrameConverter {
    format: CaptureFormat,
    width: usize,
    height: usize,
    stride: usize,
    output: PixelFormat,
    /// Packed output pixels, handed to [`PreparedImage::prepare`].
    pixels: Vec<u8>,
    /// Only used (and only given scratch space) for MJPEG.
    mjpeg: MjpegDecoder,
}

impl FrameConverter {
    /// A converter for frames of `format` at `width` x `height`, rows `stride` bytes apart
    /// (ignored for MJPEG; 0 means packed), producing `output`. `max_frame_bytes` sizes the MJPEG
    /// scratch (the driver's `sizeimage`).
    pub fn new(
        format: CaptureFormat,
        width: u32,
        height: u32,
        stride: u32,
        output: PixelFormat,
        max_frame_bytes: usize,
    ) -> Result<Self, ConvertError> {
        let geometry = |reason: String| ConvertError::Geometry {
            format,
            width,
            height,
            reason,
        };
        let (w, h) = (width as usize, height as usize);
        if w == 0 || h == 0 {
            return Err(geometry("empty image".into()));
        }
        if format == CaptureFormat::Grey && output == PixelFormat::Rgb8 {
            return Err(geometry("a grey camera cannot give RGB8".into()));
        }
        if format == CaptureFormat::Yuyv && w % 2 != 0 {
            return Err(geometry("YUYV needs an even width".into()));
        }
        let packed = format.packed_row_bytes(w).unwrap_or(0);
        let stride = if stride == 0 { packed } else { stride as usize };
        if stride < packed {
            return Err(geometry(format!(
                "stride {stride} is shorter than a row ({packed} bytes)"
            )));
        }
        Ok(Self {
            format,
            width: w,
            height: h,
            stride,
            output,
            pixels: vec![0; w * h * output.bytes_per_pixel()],
            mjpeg: MjpegDecoder::new(if format == CaptureFormat::Mjpg {
                max_frame_bytes
            } else {
                0
            }),
        })
    }

    pub fn format(&self) -> CaptureFormat {
        self.format
    }
    pub fn output(&self) -> PixelFormat {
        self.output
    }

    /// Converts one payload (already cut to `bytesused`) to packed `output` pixels.
    pub fn convert(&mut self, payload: &[u8]) -> Result<&[u8], ConvertError> {
        let layout = Layout::new(self.width, self.height, self.stride);
        let dst = &mut self.pixels;
        match (self.format, self.output) {
            (CaptureFormat::Yuyv, PixelFormat::Rgb8) => yuyv_to_rgb(payload, layout, dst)?,
            (CaptureFormat::Yuyv, PixelFormat::Grey8) => yuyv_to_grey(payload, layout, dst)?,
            (CaptureFormat::Grey, _) => grey_copy(payload, layout, dst)?,
            (CaptureFormat::Mjpg, output) => {
                let (w, h) = (layout.width, layout.height);
                self.mjpeg.decode(payload, w, h, output, dst)?
            }
        }
        Ok(&self.pixels)
    }

    /// Converts one payload and prepares it into `out` (which must have the camera's size).
    /// An image that retains its pixels (a recording) keeps an MJPEG frame's JPEG instead: the
    /// camera's own payload, a fraction of the pixels' size, which this converter decodes
    /// again to the very same pixels.
    pub fn prepare(&mut self, payload: &[u8], out: &mut PreparedImage) -> Result<(), ConvertError> {
        let output = self.output;
        let pixels = self.convert(payload)?;
        out.prepare(output, pixels)?;
        if self.format == CaptureFormat::Mjpg {
            out.retain_encoded(payload);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Through flyd's own converter, colours come back within the rounding of 8-bit YCbCr.
    #[test]
    fn round_trip_through_flyds_converter() {
        let (w, h) = (8usize, 4usize);
        let mut rgb = Vec::new();
        for i in 0..w * h {
            // Pairs of equal pixels, so that shared chroma loses nothing.
            let k = (i / 2) as u32;
            rgb.extend_from_slice(&[
                (k * 37 % 256) as u8,
                (k * 91 % 256) as u8,
                (k * 53 % 256) as u8,
            ]);
        }
        rgb[..6].copy_from_slice(&[0, 0, 0, 0, 0, 0]);
        rgb[6..12].copy_from_slice(&[255, 255, 255, 255, 255, 255]);
        let mut yuyv = vec![0; w * h * 2];
        rgb_to_yuyv(&rgb, w, &mut yuyv).expect("converts");
        assert_eq!(&yuyv[..4], &[16, 128, 16, 128], "black");
        assert_eq!(&yuyv[4..8], &[235, 128, 235, 128], "white");
        let mut back = vec![0; w * h * 3];
        yuyv_to_rgb(&yuyv, Layout::new(w, h, w * 2), &mut back).expect("converts");
        for (i, (a, b)) in rgb.iter().zip(&back).enumerate() {
            assert!(a.abs_diff(*b) <= 4, "byte {i}: {a} came back as {b}");
        }
    }

    #[test]
    fn rgb_to_yuyv_refuses_what_it_cannot_convert() {
        let mut out = vec![0; 12];
        assert!(matches!(
            rgb_to_yuyv(&[0; 18], 3, &mut out),
            Err(ConvertError::Geometry { .. })
        ));
        assert!(matches!(
            rgb_to_yuyv(&[0; 24], 4, &mut out[..6]),
            Err(ConvertError::Output {
                expected: 16,
                got: 6
            })
        ));
    }

    /// A deterministic byte generator for the garbage tests (no RNG dependency needed).
    fn noise(seed: u64, len: usize) -> Vec<u8> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..len)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 24) as u8
            })
            .collect()
    }

    fn check_rgb(y: u8, u: u8, v: u8, expected: [u8; 3]) {
        let mut dst = [0u8; 6];
        yuyv_to_rgb(&[y, u, y, v], Layout::new(2, 1, 4), &mut dst).unwrap();
        assert_eq!(dst[..3], expected, "Y={y} U={u} V={v}");
        assert_eq!(dst[3..], expected);
    }

    #[test]
    fn yuyv_bt601_limited_range_reference_colours() {
        // Black and white ends of studio swing, mid grey.
        check_rgb(16, 128, 128, [0, 0, 0]);
        check_rgb(235, 128, 128, [255, 255, 255]);
        check_rgb(126, 128, 128, [128, 128, 128]);
        // 75 % colour bars (BT.601, limited range) within one code value of the float formula.
        for (yuv, rgb) in [
            ([162u8, 44u8, 142u8], [191u8, 191u8, 0u8]), // yellow
            ([131, 156, 44], [0, 191, 191]),             // cyan
            ([112, 72, 58], [0, 191, 0]),                // green
            ([84, 184, 198], [191, 0, 191]),             // magenta
            ([65, 100, 212], [191, 0, 0]),               // red
            ([35, 212, 114], [0, 0, 191]),               // blue
        ] {
            let mut dst = [0u8; 6];
            yuyv_to_rgb(
                &[yuv[0], yuv[1], yuv[0], yuv[2]],
                Layout::new(2, 1, 4),
                &mut dst,
            )
            .unwrap();
            for c in 0..3 {
                assert!(
                    (dst[c] as i32 - rgb[c] as i32).abs() <= 2,
                    "{yuv:?} gave {:?}, expected {rgb:?}",
                    &dst[..3]
                );
            }
        }
        // Out-of-range chroma saturates instead of wrapping.
        check_rgb(255, 255, 255, [255, 125, 255]);
        check_rgb(0, 0, 0, [0, 135, 0]);
    }

    #[test]
    fn yuyv_pixel_order_and_stride_padding() {
        // 4x2 frame, rows padded to 12 bytes with junk that must be ignored.
        let (w, h, stride) = (4, 2, 12);
        let mut src = vec![0xEEu8; stride * h];
        for y in 0..h {
            for x in 0..w {
                src[y * stride + 2 * x] = (10 * (y * w + x) + 20) as u8; // Y
                src[y * stride + 2 * x + 1] = 128; // U or V: neutral
            }
        }
        let mut grey = vec![0u8; w * h];
        yuyv_to_grey(&src, Layout::new(w, h, stride), &mut grey).unwrap();
        assert_eq!(grey, [20, 30, 40, 50, 60, 70, 80, 90]);
        let mut rgb = vec![0u8; w * h * 3];
        yuyv_to_rgb(&src, Layout::new(w, h, stride), &mut rgb).unwrap();
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            assert_eq!(px[0], px[1]);
            assert_eq!(px[1], px[2]);
            assert_eq!(px[0], ycbcr_to_rgb(grey[i], 128, 128)[0]);
        }
        // The last row may stop at its last pixel (no trailing padding needed).
        let cut = &src[..stride + w * 2];
        yuyv_to_grey(cut, Layout::new(w, h, stride), &mut grey).unwrap();
    }

    #[test]
    fn grey_passthrough_drops_stride_padding() {
        let src = [1, 2, 3, 99, 4, 5, 6, 99];
        let mut dst = [0u8; 6];
        grey_copy(&src, Layout::new(3, 2, 4), &mut dst).unwrap();
        assert_eq!(dst, [1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn short_frames_are_errors_naming_the_sizes() {
        let mut dst = vec![0u8; 8 * 8 * 3];
        let err = yuyv_to_rgb(&[0; 127], Layout::new(8, 8, 16), &mut dst).unwrap_err();
        assert!(matches!(
            err,
            ConvertError::Short {
                format: CaptureFormat::Yuyv,
                width: 8,
                height: 8,
                expected: 128,
                got: 127
            }
        ));
        assert!(err.to_string().contains("127 bytes"), "{err}");
        let mut grey = vec![0u8; 64];
        assert!(matches!(
            grey_copy(&[0; 10], Layout::new(8, 8, 8), &mut grey),
            Err(ConvertError::Short { expected: 64, .. })
        ));
        assert!(matches!(
            yuyv_to_grey(&[], Layout::new(8, 8, 16), &mut grey),
            Err(ConvertError::Short { got: 0, .. })
        ));
    }

    #[test]
    fn bad_geometry_is_an_error_not_a_panic() {
        let mut dst = vec![0u8; 3 * 2 * 3];
        assert!(matches!(
            yuyv_to_rgb(&[0; 64], Layout::new(3, 2, 6), &mut dst),
            Err(ConvertError::Geometry { .. })
        ));
        let mut dst = vec![0u8; 4 * 2 * 3];
        assert!(matches!(
            yuyv_to_rgb(&[0; 64], Layout::new(4, 2, 4), &mut dst),
            Err(ConvertError::Geometry { .. })
        ));
        // Output of the wrong size.
        assert!(matches!(
            yuyv_to_rgb(&[0; 64], Layout::new(4, 2, 8), &mut [0u8; 5]),
            Err(ConvertError::Output {
                expected: 24,
                got: 5
            })
        ));
        for (format, w, output) in [
            (CaptureFormat::Yuyv, 7, PixelFormat::Rgb8),
            (CaptureFormat::Grey, 8, PixelFormat::Rgb8),
            (CaptureFormat::Mjpg, 0, PixelFormat::Rgb8),
        ] {
            assert!(
                FrameConverter::new(format, w, 8, 0, output, 0).is_err(),
                "{format} {w} {output:?}"
            );
        }
        assert!(FrameConverter::new(CaptureFormat::Yuyv, 8, 8, 15, PixelFormat::Rgb8, 0).is_err());
    }

    #[test]
    fn fourcc_round_trip_and_serde_names() {
        for f in [
            CaptureFormat::Yuyv,
            CaptureFormat::Mjpg,
            CaptureFormat::Grey,
        ] {
            assert_eq!(CaptureFormat::from_fourcc(f.fourcc()), Some(f));
            let toml = format!("f = \"{f}\"");
            #[derive(serde::Deserialize)]
            struct T {
                f: CaptureFormat,
            }
            assert_eq!(toml::from_str::<T>(&toml).unwrap().f, f);
        }
        assert_eq!(CaptureFormat::from_fourcc(*b"NV12"), None);
        assert_eq!(fourcc_str([b'Y', 0, 0xFF, b'V']), "Y\\x00\\xffV");
    }

    // --- MJPEG -----------------------------------------------------------------------------

    /// A smooth colour test picture (JPEG-friendly, so decoded values are predictable).
    fn picture(w: u32, h: u32) -> Vec<u8> {
        let mut px = Vec::with_capacity((w * h * 3) as usize);
        for y in 0..h {
            for x in 0..w {
                px.extend_from_slice(&[
                    (x * 255 / w) as u8,
                    (y * 255 / h) as u8,
                    (128 + (x + y) % 64) as u8,
                ]);
            }
        }
        px
    }

    fn encode_jpeg(w: u32, h: u32, px: &[u8], colour: image::ExtendedColorType) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
            .encode(px, w, h, colour)
            .unwrap();
        out
    }

    /// Removes every DHT segment before the first scan, as UVC cameras send their frames.
    fn strip_dht(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut pos = 2;
        loop {
            assert_eq!(jpeg[pos], 0xFF);
            let marker = jpeg[pos + 1];
            if marker == 0xDA {
                out.extend_from_slice(&jpeg[pos..]);
                return out;
            }
            let len = u16::from_be_bytes([jpeg[pos + 2], jpeg[pos + 3]]) as usize;
            if marker != 0xC4 {
                out.extend_from_slice(&jpeg[pos..pos + 2 + len]);
            }
            pos += 2 + len;
        }
    }

    fn reference_decode(jpeg: &[u8], colour: ColorSpace) -> Vec<u8> {
        let options = DecoderOptions::new_fast().jpeg_set_out_colorspace(colour);
        JpegDecoder::new_with_options(ZCursor::new(jpeg), options)
            .decode()
            .unwrap()
    }

    #[test]
    fn standard_tables_are_well_formed() {
        assert_eq!(&STD_DHT_SEGMENT[..4], &[0xFF, 0xC4, 0x01, 0xA2]);
        // Four tables, each class/id then 16 counts summing to its number of symbols.
        let mut at = 4;
        for (id, symbols) in [(0x00, 12), (0x10, 162), (0x01, 12), (0x11, 162)] {
            assert_eq!(STD_DHT_SEGMENT[at], id);
            let counts = &STD_DHT_SEGMENT[at + 1..at + 17];
            assert_eq!(
                counts.iter().map(|&c| usize::from(c)).sum::<usize>(),
                symbols
            );
            at += 17 + symbols;
        }
        assert_eq!(at, STD_DHT_SEGMENT.len());
        // The segment is itself a valid DHT: a JPEG made of it and an SOS needs no insertion.
        let mut jpeg = vec![0xFF, 0xD8];
        jpeg.extend_from_slice(STD_DHT_SEGMENT);
        jpeg.extend_from_slice(&[0xFF, 0xDA]);
        assert!(matches!(dht_insertion_point(&jpeg), Ok(None)));
    }

    #[test]
    fn mjpeg_without_huffman_tables_decodes_like_the_original() {
        let (w, h) = (64u32, 48u32);
        let px = picture(w, h);
        let jpeg = encode_jpeg(w, h, &px, image::ExtendedColorType::Rgb8);
        let stripped = strip_dht(&jpeg);
        assert!(
            stripped.len() < jpeg.len(),
            "the encoder wrote a DHT to strip"
        );
        assert!(dht_insertion_point(&jpeg).unwrap().is_none());
        assert!(dht_insertion_point(&stripped).unwrap().is_some());
        // Without our tables the decoder refuses the frame: the test exercises the insertion.
        let mut plain = JpegDecoder::new(ZCursor::new(&stripped));
        assert!(plain.decode().is_err());

        let mut decoder = MjpegDecoder::new(jpeg.len());
        for (output, colour) in [
            (PixelFormat::Rgb8, ColorSpace::RGB),
            (PixelFormat::Grey8, ColorSpace::Luma),
        ] {
            let expected = reference_decode(&jpeg, colour);
            let mut got = vec![0u8; (w * h) as usize * output.bytes_per_pixel()];
            decoder
                .decode(&stripped, w as usize, h as usize, output, &mut got)
                .unwrap();
            assert_eq!(got, expected, "{output:?} from the stripped frame");
            decoder
                .decode(&jpeg, w as usize, h as usize, output, &mut got)
                .unwrap();
            assert_eq!(got, expected, "{output:?} from the complete frame");
        }
        // And the picture survived the round trip (JPEG is lossy: compare loosely).
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        decoder
            .decode(
                &stripped,
                w as usize,
                h as usize,
                PixelFormat::Rgb8,
                &mut rgb,
            )
            .unwrap();
        let mean_err = rgb
            .iter()
            .zip(&px)
            .map(|(a, b)| (*a as i32 - *b as i32).unsigned_abs() as u64)
            .sum::<u64>() as f64
            / px.len() as f64;
        assert!(mean_err < 4.0, "mean error {mean_err}");
    }

    #[test]
    fn mjpeg_of_another_size_is_rejected() {
        let px = picture(32, 16);
        let jpeg = encode_jpeg(32, 16, &px, image::ExtendedColorType::Rgb8);
        let mut decoder = MjpegDecoder::new(jpeg.len());
        let mut dst = vec![0u8; 64 * 16 * 3];
        let err = decoder
            .decode(&jpeg, 64, 16, PixelFormat::Rgb8, &mut dst)
            .unwrap_err();
        assert!(matches!(
            err,
            ConvertError::JpegSize {
                width: 64,
                height: 16,
                got_width: 32,
                got_height: 16
            }
        ));
        // Larger than negotiated: refused by the decoder's cap before it allocates.
        let mut dst = vec![0u8; 16 * 16 * 3];
        assert!(
            decoder
                .decode(&jpeg, 16, 16, PixelFormat::Rgb8, &mut dst)
                .is_err()
        );
    }

    #[test]
    fn mjpeg_garbage_and_truncations_are_errors_not_panics() {
        let (w, h) = (32usize, 24usize);
        let px = picture(w as u32, h as u32);
        let jpeg = strip_dht(&encode_jpeg(
            w as u32,
            h as u32,
            &px,
            image::ExtendedColorType::Rgb8,
        ));
        let mut decoder = MjpegDecoder::new(jpeg.len());
        let mut dst = vec![0u8; w * h * 3];
        // Every truncation is refused, rather than decoded with grey where the tail was.
        for cut in 0..jpeg.len() - 1 {
            let r = decoder.decode(&jpeg[..cut], w, h, PixelFormat::Rgb8, &mut dst);
            assert!(r.is_err(), "a frame cut at {cut} of {} decoded", jpeg.len());
        }
        // Padding after the EOI (some drivers count it in bytesused) is fine.
        let mut padded = jpeg.clone();
        padded.extend_from_slice(&[0; 100]);
        decoder
            .decode(&padded, w, h, PixelFormat::Rgb8, &mut dst)
            .unwrap();
        // Random bytes, alone and after a valid header.
        let header_end = dht_insertion_point(&jpeg).unwrap().unwrap();
        for seed in 0..300 {
            let junk = noise(seed, (seed as usize * 37) % 2000);
            let _ = decoder.decode(&junk, w, h, PixelFormat::Rgb8, &mut dst);
            let mut frame = jpeg[..header_end + 14].to_vec();
            frame.extend_from_slice(&junk);
            let _ = decoder.decode(&frame, w, h, PixelFormat::Grey8, &mut dst[..w * h]);
        }
        // Single-byte corruptions anywhere in the frame.
        for (i, seed) in (0..jpeg.len()).zip(1000..) {
            let mut frame = jpeg.clone();
            frame[i] ^= noise(seed, 1)[0] | 1;
            let _ = decoder.decode(&frame, w, h, PixelFormat::Rgb8, &mut dst);
        }
    }

    #[test]
    fn marker_walk_rejects_malformed_headers() {
        for (jpeg, what) in [
            (&[][..], "empty"),
            (&[0xFF, 0xD8][..], "SOI only"),
            (&[0xFF, 0xD8, 0xFF, 0xD9][..], "EOI before scan"),
            (&[0xFF, 0xD8, 0xFF, 0xE0, 0x00][..], "truncated length"),
            (&[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x01][..], "length below 2"),
            (
                &[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x10, 1][..],
                "segment past end",
            ),
            (&[0xFF, 0xD8, 0x12][..], "no marker"),
            (&[0xFF, 0xD8, 0xFF, 0x00][..], "stuffed byte"),
            (&[0xFF, 0xD8, 0xFF, 0xFF, 0xFF][..], "fill to the end"),
        ] {
            assert!(dht_insertion_point(jpeg).is_err(), "{what}");
        }
        // Fill bytes and standalone markers are skipped; the SOS offset is where the marker's
        // first 0xFF is.
        let jpeg = [
            0xFF, 0xD8, 0xFF, 0xFF, 0xD0, 0xFF, 0xE0, 0x00, 0x02, 0xFF, 0xDA,
        ];
        assert!(matches!(dht_insertion_point(&jpeg), Ok(Some(9))));
    }

    #[test]
    fn converter_prepares_each_format_without_reallocating() {
        let (w, h) = (16u32, 8u32);
        let mut out = PreparedImage::new(w, h).unwrap();

        let yuyv: Vec<u8> = (0..w * h * 2)
            .map(|i| {
                if i % 2 == 0 {
                    (16 + i % 200) as u8
                } else {
                    128
                }
            })
            .collect();
        let mut conv =
            FrameConverter::new(CaptureFormat::Yuyv, w, h, 0, PixelFormat::Rgb8, 0).unwrap();
        let before = conv.pixels.as_ptr();
        for _ in 0..3 {
            conv.prepare(&yuyv, &mut out).unwrap();
        }
        assert_eq!(conv.pixels.as_ptr(), before);
        assert_eq!(out.channels(), 3);
        // Pixel 1 is the second Y of the first pair: byte 2, Y = 18, neutral chroma. (The
        // converter's packed output; `prepare` then normalises it photometrically.)
        assert_eq!(conv.pixels[3..6], [2, 2, 2]);
        let mut conv =
            FrameConverter::new(CaptureFormat::Yuyv, w, h, 0, PixelFormat::Grey8, 0).unwrap();
        conv.prepare(&yuyv, &mut out).unwrap();
        assert_eq!(out.channels(), 1);
        assert_eq!(conv.pixels[1], 18);

        let grey: Vec<u8> = (0..w * h).map(|i| i as u8).collect();
        let mut conv =
            FrameConverter::new(CaptureFormat::Grey, w, h, 0, PixelFormat::Grey8, 0).unwrap();
        conv.prepare(&grey, &mut out).unwrap();
        assert_eq!(conv.pixels[(w + 3) as usize], 19);
        // Normalisation keeps the order of grey levels.
        assert!(out.colour(3, 1)[0] > out.colour(2, 1)[0]);

        let px = picture(w, h);
        let jpeg = strip_dht(&encode_jpeg(w, h, &px, image::ExtendedColorType::Rgb8));
        let mut conv =
            FrameConverter::new(CaptureFormat::Mjpg, w, h, 0, PixelFormat::Rgb8, jpeg.len())
                .unwrap();
        let scratch = conv.mjpeg.with_dht.as_ptr();
        for _ in 0..3 {
            conv.prepare(&jpeg, &mut out).unwrap();
        }
        assert_eq!(conv.mjpeg.with_dht.as_ptr(), scratch);
        assert_eq!(out.channels(), 3);

        // A prepared image of another size is an error, not a panic.
        let mut small = PreparedImage::new(8, 8).unwrap();
        assert!(matches!(
            conv.prepare(&jpeg, &mut small),
            Err(ConvertError::Frame(_))
        ));
    }

    #[test]
    fn converter_survives_random_payloads_of_every_length() {
        let (w, h) = (8u32, 8u32);
        let mut out = PreparedImage::new(w, h).unwrap();
        for format in [
            CaptureFormat::Yuyv,
            CaptureFormat::Grey,
            CaptureFormat::Mjpg,
        ] {
            let output = format.natural_output();
            let mut conv = FrameConverter::new(format, w, h, 0, output, 256).unwrap();
            for len in 0..200usize {
                let payload = noise(len as u64, len);
                let r = conv.prepare(&payload, &mut out);
                let needed = match format {
                    CaptureFormat::Yuyv => Some(128),
                    CaptureFormat::Grey => Some(64),
                    CaptureFormat::Mjpg => None,
                };
                if let Some(needed) = needed {
                    assert_eq!(r.is_ok(), len >= needed, "{format} len {len}: {r:?}");
                }
            }
        }
    }
}
