//! A sequence's motion from a candump log of the vehicle's bus, as the daemon receives it
//! (`flyd run --can-input`): the log's first frame is due with the sequence's first frame,
//! every `VCU_Motion` goes through the daemon's [`MotionMonitor`] (E2E CRC, alive counter,
//! staleness, plausibility) at its recorded time, and a frame's motion is what the monitor
//! trusts at that frame's time: none while it trusts none (the decision then takes the
//! assumed speed and the flies stay where they are, as in the daemon).

use std::path::Path;
use std::time::Duration;

use flyd_core::can::motion_monitor::{MotionConfig, MotionCounters, MotionMonitor};
use flyd_core::kinematics::VehicleMotion;

use super::ReplayError;
use crate::bus::CandumpReplayRx;

/// What a log gave a sequence.
#[derive(Debug, Clone)]
pub struct CanMotion {
    /// Each frame's trusted motion, if any.
    pub per_frame: Vec<Option<VehicleMotion>>,
    /// The monitor's counts over the frames used.
    pub counters: MotionCounters,
    /// `VCU_Motion` frames due after the sequence's last frame (not used).
    pub unused: usize,
}

impl CanMotion {
    /// Frames without a trusted motion.
    pub fn untrusted_frames(&self) -> usize {
        self.per_frame.iter().filter(|m| m.is_none()).count()
    }
}

/// The motion of `frames` frames at `fps` from the candump log at `path`, the `VCU_Motion`
/// frames of CAN ID `id` checked with `config`.
pub fn from_candump(
    path: &Path,
    frames: usize,
    fps: f64,
    id: u32,
    config: MotionConfig,
) -> Result<CanMotion, ReplayError> {
    let log = CandumpReplayRx::open(path, || Duration::ZERO)
        .map_err(|e| ReplayError::CanInput(Box::new(e)))?;
    let mut received = log.into_frames().filter(|(_, f)| f.id == id).peekable();
    let mut monitor = MotionMonitor::new(config);
    let mut per_frame = Vec::with_capacity(frames);
    for i in 0..frames {
        let t = Duration::from_secs_f64(i as f64 / fps);
        while let Some((at, frame)) = received.next_if(|(at, _)| *at <= t) {
            // A rejected frame is counted by the monitor, as the daemon's is.
            let _ = monitor.receive(frame.payload(), at);
        }
        per_frame.push(monitor.status(t).motion());
    }
    Ok(CanMotion {
        per_frame,
        counters: monitor.counters(),
        unused: received.count(),
    })
}
