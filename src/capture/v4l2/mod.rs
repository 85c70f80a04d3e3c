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
mod tests {
    use super::stream::{BufferQueue, wait_for_buffer};
    use super::*;
    use std::path::Path;
    use std::time::Instant;
    use v4l::buffer::Metadata;

    fn config(device: &str) -> V4l2Config {
        V4l2Config {
            device: device.into(),
            width: 640,
            height: 480,
            fps: 30,
            format: CaptureFormat::Yuyv,
        }
    }

    #[test]
    fn config_parses_and_rejects_unknown_keys() {
        let parse = |rest: &str| {
            let text =
                format!("device = \"/dev/video0\"\nwidth = 640\nheight = 480\nfps = 30\n{rest}");
            toml::from_str::<V4l2Config>(&text)
        };
        let c = parse("format = \"MJPG\"").unwrap();
        assert_eq!(c.format, CaptureFormat::Mjpg);
        assert_eq!(c.device, Path::new("/dev/video0"));
        c.validate().unwrap();
        let err = parse("format = \"YUYV\"\ncolour = true").unwrap_err();
        assert!(err.to_string().contains("colour"), "{err}");
        let err = parse("format = \"H264\"").unwrap_err();
        assert!(err.to_string().contains("H264"), "{err}");
    }

    #[test]
    fn config_validation_names_the_key() {
        let check = |edit: fn(&mut V4l2Config), key: &str| {
            let mut c = config("/dev/video0");
            edit(&mut c);
            assert_eq!(c.validate().unwrap_err().key, key);
        };
        check(|c| c.device = PathBuf::new(), "device");
        check(|c| c.width = 4, "width");
        check(|c| c.height = 100_000, "height");
        check(|c| c.width = 641, "width");
        check(|c| c.fps = 0, "fps");
        let mut grey_odd = config("/dev/video0");
        grey_odd.format = CaptureFormat::Grey;
        grey_odd.width = 641;
        grey_odd.validate().unwrap();
    }

    #[test]
    fn format_mismatch_names_device_and_both_formats() {
        let c = config("/dev/video3");
        let mut got = Negotiated {
            width: 640,
            height: 480,
            fourcc: *b"YUYV",
            stride: 1280,
            size_image: 614_400,
        };
        check_format("/dev/video3", &c, &got).unwrap();
        got.fourcc = *b"MJPG";
        let msg = check_format("/dev/video3", &c, &got)
            .unwrap_err()
            .to_string();
        assert_eq!(
            msg,
            "device /dev/video3: asked for 640x480 YUYV, the driver accepted 640x480 MJPG"
        );
        got = Negotiated {
            width: 320,
            height: 240,
            fourcc: *b"YUYV",
            ..got
        };
        let err = check_format("/dev/video3", &c, &got).unwrap_err();
        assert!(matches!(err, SourceError::Format { .. }));
        assert!(err.to_string().contains("320x240 YUYV"), "{err}");
    }

    #[test]
    fn frame_rate_check() {
        check_frame_rate("cam", 30, 1, 30).unwrap();
        check_frame_rate("cam", 30, 1001, 30000).unwrap();
        let err = check_frame_rate("cam", 30, 1, 15).unwrap_err().to_string();
        assert!(err.contains("30 fps") && err.contains("1/15"), "{err}");
        assert!(check_frame_rate("cam", 30, 0, 0).is_err());
    }

    #[test]
    fn capability_check_rejects_metadata_nodes() {
        let capture = CAP_VIDEO_CAPTURE | CAP_STREAMING;
        check_capabilities(capture | CAP_DEVICE_CAPS, capture).unwrap();
        check_capabilities(capture, 0).unwrap(); // old driver without device_caps
        // uvcvideo's second node: the device captures, this node only has metadata.
        let meta_capture = 0x0080_0000;
        let err = check_capabilities(capture | CAP_DEVICE_CAPS, meta_capture | CAP_STREAMING)
            .unwrap_err();
        assert!(err.contains("metadata"), "{err}");
        assert!(
            check_capabilities(CAP_VIDEO_CAPTURE | CAP_DEVICE_CAPS, CAP_VIDEO_CAPTURE).is_err()
        );
    }

    #[test]
    fn payload_is_cut_to_bytesused() {
        let buf = [1u8, 2, 3, 4, 5, 6];
        assert_eq!(payload(&buf, 4).unwrap(), &[1, 2, 3, 4]);
        assert_eq!(payload(&buf, 6).unwrap(), &buf);
        assert!(payload(&buf, 7).unwrap_err().contains("exceeds"));
        assert!(payload(&buf, 0).is_err());
    }

    #[test]
    fn timestamps_come_from_the_kernel_only_when_monotonic_and_sane() {
        let now = Duration::from_secs(1000);
        let mono = BUF_FLAG_TIMESTAMP_MONOTONIC | 0x0001_0000; // + TSTAMP_SRC_SOE
        assert_eq!(
            frame_timestamp(mono, 999, 250_000, now),
            (Duration::from_micros(999_250_000), true)
        );
        // Unknown clock, copied (mem2mem) timestamps, garbage, the future: the dequeue time.
        assert_eq!(frame_timestamp(0, 999, 0, now), (now, false));
        assert_eq!(frame_timestamp(0x4000, 999, 0, now), (now, false));
        assert_eq!(frame_timestamp(mono, -1, 0, now), (now, false));
        assert_eq!(frame_timestamp(mono, 999, 1_000_000, now), (now, false));
        assert_eq!(frame_timestamp(mono, 1001, 0, now), (now, false));
    }

    #[test]
    fn poll_timeouts_round_up_and_fit_v4l() {
        assert_eq!(poll_timeout(Duration::ZERO), Duration::from_millis(1));
        assert_eq!(
            poll_timeout(Duration::from_micros(1500)),
            Duration::from_millis(2)
        );
        assert_eq!(
            poll_timeout(Duration::from_millis(100)),
            Duration::from_millis(100)
        );
        assert_eq!(
            poll_timeout(Duration::from_secs(u64::MAX)),
            Duration::from_millis(i32::MAX as u64)
        );
    }

    #[test]
    fn io_errors_map_to_timeout_or_reopen() {
        let t = Duration::from_millis(100);
        let timed_out = io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF");
        assert!(matches!(
            classify("/dev/video0", "capture", &timed_out, t),
            SourceError::Timeout(d) if d == t
        ));
        let gone = classify(
            "/dev/video0",
            "capture",
            &io::Error::from_raw_os_error(libc::ENODEV),
            t,
        );
        assert!(!gone.is_transient());
        let msg = gone.to_string();
        assert!(
            msg.contains("/dev/video0") && msg.contains("unplugged"),
            "{msg}"
        );
        for errno in [libc::EIO, libc::EPIPE, libc::EINVAL] {
            assert!(matches!(
                classify("d", "capture", &io::Error::from_raw_os_error(errno), t),
                SourceError::Disconnected { .. }
            ));
        }
        assert!(matches!(
            open_error(
                "d",
                "VIDIOC_QUERYCAP",
                &io::Error::from_raw_os_error(libc::ENOTTY)
            ),
            SourceError::Format { .. }
        ));
        let denied = open_error("d", "open", &io::Error::from_raw_os_error(libc::EACCES));
        assert!(denied.to_string().contains("group video"), "{denied}");
    }

    /// What happens during one wait of the model camera.
    #[derive(Debug, Clone, Copy)]
    enum Event {
        /// A frame with this sequence number fills the oldest queued buffer.
        Frame(u32),
        /// Nothing arrives: the poll times out.
        Nothing,
        /// A signal interrupts the poll.
        Interrupted,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Owner {
        User,
        Kernel,
    }

    /// A strict model of a V4L2 capture queue behind `v4l` 0.14's mmap stream: QBUF of a buffer
    /// the kernel owns is EINVAL, as in videobuf2; `next_with` and `dequeue` do what `v4l`'s
    /// `next()` and `dequeue()` do, including remembering the last dequeued index.
    struct ModelQueue {
        owner: Vec<Owner>,
        /// Kernel-owned buffers in the order they were queued (filled first in, first out).
        queued: std::collections::VecDeque<usize>,
        meta: Vec<Metadata>,
        active: bool,
        /// `v4l`'s `arena_index`: the buffer the next `next()` requeues.
        last: usize,
        events: std::collections::VecDeque<Event>,
    }

    impl ModelQueue {
        fn new(events: &[Event]) -> Self {
            Self {
                owner: vec![Owner::User; 4],
                queued: Default::default(),
                meta: vec![Metadata::default(); 4],
                active: false,
                last: 0,
                events: events.iter().copied().collect(),
            }
        }
        fn qbuf(&mut self, i: usize) -> io::Result<()> {
            if self.owner[i] != Owner::User {
                return Err(io::Error::from_raw_os_error(libc::EINVAL));
            }
            self.owner[i] = Owner::Kernel;
            self.queued.push_back(i);
            Ok(())
        }
        fn dqbuf(&mut self) -> io::Result<usize> {
            match self.events.pop_front().unwrap_or(Event::Nothing) {
                Event::Nothing => Err(io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF")),
                Event::Interrupted => Err(io::Error::from_raw_os_error(libc::EINTR)),
                Event::Frame(sequence) => {
                    // With no buffer queued the driver drops the frame.
                    let Some(i) = self.queued.pop_front() else {
                        return Err(io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF"));
                    };
                    self.owner[i] = Owner::User;
                    self.meta[i] = Metadata {
                        bytesused: 1,
                        sequence,
                        ..Metadata::default()
                    };
                    Ok(i)
                }
            }
        }
    }

    impl BufferQueue for ModelQueue {
        fn set_timeout(&mut self, _: Duration) {}
        fn dequeue(&mut self) -> io::Result<()> {
            self.last = self.dqbuf()?;
            Ok(())
        }
        fn next_with<R>(&mut self, f: &mut impl FnMut(&[u8], &Metadata) -> R) -> io::Result<R> {
            if !self.active {
                for i in 0..self.owner.len() {
                    self.qbuf(i)?;
                }
                self.active = true;
            } else {
                self.qbuf(self.last)?;
            }
            self.last = self.dqbuf()?;
            Ok(f(&[0], &self.meta[self.last]))
        }
    }

    /// One `next_frame`-like call per entry: the sequence delivered, or the error kind.
    fn run_capture_loop(events: &[Event], calls: usize) -> Vec<Result<u32, io::ErrorKind>> {
        let mut queue = ModelQueue::new(events);
        let mut resync = false;
        (0..calls)
            .map(|_| {
                let deadline = Instant::now() + Duration::from_secs(5);
                wait_for_buffer(&mut queue, &mut resync, deadline, &mut |_, meta| {
                    meta.sequence
                })
                .map_err(|e| e.kind())
            })
            .collect()
    }

    #[test]
    fn the_model_reproduces_v4l_requeueing_after_a_timeout() {
        // Calling v4l's next() again after a timed-out wait: QBUF of a buffer the kernel
        // already owns, EINVAL, however many frames then arrive.
        use Event::*;
        let mut queue = ModelQueue::new(&[Frame(0), Nothing, Frame(1), Frame(2)]);
        let mut seq = |_: &[u8], m: &Metadata| m.sequence;
        assert_eq!(queue.next_with(&mut seq).unwrap(), 0);
        assert_eq!(
            queue.next_with(&mut seq).unwrap_err().kind(),
            io::ErrorKind::TimedOut
        );
        for _ in 0..3 {
            let err = queue.next_with(&mut seq).unwrap_err();
            assert_eq!(err.raw_os_error(), Some(libc::EINVAL));
        }
    }

    #[test]
    fn capture_loop_recovers_after_timeouts() {
        use Event::*;
        use io::ErrorKind::TimedOut;
        let got = run_capture_loop(
            &[
                Frame(0),
                Nothing,
                Frame(1), // taken back by the resync dequeue: dropped
                Frame(2),
                Nothing,
                Nothing,  // the resync dequeue itself times out: still resyncing
                Frame(3), // dropped by the resync
                Frame(4),
                Frame(5),
            ],
            7,
        );
        assert_eq!(
            got,
            [
                Ok(0),
                Err(TimedOut),
                Ok(2),
                Err(TimedOut),
                Err(TimedOut),
                Ok(4),
                Ok(5)
            ]
        );
    }

    #[test]
    fn capture_loop_recovers_from_a_timeout_before_the_first_frame() {
        use Event::*;
        let got = run_capture_loop(&[Nothing, Frame(0), Frame(1), Frame(2)], 3);
        assert_eq!(got, [Err(io::ErrorKind::TimedOut), Ok(1), Ok(2)]);
    }

    #[test]
    fn capture_loop_retries_interrupted_waits_within_the_call() {
        use Event::*;
        // EINTR in the wait: retried in the same call, after taking a buffer back.
        let got = run_capture_loop(&[Frame(0), Interrupted, Frame(1), Frame(2), Frame(3)], 2);
        assert_eq!(got, [Ok(0), Ok(2)]);
        // EINTR in the resync dequeue itself.
        let got = run_capture_loop(&[Nothing, Interrupted, Frame(0), Frame(1)], 2);
        assert_eq!(got, [Err(io::ErrorKind::TimedOut), Ok(1)]);
    }

    #[test]
    fn capture_loop_never_requeues_a_kernel_buffer() {
        // Every pattern of up to 8 events, through 8 calls: no EINVAL ever reaches the caller
        // (it would mean a QBUF of a buffer the kernel owns), and every frame delivered is
        // newer than the last.
        use Event::*;
        let choices = [Frame(0), Nothing, Interrupted];
        for pattern in 0..3usize.pow(8) {
            let mut seq = 0;
            let events: Vec<Event> = (0..8)
                .map(|k| match choices[pattern / 3usize.pow(k) % 3] {
                    Frame(_) => {
                        seq += 1;
                        Frame(seq)
                    }
                    e => e,
                })
                .collect();
            let mut last = 0;
            for r in run_capture_loop(&events, 8) {
                match r {
                    Ok(s) => {
                        assert!(s > last, "{events:?}");
                        last = s;
                    }
                    Err(kind) => assert_eq!(kind, io::ErrorKind::TimedOut, "{events:?}"),
                }
            }
        }
    }

    #[test]
    fn opening_a_missing_node_names_the_path() {
        let path = "/dev/video-flyd-test-does-not-exist";
        let err = V4l2Source::open(config(path)).unwrap_err();
        assert!(matches!(err, SourceError::Disconnected { .. }), "{err:?}");
        let msg = Chain(&err).to_string();
        assert!(msg.contains(path), "{msg}");
        assert!(msg.contains("No such file"), "{msg}");
    }

    #[test]
    fn opening_something_that_is_not_v4l2_is_a_format_error() {
        // /dev/null opens read-write like a camera node but knows no V4L2 ioctl.
        let err = V4l2Source::open(config("/dev/null")).unwrap_err();
        assert!(matches!(err, SourceError::Format { .. }), "{err:?}");
        assert!(err.to_string().contains("not a V4L2 device"), "{err}");
        let file = tempfile::NamedTempFile::new().unwrap();
        let err = V4l2Source::open(config(file.path().to_str().unwrap())).unwrap_err();
        assert!(err.to_string().contains("not a V4L2 device"), "{err}");
    }

    #[test]
    fn a_closed_source_reports_disconnected_and_reopen_retries() {
        let path = "/dev/video-flyd-test-does-not-exist";
        let mut source = V4l2Source::new(config(path), PixelFormat::Rgb8);
        assert!(!source.is_open());
        assert_eq!(source.name(), path);
        assert_eq!(source.size(), (640, 480));
        let mut out = PreparedImage::new(640, 480).unwrap();
        let err = source
            .next_frame(&mut out, Duration::from_millis(10))
            .unwrap_err();
        assert!(matches!(err, SourceError::Disconnected { .. }));
        assert!(err.to_string().contains(path));
        assert!(source.reopen().is_err());
        assert!(!source.is_open());
        source.close().unwrap();
    }

    #[test]
    fn a_bad_config_fails_before_touching_the_device() {
        let mut c = config("/dev/null");
        c.width = 641;
        let err = Chain(&V4l2Source::open(c).unwrap_err()).to_string();
        assert!(err.contains("width") && err.contains("641"), "{err}");
    }

    /// Says loudly that a test did not run: written to the stderr stream itself, which the test
    /// harness does not capture, so it shows in every `cargo test` run.
    fn skip(reason: &str) {
        use std::io::Write;
        let _ = writeln!(io::stderr(), "SKIP: {reason}");
    }

    /// Streams from a real camera when there is one (a rig, or a machine with `vivid` loaded).
    /// `FLYD_TEST_VIDEO` picks the node (default /dev/video0).
    #[test]
    fn real_device_streams_monotonic_frames() {
        let path = std::env::var("FLYD_TEST_VIDEO").unwrap_or_else(|_| "/dev/video0".into());
        if !Path::new(&path).exists() {
            skip(&format!(
                "real_device_streams_monotonic_frames: no {path} on this machine (no V4L2 \
                 here); the open/convert paths are covered by the other tests and the VM \
                 suite's v4l2loopback cameras; run this one where vivid is loaded"
            ));
            return;
        }
        for format in [CaptureFormat::Yuyv, CaptureFormat::Grey] {
            // Drivers offer different rates per size (vivid's webcam input caps larger sizes
            // lower): take the first one granted exactly.
            let mut refusals = Vec::new();
            let mut opened = None;
            for fps in [30, 25, 15, 10] {
                let mut c = config(&path);
                c.format = format;
                c.fps = fps;
                match V4l2Source::open(c) {
                    Ok(s) => {
                        opened = Some(s);
                        break;
                    }
                    Err(SourceError::Format { reason, .. }) => refusals.push(reason),
                    Err(e) => panic!("{e}"),
                }
            }
            let Some(mut source) = opened else {
                skip(&format!(
                    "{path} cannot do 640x480 {format}: {}",
                    refusals.join("; ")
                ));
                continue;
            };
            let mut out = PreparedImage::new(640, 480).unwrap();
            let mut last: Option<FrameMeta> = None;
            for _ in 0..10 {
                let meta = source
                    .next_frame(&mut out, Duration::from_secs(2))
                    .unwrap_or_else(|e| panic!("{format}: {e}"));
                assert!(meta.timestamp <= monotonic_now());
                if let Some(prev) = last {
                    assert!(meta.timestamp > prev.timestamp, "{prev:?} then {meta:?}");
                    assert!(meta.sequence > prev.sequence, "{prev:?} then {meta:?}");
                }
                last = Some(meta);
            }
            // A timeout shorter than a frame period leaves the stream usable (the resync path,
            // v4l's requeue-after-timeout bug). Drain ready frames until one wait times out.
            let timed_out = (0..20).any(|_| {
                matches!(
                    source.next_frame(&mut out, Duration::from_micros(1)),
                    Err(SourceError::Timeout(_))
                )
            });
            assert!(timed_out, "a 1 ms wait never timed out at <= 30 fps");
            source
                .next_frame(&mut out, Duration::from_secs(2))
                .expect("a frame after a timeout");
            source.reopen().expect("reopen");
            source
                .next_frame(&mut out, Duration::from_secs(2))
                .expect("a frame after reopen");
            source.close().expect("clean teardown");
        }
    }
}
