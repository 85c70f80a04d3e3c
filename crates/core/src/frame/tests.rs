#[test]
fn a_row_shift_reads_each_row_that_far_down() {
    let (w, h) = (16usize, 12usize);
    let px: Vec<u8> = (0..w * h * 3)
        .map(|i| ((i / (w * 3)) * 20 + i % 3) as u8)
        .collect();
    let plain = PreparedImage::from_pixels(16, 12, PixelFormat::Rgb8, &px).expect("plain");
    let shifted = |s: f64| {
        let mut img = PreparedImage::new(16, 12).expect("image").with_row_shift(s);
        img.prepare(PixelFormat::Rgb8, &px).expect("prepare");
        img
    };
    let (down, up, half) = (shifted(1.0), shifted(-2.0), shifted(0.5));
    for y in 2..h as u32 - 2 {
        for x in 0..w as u32 {
            assert_eq!(down.colour(x, y), plain.colour(x, y + 1), "({x}, {y})");
            assert_eq!(up.colour(x, y), plain.colour(x, y - 2), "({x}, {y})");
            let (a, b) = (plain.colour(x, y), plain.colour(x, y + 1));
            for c in 0..3 {
                let mid = (u16::from(a[c]) + u16::from(b[c])).div_ceil(2) as u8;
                assert!(half.colour(x, y)[c].abs_diff(mid) <= 1, "({x}, {y})");
            }
        }
    }
    // The last rows repeat the edge; 0 and non-finite shifts change nothing.
    assert_eq!(down.colour(3, 11), plain.colour(3, 11));
    assert_eq!(shifted(f64::NAN).data(), plain.data());
    assert_eq!(shifted(0.0).data(), plain.data());
    assert_eq!(shifted(100.0).row_shift(), MAX_ROW_SHIFT);
}

#[test]
fn retained_pixels_or_the_jpeg_they_came_from() {
    let px = vec![9u8; 16 * 16 * 3];
    let mut plain = PreparedImage::new(16, 16).expect("image");
    plain.prepare(PixelFormat::Rgb8, &px).expect("prepare");
    assert_eq!(plain.pixels(), None, "not retained unless asked");
    assert!(!plain.retain_encoded(&[1, 2, 3]));
    let mut kept = PreparedImage::new(16, 16).expect("image").retain_pixels();
    kept.prepare(PixelFormat::Rgb8, &px).expect("prepare");
    assert_eq!(
        kept.pixels(),
        Some(Retained::Raw(PixelFormat::Rgb8, &px[..]))
    );
    assert!(kept.retain_encoded(&[0xFF, 0xD8, 0xFF, 0xD9]));
    assert_eq!(
        kept.pixels(),
        Some(Retained::Jpeg(&[0xFF, 0xD8, 0xFF, 0xD9][..]))
    );
    // A JPEG larger than the raw frame keeps the pixels.
    kept.prepare(PixelFormat::Grey8, &px[..256])
        .expect("prepare");
    assert!(!kept.retain_encoded(&vec![0; 16 * 16 * 3 + 1]));
    assert_eq!(
        kept.pixels(),
        Some(Retained::Raw(PixelFormat::Grey8, &px[..256]))
    );
    // A clone keeps its buffer (no reallocation on its first frame).
    assert_eq!(kept.clone().pixels(), kept.pixels());
}

use super::prepare::Affine;
use super::*;

#[test]
fn layout_and_border() {
    let (w, h) = (20u32, 10u32);
    let px: Vec<u8> = (0..w * h * 3).map(|i| (i % 251) as u8).collect();
    let img = PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, &px).unwrap();
    // Normalisation is monotonic per channel: brighter input stays brighter.
    let (a, b) = (img.colour(3, 2), img.colour(4, 2));
    for c in 0..3 {
        assert!(a[c] < b[c], "{a:?} {b:?}");
    }
    // Border replicates the nearest edge pixel, gradient byte included.
    let d = img.data();
    let corner = img.offset(0, 0);
    let outside = img.offset(-(PAD as isize), -(PAD as isize));
    assert_eq!(d[corner..corner + 4], d[outside..outside + 4]);
    let edge = img.offset(19, 9);
    let beyond = img.offset(19 + PAD as isize - 1, 9 + PAD as isize - 1);
    assert_eq!(d[edge..edge + 4], d[beyond..beyond + 4]);
}

#[test]
fn sobel_of_a_vertical_step() {
    let (w, h) = (16u32, 16u32);
    let px: Vec<u8> = (0..w * h)
        .map(|i| if i % w < 8 { 0 } else { 100 })
        .collect();
    let img = PreparedImage::from_pixels(w, h, PixelFormat::Grey8, &px).unwrap();
    // Normalised: mean 50, std 50 -> gain 48/50: 0 -> 80, 100 -> 176 (mean 128, std 48).
    assert_eq!(img.colour(3, 0), [80, 0, 0]);
    assert_eq!(img.colour(9, 0), [176, 0, 0]);
    // Sobel gx at the step is 4 * 96 = 384, quantised /4 -> 96.
    assert_eq!(img.gradient(7, 5), 96);
    assert_eq!(img.gradient(8, 5), 96);
    assert_eq!(img.gradient(3, 5), 0);
}

/// The straightforward statistics: a histogram, then mean and variance over its bins.
fn reference_stats(pixels: &[u8], channels: usize) -> Vec<(f64, f64)> {
    let mut hist = vec![[0u64; 256]; channels];
    for (k, &v) in pixels.iter().enumerate() {
        hist[k % channels][v as usize] += 1;
    }
    hist.iter()
        .map(|h| {
            let n: f64 = h.iter().map(|&k| k as f64).sum();
            let mean = h
                .iter()
                .enumerate()
                .map(|(v, &k)| v as f64 * k as f64)
                .sum::<f64>()
                / n;
            let var = h
                .iter()
                .enumerate()
                .map(|(v, &k)| (v as f64 - mean).powi(2) * k as f64)
                .sum::<f64>()
                / n;
            (mean, var)
        })
        .collect()
}

#[test]
fn normalisation_matches_the_histogram_reference() {
    // Odd widths (a remainder after the 48-byte chunks), grey and colour, flat and busy.
    let mut x = 777u32;
    let mut noise = |span: u32| {
        x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
        ((x >> 16) % span) as u8
    };
    for (w, h, format) in [
        (37u32, 21u32, PixelFormat::Rgb8),
        (640, 48, PixelFormat::Rgb8),
        (53, 17, PixelFormat::Grey8),
    ] {
        let channels = format.bytes_per_pixel();
        for span in [1u32, 7, 256] {
            let px: Vec<u8> = (0..(w * h) as usize * channels)
                .map(|_| 60 + noise(span).min(195))
                .collect();
            let img = PreparedImage::new(w, h).unwrap();
            let (got, _) = img.normalisation(format, &px);
            for (c, &(mean, var)) in reference_stats(&px, channels).iter().enumerate() {
                let want = Affine::normalising(mean, var);
                let what = format!("{w}x{h} {format:?} span {span} channel {c}");
                // The integer sums are exact: the same map, to within the last bit of the
                // f64 variance (E[v^2] - mean^2 against the centred sum).
                assert!((got[c].gain - want.gain).abs() <= 1, "{what}");
                assert!((got[c].offset - want.offset).abs() <= 256, "{what}");
                // And the fixed-point map is the exact one to within a grey level.
                let gain = NORMALISED_STD / var.sqrt().max(NORMALISED_STD / 4.0);
                let mut ties = 0;
                for v in 0..=255u8 {
                    let exact = ((v as f64 - mean) * gain + NORMALISED_MEAN)
                        .round()
                        .clamp(0.0, 255.0) as i32;
                    let d = (got[c].apply(v) - exact).abs();
                    assert!(d <= 1, "{what}: {v} -> {} vs {exact}", got[c].apply(v));
                    ties += d;
                }
                assert!(ties <= 2, "{what}: {ties} values off by one");
            }
        }
    }
}

#[test]
fn every_instruction_set_prepares_the_same_bytes() {
    let detected = Isa::detect();
    if detected == Isa::BASELINE {
        println!("SKIP every_instruction_set_prepares_the_same_bytes: only the baseline here");
        return;
    }
    let mut x = 4242u32;
    for (w, h, format) in [
        (640u32, 48u32, PixelFormat::Rgb8),
        (37, 29, PixelFormat::Grey8),
    ] {
        let px: Vec<u8> = (0..(w * h) as usize * format.bytes_per_pixel())
            .map(|k| {
                x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
                // A ramp with noise: every gradient magnitude and a full-range histogram.
                ((k % 251) as u32 / 2 + (x >> 16) % 128) as u8
            })
            .collect();
        let (mut a, mut b) = (
            PreparedImage::new(w, h).unwrap(),
            PreparedImage::new(w, h).unwrap(),
        );
        a.prepare_on(Isa::BASELINE, format, &px);
        b.prepare_on(detected, format, &px);
        assert!(a.data == b.data, "{format:?}: prepared bytes differ");
        assert_eq!(a.block_means, b.block_means);
        assert!(
            a.data.iter().skip(3).step_by(4).any(|&g| g > 100),
            "strong gradients"
        );
    }
}

#[test]
fn normalisation_removes_gain_and_offset() {
    let (w, h) = (32u32, 24u32);
    let mut x = 12345u32;
    let px: Vec<u8> = (0..w * h * 3)
        .map(|_| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            40 + ((x >> 16) % 120) as u8
        })
        .collect();
    // Another camera: 1.3x gain, +15 offset (no clipping: 40..160 -> 67..223).
    let other: Vec<u8> = px
        .iter()
        .map(|&v| (v as f32 * 1.3 + 15.0).round() as u8)
        .collect();
    let a = PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, &px).unwrap();
    let b = PreparedImage::from_pixels(w, h, PixelFormat::Rgb8, &other).unwrap();
    let mut worst = 0i32;
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                worst = worst.max((a.colour(x, y)[c] as i32 - b.colour(x, y)[c] as i32).abs());
            }
        }
    }
    assert!(
        worst <= 1,
        "differ by {worst} grey levels after normalisation"
    );
    // And the statistics are the documented ones.
    let mean = (0..w * h)
        .map(|i| a.colour(i % w, i / w)[0] as f64)
        .sum::<f64>()
        / (w * h) as f64;
    assert!((mean - NORMALISED_MEAN).abs() < 1.0, "{mean}");
}

#[test]
fn wrong_sizes_are_errors() {
    assert!(matches!(
        PreparedImage::from_pixels(16, 16, PixelFormat::Rgb8, &[0; 10]),
        Err(FrameError::SizeMismatch {
            expected: 768,
            got: 10,
            ..
        })
    ));
    assert!(PreparedImage::new(2, 100000).is_err());
}
