//! Writes one frame of a mock scenario as PNGs: left and right images and a false-colour depth
//! map of the left image, for looking at what the simulated cameras see.
//!
//! `cargo run --release --example mock_snapshot -- [scenario] [frame] [out-prefix]`
//! (defaults: pedestrian-4m, 0, /tmp/mock-) writes `<prefix>left.png`, `<prefix>right.png` and
//! `<prefix>depth.png`.

use anyhow::{Context, Result, bail};
use flyd::mock::MockStereo;
use hw_mock::Scenario;

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_else(|| "pedestrian-4m".into());
    let frame: u32 = match args.next() {
        Some(f) => f.parse().context("frame must be a number")?,
        None => 0,
    };
    let prefix = args.next().unwrap_or_else(|| "/tmp/mock-".into());
    let Some(scenario) = Scenario::by_name(&name) else {
        bail!("unknown scenario {name:?}; known: {:?}", Scenario::names());
    };
    let (w, h) = (640, 480);
    let mut stereo = MockStereo::new(scenario, w, h)?;
    stereo.set_ground_truth(true);
    let (left, right) = stereo.frame(frame)?;
    for (side, img) in [("left", left), ("right", right)] {
        let path = format!("{prefix}{side}.png");
        image::save_buffer(&path, img, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("writing {path}"))?;
        println!("wrote {path}");
    }
    // Depth: near = bright; 1/z keeps the near field readable; sky black.
    let depth = stereo.left_depth().context("ground truth was enabled")?;
    let grey: Vec<u8> = depth
        .iter()
        .map(|z| {
            if z.is_finite() && *z > 0.0 {
                (255.0 * (2.0 / z).min(1.0)).round() as u8
            } else {
                0
            }
        })
        .collect();
    let path = format!("{prefix}depth.png");
    image::save_buffer(&path, &grey, w, h, image::ExtendedColorType::L8)
        .with_context(|| format!("writing {path}"))?;
    println!("wrote {path}");
    Ok(())
}
