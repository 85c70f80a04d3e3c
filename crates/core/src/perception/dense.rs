//! A cluster's matches checked by a dense local matcher: the disparity a larger window
//! prefers along the whole epipolar line.
//!
//! The fitness compares 7 x 7 windows (every third row): small enough that a repeated
//! structure (a row of tree trunks, a fence) matches as well, or better, a period away. On
//! KITTI odometry 00's frame 1, flies on a trunk 22-35 m away matched the next trunk of the
//! row 47 px away (the truth: 11-17 px), unique within 4 px and better than the true match
//! along the line, and made an "obstacle" 8.1 m ahead. A window of 11 x 11 takes in what
//! surrounds the trunk, which differs from one trunk to the next: its zero-mean normalised
//! cross-correlation (ZNCC, insensitive to the cameras' gain and offset) peaks at the true
//! disparity (there: 0.92 at 11 px against 0.80 at 47 px).
//!
//! [`agrees`] finds, for one left pixel, the disparity of the best ZNCC over the search range
//! and says whether the fly's own is within [`TOLERANCE_PX`] of it. Pure and allocation
//! free; `(2 RADIUS + 1)^2` samples per channel and disparity.

use crate::frame::{BPP, PreparedImage};

/// Half the window side, pixels (11 x 11).
pub const RADIUS: i32 = 5;
/// A fly agrees when its disparity is within this of the window's best, pixels.
pub const TOLERANCE_PX: f32 = 2.0;
/// Windows this flat (standard deviation of the grey levels) say nothing: no verdict.
const FLAT: f32 = 2.0;

/// Whether the match of left pixel `(u, v)` with right pixel `(ur, vr)` is the one an 11 x 11
/// window prefers along the right image's row `vr` over the disparities `range` (whole
/// pixels, low..=high; the disparity being `u - ur`): `None` when a window leaves the image or
/// is flat, or no disparity of the range fits. A rig that is not rectified has its epipolar
/// lines curve; near the fly's own match they are the row, which is where a repeated
/// structure's other matches lie too.
pub fn agrees(
    left: &PreparedImage,
    right: &PreparedImage,
    (u, v): (f32, f32),
    (ur, vr): (f32, f32),
    range: (u32, u32),
) -> Option<bool> {
    let (x, y) = (u.round() as i32, v.round() as i32);
    let yr = vr.round() as i32;
    let disparity = u - ur;
    if yr - RADIUS < 0 || yr + RADIUS >= right.height() as i32 {
        return None;
    }
    let (w, h) = (left.width() as i32, left.height() as i32);
    // Windows inside the image (the padding only replicates its edges).
    if right.width() as i32 != w
        || right.height() as i32 != h
        || x - RADIUS < 0
        || y - RADIUS < 0
        || x + RADIUS >= w
        || y + RADIUS >= h
    {
        return None;
    }
    let channels = usize::from(left.channels().min(right.channels()).max(1));
    let (ld, rd) = (left.data(), right.data());
    let n = ((2 * RADIUS + 1) * (2 * RADIUS + 1)) as f32 * channels as f32;
    // The left window's mean and spread, once.
    let (mut sa, mut saa) = (0f32, 0f32);
    for j in -RADIUS..=RADIUS {
        let o = left.offset((x - RADIUS) as isize, (y + j) as isize);
        for i in 0..(2 * RADIUS + 1) as usize {
            for c in 0..channels {
                let a = f32::from(ld[o + i * BPP + c]);
                sa += a;
                saa += a * a;
            }
        }
    }
    let va = saa - sa * sa / n;
    if va <= FLAT * FLAT * n {
        return None;
    }
    // Disparities whose right window stays in the image.
    let lo = range.0 as i32;
    let hi = (range.1 as i32).min(x - RADIUS);
    let mut best: Option<(f32, i32)> = None;
    for d in lo..=hi {
        let xr = x - d;
        let (mut sb, mut sbb, mut sab) = (0f32, 0f32, 0f32);
        for j in -RADIUS..=RADIUS {
            let lo_ = left.offset((x - RADIUS) as isize, (y + j) as isize);
            let ro = right.offset((xr - RADIUS) as isize, (yr + j) as isize);
            for i in 0..(2 * RADIUS + 1) as usize {
                for c in 0..channels {
                    let a = f32::from(ld[lo_ + i * BPP + c]);
                    let b = f32::from(rd[ro + i * BPP + c]);
                    sb += b;
                    sbb += b * b;
                    sab += a * b;
                }
            }
        }
        let vb = sbb - sb * sb / n;
        if vb <= 0.0 {
            continue;
        }
        let zncc = (sab - sa * sb / n) / (va * vb).sqrt();
        if best.is_none_or(|(z, _)| zncc > z) {
            best = Some((zncc, d));
        }
    }
    best.map(|(_, d)| (d as f32 - disparity).abs() <= TOLERANCE_PX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::PixelFormat;

    /// A textured left image and a right one shifted by `shift` px, with a copy of a patch
    /// `period` px to the left of it (a repeated structure the small window also matches).
    fn pair(shift: usize) -> (PreparedImage, PreparedImage) {
        let (w, h) = (160usize, 60usize);
        let mut noise = 12345u32;
        let mut img = vec![0u8; w * h];
        for p in img.iter_mut() {
            noise ^= noise << 13;
            noise ^= noise >> 17;
            noise ^= noise << 5;
            *p = (noise % 200) as u8 + 20;
        }
        let mut right = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                right[y * w + x] = img[y * w + (x + shift).min(w - 1)];
            }
        }
        let mut l = PreparedImage::new(w as u32, h as u32).expect("image");
        let mut r = PreparedImage::new(w as u32, h as u32).expect("image");
        l.prepare(PixelFormat::Grey8, &img).expect("left");
        r.prepare(PixelFormat::Grey8, &right).expect("right");
        (l, r)
    }

    #[test]
    fn the_true_disparity_agrees_a_wrong_one_does_not() {
        let (l, r) = pair(12);
        let at = |d: f32| agrees(&l, &r, (100.0, 30.0), (100.0 - d, 30.0), (0, 60));
        assert_eq!(at(12.0), Some(true));
        assert_eq!(at(13.5), Some(true));
        assert_eq!(at(40.0), Some(false));
        // Outside the image: no verdict.
        assert_eq!(agrees(&l, &r, (2.0, 30.0), (-10.0, 30.0), (0, 60)), None);
        assert_eq!(agrees(&l, &r, (100.0, 58.0), (88.0, 58.0), (0, 60)), None);
    }

    #[test]
    fn a_flat_window_gives_no_verdict() {
        let mut l = PreparedImage::new(64, 32).expect("image");
        l.prepare(PixelFormat::Grey8, &[90u8; 64 * 32])
            .expect("left");
        let r = l.clone();
        assert_eq!(agrees(&l, &r, (40.0, 16.0), (37.0, 16.0), (0, 20)), None);
    }
}
