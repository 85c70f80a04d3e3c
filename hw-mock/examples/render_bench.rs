//! The renderer's benchmark: stereo pairs a second that [`CameraRenderer`] renders for a
//! scenario, at 640x480 on one thread, the median of several runs.
//!
//! Run (release, one thread: the renderer has none of its own):
//!
//! ```text
//! cargo run -p hw-mock --release --example render_bench            # every case
//! cargo run -p hw-mock --release --example render_bench -- ramp-30 # one scenario
//! RENDER_BENCH_RUNS=9 RENDER_BENCH_FRAMES=60 cargo run ...         # more, longer runs
//! ```
//!
//! A case is a scenario: a run renders frames 0, 1, 2, ... of it through a left and a right
//! camera (a pinhole pair shaped as flyd's simulated rig: f = 520 px, 1.3 m up, pitched 5
//! degrees down, 0.30 m baseline; no distortion), each frame a new [`Scenario::scene_at`], as
//! flyd's mock feed renders it. Each run starts from fresh renderers primed on a frame before
//! the run's first one (their construction is not timed), so a moving scene pays its full
//! per-frame price. The cases:
//! - `pedestrian-4m`: stationary vehicle, a pedestrian (only the sensor noise runs per frame);
//! - `car-approaching`: stationary vehicle, a moving obstacle (its tiles re-traced);
//! - `drive-30`: a straight road moving towards the vehicle ([`Scene::driving`]);
//! - `bend-30`: a constant bend;
//! - `ramp-30`, `s-bend-40`: roads of a curvature profile.
//!
//! It prints, per case, the median pairs/s over the runs and the spread (min..max). With
//! `RENDER_BENCH_CHECK=1` it then renders the first frames of each case again through the
//! reference [`hw_mock::render`] and prints how many bytes of image and depth differ (the fast
//! path is meant to be bit for bit the reference: 0).

use hw_mock::{CameraRenderer, RayCamera, Scenario, Scene, SensorModel, render};
use std::time::Instant;

const CASES: [&str; 6] = [
    "pedestrian-4m",
    "car-approaching",
    "drive-30",
    "bend-30",
    "ramp-30",
    "s-bend-40",
];

/// A pinhole camera pitched down, as flyd's `mock_rig` (without its lens distortion).
struct Pinhole {
    w: u32,
    h: u32,
    f: f64,
    cx: f64,
    cy: f64,
    centre: [f64; 3],
    /// sin and cos of the downward pitch.
    pitch: (f64, f64),
}

impl Pinhole {
    fn new(x: f64) -> Self {
        let (w, h) = (640u32, 480u32);
        Self {
            w,
            h,
            f: 520.0,
            cx: 0.5 * (f64::from(w) - 1.0) + 0.004 * f64::from(w),
            cy: 0.5 * (f64::from(h) - 1.0) - 0.003 * f64::from(h),
            centre: [x, 1.3, 0.0],
            pitch: 5f64.to_radians().sin_cos(),
        }
    }
}

impl RayCamera for Pinhole {
    fn size(&self) -> (u32, u32) {
        (self.w, self.h)
    }

    fn ray(&self, u: f64, v: f64) -> Option<([f64; 3], [f64; 3])> {
        let d = [(u - self.cx) / self.f, -(v - self.cy) / self.f, 1.0];
        let (s, c) = self.pitch;
        // Pitched down: rotate about x.
        let d = [d[0], d[1] * c - d[2] * s, d[1] * s + d[2] * c];
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Some((self.centre, [d[0] / n, d[1] / n, d[2] / n]))
    }
}

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&v| v > 0)
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs = env_u32("RENDER_BENCH_RUNS", 5);
    let frames = env_u32("RENDER_BENCH_FRAMES", 30);
    let wanted: Vec<String> = std::env::args().skip(1).collect();
    let cases: Vec<&str> = if wanted.is_empty() {
        CASES.to_vec()
    } else {
        wanted.iter().map(String::as_str).collect()
    };
    let (left_cam, right_cam) = (Pinhole::new(-0.15), Pinhole::new(0.15));
    let sensor = SensorModel::default();
    let n = 640 * 480;
    let (mut rgb, mut depth) = (vec![0u8; n * 3], vec![0f32; n]);
    println!("640x480, {runs} runs of {frames} stereo pairs each, one thread");
    for name in cases {
        let scenario = Scenario::by_name(name).ok_or(format!("no scenario {name}"))?;
        let mut rates = Vec::new();
        for run in 0..runs {
            let (mut left, mut right) = (
                CameraRenderer::new(&left_cam)?,
                CameraRenderer::new(&right_cam)?,
            );
            // Start each run at another place of the scenario (within its frames).
            let first = (run * 7) % scenario.frame_count().saturating_sub(frames + 1).max(1);
            let prime = scenario.scene_at(first);
            left.render(&prime, &sensor, first, 0, &mut rgb, Some(&mut depth))?;
            right.render(&prime, &sensor, first, 1, &mut rgb, Some(&mut depth))?;
            let start = Instant::now();
            for f in first + 1..=first + frames {
                let scene = scenario.scene_at(f);
                left.render(&scene, &sensor, f, 0, &mut rgb, Some(&mut depth))?;
                right.render(&scene, &sensor, f, 1, &mut rgb, Some(&mut depth))?;
            }
            rates.push(f64::from(frames) / start.elapsed().as_secs_f64());
        }
        rates.sort_by(f64::total_cmp);
        let median = rates[rates.len() / 2];
        println!(
            "{name:>16}: {median:8.1} pairs/s (median; {:.1}..{:.1})",
            rates[0],
            rates[rates.len() - 1]
        );
        if std::env::var_os("RENDER_BENCH_CHECK").is_some() {
            let scenes: Vec<(Scene, u32)> = (1..=3).map(|f| (scenario.scene_at(f), f)).collect();
            let differ = check(&scenes, [&left_cam, &right_cam], &sensor)?;
            println!(
                "{name:>16}: {differ} bytes differ from the reference (3 frames, both cameras)"
            );
        }
    }
    Ok(())
}

/// Renders `scenes` in order through fresh fast renderers and through the reference; the
/// number of image bytes and depth values that differ.
fn check(
    scenes: &[(Scene, u32)],
    cams: [&Pinhole; 2],
    sensor: &SensorModel,
) -> Result<usize, Box<dyn std::error::Error>> {
    let n = 640 * 480;
    let mut differ = 0;
    for (index, cam) in cams.into_iter().enumerate() {
        let index = u8::try_from(index)?;
        let mut fast = CameraRenderer::new(cam)?;
        for (scene, frame) in scenes {
            let (mut a, mut b) = (vec![0u8; n * 3], vec![0u8; n * 3]);
            let (mut da, mut db) = (vec![0f32; n], vec![0f32; n]);
            render(scene, cam, sensor, *frame, index, &mut a, Some(&mut da))?;
            fast.render(scene, sensor, *frame, index, &mut b, Some(&mut db))?;
            differ += a.iter().zip(&b).filter(|(x, y)| x != y).count();
            differ += da
                .iter()
                .zip(&db)
                .filter(|(x, y)| x.to_bits() != y.to_bits())
                .count();
        }
    }
    Ok(differ)
}
