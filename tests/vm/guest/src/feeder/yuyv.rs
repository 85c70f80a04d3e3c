//! RGB8 to YUYV (BT.601 limited range), the inverse of what flyd's capture converter assumes
//! (`flyd::capture::convert::yuyv_to_rgb`): a camera that sends what hw-mock rendered.

/// Converts packed RGB8 (`width * height * 3` bytes) into YUYV (`width * height * 2` bytes).
/// Each pair of pixels shares the mean of their chroma. `width` must be even.
pub fn rgb_to_yuyv(rgb: &[u8], width: usize, yuyv: &mut [u8]) {
    assert!(
        width.is_multiple_of(2),
        "YUYV needs an even width, got {width}"
    );
    assert_eq!(rgb.len() / 3 * 2, yuyv.len(), "RGB and YUYV sizes differ");
    for (px, out) in rgb.chunks_exact(6).zip(yuyv.chunks_exact_mut(4)) {
        let (y0, u0, v0) = ycbcr(px[0], px[1], px[2]);
        let (y1, u1, v1) = ycbcr(px[3], px[4], px[5]);
        out[0] = y0;
        out[1] = ((u0 + u1 + 1) / 2) as u8;
        out[2] = y1;
        out[3] = ((v0 + v1 + 1) / 2) as u8;
    }
}

/// BT.601 limited range, 8-bit fixed point: Y in 16..=235, Cb and Cr in 16..=240 (as i32).
fn ycbcr(r: u8, g: u8, b: u8) -> (u8, i32, i32) {
    let (r, g, b) = (i32::from(r), i32::from(g), i32::from(b));
    let y = ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16;
    let cb = ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128;
    let cr = ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128;
    (y as u8, cb, cr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flyd::capture::convert::{Layout, yuyv_to_rgb};

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
        rgb_to_yuyv(&rgb, w, &mut yuyv);
        assert_eq!(&yuyv[..4], &[16, 128, 16, 128], "black");
        assert_eq!(&yuyv[4..8], &[235, 128, 235, 128], "white");
        let mut back = vec![0; w * h * 3];
        yuyv_to_rgb(&yuyv, Layout::new(w, h, w * 2), &mut back).expect("converts");
        for (i, (a, b)) in rgb.iter().zip(&back).enumerate() {
            assert!(a.abs_diff(*b) <= 4, "byte {i}: {a} came back as {b}");
        }
    }
}
