//! `flyd-feeder`: plays a hw-mock scenario into two v4l2loopback cameras, so that the real flyd
//! captures it through the kernel's V4L2 stack (issue 4's kernel-in-the-loop tests).
//!
//! Frames are rendered through `flyd::mock::MockStereo` (flyd's own mock rig: flyd configured
//! with `[calibration] builtin = "mock"` and the same size sees a consistent stereo pair),
//! converted to YUYV (BT.601 limited range, what flyd's converter assumes), and written with
//! `write()` to the output side of each loopback device after `VIDIOC_S_FMT` (VIDEO_OUTPUT).
//!
//! ```text
//! flyd-feeder --left /dev/video0 --right /dev/video1 --scenario pedestrian-steps-in \
//!     --width 320 --height 240 [--fps 30] [--frames N] [--prerender] [--timeline FILE]
//!     [--stop-camera left|right | --garbage left|right | --format left|right [--as WxH:FOURCC]]
//!     [--at-frame N] [--resume-at M]
//! ```
//!
//! Faults, on one camera (the other keeps its normal frames):
//! - `--stop-camera CAM --at-frame N [--resume-at M]`: nothing written to CAM for frames N..M.
//! - `--garbage CAM [--at-frame N] [--resume-at M]`: random bytes of the right length instead.
//! - `--black CAM [--at-frame N] [--resume-at M]`: black frames (YUYV Y=16, U=V=128).
//! - `--freeze CAM [--at-frame N] [--resume-at M]`: frame N again and again (a frozen sensor
//!   whose driver keeps delivering, with fresh timestamps).
//! - `--format CAM [--as WxH:FOURCC]`: CAM's output format is set to another one from the start
//!   (default: half the size, YUYV) and frames of that size are written.
//!
//! `--timeline FILE` records, per frame index, the CLOCK_REALTIME time it was written (the
//! clock of candump's timestamps) and what each camera got, so the host can count frames
//! between a scenario event and a CAN frame: `INDEX SECONDS LEFT RIGHT`, with LEFT and RIGHT
//! one of `frame`, `skip`, `garbage`, `black`, `frozen`, `format`.

#[path = "../output.rs"]
mod output;

use std::fs::File;
use std::io::{BufWriter, Write};
use std::mem::ManuallyDrop;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, bail, ensure};
use clap::{Parser, ValueEnum};
use flyd::capture::convert::rgb_to_yuyv;
use flyd::mock::MockStereo;
use hw_mock::Scenario;
use v4l::Device;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Camera {
    Left,
    Right,
}

#[derive(Parser, Debug)]
#[command(
    name = "flyd-feeder",
    about = "Plays a hw-mock scenario into two V4L2 loopback cameras"
)]
struct Args {
    /// Output side of the left camera's loopback device.
    #[arg(long)]
    left: String,
    /// Output side of the right camera's loopback device.
    #[arg(long)]
    right: String,
    /// hw-mock scenario: empty-road, pedestrian-4m, pedestrian-steps-in, car-approaching.
    #[arg(long, default_value = "pedestrian-steps-in")]
    scenario: String,
    #[arg(long, default_value_t = 640)]
    width: u32,
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Frames per second written (default: the scenario's, 30). Lower it when the machine
    /// cannot keep up; flyd timestamps frames on capture anyway.
    #[arg(long)]
    fps: Option<f64>,
    /// Frames to write (default: the scenario's length; 0 = until killed). Past the scenario's
    /// end its last scene goes on.
    #[arg(long)]
    frames: Option<u32>,
    /// Render the whole scenario before writing the first frame (for slow machines: writing is
    /// then only a copy per frame).
    #[arg(long)]
    prerender: bool,
    /// Write a line per frame: INDEX REALTIME_SECONDS LEFT RIGHT.
    #[arg(long)]
    timeline: Option<String>,
    /// Stop writing to this camera from --at-frame until --resume-at.
    #[arg(long, conflicts_with_all = ["garbage", "format", "black", "freeze"])]
    stop_camera: Option<Camera>,
    /// Write random bytes (of the right length) to this camera from --at-frame until --resume-at.
    #[arg(long, conflicts_with_all = ["format", "black", "freeze"])]
    garbage: Option<Camera>,
    /// Write black frames to this camera from --at-frame until --resume-at.
    #[arg(long, conflicts_with_all = ["format", "freeze"])]
    black: Option<Camera>,
    /// Write the --at-frame frame again to this camera until --resume-at.
    #[arg(long, conflicts_with = "format")]
    freeze: Option<Camera>,
    /// Give this camera another format from the start (see --as) and frames of that size.
    #[arg(long)]
    format: Option<Camera>,
    /// The wrong format of --format: WxH:FOURCC (YUYV, GREY, RGB3, BGR3). Default: half size,
    /// YUYV.
    #[arg(long = "as", requires = "format")]
    format_as: Option<String>,
    /// Lead-in: write the scenario's first frames over and over (paced, not in the timeline)
    /// until FILE exists, then play the scenario from its start. Lets flyd start and warm up
    /// on the empty first scene however slow the machine is.
    #[arg(long, value_name = "FILE")]
    wait_for: Option<String>,
    /// First frame index of --stop-camera or --garbage.
    #[arg(long, default_value_t = 0)]
    at_frame: u32,
    /// Frame index at which --stop-camera or --garbage ends (default: never).
    #[arg(long)]
    resume_at: Option<u32>,
}

/// What one camera gets at one frame index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Feed {
    Frame,
    Skip,
    Garbage,
    Black,
    Frozen,
    Format,
}

impl Feed {
    fn name(self) -> &'static str {
        match self {
            Feed::Frame => "frame",
            Feed::Skip => "skip",
            Feed::Garbage => "garbage",
            Feed::Black => "black",
            Feed::Frozen => "frozen",
            Feed::Format => "format",
        }
    }
}

/// A wrong output format: size and fourcc, with its bytes per pixel.
struct WrongFormat {
    width: u32,
    height: u32,
    fourcc: [u8; 4],
    bytes_per_pixel: usize,
}

fn parse_format(spec: Option<&str>, width: u32, height: u32) -> Result<WrongFormat> {
    let Some(spec) = spec else {
        return Ok(WrongFormat {
            width: width / 2,
            height: height / 2,
            fourcc: *b"YUYV",
            bytes_per_pixel: 2,
        });
    };
    let (size, code) = spec
        .split_once(':')
        .with_context(|| format!("--as {spec:?}: expected WxH:FOURCC"))?;
    let (w, h) = size
        .split_once('x')
        .with_context(|| format!("--as {spec:?}: expected WxH:FOURCC"))?;
    let fourcc: [u8; 4] = code
        .as_bytes()
        .try_into()
        .with_context(|| format!("--as {spec:?}: FOURCC has four characters"))?;
    let bytes_per_pixel = match &fourcc {
        b"YUYV" | b"UYVY" => 2,
        b"GREY" => 1,
        b"RGB3" | b"BGR3" => 3,
        _ => bail!("--as {spec:?}: FOURCC one of YUYV, UYVY, GREY, RGB3, BGR3"),
    };
    Ok(WrongFormat {
        width: w.parse().context("--as width")?,
        height: h.parse().context("--as height")?,
        fourcc,
        bytes_per_pixel,
    })
}

/// One loopback device, opened for output with its format set.
struct Sink {
    path: String,
    _dev: Device,
    out: ManuallyDrop<File>,
    frame_len: usize,
}

impl Sink {
    fn open(path: &str, width: u32, height: u32, fourcc: [u8; 4], bpp: usize) -> Result<Sink> {
        // `dev` lives as long as `out` in this struct.
        let (dev, out, got) = output::open_output(path, width, height, &fourcc)?;
        eprintln!("flyd-feeder: {path} output format {got}");
        Ok(Sink {
            path: path.to_string(),
            _dev: dev,
            out,
            frame_len: width as usize * height as usize * bpp,
        })
    }

    fn write(&mut self, frame: &[u8]) -> Result<()> {
        debug_assert_eq!(frame.len(), self.frame_len);
        self.out
            .write_all(frame)
            .with_context(|| format!("writing a frame to {}", self.path))
    }
}

/// The scenario's frames as YUYV, rendered on demand or all in advance.
struct Frames {
    stereo: MockStereo,
    width: usize,
    frame_len: usize,
    prerendered: Vec<[Vec<u8>; 2]>,
    current: [Vec<u8>; 2],
}

/// Frames the lead-in cycles through (each with its own noise).
const LEAD_IN_FRAMES: u32 = 8;

/// Past the end of a pre-rendered scenario, its last frames play again (the last scene is still).
const LOOP_FRAMES: u32 = 30;

impl Frames {
    fn new(stereo: MockStereo) -> Frames {
        let (w, h) = stereo.size();
        let frame_len = w as usize * h as usize * 2;
        Frames {
            stereo,
            width: w as usize,
            frame_len,
            prerendered: Vec::new(),
            current: [vec![0; frame_len], vec![0; frame_len]],
        }
    }

    fn render(&mut self, index: u32) -> Result<[Vec<u8>; 2]> {
        let mut out = [vec![0; self.frame_len], vec![0; self.frame_len]];
        self.render_into(index, &mut out)?;
        Ok(out)
    }

    fn render_into(&mut self, index: u32, out: &mut [Vec<u8>; 2]) -> Result<()> {
        let (l, r) = self
            .stereo
            .frame(index)
            .with_context(|| format!("rendering frame {index}"))?;
        rgb_to_yuyv(l, self.width, &mut out[0]).context("YUYV of the left frame")?;
        rgb_to_yuyv(r, self.width, &mut out[1]).context("YUYV of the right frame")?;
        Ok(())
    }

    fn prerender(&mut self) -> Result<()> {
        let n = self.stereo.scenario().frame_count();
        let started = Instant::now();
        self.prerendered = (0..n).map(|i| self.render(i)).collect::<Result<_>>()?;
        eprintln!(
            "flyd-feeder: pre-rendered {n} frames in {:.1} s",
            started.elapsed().as_secs_f64()
        );
        Ok(())
    }

    /// Frame `index` for both cameras.
    fn get(&mut self, index: u32) -> Result<&[Vec<u8>; 2]> {
        let n = self.prerendered.len() as u32;
        if n == 0 {
            let mut current = std::mem::take(&mut self.current);
            let result = self.render_into(index, &mut current);
            self.current = current;
            result?;
            return Ok(&self.current);
        }
        let i = if index < n {
            index
        } else {
            let k = LOOP_FRAMES.min(n);
            n - k + (index - n) % k
        };
        Ok(&self.prerendered[i as usize])
    }
}

/// Random bytes from splitmix64: garbage that differs per frame and camera.
fn garbage(buf: &mut [u8], index: u32, camera: usize) {
    let mut state = (u64::from(index) << 8) | camera as u64;
    for chunk in buf.chunks_mut(8) {
        state = hw_mock::splitmix64(state);
        chunk.copy_from_slice(&state.to_le_bytes()[..chunk.len()]);
    }
}

fn realtime() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let scenario = Scenario::by_name(&args.scenario).with_context(|| {
        format!(
            "unknown scenario {:?}; one of {:?}",
            args.scenario,
            Scenario::names()
        )
    })?;
    ensure!(args.width % 2 == 0, "--width must be even for YUYV");
    let fps = args.fps.unwrap_or(scenario.fps());
    ensure!(fps > 0.0 && fps.is_finite(), "--fps must be positive");
    let frames = args.frames.unwrap_or(scenario.frame_count());
    let fault = args
        .stop_camera
        .or(args.garbage)
        .or(args.black)
        .or(args.freeze)
        .or(args.format);
    let fault_feed = if args.stop_camera.is_some() {
        Feed::Skip
    } else if args.garbage.is_some() {
        Feed::Garbage
    } else if args.black.is_some() {
        Feed::Black
    } else if args.freeze.is_some() {
        Feed::Frozen
    } else {
        Feed::Format
    };
    let wrong = parse_format(args.format_as.as_deref(), args.width, args.height)?;

    let started = Instant::now();
    let stereo = MockStereo::new(scenario.clone(), args.width, args.height)
        .context("building the mock rig")?;
    let mut source = Frames::new(stereo);
    eprintln!(
        "flyd-feeder: {} ({} frames at {} fps, first obstacle at frame {:?}), {}x{}, writing {} \
         frames at {fps} fps; rig ready in {:.1} s",
        scenario.name(),
        scenario.frame_count(),
        scenario.fps(),
        scenario.first_obstacle_frame(),
        args.width,
        args.height,
        if frames == 0 {
            "unlimited".to_string()
        } else {
            frames.to_string()
        },
        started.elapsed().as_secs_f64()
    );
    if args.prerender {
        source.prerender()?;
    }

    let mut sinks = Vec::new();
    for (camera, path) in [(Camera::Left, &args.left), (Camera::Right, &args.right)] {
        sinks.push(if args.format == Some(camera) {
            Sink::open(
                path,
                wrong.width,
                wrong.height,
                wrong.fourcc,
                wrong.bytes_per_pixel,
            )?
        } else {
            Sink::open(path, args.width, args.height, *b"YUYV", 2)?
        });
    }
    let mut scratch: Vec<Vec<u8>> = sinks.iter().map(|s| vec![0; s.frame_len]).collect();
    let mut timeline = match &args.timeline {
        Some(path) => Some(BufWriter::new(
            File::create(path).with_context(|| format!("creating {path}"))?,
        )),
        None => None,
    };

    let period = Duration::from_secs_f64(1.0 / fps);
    if let Some(file) = &args.wait_for {
        let start = Instant::now();
        let mut n: u32 = 0;
        // The scenario's first frames in turn, not frame 0 alone: each has its own sensor
        // noise, as a live camera filming a still scene (one image again and again is a
        // frozen camera to flyd). They show the first scene: none is past the first obstacle.
        let lead_in = scenario
            .first_obstacle_frame()
            .filter(|&f| f > 0)
            .unwrap_or(u32::MAX)
            .min(scenario.frame_count())
            .clamp(1, LEAD_IN_FRAMES);
        while !std::path::Path::new(file).exists() {
            let pair = source.get(n % lead_in)?;
            for c in 0..2 {
                if sinks[c].frame_len == pair[c].len() {
                    sinks[c].write(&pair[c])?;
                } else {
                    garbage(&mut scratch[c], n, c);
                    sinks[c].write(&scratch[c])?;
                }
            }
            if n == 0 {
                eprintln!(
                    "flyd-feeder: lead-in: first frame written; frames 0..{lead_in} until {file} exists"
                );
            }
            n += 1;
            if let Some(wait) = period.mul_f64(f64::from(n)).checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        eprintln!(
            "flyd-feeder: lead-in: {n} frames in {:.1} s; {file} exists, playing",
            start.elapsed().as_secs_f64()
        );
    }
    let start = Instant::now();
    let mut last_feed = [Feed::Frame; 2];
    let mut index: u32 = 0;
    while frames == 0 || index < frames {
        let faulty = index >= args.at_frame && args.resume_at.is_none_or(|m| index < m);
        let mut feeds = [Feed::Frame; 2];
        for (c, camera) in [Camera::Left, Camera::Right].into_iter().enumerate() {
            if fault == Some(camera) && (fault_feed == Feed::Format || faulty) {
                feeds[c] = fault_feed;
            }
        }
        let pair = source.get(index)?;
        for c in 0..2 {
            match feeds[c] {
                Feed::Frame => sinks[c].write(&pair[c])?,
                Feed::Skip => {}
                Feed::Black => {
                    for px in scratch[c].chunks_exact_mut(2) {
                        px.copy_from_slice(&[16, 128]);
                    }
                    sinks[c].write(&scratch[c])?;
                }
                Feed::Frozen => {
                    // The first frozen frame is the real one; then it is written again.
                    if last_feed[c] != Feed::Frozen {
                        scratch[c].copy_from_slice(&pair[c]);
                    }
                    sinks[c].write(&scratch[c])?;
                }
                Feed::Garbage | Feed::Format => {
                    garbage(&mut scratch[c], index, c);
                    sinks[c].write(&scratch[c])?;
                }
            }
            if feeds[c] != last_feed[c] || index == 0 {
                eprintln!(
                    "flyd-feeder: frame {index}: {} camera ({}) gets {}",
                    ["left", "right"][c],
                    sinks[c].path,
                    feeds[c].name()
                );
            }
        }
        last_feed = feeds;
        if let Some(t) = timeline.as_mut() {
            writeln!(
                t,
                "{index} {:.6} {} {}",
                realtime(),
                feeds[0].name(),
                feeds[1].name()
            )?;
            t.flush()?;
        }
        if index == 0 {
            eprintln!("flyd-feeder: first frame written");
        } else if index.is_multiple_of(150) {
            eprintln!(
                "flyd-feeder: frame {index}, {:.1} fps",
                f64::from(index) / start.elapsed().as_secs_f64()
            );
        }
        index += 1;
        // Pace against the start, so a slow write does not stretch the whole run.
        if let Some(wait) = period
            .mul_f64(f64::from(index))
            .checked_sub(start.elapsed())
        {
            std::thread::sleep(wait);
        }
    }
    eprintln!(
        "flyd-feeder: wrote {index} frames in {:.1} s ({:.1} fps)",
        start.elapsed().as_secs_f64(),
        f64::from(index) / start.elapsed().as_secs_f64()
    );
    Ok(())
}
