//! Writes one frame of a mock scenario as PNGs: left and right images and a false-colour depth
//! map of the left image, for looking at what the simulated cameras see.
//!
//! `cargo run --release --example mock_snapshot -- [scenario] [frame] [out-prefix] [WxH]`
//! (defaults: pedestrian-4m, 0, /tmp/mock-, 640x480) writes `<prefix>left.png`,
//! `<prefix>right.png` and `<prefix>depth.png`, and each image as a YUYV camera would deliver
//! it to flyd: `<prefix>left-yuyv.png` (colour from its shared chroma, `cameras.channels =
//! "colour"`) and `<prefix>left-luma.png` (`"luma"`, the default), likewise for the right.

use anyhow::{Context, Result, bail};
use flyd::capture::convert::{Layout, rgb_to_yuyv, yuyv_to_grey, yuyv_to_rgb};
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
    let (w, h) = match args.next() {
        Some(size) => {
            let (w, h) = size.split_once('x').context("size as WxH")?;
            (w.parse().context("width")?, h.parse().context("height")?)
        }
        None => (640u32, 480u32),
    };
    let mut stereo = MockStereo::new(scenario, w, h)?;
    stereo.set_ground_truth(true);
    let (left, right) = stereo.frame(frame)?;
    for (side, img) in [("left", left), ("right", right)] {
        let path = format!("{prefix}{side}.png");
        image::save_buffer(&path, img, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("writing {path}"))?;
        println!("wrote {path}");
        let (wu, hu) = (w as usize, h as usize);
        let mut yuyv = vec![0; wu * hu * 2];
        rgb_to_yuyv(img, wu, &mut yuyv)?;
        let layout = Layout::new(wu, hu, wu * 2);
        let mut colour = vec![0; wu * hu * 3];
        yuyv_to_rgb(&yuyv, layout, &mut colour)?;
        let mut luma = vec![0; wu * hu];
        yuyv_to_grey(&yuyv, layout, &mut luma)?;
        for (kind, pixels, colour_type) in [
            ("yuyv", &colour, image::ExtendedColorType::Rgb8),
            ("luma", &luma, image::ExtendedColorType::L8),
        ] {
            let path = format!("{prefix}{side}-{kind}.png");
            image::save_buffer(&path, pixels, w, h, colour_type)
                .with_context(|| format!("writing {path}"))?;
            println!("wrote {path}");
        }
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
