//! Opening the hardware a configuration names (for `flyd run`; tests build their own).

use std::fs::File;
use std::io::{self, BufWriter};
use std::path::Path;

use super::DaemonError;
use super::clock::SharedClock;
use crate::can::bus::{CanBus, CandumpLogBus, RetryPolicy, SocketCanBus, SystemClock};
use crate::config::{CameraSource, CanTarget, DaemonConfig};
use crate::source::FrameSource;

/// The bus `target` names: a SocketCAN interface, or a candump log (`-` = stdout) whose
/// lines carry wall-clock timestamps as `candump -l` writes them (each line is flushed
/// as it is written, so a pipe or `tail -f` sees frames live).
pub fn open_bus(target: &CanTarget) -> Result<Box<dyn CanBus>, DaemonError> {
    match target {
        CanTarget::Interface(iface) => SocketCanBus::open(iface, RetryPolicy::default())
            .map(|bus| Box::new(bus) as Box<dyn CanBus>)
            .map_err(|error| DaemonError::Bus {
                target: iface.clone(),
                error,
            }),
        CanTarget::Log { path, iface } if path == Path::new("-") => Ok(Box::new(
            CandumpLogBus::new(io::stdout(), iface.clone(), SystemClock),
        )),
        CanTarget::Log { path, iface } => {
            let file = File::create(path).map_err(|error| DaemonError::CanLog {
                path: path.display().to_string(),
                error,
            })?;
            Ok(Box::new(CandumpLogBus::new(
                BufWriter::new(file),
                iface.clone(),
                SystemClock,
            )))
        }
    }
}

/// Left and right camera.
pub type Cameras = (Box<dyn FrameSource>, Box<dyn FrameSource>);

/// The two cameras the configuration names, stamping frames on `clock`.
pub fn open_cameras(config: &DaemonConfig, _clock: &SharedClock) -> Result<Cameras, DaemonError> {
    match &config.cameras.source {
        CameraSource::Mock { scenario } => Err(DaemonError::Cameras(format!(
            "mock scenario '{scenario}': hw-mock is not part of this build yet"
        ))),
        CameraSource::Devices { left, right } => Err(DaemonError::Cameras(format!(
            "{} and {}: V4L2 capture is not part of this build yet",
            left.display(),
            right.display()
        ))),
    }
}
