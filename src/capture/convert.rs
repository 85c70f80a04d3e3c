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
mod tests;
