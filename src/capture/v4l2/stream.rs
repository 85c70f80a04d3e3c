//! Streaming: waiting for a filled buffer (`poll` with a deadline), and the open, configured
//! and streaming device ([`Streaming`]) that turns each buffer into a prepared frame.

use super::ioctl::{query_capabilities, set_format, set_frame_rate};
use super::{
    BUF_FLAG_ERROR, BUFFERS, V4l2Config, check_capabilities, check_format, check_frame_rate,
    classify, frame_timestamp, monotonic_now, open_error, payload, poll_timeout, retry_in_place,
};
use crate::capture::convert::{ConvertError, FrameConverter};
use crate::source::{FrameMeta, SourceError};
use flyd_core::frame::{PixelFormat, PreparedImage};
use std::io;
use std::time::{Duration, Instant};
use v4l::buffer::{Metadata, Type as BufferType};
use v4l::device::Device;
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::{CaptureStream, Stream as _};

// --- Waiting for a buffer -------------------------------------------------------------------------

/// The stream operations the capture loop uses, as `v4l`'s mmap stream implements them; a trait
/// so that the loop's handling of `v4l`'s requeue behaviour is tested against a model of the
/// kernel's queue (no V4L2 here).
pub(super) trait BufferQueue {
    /// The poll timeout of the next wait.
    fn set_timeout(&mut self, timeout: Duration);
    /// A bare VIDIOC_DQBUF (after a poll): takes one filled buffer back without looking at it;
    /// the next `next_with` requeues it.
    fn dequeue(&mut self) -> io::Result<()>;
    /// `v4l`'s `next()`: requeue the last buffer (queue all and STREAMON the first time), wait,
    /// dequeue, and hand the buffer to `f` before it can be requeued.
    fn next_with<R>(&mut self, f: &mut impl FnMut(&[u8], &Metadata) -> R) -> io::Result<R>;
}

impl BufferQueue for MmapStream<'static> {
    fn set_timeout(&mut self, timeout: Duration) {
        MmapStream::set_timeout(self, timeout);
    }
    fn dequeue(&mut self) -> io::Result<()> {
        CaptureStream::dequeue(self).map(|_| ())
    }
    fn next_with<R>(&mut self, f: &mut impl FnMut(&[u8], &Metadata) -> R) -> io::Result<R> {
        let (buffer, meta) = CaptureStream::next(self)?;
        Ok(f(buffer, meta))
    }
}

/// Waits until `deadline` for the next filled buffer and hands it to `on_buffer`.
///
/// `resync` carries the queue's state between calls: after a wait that returned no buffer
/// (timeout, EINTR, EAGAIN), every buffer is with the kernel, including the one `next()` will
/// requeue, so first take one back with a bare dequeue (its frame is dropped). Interrupted waits
/// are retried until the deadline; a timeout or any other error is returned.
pub(super) fn wait_for_buffer<Q: BufferQueue, R>(
    queue: &mut Q,
    resync: &mut bool,
    deadline: Instant,
    on_buffer: &mut impl FnMut(&[u8], &Metadata) -> R,
) -> io::Result<R> {
    loop {
        let remaining = deadline.saturating_duration_since(Instant::now());
        if remaining.is_zero() {
            return Err(io::Error::new(io::ErrorKind::TimedOut, "deadline passed"));
        }
        queue.set_timeout(poll_timeout(remaining));
        let waited = if *resync {
            queue.dequeue().map(|()| {
                *resync = false;
                None
            })
        } else {
            queue.next_with(on_buffer).map(Some)
        };
        match waited {
            Ok(Some(r)) => return Ok(r),
            Ok(None) => continue,
            Err(e) => {
                let no_buffer = retry_in_place(&e) || e.kind() == io::ErrorKind::TimedOut;
                *resync |= no_buffer;
                if !retry_in_place(&e) {
                    return Err(e);
                }
            }
        }
    }
}

// --- Streaming ----------------------------------------------------------------------------------

/// An open, configured device and its mmap stream (started lazily by the first frame).
pub(super) struct Streaming {
    /// `Option` only so that teardown can take them in its own order; always `Some` otherwise.
    stream: Option<MmapStream<'static>>,
    device: Option<Device>,
    converter: FrameConverter,
    /// Set after a wait that returned no buffer (see the module docs): take a buffer back with
    /// a bare dequeue before the next `next()`.
    resync: bool,
    /// The driver's timestamps were unusable once already (logged once per open).
    clock_warned: bool,
}

impl Streaming {
    pub(super) fn open(
        name: &str,
        config: &V4l2Config,
        output: PixelFormat,
    ) -> Result<Self, SourceError> {
        if let Err(e) = config.validate() {
            return Err(SourceError::Format {
                device: name.to_owned(),
                reason: "bad camera config".into(),
                cause: Some(e.into()),
            });
        }
        let device = Device::with_path(&config.device).map_err(|e| open_error(name, "open", &e))?;
        let fd = device.handle().fd();
        let (caps, device_caps) =
            query_capabilities(fd).map_err(|e| open_error(name, "VIDIOC_QUERYCAP", &e))?;
        check_capabilities(caps, device_caps).map_err(|reason| SourceError::Format {
            device: name.to_owned(),
            reason,
            cause: None,
        })?;
        let negotiated = set_format(fd, config).map_err(|e| match e.raw_os_error() {
            Some(libc::EINVAL) => SourceError::Format {
                device: name.to_owned(),
                reason: format!(
                    "VIDIOC_S_FMT refused {}x{} {}",
                    config.width, config.height, config.format
                ),
                cause: Some(e.into()),
            },
            _ => open_error(name, "VIDIOC_S_FMT", &e),
        })?;
        check_format(name, config, &negotiated)?;
        match set_frame_rate(fd, config.fps) {
            Ok(Some((num, den))) => check_frame_rate(name, config.fps, num, den)?,
            Ok(None) => tracing::warn!(
                device = name,
                fps = config.fps,
                "driver has no frame-rate control; streaming at its own rate"
            ),
            Err(e) => return Err(open_error(name, "VIDIOC_S_PARM", &e)),
        }
        let converter = FrameConverter::new(
            config.format,
            negotiated.width,
            negotiated.height,
            negotiated.stride,
            output,
            negotiated.size_image as usize,
        )
        .map_err(|e| SourceError::Format {
            device: name.to_owned(),
            reason: "the negotiated format".into(),
            cause: Some(e.into()),
        })?;
        let stream = MmapStream::with_buffers(&device, BufferType::VideoCapture, BUFFERS)
            .map_err(|e| open_error(name, "mmap buffers", &e))?;
        tracing::info!(
            device = name,
            width = negotiated.width,
            height = negotiated.height,
            format = %config.format,
            stride = negotiated.stride,
            size_image = negotiated.size_image,
            "camera configured"
        );
        Ok(Self {
            stream: Some(stream),
            device: Some(device),
            converter,
            resync: false,
            clock_warned: false,
        })
    }

    pub(super) fn next_frame(
        &mut self,
        name: &str,
        out: &mut PreparedImage,
        timeout: Duration,
    ) -> Result<FrameMeta, SourceError> {
        let Some(stream) = self.stream.as_mut() else {
            return Err(SourceError::Disconnected {
                device: name.to_owned(),
                reason: "stream closed".into(),
                cause: None,
            });
        };
        let converter = &mut self.converter;
        let clock_warned = &mut self.clock_warned;
        let deadline = Instant::now() + timeout;
        let mut on_buffer = |buffer: &[u8], meta: &Metadata| {
            let now = monotonic_now();
            let corrupt =
                |reason: String, cause: Option<crate::source::Cause>| SourceError::Corrupt {
                    device: name.to_owned(),
                    reason,
                    cause,
                };
            if meta.flags.bits() & BUF_FLAG_ERROR != 0 {
                return Err(corrupt(
                    format!("driver flagged buffer {} as corrupt", meta.sequence),
                    None,
                ));
            }
            let data = payload(buffer, meta.bytesused).map_err(|r| corrupt(r, None))?;
            converter.prepare(data, out).map_err(|e| match e {
                ConvertError::Frame(_) | ConvertError::Output { .. } => SourceError::Format {
                    device: name.to_owned(),
                    reason: "converting a frame".into(),
                    cause: Some(e.into()),
                },
                _ => corrupt(format!("buffer {}", meta.sequence), Some(e.into())),
            })?;
            // time_t is i32 on 32-bit ARM.
            #[allow(clippy::unnecessary_cast)]
            let (timestamp, from_kernel) = frame_timestamp(
                meta.flags.bits(),
                meta.timestamp.sec as i64,
                meta.timestamp.usec as i64,
                now,
            );
            if !from_kernel && !*clock_warned {
                *clock_warned = true;
                tracing::warn!(
                    device = name,
                    flags = meta.flags.bits(),
                    "buffer timestamps are not CLOCK_MONOTONIC; using the dequeue time"
                );
            }
            Ok(FrameMeta {
                timestamp,
                sequence: meta.sequence as u64,
            })
        };
        match wait_for_buffer(stream, &mut self.resync, deadline, &mut on_buffer) {
            Ok(frame) => frame,
            Err(e) => Err(classify(name, "capture", &e, timeout)),
        }
    }

    /// Stops streaming and releases the buffers and the device, without the `v4l` panics.
    ///
    /// Order matters: we call STREAMOFF ourselves first. If it succeeds (or fails with ENODEV,
    /// the unplugged case), `v4l`'s `Drop` repeats it, which V4L2 defines as a no-op returning 0
    /// (or ENODEV again, which it ignores), then unmaps and frees the buffers (which cannot be
    /// busy any more). The drop is still wrapped in `catch_unwind` as a last guard.
    ///
    /// If our STREAMOFF fails otherwise, dropping the stream would panic (and freeing the
    /// buffers of a streaming queue fails with EBUSY, a second panic while unwinding: abort).
    /// Then the stream is leaked (its mappings stay until the process exits, as does the
    /// driver's claim on the camera if the kernel keeps the file open for them) and the file
    /// descriptor is closed by hand: the leaked stream holds a reference to `v4l`'s handle, so
    /// the handle never closes that descriptor a second time. The error says so.
    pub(super) fn teardown(&mut self) -> Result<(), String> {
        let (Some(mut stream), Some(device)) = (self.stream.take(), self.device.take()) else {
            return Ok(());
        };
        let fd = device.handle().fd();
        let stopped = loop {
            match stream.stop() {
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) if e.raw_os_error() == Some(libc::ENODEV) => break Ok(()),
                r => break r,
            }
        };
        if let Err(e) = stopped {
            std::mem::forget(stream);
            drop(device);
            // SAFETY: `fd` is open and owned by the handle that the leaked stream keeps alive
            // forever, so nothing else closes it.
            unsafe { libc::close(fd) };
            return Err(format!(
                "VIDIOC_STREAMOFF failed ({e}); leaked the stream's buffers and closed the device"
            ));
        }
        let dropped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || drop(stream)));
        drop(device);
        dropped.map_err(|_| "releasing the stream's buffers panicked in v4l".to_owned())
    }
}

impl Drop for Streaming {
    fn drop(&mut self) {
        if let Err(reason) = self.teardown() {
            tracing::warn!(reason, "camera teardown");
        }
    }
}
