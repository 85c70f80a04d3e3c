//! A v4l2loopback camera's output side, shared by the guest programs.

use std::fs::File;
use std::mem::ManuallyDrop;
use std::os::fd::FromRawFd;

use anyhow::{Context, Result, ensure};
use v4l::video::Output;
use v4l::{Device, Format, FourCC};

/// The output side of `path` set to `width` x `height` `fourcc` (checked: the driver must not
/// change it), and a `File` on the device's descriptor, which is how v4l2loopback takes frames
/// (`write()`). The `File` must not outlive the `Device`.
pub fn open_output(
    path: &str,
    width: u32,
    height: u32,
    fourcc: &[u8; 4],
) -> Result<(Device, ManuallyDrop<File>, Format)> {
    let dev = Device::with_path(path).with_context(|| format!("opening {path}"))?;
    let wanted = Format::new(width, height, FourCC::new(fourcc));
    let got = Output::set_format(&dev, &wanted)
        .with_context(|| format!("VIDIOC_S_FMT (VIDEO_OUTPUT) {wanted} on {path}"))?;
    ensure!(
        (got.width, got.height, got.fourcc) == (wanted.width, wanted.height, wanted.fourcc),
        "{path} accepted {got} instead of {wanted}"
    );
    // SAFETY: the descriptor belongs to `dev`, which the caller keeps as long as the `File`;
    // ManuallyDrop keeps the `File` from closing it.
    let out = ManuallyDrop::new(unsafe { File::from_raw_fd(dev.handle().fd()) });
    Ok((dev, out, got))
}
