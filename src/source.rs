//! The camera abstraction the daemon's capture threads drive.
//!
//! A [`FrameSource`] is one camera: a V4L2 device ([`crate::capture`]), a hw-mock scenario
//! renderer, or a test double. The capture thread owns it and calls [`FrameSource::next_frame`]
//! in a loop; the source converts whatever the device delivers (YUYV, MJPEG, GREY...) into a
//! [`PreparedImage`] in place, so per-frame work (colour conversion, gradients) happens on the
//! capture thread and the evolution thread only evaluates flies.
//!
//! Contract:
//! - `next_frame` waits at most `timeout` and then returns [`SourceError::Timeout`]: a capture
//!   thread must notice an unplugged camera instead of hanging.
//! - Timestamps are CLOCK_MONOTONIC capture times (the kernel's buffer timestamp for V4L2), as a
//!   `Duration` since the clock's epoch, so both cameras' frames can be paired by time.
//! - Retryable errors (timeout, device gone) leave the source usable or reopenable; fatal ones
//!   (a format the device will not deliver) are reported and retried with backoff by the caller.

use flyd_core::frame::PreparedImage;
use std::time::Duration;

pub use flyd_core::pairing::{FrameMeta, Side};

/// What caused a [`SourceError`] (an I/O error of the device, a frame that does not decode).
pub type Cause = Box<dyn std::error::Error + Send + Sync>;

/// Why a source delivered no frame. `reason` says what flyd was doing; the error underneath,
/// if any, is the `source()`.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// No frame within the timeout.
    #[error("no frame within {0:?}")]
    Timeout(Duration),
    /// The device vanished or stopped streaming; reopen it (with backoff).
    #[error("device {device} disconnected: {reason}")]
    Disconnected {
        device: String,
        reason: String,
        #[source]
        cause: Option<Cause>,
    },
    /// The device delivers a format or size flyd cannot use.
    #[error("device {device}: {reason}")]
    Format {
        device: String,
        reason: String,
        #[source]
        cause: Option<Cause>,
    },
    /// A frame arrived but could not be decoded (e.g. corrupt MJPEG); the next one may be fine.
    #[error("device {device}: corrupt frame: {reason}")]
    Corrupt {
        device: String,
        reason: String,
        #[source]
        cause: Option<Cause>,
    },
    /// The source has no more frames (end of a recorded or mock scenario).
    #[error("end of stream")]
    EndOfStream,
}

impl SourceError {
    /// Whether the capture loop should keep calling `next_frame` (as opposed to reopening).
    pub fn is_transient(&self) -> bool {
        matches!(self, SourceError::Timeout(_) | SourceError::Corrupt { .. })
    }
}

/// One camera.
pub trait FrameSource: Send {
    /// A human-readable name for logs ("/dev/video0", "mock:left").
    fn name(&self) -> &str;
    /// Image size this source delivers.
    fn size(&self) -> (u32, u32);
    /// Waits up to `timeout` for the next frame and prepares it into `out` (same size as
    /// [`FrameSource::size`]), reusing `out`'s buffers.
    fn next_frame(
        &mut self,
        out: &mut PreparedImage,
        timeout: Duration,
    ) -> Result<FrameMeta, SourceError>;
    /// Closes and reopens the device after a disconnect or format error. The default does
    /// nothing (sources that cannot vanish).
    fn reopen(&mut self) -> Result<(), SourceError> {
        Ok(())
    }
}
