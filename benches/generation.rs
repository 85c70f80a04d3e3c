//! One generation of the fly engine (5000 flies, 640x480 hw-mock pedestrian-4m), with and
//! without a new frame, and the preparation of one 640x480 RGB frame (what each capture
//! thread does per frame). `cargo bench --bench generation`; `flyd bench` reports the
//! generations in the proportions the daemon runs them.

use criterion::{Criterion, criterion_group, criterion_main};
use flyd::mock::MockStereo;
use flyd_core::engine::{Engine, EngineParams};
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use std::hint::black_box;

fn frames(mock: &mut MockStereo) -> Vec<StereoFrame> {
    (0..2u32)
        .map(|i| {
            let (l, r) = mock.frame(i).expect("render");
            let prep = |px: &[u8]| {
                PreparedImage::from_pixels(640, 480, PixelFormat::Rgb8, px).expect("prepare")
            };
            StereoFrame::new(prep(l), prep(r), i as u64)
        })
        .collect()
}

fn generation(c: &mut Criterion) {
    let scenario = hw_mock::Scenario::by_name("pedestrian-4m").expect("scenario");
    let mut mock = MockStereo::new(scenario, 640, 480).expect("mock");
    let frames = frames(&mut mock);
    let mut engine = Engine::new(mock.rig(), EngineParams::default()).expect("engine");
    for _ in 0..50 {
        engine.step(&frames[0]).expect("warm-up");
    }
    c.bench_function("generation/same_frame", |b| {
        b.iter(|| black_box(engine.step(&frames[0]).expect("step")))
    });
    let mut k = 0usize;
    c.bench_function("generation/new_frame", |b| {
        b.iter(|| {
            k += 1;
            black_box(engine.step(&frames[k % 2]).expect("step"))
        })
    });
}

fn prepare(c: &mut Criterion) {
    let scenario = hw_mock::Scenario::by_name("pedestrian-4m").expect("scenario");
    let mut mock = MockStereo::new(scenario, 640, 480).expect("mock");
    let (left, _) = mock.frame(0).expect("render");
    let pixels = left.to_vec();
    let mut image = PreparedImage::new(640, 480).expect("image");
    c.bench_function("prepare/640x480_rgb", |b| {
        b.iter(|| {
            image
                .prepare(PixelFormat::Rgb8, black_box(&pixels))
                .expect("prepare")
        })
    });
    // A right camera with a row correction (rectification.right_row_offset_px).
    let mut shifted = PreparedImage::new(640, 480)
        .expect("image")
        .with_row_shift(0.37);
    c.bench_function("prepare/640x480_rgb_row_shift", |b| {
        b.iter(|| {
            shifted
                .prepare(PixelFormat::Rgb8, black_box(&pixels))
                .expect("prepare")
        })
    });
}

criterion_group!(benches, generation, prepare);
criterion_main!(benches);
