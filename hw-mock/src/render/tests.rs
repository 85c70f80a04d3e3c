//! The fast path held to the reference, and the reference held to the images every evaluation
//! figure was measured on (golden hashes).

use super::*;
use crate::{Scenario, splitmix64};

/// A pinhole camera pitched 5 degrees down, as flyd's simulated rig (no distortion), at a
/// reduced size: the horizon, the near road and the roadside all in view.
struct Pitched {
    w: u32,
    h: u32,
    f: f64,
    centre: [f64; 3],
}

impl Pitched {
    fn new(x: f64) -> Self {
        Self {
            w: 160,
            h: 120,
            f: 130.0,
            centre: [x, 1.3, 0.0],
        }
    }
}

impl RayCamera for Pitched {
    fn size(&self) -> (u32, u32) {
        (self.w, self.h)
    }
    fn ray(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])> {
        let cx = 0.5 * (f64::from(self.w) - 1.0) + 0.6;
        let cy = 0.5 * (f64::from(self.h) - 1.0) - 0.4;
        let d = [(u - cx) / self.f, -(v - cy) / self.f, 1.0];
        let (s, c) = 5f64.to_radians().sin_cos();
        let d = [d[0], d[1] * c - d[2] * s, d[1] * s + d[2] * c];
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Some((self.centre, [d[0] / n, d[1] / n, d[2] / n]))
    }
}

/// A hash of an image and its depth, bit for bit.
fn hash(rgb: &[u8], depth: &[f32]) -> u64 {
    let bytes = rgb.iter().map(|&b| u64::from(b));
    let bits = depth.iter().map(|d| u64::from(d.to_bits()));
    bytes
        .chain(bits)
        .fold(0x5EED, |h, v| splitmix64(h ^ v.wrapping_mul(0x9E37)))
}

/// Frames of each scenario kind the golden hashes cover: standing, straight driving, a lane
/// change, bends (with a parked car and a pedestrian), roads of a profile (with a stopped
/// car, a pedestrian on the kerb).
const GOLDEN: [(&str, u32); 12] = [
    ("pedestrian-4m", 0),
    ("car-approaching", 40),
    ("drive-30", 17),
    ("drive-30-to-pedestrian", 60),
    ("drive-30-lane-change", 100),
    ("bend-30", 45),
    ("bend-30-parked-car", 30),
    ("bend-40-to-pedestrian", 70),
    ("ramp-30", 90),
    ("ramp-30-stopped-car", 50),
    ("ramp-30-pedestrian-on-kerb", 100),
    ("s-bend-40", 120),
];

fn reference_hash(name: &str, frame: u32) -> u64 {
    let scene = Scenario::by_name(name).expect("scenario").scene_at(frame);
    let sensor = SensorModel::default();
    let mut h = 0;
    for (index, x) in [(0u8, -0.15), (1, 0.15)] {
        let cam = Pitched::new(x);
        let n = (cam.w * cam.h) as usize;
        let (mut rgb, mut depth) = (vec![0; n * 3], vec![0.0; n]);
        render(
            &scene,
            &cam,
            &sensor,
            frame,
            index,
            &mut rgb,
            Some(&mut depth),
        )
        .expect("ok");
        h ^= hash(&rgb, &depth).rotate_left(u32::from(index));
    }
    h
}

/// The reference renders of [`GOLDEN`] as they were when the project's figures were measured
/// (x86-64, glibc's libm): a faster reference must not change a bit.
#[test]
fn the_reference_renders_the_images_of_before() {
    const HASHES: [u64; 12] = [
        0x04d2_65a1_ec52_864b,
        0xec7a_5612_1c5e_3517,
        0x96af_b854_40da_102f,
        0x054e_fa8a_d9fe_12cd,
        0xf200_b113_d268_c475,
        0x57ae_17f7_48cf_22e9,
        0xf6d2_232d_3fd6_539d,
        0x8886_a843_070c_2592,
        0xf708_9a62_c8dc_5890,
        0xe7ed_ac86_43d3_d714,
        0x7c51_d5e4_e2bc_16dd,
        0xafaa_bc29_d338_ab88,
    ];
    for ((name, frame), want) in GOLDEN.into_iter().zip(HASHES) {
        let got = reference_hash(name, frame);
        assert_eq!(got, want, "{name} frame {frame}: {got:#018x}");
    }
}

#[test]
#[ignore = "prints the golden hashes"]
fn print_golden_hashes() {
    for (name, frame) in GOLDEN {
        println!("{:#018x}, // {name} {frame}", reference_hash(name, frame));
    }
}

/// Every 15th frame of every scenario, for checking a change against the images of before it
/// (`cargo test -p hw-mock --release print_many -- --ignored --nocapture > before.txt`).
#[test]
#[ignore = "prints hashes of many frames"]
fn print_many_hashes() {
    for name in Scenario::names() {
        let scenario = Scenario::by_name(name).expect("scenario");
        for frame in (0..scenario.frame_count()).step_by(15) {
            println!("{name} {frame} {:#018x}", reference_hash(name, frame));
        }
    }
}

/// One renderer per camera through a sequence of scenes, each frame compared with the
/// reference bit for bit (image and depth).
fn fast_matches_reference(scenes: &[(Scene, u32)], what: &str) {
    let sensor = SensorModel::default();
    let cams = [Pitched::new(-0.15), Pitched::new(0.15)];
    let mut fast: Vec<CameraRenderer> = cams
        .iter()
        .map(|c| CameraRenderer::new(c).expect("valid"))
        .collect();
    let n = (cams[0].w * cams[0].h) as usize;
    for (k, (scene, frame)) in scenes.iter().enumerate() {
        for (index, (cam, r)) in cams.iter().zip(&mut fast).enumerate() {
            let index = index as u8;
            let (mut a, mut b) = (vec![0; n * 3], vec![0; n * 3]);
            let (mut da, mut db) = (vec![0.0; n], vec![0.0; n]);
            render(scene, cam, &sensor, *frame, index, &mut a, Some(&mut da)).expect("ok");
            r.render(scene, &sensor, *frame, index, &mut b, Some(&mut db))
                .expect("ok");
            let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
            assert_eq!(
                differ, 0,
                "{what}: scene {k} (frame {frame}) camera {index}"
            );
            let same = da.iter().zip(&db).all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(
                same,
                "{what}: scene {k} (frame {frame}) camera {index}: depths differ"
            );
        }
    }
}

/// Consecutive frames of a scenario (each a new pose: the moving paths), from `first`.
fn frames(name: &str, first: u32, count: u32, step: u32) -> Vec<(Scene, u32)> {
    let s = Scenario::by_name(name).expect("scenario");
    (0..count)
        .map(|i| first + i * step)
        .map(|f| (s.scene_at(f), f))
        .collect()
}

#[test]
fn fast_path_matches_the_reference_driving_straight() {
    let mut scenes = frames("drive-30", 10, 3, 1);
    // A pedestrian coming into the lane, then gone, then standing still again.
    scenes.extend(frames("drive-30-to-pedestrian", 50, 2, 1));
    scenes.extend(frames("drive-30", 52, 1, 1));
    scenes.extend(frames("pedestrian-4m", 0, 2, 1));
    scenes.extend(frames("drive-30-lane-change", 90, 2, 10));
    fast_matches_reference(&scenes, "straight");
}

#[test]
fn fast_path_matches_the_reference_on_bends() {
    let mut scenes = frames("bend-30", 20, 2, 1);
    // A car fixed to the road (traced with the static world), a pedestrian in the lane.
    scenes.extend(frames("bend-30-parked-car", 25, 2, 30));
    scenes.extend(frames("bend-40-to-pedestrian", 60, 2, 1));
    scenes.extend(frames("bend-30", 60, 1, 1));
    fast_matches_reference(&scenes, "bend");
}

#[test]
fn fast_path_matches_the_reference_on_roads_of_a_profile() {
    let mut scenes = frames("ramp-30", 40, 2, 1);
    scenes.extend(frames("ramp-30-stopped-car", 40, 2, 35));
    scenes.extend(frames("ramp-30-pedestrian-on-kerb", 90, 2, 20));
    scenes.extend(frames("s-bend-40-to-pedestrian", 30, 2, 40));
    scenes.extend(frames("s-bend-40", 149, 1, 1));
    // Back to standing: the static world of a straight road again.
    scenes.extend(frames("car-approaching", 30, 2, 1));
    fast_matches_reference(&scenes, "profile");
}
