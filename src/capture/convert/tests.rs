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
    let mut conv = FrameConverter::new(CaptureFormat::Yuyv, w, h, 0, PixelFormat::Rgb8, 0).unwrap();
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
        FrameConverter::new(CaptureFormat::Mjpg, w, h, 0, PixelFormat::Rgb8, jpeg.len()).unwrap();
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
