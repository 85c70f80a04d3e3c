//! Measures the mock cameras' rendering cost at 640x480 through the simulated rig.
//!
//! `cargo run --release --example mock_timing`
//!
//! Prints, per operation, the median and the minimum over many repetitions (the machine is
//! shared: the minimum is the cost without interference, the median what a busy machine sees):
//! one-off setup (ray table and static background of one camera), a re-render of a changed scene
//! (obstacle re-trace plus sensor model), a noise-only frame (static scene: the common case), and
//! the stereo frame pair of each scenario over its whole length (what the 30 fps feed costs).

use std::time::{Duration, Instant};

use anyhow::Result;
use flyd::mock::{MockStereo, mock_rig};
use hw_mock::{CameraRenderer, Obstacle, Scenario, Scene, SensorModel};

/// (median, min) in milliseconds.
fn stats(mut t: Vec<Duration>) -> (f64, f64) {
    t.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    (ms(t[t.len() / 2]), ms(t[0]))
}

fn timed(reps: u32, mut f: impl FnMut(u32) -> Result<()>) -> Result<(f64, f64)> {
    let mut t = Vec::new();
    for i in 0..reps {
        let start = Instant::now();
        f(i)?;
        t.push(start.elapsed());
    }
    Ok(stats(t))
}

fn report(what: &str, (median, min): (f64, f64)) {
    println!("{what:44} median {median:7.2} ms   min {min:7.2} ms");
}

fn main() -> Result<()> {
    let (w, h) = (640u32, 480u32);
    let rig = mock_rig(w, h)?;
    let sensor = SensorModel::default();
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    let mut depth = vec![0f32; (w * h) as usize];

    let mut cam = None;
    let setup = timed(3, |_| {
        cam = Some(CameraRenderer::new(&flyd::mock::Rays(&rig.left))?);
        Ok(())
    })?;
    report("setup: rays + static world, one camera", setup);
    let Some(mut cam) = cam else {
        anyhow::bail!("no renderer")
    };

    // A different scene every frame: full obstacle re-trace plus sensor model.
    let car = |i: u32| Scene::with(vec![Obstacle::car(0.0, 5.0 + 0.1 * f64::from(i))]);
    let ped = |i: u32| Scene::with(vec![Obstacle::pedestrian(0.01 * f64::from(i), 4.0)]);
    let r = timed(60, |i| {
        Ok(cam.render(&car(i), &sensor, i, 0, &mut rgb, None)?)
    })?;
    report("re-render, changed scene (car rear at 5 m)", r);
    let r = timed(60, |i| {
        Ok(cam.render(&ped(i), &sensor, i, 0, &mut rgb, None)?)
    })?;
    report("re-render, changed scene (pedestrian 4 m)", r);
    let r = timed(60, |i| {
        // An obstacle in view, then gone: also restores the tiles it covered.
        let s = if i % 2 == 0 { Scene::empty() } else { ped(0) };
        Ok(cam.render(&s, &sensor, i, 0, &mut rgb, None)?)
    })?;
    report("re-render, alternating empty / pedestrian", r);

    // Static scene: noise only.
    let scene = ped(0);
    cam.render(&scene, &sensor, 0, 0, &mut rgb, None)?;
    let r = timed(300, |i| {
        Ok(cam.render(&scene, &sensor, i, 0, &mut rgb, None)?)
    })?;
    report("noise-only frame, static scene", r);
    let r = timed(300, |i| {
        Ok(cam.render(&scene, &sensor, i, 0, &mut rgb, Some(&mut depth))?)
    })?;
    report("noise-only frame + ground-truth depth", r);

    for name in Scenario::names() {
        let Some(s) = Scenario::by_name(name) else {
            continue;
        };
        let frames = s.frame_count();
        let mut stereo = MockStereo::new(s, w, h)?;
        let mut t = Vec::new();
        for f in 0..frames {
            let start = Instant::now();
            stereo.frame(f)?;
            t.push(start.elapsed());
        }
        let total: Duration = t.iter().sum();
        let mean = total.as_secs_f64() * 1e3 / f64::from(frames);
        let (median, min) = stats(t);
        println!(
            "{name:20} stereo pair: mean {mean:6.2} ms (= {:4.1} % of a core at 30 fps), median {median:6.2}, min {min:6.2} ms",
            mean * 3.0
        );
    }
    Ok(())
}
