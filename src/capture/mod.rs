//! Camera capture: V4L2 devices as [`FrameSource`](crate::source::FrameSource)s.
//!
//! - [`convert`]: pure, tested conversions of what cameras send (YUYV, MJPEG, GREY) into the
//!   packed RGB8 or grey pixels [`PreparedImage`](flyd_core::frame::PreparedImage) takes.
//! - [`v4l2`]: [`V4l2Source`], the thin device layer over the `v4l` crate: format negotiation,
//!   mmap streaming with a dequeue timeout, teardown that survives a vanished device.
//!
//! The split is deliberate: this machine and CI have no V4L2, so everything that can be a pure
//! function is one, and the device layer only moves bytes between the kernel and those
//! functions. Real-device behaviour is checked in a VM (tests/vm: two v4l2loopback cameras fed
//! by the feeder), which CI boots under QEMU.

pub mod convert;
pub mod v4l2;

pub use convert::{CaptureFormat, ConvertError, FrameConverter, MjpegDecoder};
pub use v4l2::{V4l2Config, V4l2ConfigError, V4l2Source};
