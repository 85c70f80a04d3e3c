//! The CAN frames flyd sends, recorded: a [`CanBus`] wrapper the control thread sends through.

use flyd_core::can::bus::{BusError, CanBus};

use super::Recorder;
use crate::os_clock::SharedClock;

/// A bus that hands every frame it accepted to the recorder (`/can/tx`), at the clock's time.
pub struct RecordingBus {
    inner: Box<dyn CanBus>,
    recorder: Option<Recorder>,
    clock: SharedClock,
    sent: u64,
}

impl RecordingBus {
    pub fn new(inner: Box<dyn CanBus>, recorder: Option<Recorder>, clock: SharedClock) -> Self {
        Self {
            inner,
            recorder,
            clock,
            sent: 0,
        }
    }
}

impl CanBus for RecordingBus {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        self.inner.send(id, data)?;
        if let Some(recorder) = &self.recorder {
            self.sent += 1;
            recorder.can(true, self.sent, self.clock.now(), id, data);
        }
        Ok(())
    }
}
