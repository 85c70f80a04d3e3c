//! Stereo benchmark data: ground-truth disparity maps in Middlebury's PFM files.
//!
//! # PFM
//! A text header then raw `float32` samples:
//!
//! ```text
//! Pf              "Pf": one channel; "PF": three (RGB), of which channel 0 is used
//! 450 375         width height
//! -1              scale: negative = little-endian samples, positive = big-endian
//! <width * height * channels float32, rows stored bottom to top>
//! ```
//!
//! Header fields are separated by whitespace, and exactly one whitespace byte ends the header.
//! The magnitude of the scale is ignored (Middlebury writes 1).
//!
//! # Conventions
//! A [`DisparityMap`] is stored top row first (image order, unlike the file). Disparities are in
//! pixels with Middlebury's convention: the left pixel (x, y) matches the right pixel (x - d, y).
//! Unknown pixels (`inf` in Middlebury files; any non-finite sample) are stored as
//! [`f32::INFINITY`] and reported as `None` by [`DisparityMap::get`].
//!
//! Malformed, truncated or oversized files give a [`DatasetError`] naming the file, never a panic
//! (the pixel buffer is only allocated once the file is known to hold all of it).

use std::path::{Path, PathBuf};

/// A dense disparity map, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    /// `width * height` disparities in pixels; unknown ones are [`f32::INFINITY`].
    pub data: Vec<f32>,
}

impl DisparityMap {
    /// Disparity at pixel (x, y), `None` when unknown or outside the map.
    pub fn get(&self, x: usize, y: usize) -> Option<f32> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.data
            .get(y * self.width + x)
            .copied()
            .filter(|d| d.is_finite())
    }

    /// Fraction of pixels whose disparity is known.
    pub fn known_fraction(&self) -> f64 {
        if self.data.is_empty() {
            return 0.0;
        }
        self.data.iter().filter(|d| d.is_finite()).count() as f64 / self.data.len() as f64
    }
}

/// Why a dataset file cannot be used (as [`crate::calib::CalibError`]: the message names the
/// file, a wrapped cause is the `source()`).
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("disparity file {}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        error: std::io::Error,
    },
    #[error("disparity file {}: {message}", file.display())]
    Format { file: PathBuf, message: String },
}

/// Reads a PFM disparity map (see the module documentation).
pub fn read_pfm(path: &Path) -> Result<DisparityMap, DatasetError> {
    let bytes = std::fs::read(path).map_err(|error| DatasetError::Io {
        file: path.to_path_buf(),
        error,
    })?;
    parse_pfm(&bytes, path)
}

/// Parses the bytes of a PFM file; `origin` names it in errors.
pub fn parse_pfm(bytes: &[u8], origin: &Path) -> Result<DisparityMap, DatasetError> {
    let error = |message: String| DatasetError::Format {
        file: origin.to_path_buf(),
        message,
    };
    let channels = match bytes.get(..2) {
        Some(b"Pf") => 1,
        Some(b"PF") => 3,
        _ => {
            let start = String::from_utf8_lossy(&bytes[..bytes.len().min(2)]).into_owned();
            return Err(error(format!(
                "not a PFM file: expected the header 'Pf' or 'PF', got {start:?}"
            )));
        }
    };
    let mut header = Header { bytes, pos: 2 };
    if !header.next_is_whitespace() {
        return Err(error(
            "no whitespace after the 'Pf'/'PF' header".to_string(),
        ));
    }
    let mut dimension = |name: &str| {
        let token = header.token();
        token
            .and_then(|t| t.parse::<usize>().ok())
            .filter(|&n| n > 0)
            .ok_or_else(|| {
                error(format!(
                    "{name} must be a positive whole number, got {:?}",
                    token.unwrap_or("end of file")
                ))
            })
    };
    let width = dimension("width")?;
    let height = dimension("height")?;
    let scale_token = header.token();
    let scale = scale_token
        .and_then(|t| t.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s != 0.0)
        .ok_or_else(|| {
            error(format!(
                "the scale must be a non-zero number (its sign gives the byte order), got {:?}",
                scale_token.unwrap_or("end of file")
            ))
        })?;
    // Exactly one whitespace byte separates the header from the samples: the first sample may
    // itself start with a byte that looks like whitespace.
    if !header.next_is_whitespace() {
        return Err(error(
            "the header does not end with a whitespace byte after the scale".to_string(),
        ));
    }
    let pixels = &bytes[header.pos..];
    let expected = width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(channels * 4))
        .ok_or_else(|| error(format!("{width}x{height} is too large an image")))?;
    if pixels.len() < expected {
        return Err(error(format!(
            "truncated: {width}x{height}x{channels} float32 samples need {expected} bytes, the \
             file has {}",
            pixels.len()
        )));
    }
    if pixels.len() > expected {
        return Err(error(format!(
            "{} unexpected bytes after the {width}x{height}x{channels} samples",
            pixels.len() - expected
        )));
    }

    let little_endian = scale < 0.0;
    let sample = |index: usize| {
        let offset = index * channels * 4;
        let mut raw = [0u8; 4];
        raw.copy_from_slice(&pixels[offset..offset + 4]);
        let value = if little_endian {
            f32::from_le_bytes(raw)
        } else {
            f32::from_be_bytes(raw)
        };
        if value.is_finite() {
            value
        } else {
            f32::INFINITY
        }
    };
    let mut data = Vec::with_capacity(width * height);
    // The file stores the bottom row first.
    for y in 0..height {
        let file_row = height - 1 - y;
        data.extend((0..width).map(|x| sample(file_row * width + x)));
    }
    Ok(DisparityMap {
        width,
        height,
        data,
    })
}

/// A cursor over the text header.
struct Header<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Header<'a> {
    /// Consumes one whitespace byte, if that is what comes next.
    fn next_is_whitespace(&mut self) -> bool {
        let is_space = self
            .bytes
            .get(self.pos)
            .is_some_and(u8::is_ascii_whitespace);
        if is_space {
            self.pos += 1;
        }
        is_space
    }

    /// The next whitespace-delimited token, leaving the cursor just after it. `None` at the end of
    /// the file or if the token is not short ASCII text (header numbers are a few characters).
    fn token(&mut self) -> Option<&'a str> {
        while self
            .bytes
            .get(self.pos)
            .is_some_and(u8::is_ascii_whitespace)
        {
            self.pos += 1;
        }
        let start = self.pos;
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
            && self.pos - start < 32
        {
            self.pos += 1;
        }
        let token = std::str::from_utf8(&self.bytes[start..self.pos]).ok()?;
        (!token.is_empty()).then_some(token)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(relative: &str) -> PathBuf {
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
            .join("tests/fixtures")
            .join(relative)
    }

    /// A PFM file of `rows` (given top row first, as an image), in the given byte order and with
    /// `channels` copies of each value except channel 0 which holds the value.
    fn pfm(rows: &[&[f32]], channels: usize, little_endian: bool) -> Vec<u8> {
        let magic = if channels == 1 { "Pf" } else { "PF" };
        let scale = if little_endian { "-1.0" } else { "1.0" };
        let mut out = format!("{magic}\n{} {}\n{scale}\n", rows[0].len(), rows.len()).into_bytes();
        for row in rows.iter().rev() {
            for &v in *row {
                for c in 0..channels {
                    let v = if c == 0 { v } else { -7.0 };
                    out.extend(if little_endian {
                        v.to_le_bytes()
                    } else {
                        v.to_be_bytes()
                    });
                }
            }
        }
        out
    }

    fn format_error(bytes: &[u8]) -> String {
        match parse_pfm(bytes, Path::new("bad.pfm")) {
            Ok(map) => panic!("parsed {map:?}"),
            Err(e) => {
                let message = e.to_string();
                assert!(message.contains("bad.pfm"), "{message}");
                message
            }
        }
    }

    const ROWS: [&[f32]; 2] = [&[1.0, 2.5, f32::INFINITY], &[4.0, f32::NAN, 6.0]];

    #[test]
    fn rows_come_out_top_to_bottom_in_both_byte_orders() {
        for little_endian in [true, false] {
            let map = parse_pfm(&pfm(&ROWS, 1, little_endian), Path::new("t.pfm")).expect("valid");
            assert_eq!((map.width, map.height), (3, 2));
            assert_eq!(map.get(0, 0), Some(1.0));
            assert_eq!(map.get(1, 0), Some(2.5));
            assert_eq!(map.get(2, 0), None, "inf is unknown");
            assert_eq!(map.get(0, 1), Some(4.0));
            assert_eq!(map.get(1, 1), None, "NaN is unknown too");
            assert_eq!(map.data[4], f32::INFINITY);
            assert_eq!(map.get(3, 0), None, "outside");
            assert_eq!(map.get(0, 2), None, "outside");
            assert_eq!(map.known_fraction(), 4.0 / 6.0);
        }
    }

    #[test]
    fn colour_pfm_uses_channel_zero() {
        let colour = parse_pfm(&pfm(&ROWS, 3, true), Path::new("c.pfm")).expect("valid");
        let grey = parse_pfm(&pfm(&ROWS, 1, true), Path::new("g.pfm")).expect("valid");
        assert_eq!(colour, grey);
    }

    #[test]
    fn header_fields_may_be_split_across_lines() {
        let mut bytes = b"Pf\n3\n2\n-1\n".to_vec();
        bytes.extend_from_slice(&pfm(&ROWS, 1, true)[b"Pf\n3 2\n-1.0\n".len()..]);
        let map = parse_pfm(&bytes, Path::new("t.pfm")).expect("valid");
        assert_eq!(map.get(1, 0), Some(2.5));
    }

    #[test]
    fn malformed_files_are_errors() {
        assert!(format_error(b"").contains("not a PFM"));
        assert!(format_error(b"P6\n3 2\n255\n").contains("not a PFM"));
        assert!(format_error(b"Pfx3 2\n-1\n").contains("whitespace"));
        assert!(format_error(b"Pf\n").contains("width"));
        assert!(format_error(b"Pf\n0 2\n-1\n").contains("width"));
        assert!(format_error(b"Pf\n-3 2\n-1\n").contains("width"));
        assert!(format_error(b"Pf\n3 two\n-1\n").contains("height"));
        assert!(format_error(b"Pf\n3 2\n0\n").contains("scale"));
        assert!(format_error(b"Pf\n3 2\nnan\n").contains("scale"));
        assert!(format_error(b"Pf\n3 2\n-1").contains("whitespace"));
        assert!(format_error(b"Pf\n99999999999 99999999999\n-1\n").contains("too large"));
        assert!(format_error(b"Pf\n4000000 4000000\n-1\n").contains("truncated"));
        let mut extra = pfm(&ROWS, 1, true);
        extra.extend_from_slice(b"\n\n");
        assert!(format_error(&extra).contains("2 unexpected bytes"));
        assert!(format_error(&[0xff; 64]).contains("not a PFM"));
    }

    #[test]
    fn every_truncation_is_an_error() {
        let bytes = pfm(&ROWS, 3, false);
        for end in 0..bytes.len() {
            assert!(
                parse_pfm(&bytes[..end], Path::new("t.pfm")).is_err(),
                "{end}"
            );
        }
        assert!(parse_pfm(&bytes, Path::new("t.pfm")).is_ok());
    }

    #[test]
    fn missing_files_are_io_errors_naming_the_file() {
        let err = read_pfm(&fixture("no-such-set/disp0.pfm")).expect_err("missing");
        assert!(matches!(err, DatasetError::Io { .. }));
        assert!(err.to_string().contains("no-such-set/disp0.pfm"), "{err}");
    }

    #[test]
    fn cones_ground_truth_matches_the_image_pair() {
        let map = read_pfm(&fixture("middlebury-cones/disp0.pfm")).expect("fixture");
        assert_eq!((map.width, map.height), (450, 375));
        let known = map.known_fraction();
        assert!((0.96..0.975).contains(&known), "known fraction {known}");

        // With the rows in the right order, left (x, y) and right (x - d, y) show the same surface;
        // upside down, the disparities belong to other rows and the match falls apart.
        let left = image::open(fixture("middlebury-cones/im0.png"))
            .expect("im0")
            .to_luma8();
        let right = image::open(fixture("middlebury-cones/im1.png"))
            .expect("im1")
            .to_luma8();
        let mismatch = |flipped: bool| {
            let (mut sum, mut n) = (0.0, 0usize);
            for y in 0..map.height {
                for x in 0..map.width {
                    let row = if flipped { map.height - 1 - y } else { y };
                    let Some(d) = map.get(x, row) else { continue };
                    let xr = (x as f64 - f64::from(d)).round();
                    if xr < 0.0 {
                        continue;
                    }
                    let a = f64::from(left.get_pixel(x as u32, y as u32)[0]);
                    let b = f64::from(right.get_pixel(xr as u32, y as u32)[0]);
                    sum += (a - b).abs();
                    n += 1;
                }
            }
            sum / n as f64
        };
        let (upright, flipped) = (mismatch(false), mismatch(true));
        assert!(
            upright < 15.0 && upright < 0.4 * flipped,
            "mean grey difference {upright} upright vs {flipped} flipped"
        );
    }

    #[test]
    fn motorcycle_ground_truth_lies_in_the_calibrated_depth_range() {
        let map = read_pfm(&fixture("middlebury-motorcycle/disp0.pfm")).expect("fixture");
        assert_eq!((map.width, map.height), (741, 500));
        let known = map.known_fraction();
        assert!((0.92..0.935).contains(&known), "known fraction {known}");
        let calib = crate::calib::load(&fixture("middlebury-motorcycle/calib.txt")).expect("calib");
        let (near, far) = calib.depth_range.expect("depth range");
        let (b, f, doffs) = (0.193001, 994.978, 31.086);
        for d in map.data.iter().filter(|d| d.is_finite()) {
            let z = b * f / (f64::from(*d) + doffs);
            assert!(near <= z && z <= far, "disparity {d} gives {z} m");
        }
    }
}
