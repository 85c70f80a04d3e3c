//! A capture thread: one camera's [`FrameSource`] into its [`FrameWriter`].
//!
//! The loop never waits on anyone but the camera: it prepares each frame straight into the
//! ring's write slot and publishes it (one atomic swap). A dequeue waits at most
//! `poll_timeout`, so an unplugged camera is noticed (its frames stop: the control thread's
//! stale-camera fault) and a stop request is seen. Device errors (disconnect, wrong format) are
//! logged once per episode, flagged for the CAMERA_ERROR fault, and the device is reopened with
//! exponential backoff until it delivers again. End of stream (a finished mock scenario) asks
//! the daemon to end. Each frame is measured for the sensor checks ([`ImageCheck`]: contrast,
//! texture, whether it repeats the previous one; a sampled pass, about 20 us at 640x480) and
//! the result published with it.

use flyd_core::chain::Chain;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use super::ring::FrameWriter;
use crate::os_clock::SharedClock;
use crate::source::Side;
use crate::source::{FrameSource, SourceError};
use crate::thread::Shutdown;
use flyd_core::sensor::ImageCheck;

/// What the control thread reads about a camera (lock-free, `Relaxed`: statistics and
/// timestamps, nothing is synchronised through them).
#[derive(Debug)]
pub struct CameraHealth {
    /// Arrival time (daemon clock, ns) of the newest frame; `u64::MAX` before the first one.
    last_frame_ns: AtomicU64,
    error: AtomicBool,
    timeouts: AtomicU64,
    errors: AtomicU64,
    end_of_stream: AtomicBool,
}

impl Default for CameraHealth {
    fn default() -> Self {
        Self {
            last_frame_ns: AtomicU64::new(u64::MAX),
            error: AtomicBool::new(false),
            timeouts: AtomicU64::new(0),
            errors: AtomicU64::new(0),
            end_of_stream: AtomicBool::new(false),
        }
    }
}

impl CameraHealth {
    pub fn last_frame_at(&self) -> Option<Duration> {
        match self.last_frame_ns.load(Ordering::Relaxed) {
            u64::MAX => None,
            ns => Some(Duration::from_nanos(ns)),
        }
    }
    pub fn has_error(&self) -> bool {
        self.error.load(Ordering::Relaxed)
    }
    pub fn timeouts(&self) -> u64 {
        self.timeouts.load(Ordering::Relaxed)
    }
    pub fn errors(&self) -> u64 {
        self.errors.load(Ordering::Relaxed)
    }
    pub fn end_of_stream(&self) -> bool {
        self.end_of_stream.load(Ordering::Relaxed)
    }
}

pub struct CaptureThread {
    pub side: Side,
    pub source: Box<dyn FrameSource>,
    pub writer: FrameWriter,
    pub health: Arc<CameraHealth>,
    pub clock: SharedClock,
    pub poll_timeout: Duration,
    /// Threads stop when set.
    pub stop: Shutdown,
    /// Set to end the daemon (end of stream).
    pub finish: Shutdown,
    /// Gets a copy of every frame as prepared (never waits: a full queue drops it).
    pub recorder: Option<crate::record::Recorder>,
    /// The right camera's row correction in force ([`super::rows`]), given to each frame
    /// before it is prepared; `None` for the left camera.
    pub row_shift: Option<super::rows::SharedRowShift>,
}

const BACKOFF_MIN: Duration = Duration::from_millis(50);
const BACKOFF_MAX: Duration = Duration::from_secs(2);

impl CaptureThread {
    pub fn run(mut self) {
        let camera = self.source.name().to_string();
        let side = self.side.name();
        let mut backoff = BACKOFF_MIN;
        let mut in_error = false;
        let mut logged_error = String::new();
        let (w, h) = self.source.size();
        let mut check = ImageCheck::new(w, h);
        while !self.stop.is_requested() {
            let slot = self.writer.slot();
            if let Some(shift) = &self.row_shift {
                slot.image.set_row_shift(shift.get());
            }
            match self.source.next_frame(&mut slot.image, self.poll_timeout) {
                Ok(meta) => {
                    let now = self.clock.now();
                    slot.meta = meta;
                    slot.arrival = now;
                    slot.health = check.observe(&slot.image);
                    if let Some(recorder) = &self.recorder
                        && let Some(frame) = slot.image.pixels()
                    {
                        recorder.frame(self.side, meta.timestamp, (w, h), frame);
                    }
                    self.writer.publish();
                    let ns = u64::try_from(now.as_nanos()).unwrap_or(u64::MAX - 1);
                    self.health.last_frame_ns.store(ns, Ordering::Relaxed);
                    if in_error {
                        tracing::info!(camera, side, "camera delivers again");
                        self.health.error.store(false, Ordering::Relaxed);
                        in_error = false;
                        backoff = BACKOFF_MIN;
                    }
                }
                Err(SourceError::Timeout(_)) => {
                    self.health.timeouts.fetch_add(1, Ordering::Relaxed);
                }
                Err(e @ SourceError::Corrupt { .. }) => {
                    self.health.errors.fetch_add(1, Ordering::Relaxed);
                    tracing::debug!(camera, side, error = %Chain(&e), "corrupt frame skipped");
                }
                Err(SourceError::EndOfStream) => {
                    tracing::info!(camera, side, "end of stream: ending the run");
                    self.health.end_of_stream.store(true, Ordering::Relaxed);
                    self.finish.request();
                    break;
                }
                Err(e) => {
                    self.health.errors.fetch_add(1, Ordering::Relaxed);
                    self.health.error.store(true, Ordering::Relaxed);
                    if !in_error {
                        tracing::warn!(
                            camera, side, error = %Chain(&e),
                            "camera error: reopening with backoff (logged once until it recovers)"
                        );
                        in_error = true;
                        logged_error = Chain(&e).to_string();
                    }
                    if self.stop.sleep(backoff) {
                        break;
                    }
                    backoff = (backoff * 2).min(BACKOFF_MAX);
                    if let Err(e) = self.source.reopen() {
                        // A reopen that fails for another reason than the one logged (a camera
                        // that is "not open" at start-up, then has the wrong format) is worth a
                        // warning of its own: the first error alone does not say what is wrong.
                        let text = Chain(&e).to_string();
                        if text != logged_error {
                            tracing::warn!(
                                camera, side, error = %Chain(&e),
                                "camera error: reopening with backoff (logged once until it recovers)"
                            );
                            logged_error = text;
                        } else {
                            tracing::debug!(camera, side, error = %Chain(&e), "reopen failed");
                        }
                    }
                }
            }
        }
    }
}
