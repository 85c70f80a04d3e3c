//! The raw V4L2 ioctls flyd issues besides the `v4l` crate's streaming: capabilities, format
//! and frame rate. Nothing here is reachable without a V4L2 node (the VM suite's v4l2loopback
//! cameras exercise it).

use super::{CAP_TIMEPERFRAME, FIELD_NONE, Negotiated, V4l2Config};
use std::io;
use std::os::raw::{c_int, c_void};
use v4l::buffer::Type as BufferType;
use v4l::v4l_sys;
use v4l::v4l2::vidioc;

// --- Raw ioctls (the device layer; nothing here is reachable without a V4L2 node) ---------------

/// One ioctl through `v4l`'s wrapper, retried on EINTR.
///
/// # Safety
/// `T` must be the argument type `request` is defined with.
pub(super) unsafe fn xioctl<T>(
    fd: c_int,
    request: vidioc::_IOC_TYPE,
    arg: &mut T,
) -> io::Result<()> {
    loop {
        // SAFETY: the caller guarantees `T` matches `request`; `arg` outlives the call.
        match unsafe { v4l::v4l2::ioctl(fd, request, arg as *mut T as *mut c_void) } {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            r => return r,
        }
    }
}

pub(super) fn query_capabilities(fd: c_int) -> io::Result<(u32, u32)> {
    // SAFETY: all-zero is a valid v4l2_capability.
    let mut caps: v4l_sys::v4l2_capability = unsafe { std::mem::zeroed() };
    // SAFETY: VIDIOC_QUERYCAP takes a v4l2_capability.
    unsafe { xioctl(fd, vidioc::VIDIOC_QUERYCAP, &mut caps)? };
    Ok((caps.capabilities, caps.device_caps))
}

pub(super) fn set_format(fd: c_int, config: &V4l2Config) -> io::Result<Negotiated> {
    // SAFETY: all-zero is a valid v4l2_format.
    let mut fmt: v4l_sys::v4l2_format = unsafe { std::mem::zeroed() };
    fmt.type_ = BufferType::VideoCapture as u32;
    // SAFETY: `pix` is the union member for VIDEO_CAPTURE; plain integers, no invalid values.
    unsafe {
        fmt.fmt.pix.width = config.width;
        fmt.fmt.pix.height = config.height;
        fmt.fmt.pix.pixelformat = u32::from_le_bytes(config.format.fourcc());
        fmt.fmt.pix.field = FIELD_NONE;
        xioctl(fd, vidioc::VIDIOC_S_FMT, &mut fmt)?;
        let pix = fmt.fmt.pix;
        Ok(Negotiated {
            width: pix.width,
            height: pix.height,
            fourcc: pix.pixelformat.to_le_bytes(),
            stride: pix.bytesperline,
            size_image: pix.sizeimage,
        })
    }
}

/// Asks for `fps`; returns the granted interval, or `None` if the driver has no frame-rate
/// control (it then streams at its own rate).
pub(super) fn set_frame_rate(fd: c_int, fps: u32) -> io::Result<Option<(u32, u32)>> {
    // SAFETY: all-zero is a valid v4l2_streamparm.
    let mut parm: v4l_sys::v4l2_streamparm = unsafe { std::mem::zeroed() };
    parm.type_ = BufferType::VideoCapture as u32;
    // SAFETY: G_PARM/S_PARM take a v4l2_streamparm; `capture` is the member for VIDEO_CAPTURE.
    unsafe {
        match xioctl(fd, vidioc::VIDIOC_G_PARM, &mut parm) {
            Err(e) if e.raw_os_error() == Some(libc::ENOTTY) => return Ok(None),
            r => r?,
        }
        if parm.parm.capture.capability & CAP_TIMEPERFRAME == 0 {
            return Ok(None);
        }
        parm.parm.capture.timeperframe.numerator = 1;
        parm.parm.capture.timeperframe.denominator = fps;
        xioctl(fd, vidioc::VIDIOC_S_PARM, &mut parm)?;
        let t = parm.parm.capture.timeperframe;
        Ok(Some((t.numerator, t.denominator)))
    }
}
