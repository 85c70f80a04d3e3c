//! `v4l2-smoke`: both ends of the V4L2 smoke test, run inside the test VM against v4l2loopback.
//!
//! ```text
//! v4l2-smoke produce DEVICE CAMERA FRAMES FPS   set VIDEO_OUTPUT YUYV 64x48, write FRAMES frames
//! v4l2-smoke capture DEVICE CAMERA FRAMES FILE  mmap-stream FRAMES frames, check, append to FILE
//! v4l2-smoke grab DEVICE FRAMES FILE            mmap-stream FRAMES frames, unchecked, to FILE
//! ```
//!
//! The producer uses `VIDIOC_S_FMT` on the output side and plain `write()`, as a feeder would;
//! the capture side uses the `v4l` crate's mmap streaming, as flyd does. The capture checks every
//! frame against [`pattern`] (right camera, intact, indices increasing) and writes the raw
//! frames out so that the host can check the same bytes again.

mod output;
mod pattern;

use std::fs::File;
use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail, ensure};
use v4l::buffer::Type;
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

const YUYV: &[u8; 4] = b"YUYV";

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.iter().map(String::as_str).collect::<Vec<_>>()[..] {
        ["produce", device, camera, frames, fps] => {
            produce(device, camera.parse()?, frames.parse()?, fps.parse()?)
        }
        ["capture", device, camera, frames, out] => {
            capture(device, camera.parse()?, frames.parse()?, out)
        }
        ["grab", device, frames, out] => grab(device, frames.parse()?, out),
        _ => bail!(
            "usage: v4l2-smoke produce DEVICE CAMERA FRAMES FPS\n       \
             v4l2-smoke capture DEVICE CAMERA FRAMES FILE\n       \
             v4l2-smoke grab DEVICE FRAMES FILE"
        ),
    }
}

fn produce(device: &str, camera: u8, frames: u32, fps: u32) -> Result<()> {
    // `_dev` outlives `out`.
    let (_dev, mut out, got) = output::open_output(device, pattern::WIDTH, pattern::HEIGHT, YUYV)?;
    eprintln!("produce: {device} output format {got}");
    let period = Duration::from_secs(1) / fps.max(1);
    let start = Instant::now();
    for index in 0..frames {
        out.write_all(&pattern::frame(camera, index))
            .with_context(|| format!("writing frame {index} to {device}"))?;
        if index == 0 {
            eprintln!("produce: {device} first frame written");
        }
        // Pace against the start, so a slow write does not stretch the whole run.
        if let Some(wait) = (period * (index + 1)).checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
    }
    eprintln!("produce: {device} wrote {frames} frames");
    Ok(())
}

fn capture(device: &str, camera: u8, frames: u32, out_path: &str) -> Result<()> {
    let dev = Device::with_path(device).with_context(|| format!("opening {device}"))?;
    let caps = dev.query_caps()?;
    let format = Capture::format(&dev).with_context(|| format!("VIDIOC_G_FMT on {device}"))?;
    eprintln!(
        "capture: {device} driver {} card {:?} format {format}",
        caps.driver, caps.card
    );
    ensure!(
        (format.width, format.height, format.fourcc)
            == (pattern::WIDTH, pattern::HEIGHT, FourCC::new(YUYV)),
        "{device} capture format is {format}, expected {}x{} YUYV",
        pattern::WIDTH,
        pattern::HEIGHT
    );

    let mut out = File::create(out_path).with_context(|| format!("creating {out_path}"))?;
    let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
        .with_context(|| format!("mmap buffers on {device}"))?;
    stream.set_timeout(Duration::from_secs(5));
    let mut last: Option<u32> = None;
    for n in 0..frames {
        let (buf, meta) = stream
            .next()
            .with_context(|| format!("dequeuing frame {n} from {device}"))?;
        // The slice is the whole mmap buffer: only bytesused of it is the frame.
        let bytes = &buf[..meta.bytesused as usize];
        let (got_camera, index) = pattern::identify(bytes)
            .map_err(anyhow::Error::msg)
            .with_context(|| format!("frame {n} from {device}"))?;
        ensure!(
            got_camera == camera,
            "{device} delivered camera {got_camera}'s frame, expected camera {camera}'s"
        );
        ensure!(
            last.is_none_or(|last| index > last),
            "{device}: frame index {index} after {last:?}"
        );
        last = Some(index);
        out.write_all(bytes)?;
    }
    out.sync_all()?;
    eprintln!(
        "capture: {device} {frames} frames checked, last index {}",
        last.unwrap_or(0)
    );
    Ok(())
}

/// Saves FRAMES captured frames (whatever their content: the feeder's, checked on the host).
fn grab(device: &str, frames: u32, out_path: &str) -> Result<()> {
    let dev = Device::with_path(device).with_context(|| format!("opening {device}"))?;
    let format = Capture::format(&dev).with_context(|| format!("VIDIOC_G_FMT on {device}"))?;
    eprintln!("grab: {device} format {format}");
    let mut out = File::create(out_path).with_context(|| format!("creating {out_path}"))?;
    let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
        .with_context(|| format!("mmap buffers on {device}"))?;
    stream.set_timeout(Duration::from_secs(10));
    for n in 0..frames {
        let (buf, meta) = stream
            .next()
            .with_context(|| format!("dequeuing frame {n} from {device}"))?;
        out.write_all(&buf[..meta.bytesused as usize])?;
    }
    out.sync_all()?;
    eprintln!("grab: {device} {frames} frames saved");
    Ok(())
}

#[cfg(test)]
mod pattern_tests {
    use crate::pattern::{frame, identify};

    #[test]
    fn a_frame_identifies_as_itself() {
        assert_eq!(identify(&frame(1, 42)), Ok((1, 42)));
    }

    #[test]
    fn a_changed_byte_is_reported() {
        let mut f = frame(0, 3);
        f[100] ^= 1;
        assert!(identify(&f).unwrap_err().contains("byte 100"));
    }

    #[test]
    fn frames_differ_by_camera_and_index() {
        assert_ne!(frame(0, 1)[9..], frame(1, 1)[9..]);
        assert_ne!(frame(0, 1)[9..], frame(0, 2)[9..]);
    }
}
