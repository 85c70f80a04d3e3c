//! Opening the hardware a configuration names (for `flyd run`; tests build their own).

use std::fs::File;
use std::io::{self, BufWriter};
use std::path::Path;

use super::DaemonError;
use crate::bus::{
    CandumpLogBus, CandumpReplayRx, ReopeningBus, RetryPolicy, SocketCanBus, SocketCanRx,
};
use crate::capture::{V4l2Config, V4l2Source};
use crate::config::{CameraSource, CanTarget, DaemonConfig};
use crate::mock::camera::mock_cameras;
use crate::mock::vehicle::MockVehicle;
use crate::os_clock::SharedClock;
use crate::os_clock::SystemClock;
use crate::source::FrameSource;
use flyd_core::can::bus::{CanBus, CanReceiver};

/// The bus `target` names: a SocketCAN interface, or a candump log (`-` = stdout) whose
/// lines carry wall-clock timestamps as `candump -l` writes them (each line is flushed
/// as it is written, so a pipe or `tail -f` sees frames live).
pub fn open_bus(target: &CanTarget) -> Result<Box<dyn CanBus>, DaemonError> {
    match target {
        // Reopened when it vanishes, waited for when it does not exist yet (the unit need not
        // start after the interface: systemd/README.md).
        CanTarget::Interface(iface) => {
            let name = iface.clone();
            let open = move || SocketCanBus::open(&name, RetryPolicy::default());
            ReopeningBus::new(iface, open, super::MonotonicClock)
                .map(|bus| Box::new(bus) as Box<dyn CanBus>)
                .map_err(|error| DaemonError::Bus {
                    target: iface.clone(),
                    error,
                })
        }
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

/// Where the vehicle's frames (its motion) come from, or `None` when the configuration
/// wants no motion (`vehicle.motion = "none"`) or nothing can send it:
///
/// - `input`, a candump log (`flyd run --can-input`): its frames replayed on `clock` from now,
///   whatever the bus (a recorded drive's bus, without a kernel);
/// - a SocketCAN interface: a socket of its own receiving the motion's ID only, reopened as
///   the sending one is when the interface goes;
/// - a candump log as the bus, with mock cameras: the hw-mock vehicle, sending its scenario's
///   speed ([`MockVehicle`]); with real cameras nothing (MotionFault, assumed speed).
pub fn open_receiver(
    config: &DaemonConfig,
    input: Option<&Path>,
    clock: &SharedClock,
) -> Result<Option<Box<dyn CanReceiver>>, DaemonError> {
    if config.motion().is_none() {
        return Ok(None);
    }
    let motion = config.can.messages.motion;
    if let Some(path) = input {
        let clock = clock.clone();
        let rx = CandumpReplayRx::open(path, move || clock.now())?;
        tracing::info!(
            input = %path.display(),
            frames = rx.remaining(),
            "CAN input: replaying a candump log as the received frames"
        );
        return Ok(Some(Box::new(rx)));
    }
    match (&config.can.target, &config.cameras.source) {
        (CanTarget::Interface(iface), _) => {
            let name = iface.clone();
            let open = move || SocketCanRx::open(&name, &[motion.id]);
            ReopeningBus::beside(iface, open, super::MonotonicClock)
                .map(|rx| Some(Box::new(rx) as Box<dyn CanReceiver>))
                .map_err(|error| DaemonError::Bus {
                    target: iface.clone(),
                    error,
                })
        }
        (CanTarget::Log { .. }, CameraSource::Mock { scenario, .. }) => {
            Ok(hw_mock::Scenario::by_name(scenario).map(|s| {
                Box::new(MockVehicle::new(s, motion, clock.clone())) as Box<dyn CanReceiver>
            }))
        }
        (CanTarget::Log { .. }, CameraSource::Devices { .. }) => Ok(None),
    }
}

/// Left and right camera.
pub type Cameras = (Box<dyn FrameSource>, Box<dyn FrameSource>);

/// The two cameras the configuration names. V4L2 devices stamp frames with the kernel's
/// CLOCK_MONOTONIC buffer time (pair them with [`super::MonotonicClock`]); mock cameras with
/// `clock`.
pub fn open_cameras(config: &DaemonConfig, clock: &SharedClock) -> Result<Cameras, DaemonError> {
    match &config.cameras.source {
        CameraSource::Mock {
            scenario,
            faults,
            looped,
        } => {
            let (w, h) = (config.cameras.width, config.cameras.height);
            let (mut left, mut right, _) = mock_cameras(scenario, w, h, clock, faults)?;
            if *looped {
                left.play_in_a_loop();
                right.play_in_a_loop();
            }
            if config.cameras.pixel_format == crate::capture::CaptureFormat::Mjpg {
                // The V4L2 MJPEG path (decode, then prepare), on the mock's frames.
                for camera in [&mut left, &mut right] {
                    camera.deliver_mjpeg().map_err(|e| {
                        DaemonError::MockCameras(crate::mock::camera::MockCameraError::Mjpeg(e))
                    })?;
                }
            }
            Ok((Box::new(left), Box::new(right)))
        }
        CameraSource::Devices { left, right } => {
            let c = &config.cameras;
            let camera =
                |device: &std::path::PathBuf| -> Result<Box<dyn FrameSource>, DaemonError> {
                    let v4l2 = V4l2Config {
                        device: device.clone(),
                        width: c.width,
                        height: c.height,
                        fps: c.fps.round() as u32,
                        format: c.pixel_format,
                    };
                    v4l2.validate().map_err(|error| DaemonError::CameraConfig {
                        device: device.display().to_string(),
                        error,
                    })?;
                    // Not opened here: a camera missing at start is a fault the daemon reports
                    // (CAMERA_ERROR, safe command) while its capture thread retries, not a
                    // reason to refuse to start.
                    let output = c.device_output();
                    Ok(Box::new(V4l2Source::new(v4l2, output)))
                };
            Ok((camera(left)?, camera(right)?))
        }
    }
}

/// The lock that keeps a second flyd off `iface`: an abstract Unix socket named
/// `flyd-can-IFACE` (no file to leave behind; released by the kernel when the process ends,
/// however it ends; per network namespace, as the interfaces themselves).
pub struct InterfaceLock(#[allow(dead_code)] std::os::unix::net::UnixDatagram);

/// Takes the lock of `iface`, or says which flyd holds it.
pub fn lock_interface(iface: &str) -> Result<InterfaceLock, DaemonError> {
    use std::os::linux::net::SocketAddrExt;
    let name = format!("flyd-can-{iface}");
    let addr =
        std::os::unix::net::SocketAddr::from_abstract_name(name.as_bytes()).map_err(|error| {
            DaemonError::Lock {
                iface: iface.into(),
                name: name.clone(),
                error,
            }
        })?;
    std::os::unix::net::UnixDatagram::bind_addr(&addr)
        .map(InterfaceLock)
        .map_err(|error| DaemonError::Lock {
            iface: iface.into(),
            name,
            error,
        })
}
