//! The raw `[cameras]` table: the devices or the mock scenario, image size, frame rate, pixel
//! format, channels, pairing tolerance, staleness and the mock's injected faults.

use std::path::PathBuf;

use serde::Deserialize;

use super::{Invalid, bad, millis};
use crate::capture::CaptureFormat;
use crate::config::{CameraSource, CamerasConfig, Channels};
use crate::mock::camera::{MAX_MOCK_FAULTS, MockFault};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCameras {
    left: Option<PathBuf>,
    right: Option<PathBuf>,
    mock: Option<String>,
    width: u32,
    height: u32,
    fps: f64,
    #[serde(default = "default_pixel_format")]
    pixel_format: CaptureFormat,
    #[serde(default)]
    channels: Channels,
    #[serde(default = "default_tolerance_ms")]
    timestamp_tolerance_ms: f64,
    #[serde(default = "default_stale_frames")]
    stale_frames: u32,
    #[serde(default)]
    mock_faults: Vec<MockFault>,
    #[serde(default)]
    mock_loop: bool,
}

fn default_pixel_format() -> CaptureFormat {
    CaptureFormat::Yuyv
}
fn default_tolerance_ms() -> f64 {
    10.0
}
fn default_stale_frames() -> u32 {
    3
}

/// Image sizes and frame rates a configuration may ask for.
const MIN_WIDTH: u32 = 160;
const MIN_HEIGHT: u32 = 120;
const MAX_SIDE: u32 = 4096;
const MIN_FPS: f64 = 5.0;
const MAX_FPS: f64 = 120.0;
/// Longest a camera may deliver nothing before it is stale, seconds.
const MAX_STALE_S: f64 = 1.0;

impl RawCameras {
    pub(super) fn resolve(self) -> Result<CamerasConfig, Invalid> {
        let source = match (self.left, self.right, self.mock) {
            (None, None, Some(scenario)) => {
                match hw_mock::Scenario::by_name(&scenario) {
                    None => {
                        return bad(
                            "cameras.mock",
                            format!(
                                "unknown scenario '{scenario}' (known: {})",
                                hw_mock::Scenario::names().join(", ")
                            ),
                        );
                    }
                    Some(s) if !s.live() => {
                        return bad(
                            "cameras.mock",
                            format!(
                                "scenario '{scenario}' renders every frame in full, a few a \
                                 second: use it with `flyd replay --scenario`, not as a live \
                                 camera"
                            ),
                        );
                    }
                    Some(_) => {}
                }
                if self.mock_faults.len() > MAX_MOCK_FAULTS {
                    return bad(
                        "cameras.mock_faults",
                        format!(
                            "at most {MAX_MOCK_FAULTS} faults, got {}",
                            self.mock_faults.len()
                        ),
                    );
                }
                for (i, f) in self.mock_faults.iter().enumerate() {
                    if let Err(reason) = f.check() {
                        return bad(&format!("cameras.mock_faults[{i}]"), reason);
                    }
                }
                CameraSource::Mock {
                    scenario,
                    faults: self.mock_faults,
                    looped: self.mock_loop,
                }
            }
            (Some(left), Some(right), None) => {
                if self.mock_loop {
                    return bad(
                        "cameras.mock_loop",
                        "loops mock cameras only (cameras.mock)",
                    );
                }
                if !self.mock_faults.is_empty() {
                    return bad(
                        "cameras.mock_faults",
                        "faults are injected into mock cameras only (cameras.mock)",
                    );
                }
                if left == right {
                    return bad("cameras.right", "must be another device than cameras.left");
                }
                CameraSource::Devices { left, right }
            }
            (_, _, Some(_)) => {
                return bad(
                    "cameras.mock",
                    "give either mock = \"scenario\" or left and right devices, not both",
                );
            }
            (None, _, None) => return bad("cameras.left", "missing (or give cameras.mock)"),
            (_, None, None) => return bad("cameras.right", "missing (or give cameras.mock)"),
        };
        // Smaller images cannot resolve a pedestrian at the stopping distance; larger ones are
        // more than a capture thread prepares in a frame period.
        if !(MIN_WIDTH..=MAX_SIDE).contains(&self.width) {
            return bad(
                "cameras.width",
                format!(
                    "must be within {MIN_WIDTH}..={MAX_SIDE}, got {}",
                    self.width
                ),
            );
        }
        if !(MIN_HEIGHT..=MAX_SIDE).contains(&self.height) {
            return bad(
                "cameras.height",
                format!(
                    "must be within {MIN_HEIGHT}..={MAX_SIDE}, got {}",
                    self.height
                ),
            );
        }
        // Under 5 fps the vehicle travels 1.7 m between frames at 30 km/h and the debounce
        // of two frames alone takes 0.4 s.
        if !(self.fps.is_finite() && (MIN_FPS..=MAX_FPS).contains(&self.fps)) {
            return bad(
                "cameras.fps",
                format!("must be within {MIN_FPS}..={MAX_FPS}, got {}", self.fps),
            );
        }
        if matches!(source, CameraSource::Devices { .. }) {
            if self.fps.fract() != 0.0 {
                return bad(
                    "cameras.fps",
                    format!(
                        "V4L2 devices take a whole number of frames per second, got {}",
                        self.fps
                    ),
                );
            }
            if self.pixel_format == CaptureFormat::Grey && self.channels == Channels::Colour {
                return bad(
                    "cameras.channels",
                    "\"colour\" from a GREY camera: it sends luma only",
                );
            }
            if self.pixel_format == CaptureFormat::Yuyv && !self.width.is_multiple_of(2) {
                return bad(
                    "cameras.width",
                    format!(
                        "{} is odd; YUYV carries pixels in pairs (an even width)",
                        self.width
                    ),
                );
            }
        }
        let tolerance = millis(
            "cameras.timestamp_tolerance_ms",
            self.timestamp_tolerance_ms,
        )?;
        // The stale-camera fault must come well within the watchdog (WatchdogSec=2s).
        let stale_s = f64::from(self.stale_frames) / self.fps;
        if !(1..=30).contains(&self.stale_frames) || stale_s > MAX_STALE_S {
            return bad(
                "cameras.stale_frames",
                format!(
                    "must be within 1..=30 and at most {MAX_STALE_S} s of frames ({} frames at {} \
                     fps is {stale_s:.3} s)",
                    self.stale_frames, self.fps
                ),
            );
        }
        Ok(CamerasConfig {
            source,
            width: self.width,
            height: self.height,
            fps: self.fps,
            pixel_format: self.pixel_format,
            channels: self.channels,
            timestamp_tolerance: tolerance,
            stale_frames: self.stale_frames,
        })
    }
}
