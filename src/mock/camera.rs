//! hw-mock scenarios as two [`FrameSource`]s, for the demo, the tests and the end-to-end bench.
//!
//! Both cameras share one [`MockStereo`] renderer (a frame pair is rendered once, by whichever
//! capture thread asks first; the other copies its image from the cache). Frame `k` is due at
//! `start + k / fps` on the daemon clock and stamped with that time on both cameras, so the
//! pairs are exactly synchronised, like hardware-triggered cameras. A camera that falls behind
//! (a slow debug build) skips to the frame due now, and the other follows it, rather than
//! delivering an ever older backlog. After the scenario's last frame: end of stream.
//!
//! Faults can be injected per camera over a time window ([`MockFault`], `[[cameras.mock_faults]]`
//! in the configuration): black, white or grey frames, a frozen image, noise, a dark gain,
//! dropped frames. They stand for the sensor failures the daemon must not take for a clear
//! road (see [`flyd_core::sensor`]).
//!
//! The lock between the two capture threads is the mock's business (it stands for the shared
//! trigger of two real cameras); the evolution thread never touches it.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use hw_mock::Scenario;
use serde::Deserialize;

use super::{MockError, MockStereo};
use crate::os_clock::SharedClock;
use crate::source::{FrameMeta, FrameSource, Side, SourceError};
use flyd_core::frame::{PixelFormat, PreparedImage};

/// What both cameras share.
struct Feed {
    stereo: MockStereo,
    /// Index of the cached pair (`None` before the first).
    cached: Option<u32>,
    left: Vec<u8>,
    right: Vec<u8>,
    /// Capture time of the first delivered frame with an obstacle in the lane.
    first_obstacle_at: Option<Duration>,
}

/// Ground truth of a mock run, readable while it runs.
#[derive(Clone)]
pub struct MockTruth(Arc<Mutex<Feed>>, Option<u32>);

impl MockTruth {
    /// Capture timestamp of the first frame delivered that shows an obstacle in the lane (the
    /// start of a reaction-time measurement).
    pub fn first_obstacle_at(&self) -> Option<Duration> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .first_obstacle_at
    }

    /// The scenario's first frame with an obstacle in the lane.
    pub fn first_obstacle_frame(&self) -> Option<u32> {
        self.1
    }
}

pub struct MockCamera {
    name: String,
    side: Side,
    feed: Arc<Mutex<Feed>>,
    clock: SharedClock,
    start: Duration,
    period: Duration,
    /// Frames delivered before the end of the stream (the scenario's, or all when looped).
    frames: u32,
    /// The scenario's frames: frame `k` shows the scenario's frame `k % scenario_frames`.
    scenario_frames: u32,
    first_obstacle: Option<u32>,
    /// Next frame this camera wants.
    next: u32,
    /// The image delivered last (a frozen fault delivers it again).
    pixels: Vec<u8>,
    size: (u32, u32),
    /// The faults that concern this camera.
    faults: Vec<MockFault>,
    /// Delivers its frames as an MJPEG camera does ([`MockCamera::deliver_mjpeg`]).
    mjpeg: Option<MockMjpeg>,
}

/// An MJPEG camera's path for a mock one: each rendered frame JPEG-encoded (the camera's
/// encoder), then decoded and prepared by the converter V4L2 MJPEG frames go through.
struct MockMjpeg {
    jpeg: Vec<u8>,
    converter: crate::capture::FrameConverter,
}

/// JPEG quality of a mock MJPEG camera (what UVC cameras deliver at 640x480).
const MOCK_JPEG_QUALITY: u8 = 85;

/// What an injected fault does to a mock camera's frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultKind {
    /// All pixels 0 (lens covered, sensor dead).
    Black,
    /// All pixels 255 (saturated: sun in the lens, exposure stuck).
    White,
    /// All pixels 128 (a driver's blank frame).
    Grey,
    /// The last image again, with fresh timestamps (frozen sensor, stuck buffer).
    Frozen,
    /// Uniform random bytes (a broken link, interference).
    Noise,
    /// The image times `gain` (exposure or gain stuck low).
    Dark,
    /// No frame at all (the device delivers nothing).
    Drop,
}

/// Which camera a fault hits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultCamera {
    Left,
    Right,
    Both,
}

/// One injected fault: `kind` on `camera` for frames due in `[from_s, to_s)` seconds after
/// the mock's start.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MockFault {
    pub kind: FaultKind,
    pub camera: FaultCamera,
    pub from_s: f64,
    pub to_s: f64,
    /// The gain of a `dark` fault, in (0, 1].
    #[serde(default = "default_dark_gain")]
    pub gain: f64,
}

fn default_dark_gain() -> f64 {
    0.1
}

/// Most faults one run takes (a test needs a few).
pub const MAX_MOCK_FAULTS: usize = 32;

impl MockFault {
    /// Why this fault cannot be injected, if it cannot.
    pub fn check(&self) -> Result<(), String> {
        let ok = |v: f64| v.is_finite() && (0.0..=86_400.0).contains(&v);
        if !(ok(self.from_s) && ok(self.to_s) && self.from_s < self.to_s) {
            return Err(format!(
                "from_s and to_s must be seconds within 0..=86400 with from_s < to_s, got {} and {}",
                self.from_s, self.to_s
            ));
        }
        if !(self.gain.is_finite() && self.gain > 0.0 && self.gain <= 1.0) {
            return Err(format!("gain must be within (0, 1], got {}", self.gain));
        }
        Ok(())
    }

    fn hits(&self, side: Side) -> bool {
        matches!(
            (self.camera, side),
            (FaultCamera::Both, _)
                | (FaultCamera::Left, Side::Left)
                | (FaultCamera::Right, Side::Right)
        )
    }

    fn active_at(&self, t: Duration) -> bool {
        let t = t.as_secs_f64();
        self.from_s <= t && t < self.to_s
    }
}

/// The two cameras of `scenario` through the mock rig at `width` x `height`, paced on `clock`
/// at the scenario's frame rate from now on.
pub fn mock_cameras(
    scenario: &str,
    width: u32,
    height: u32,
    clock: &SharedClock,
    faults: &[MockFault],
) -> Result<(MockCamera, MockCamera, MockTruth), MockCameraError> {
    let scenario = Scenario::by_name(scenario).ok_or_else(|| MockCameraError::UnknownScenario {
        name: scenario.to_string(),
        known: Scenario::names().join(", "),
    })?;
    let period = Duration::from_secs_f64(1.0 / scenario.fps());
    let frames = scenario.frame_count();
    let first_obstacle = scenario.first_obstacle_frame();
    let stereo = MockStereo::new(scenario, width, height)?;
    let bytes = width as usize * height as usize * 3;
    let feed = Arc::new(Mutex::new(Feed {
        stereo,
        cached: None,
        left: vec![0; bytes],
        right: vec![0; bytes],
        first_obstacle_at: None,
    }));
    let start = clock.now();
    let camera = |side: Side| MockCamera {
        name: format!("mock:{}", side.name()),
        side,
        feed: feed.clone(),
        clock: clock.clone(),
        start,
        period,
        frames,
        scenario_frames: frames.max(1),
        first_obstacle,
        next: 0,
        pixels: vec![0; bytes],
        size: (width, height),
        faults: faults.iter().copied().filter(|f| f.hits(side)).collect(),
        mjpeg: None,
    };
    Ok((
        camera(Side::Left),
        camera(Side::Right),
        MockTruth(feed.clone(), first_obstacle),
    ))
}

#[derive(Debug, thiserror::Error)]
pub enum MockCameraError {
    #[error("unknown mock scenario '{name}' (known: {known})")]
    UnknownScenario { name: String, known: String },
    #[error("mock MJPEG camera")]
    Mjpeg(#[source] crate::capture::ConvertError),
    #[error("mock stereo feed")]
    Mock(#[from] MockError),
}

impl MockCamera {
    fn due(&self, k: u32) -> Duration {
        self.start + self.period * k
    }

    /// The fault active on frame `k`, if any (the first one listed).
    fn fault_at(&self, k: u32) -> Option<MockFault> {
        let t = self.due(k).saturating_sub(self.start);
        self.faults.iter().copied().find(|f| f.active_at(t))
    }

    /// Applies `fault` to the image just fetched.
    fn inject(&mut self, fault: MockFault, k: u32) {
        match fault.kind {
            FaultKind::Black => self.pixels.fill(0),
            FaultKind::White => self.pixels.fill(255),
            FaultKind::Grey => self.pixels.fill(128),
            // The image was not refreshed (`fetch`); dropped frames are not delivered at all.
            FaultKind::Frozen | FaultKind::Drop => {}
            FaultKind::Noise => {
                let seed = u64::from(k) << 1 | matches!(self.side, Side::Right) as u64;
                for (i, v) in self.pixels.iter_mut().enumerate() {
                    *v = hw_mock::splitmix64(seed.wrapping_mul(0x1_0000_0001) ^ i as u64) as u8;
                }
            }
            FaultKind::Dark => {
                let gain = fault.gain;
                for v in &mut self.pixels {
                    *v = (f64::from(*v) * gain).round() as u8;
                }
            }
        }
    }

    /// Renders (or takes from the cache) the pair this camera should deliver next, copies its
    /// image out, and returns its index.
    fn fetch(&mut self, now: Duration) -> Result<u32, SourceError> {
        let mut feed = self.feed.lock().unwrap_or_else(PoisonError::into_inner);
        let k = match feed.cached {
            // The other camera already rendered this frame or a later one: follow it.
            Some(c) if c >= self.next => c,
            _ => {
                let elapsed = now.saturating_sub(self.start);
                let due_now = (elapsed.as_nanos() / self.period.as_nanos().max(1)) as u32;
                let k = self.next.max(due_now);
                if k >= self.frames {
                    return Err(SourceError::EndOfStream);
                }
                let feed = &mut *feed;
                let (l, r) = feed.stereo.frame(k % self.scenario_frames).map_err(|e| {
                    SourceError::Format {
                        device: self.name.clone(),
                        reason: format!("rendering frame {k}"),
                        cause: Some(e.into()),
                    }
                })?;
                feed.left.copy_from_slice(l);
                feed.right.copy_from_slice(r);
                feed.cached = Some(k);
                k
            }
        };
        let src = match self.side {
            Side::Left => &feed.left,
            Side::Right => &feed.right,
        };
        let fault = self.fault_at(k);
        // A frozen camera delivers its last image again.
        if fault.is_none_or(|f| f.kind != FaultKind::Frozen) {
            self.pixels.copy_from_slice(src);
        }
        if self.first_obstacle.is_some_and(|f| k >= f) && feed.first_obstacle_at.is_none() {
            feed.first_obstacle_at = Some(self.due(k));
        }
        drop(feed);
        if let Some(f) = fault {
            self.inject(f, k);
        }
        Ok(k)
    }
}

impl MockCamera {
    /// The scenario plays again from its first frame when it ends, for ever (frame indices
    /// go on counting): a daemon on mock cameras that runs until it is stopped.
    pub fn play_in_a_loop(&mut self) {
        self.frames = u32::MAX;
    }

    /// From now on, frames come as an MJPEG camera delivers them: JPEG-encoded on this
    /// capture thread, decoded and prepared by [`crate::capture::FrameConverter`] (the V4L2
    /// MJPEG path; `cameras.pixel_format = "MJPG"` with mock cameras).
    pub fn deliver_mjpeg(&mut self) -> Result<(), crate::capture::ConvertError> {
        let (w, h) = self.size;
        let max = w as usize * h as usize * 3;
        let converter = crate::capture::FrameConverter::new(
            crate::capture::CaptureFormat::Mjpg,
            w,
            h,
            0,
            PixelFormat::Rgb8,
            max,
        )?;
        self.mjpeg = Some(MockMjpeg {
            jpeg: Vec::with_capacity(max),
            converter,
        });
        Ok(())
    }
}

impl FrameSource for MockCamera {
    fn name(&self) -> &str {
        &self.name
    }

    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn next_frame(
        &mut self,
        out: &mut PreparedImage,
        timeout: Duration,
    ) -> Result<FrameMeta, SourceError> {
        if self.next >= self.frames {
            return Err(SourceError::EndOfStream);
        }
        // Render ahead, then deliver at the due time: the frame is stamped with its due time
        // and handed over then, like a camera stamping the end of its readout (V4L2's
        // TSTAMP_SRC_EOF). The time the mock spends ray-casting is a cost of the simulation,
        // not a latency of the daemon, so it stays out of the reaction measured from the stamp.
        // A camera called late skips to the frame due now (rendered now: it is already late).
        let now = self.clock.now();
        let due = self.due(self.next);
        let k = if due > now {
            let wait = due - now;
            if wait > timeout {
                std::thread::sleep(timeout);
                return Err(SourceError::Timeout(timeout));
            }
            let k = self.fetch(now)?;
            let left = self.due(k).saturating_sub(self.clock.now());
            if !left.is_zero() {
                std::thread::sleep(left);
            }
            k
        } else {
            self.fetch(now)?
        };
        if self.fault_at(k).is_some_and(|f| f.kind == FaultKind::Drop) {
            // The frame is lost: nothing within this wait.
            self.next = k + 1;
            return Err(SourceError::Timeout(timeout));
        }
        let (w, h) = self.size;
        let prepared = match self.mjpeg.as_mut() {
            None => out
                .prepare(PixelFormat::Rgb8, &self.pixels)
                .map_err(|e| e.into()),
            Some(m) => {
                m.jpeg.clear();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut m.jpeg, MOCK_JPEG_QUALITY)
                    .encode(&self.pixels, w, h, image::ExtendedColorType::Rgb8)
                    .map_err(|e| -> Box<dyn std::error::Error + Send + Sync> { e.into() })
                    .and_then(|()| m.converter.prepare(&m.jpeg, out).map_err(|e| e.into()))
            }
        };
        prepared.map_err(|cause| SourceError::Format {
            device: self.name.clone(),
            reason: "preparing a frame".into(),
            cause: Some(cause),
        })?;
        self.next = k + 1;
        Ok(FrameMeta {
            timestamp: self.due(k),
            sequence: u64::from(k),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flyd_core::clock::ManualClock;

    #[test]
    fn both_cameras_deliver_the_same_frames_with_the_same_timestamps() {
        let clock = ManualClock::new(Duration::from_secs(100));
        let shared: SharedClock = Arc::new(clock.clone());
        let (mut l, mut r, truth) =
            mock_cameras("pedestrian-steps-in", 64, 48, &shared, &[]).expect("scenario");
        let mut img = PreparedImage::new(64, 48).expect("image");
        let t = Duration::from_millis(1);
        let a = l.next_frame(&mut img, t).expect("frame 0");
        let b = r.next_frame(&mut img, t).expect("frame 0");
        assert_eq!((a, b.sequence), (b, 0));
        assert!(matches!(
            l.next_frame(&mut img, t),
            Err(SourceError::Timeout(_))
        ));
        // The clock jumps 10 frames: the left camera skips to the frame due now, the right
        // one follows it.
        clock.advance(Duration::from_millis(340));
        let a = l.next_frame(&mut img, t).expect("frame");
        let b = r.next_frame(&mut img, t).expect("frame");
        assert_eq!(a.sequence, 10);
        assert_eq!(a, b);
        assert_eq!(truth.first_obstacle_frame(), Some(30));
        assert_eq!(truth.first_obstacle_at(), None);
        clock.advance(Duration::from_secs(1));
        l.next_frame(&mut img, t).expect("frame");
        assert_eq!(
            truth.first_obstacle_at(),
            Some(Duration::from_secs(100) + Duration::from_secs_f64(1.0 / 30.0) * 40)
        );
        clock.advance(Duration::from_secs(10));
        assert!(matches!(
            l.next_frame(&mut img, t),
            Err(SourceError::EndOfStream)
        ));
        // The right camera still delivers the pair the left one took, then ends too.
        assert_eq!(r.next_frame(&mut img, t).map(|m| m.sequence).ok(), Some(40));
        assert!(matches!(
            r.next_frame(&mut img, t),
            Err(SourceError::EndOfStream)
        ));
        assert!(mock_cameras("nope", 64, 48, &shared, &[]).is_err());
    }
}
