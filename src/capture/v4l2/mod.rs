//! [`V4l2Source`]: one V4L2 camera, opened by path, streamed with mmap buffers.
//!
//! Contract (see [`crate::source`] for the trait's):
//! - **Open** sets the format (size, fourcc) and the frame rate, then checks what the driver
//!   accepted: drivers silently substitute a format they support, and a mismatch is a
//!   [`SourceError::Format`] naming the device and both formats, never a wrong-sized frame later.
//! - **Dequeue** waits at most the caller's timeout (poll), so an unplugged camera gives
//!   [`SourceError::Timeout`] or [`SourceError::Disconnected`] instead of hanging.
//! - **Frames** are cut to `bytesused` and converted before the next dequeue (the `v4l` stream
//!   requeues the previous buffer on its next call). The timestamp is the kernel's buffer
//!   timestamp when the driver says it is CLOCK_MONOTONIC; otherwise the dequeue time on that
//!   clock (logged once per open). The sequence is the driver's.
//! - **Teardown** of a vanished device does not panic (see `Streaming::teardown`).
//!
//! Two `v4l` 0.14 behaviours this module works around, read in its source:
//! - `CaptureStream::next()` requeues the last buffer it returned *before* waiting. When a wait
//!   times out, that buffer is already back with the kernel, so the next call's QBUF fails with
//!   EINVAL, forever. After any wait that returned no buffer we take one buffer back with a bare
//!   `dequeue()` first (it is lost: one frame after a stall, when the camera was already stale).
//!   That loop, `wait_for_buffer`, runs against a strict model of the kernel's queue in the tests.
//! - `Stream`'s `Drop` calls STREAMOFF and panics on any error but ENODEV; its buffer arena's
//!   `Drop` panics likewise when unmapping or freeing fails. We stop the stream ourselves first
//!   (see `Streaming::teardown`).
//!
//! Format, capability and frame-rate ioctls go through `v4l`'s raw `ioctl` with its bindings
//! rather than `Device::format()`/`query_caps()`, which `expect()` on colour-space codes they do
//! not know and `unwrap()` the UTF-8 of card names (a USB product name cut at 32 bytes can split
//! a character).

use super::convert::{CaptureFormat, fourcc_str};
use crate::source::{FrameMeta, FrameSource, SourceError};
use flyd_core::chain::Chain;
use flyd_core::frame::{PixelFormat, PreparedImage};
use std::io;
use std::path::PathBuf;
use std::time::Duration;

/// Buffers in the mmap ring. Four lets the driver fill while we convert, without queueing so
/// many that a frame waits behind stale ones.
const BUFFERS: u32 = 4;

/// `v4l2_buffer.flags` bits (videodev2.h).
const BUF_FLAG_ERROR: u32 = 0x0000_0040;
const BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;

/// `v4l2_capability` bits.
const CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
const CAP_STREAMING: u32 = 0x0400_0000;
const CAP_DEVICE_CAPS: u32 = 0x8000_0000;
/// `v4l2_captureparm.capability`: the driver honours `timeperframe`.
const CAP_TIMEPERFRAME: u32 = 0x1000;

/// `v4l2_field`: progressive frames.
const FIELD_NONE: u32 = 1;

/// Accepted relative difference between the asked and the granted frame rate (NTSC-style
/// 30000/1001 for 30 fps is fine).
const FPS_TOLERANCE: f64 = 0.01;

/// One camera in the config file.
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct V4l2Config {
    /// Device node, e.g. `/dev/video0` or a stable `/dev/v4l/by-path/...` link.
    pub device: PathBuf,
    pub width: u32,
    pub height: u32,
    /// Frames per second asked of the driver.
    pub fps: u32,
    /// Pixel format asked of the driver: "YUYV", "MJPG" or "GREY".
    pub format: CaptureFormat,
}

/// A camera config value flyd cannot use; `key` is the field name within the camera's table.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct V4l2ConfigError {
    pub key: &'static str,
    pub reason: String,
}

impl V4l2Config {
    /// Checks values the types allow but flyd cannot use.
    pub fn validate(&self) -> Result<(), V4l2ConfigError> {
        let err = |key, reason: String| Err(V4l2ConfigError { key, reason });
        if self.device.as_os_str().is_empty() {
            return err("device", "must not be empty".into());
        }
        // The bounds of PreparedImage::new.
        for (key, v) in [("width", self.width), ("height", self.height)] {
            if !(8..=8192).contains(&v) {
                return err(key, format!("{v} is outside 8..=8192"));
            }
        }
        if self.format == CaptureFormat::Yuyv && !self.width.is_multiple_of(2) {
            return err(
                "width",
                format!("{} is odd; YUYV needs an even width", self.width),
            );
        }
        if !(1..=1000).contains(&self.fps) {
            return err("fps", format!("{} is outside 1..=1000", self.fps));
        }
        Ok(())
    }
}

/// What the driver accepted in VIDIOC_S_FMT.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Negotiated {
    pub width: u32,
    pub height: u32,
    pub fourcc: [u8; 4],
    /// Bytes per line (0 for compressed formats on some drivers).
    pub stride: u32,
    /// Largest payload of one frame.
    pub size_image: u32,
}

/// A missing or different format from the driver is a [`SourceError::Format`] naming both.
pub(crate) fn check_format(
    device: &str,
    config: &V4l2Config,
    got: &Negotiated,
) -> Result<(), SourceError> {
    let asked = (config.width, config.height, config.format.fourcc());
    if (got.width, got.height, got.fourcc) != asked {
        return Err(SourceError::Format {
            device: device.to_owned(),
            reason: format!(
                "asked for {}x{} {}, the driver accepted {}x{} {}",
                config.width,
                config.height,
                config.format,
                got.width,
                got.height,
                fourcc_str(got.fourcc)
            ),
            cause: None,
        });
    }
    Ok(())
}

/// The granted frame interval (`numerator / denominator` seconds) must match `fps`.
pub(crate) fn check_frame_rate(
    device: &str,
    fps: u32,
    numerator: u32,
    denominator: u32,
) -> Result<(), SourceError> {
    let granted = if numerator == 0 {
        0.0
    } else {
        denominator as f64 / numerator as f64
    };
    if (granted - fps as f64).abs() > FPS_TOLERANCE * fps as f64 {
        return Err(SourceError::Format {
            device: device.to_owned(),
            reason: format!(
                "asked for {fps} fps, the driver granted a frame interval of \
                 {numerator}/{denominator} s ({granted:.2} fps)"
            ),
            cause: None,
        });
    }
    Ok(())
}

/// The node must capture video with streaming I/O (a UVC camera's metadata node does not).
pub(crate) fn check_capabilities(capabilities: u32, device_caps: u32) -> Result<(), String> {
    // `device_caps` describes this node; `capabilities` the whole physical device.
    let caps = if capabilities & CAP_DEVICE_CAPS != 0 {
        device_caps
    } else {
        capabilities
    };
    let needed = CAP_VIDEO_CAPTURE | CAP_STREAMING;
    if caps & needed != needed {
        return Err(format!(
            "not a video capture node with streaming I/O (capabilities {caps:#010x}); \
             a UVC camera's metadata node looks like this: try the other /dev/video node"
        ));
    }
    Ok(())
}

/// The payload of a dequeued buffer: the mapping cut to `bytesused`.
pub(crate) fn payload(buffer: &[u8], bytesused: u32) -> Result<&[u8], String> {
    let used = bytesused as usize;
    match buffer.get(..used) {
        Some(_) if used == 0 => Err("empty buffer (bytesused 0)".into()),
        Some(p) => Ok(p),
        None => Err(format!(
            "bytesused {used} exceeds the {}-byte buffer",
            buffer.len()
        )),
    }
}

/// The capture time of a frame: the kernel's timestamp when the driver marks it
/// CLOCK_MONOTONIC and it is sane (not negative, not in the future), otherwise `now` (the
/// dequeue time on CLOCK_MONOTONIC). The flag says which was used: `true` for the kernel's.
pub(crate) fn frame_timestamp(flags: u32, sec: i64, usec: i64, now: Duration) -> (Duration, bool) {
    if flags & BUF_FLAG_TIMESTAMP_MASK == BUF_FLAG_TIMESTAMP_MONOTONIC
        && sec >= 0
        && (0..1_000_000).contains(&usec)
    {
        let t = Duration::from_secs(sec as u64) + Duration::from_micros(usec as u64);
        if t <= now {
            return (t, true);
        }
    }
    (now, false)
}

/// A poll timeout `v4l` accepts: whole milliseconds (rounded up, so a sub-millisecond rest
/// still waits) that fit its `i32` (it panics beyond).
pub(crate) fn poll_timeout(remaining: Duration) -> Duration {
    let ms = remaining
        .as_micros()
        .div_ceil(1000)
        .clamp(1, i32::MAX as u128);
    Duration::from_millis(ms as u64)
}

/// Errors of a wait that are worth retrying within the same call.
fn retry_in_place(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::Interrupted | io::ErrorKind::WouldBlock
    )
}

/// Maps an I/O error from streaming to the trait's error: a timeout is a timeout, everything
/// else means "reopen" (a vanished USB camera gives ENODEV, a dead stream EIO or EPIPE).
/// `e` again (an `io::Error` is not `Clone`): its kind, errno and message.
fn copy_io_error(e: &io::Error) -> io::Error {
    match e.raw_os_error() {
        Some(errno) => io::Error::from_raw_os_error(errno),
        None => io::Error::new(e.kind(), e.to_string()),
    }
}

pub(crate) fn classify(device: &str, op: &str, e: &io::Error, timeout: Duration) -> SourceError {
    if e.kind() == io::ErrorKind::TimedOut {
        return SourceError::Timeout(timeout);
    }
    let why = match e.raw_os_error() {
        Some(libc::ENODEV) | Some(libc::ENXIO) => "device vanished (unplugged?)",
        Some(libc::EIO) | Some(libc::EPIPE) => "stream failed",
        _ => "unexpected error",
    };
    SourceError::Disconnected {
        device: device.to_owned(),
        reason: format!("{op}: {why}"),
        cause: Some(copy_io_error(e).into()),
    }
}

/// Maps an error opening the node: a missing node or a busy device may come back (reopen with
/// backoff); a node that is not V4L2 is a configuration mistake.
pub(crate) fn open_error(device: &str, op: &str, e: &io::Error) -> SourceError {
    let cause = || Some(copy_io_error(e).into());
    let hint = match e.raw_os_error() {
        Some(libc::ENOENT) => " (camera not plugged in, or wrong path)",
        Some(libc::EACCES) | Some(libc::EPERM) => {
            " (is the user in group video, and the node allowed by DeviceAllow=?)"
        }
        Some(libc::EBUSY) => " (another process is streaming from it)",
        Some(libc::ENOTTY) => {
            return SourceError::Format {
                device: device.to_owned(),
                reason: format!("{op}: not a V4L2 device"),
                cause: cause(),
            };
        }
        _ => "",
    };
    SourceError::Disconnected {
        device: device.to_owned(),
        reason: format!("{op}{hint}"),
        cause: cause(),
    }
}

/// CLOCK_MONOTONIC, the buffers' timebase: read in one place ([`crate::os_clock::MonotonicClock`]).
fn monotonic_now() -> Duration {
    use crate::os_clock::{Clock, MonotonicClock};
    MonotonicClock.now()
}

mod ioctl;
mod stream;

use stream::Streaming;

/// One V4L2 camera (see the module docs).
pub struct V4l2Source {
    config: V4l2Config,
    name: String,
    output: PixelFormat,
    streaming: Option<Streaming>,
}

impl std::fmt::Debug for V4l2Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Source")
            .field("config", &self.config)
            .field("output", &self.output)
            .field("open", &self.is_open())
            .finish()
    }
}

impl V4l2Source {
    /// A source for `config` that is not open yet: `next_frame` reports it disconnected until
    /// [`FrameSource::reopen`] succeeds. This lets the daemon start (and report the fault)
    /// while a camera is missing.
    pub fn new(config: V4l2Config, output: PixelFormat) -> Self {
        Self {
            name: config.device.display().to_string(),
            config,
            output,
            streaming: None,
        }
    }

    /// Opens and configures the camera, delivering its natural output (RGB8 for YUYV and MJPG,
    /// grey for GREY).
    pub fn open(config: V4l2Config) -> Result<Self, SourceError> {
        let output = config.format.natural_output();
        Self::open_as(config, output)
    }

    /// Opens and configures the camera, delivering `output` (e.g. grey from a YUYV camera).
    pub fn open_as(config: V4l2Config, output: PixelFormat) -> Result<Self, SourceError> {
        let mut source = Self::new(config, output);
        source.reopen()?;
        Ok(source)
    }

    pub fn config(&self) -> &V4l2Config {
        &self.config
    }

    /// The pixel format of the prepared images.
    pub fn output(&self) -> PixelFormat {
        self.output
    }

    pub fn is_open(&self) -> bool {
        self.streaming.is_some()
    }

    /// Stops streaming and closes the device. An error means the teardown leaked the buffers
    /// (see the module docs); the source is closed either way.
    pub fn close(&mut self) -> Result<(), SourceError> {
        match self.streaming.take() {
            None => Ok(()),
            Some(mut s) => s.teardown().map_err(|reason| SourceError::Disconnected {
                device: self.name.clone(),
                reason,
                cause: None,
            }),
        }
    }
}

impl FrameSource for V4l2Source {
    fn name(&self) -> &str {
        &self.name
    }

    fn size(&self) -> (u32, u32) {
        (self.config.width, self.config.height)
    }

    fn next_frame(
        &mut self,
        out: &mut PreparedImage,
        timeout: Duration,
    ) -> Result<FrameMeta, SourceError> {
        match self.streaming.as_mut() {
            Some(s) => s.next_frame(&self.name, out, timeout),
            None => Err(SourceError::Disconnected {
                device: self.name.clone(),
                reason: "not open".into(),
                cause: None,
            }),
        }
    }

    /// Closes the device (if open) and opens it again with the same config.
    fn reopen(&mut self) -> Result<(), SourceError> {
        if let Err(e) = self.close() {
            // The old stream is gone either way; say what was leaked and go on opening.
            tracing::warn!(error = %Chain(&e), "camera teardown before reopen");
        }
        self.streaming = Some(Streaming::open(&self.name, &self.config, self.output)?);
        Ok(())
    }
}

#[cfg(test)]
mod tests;
