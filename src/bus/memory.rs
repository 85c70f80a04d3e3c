//! In memory, for tests: [`MemoryBus`] records the frames sent (and can be told to fail),
//! [`MemoryRx`] hands over the frames a test pushed.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver, ReceivedFrame, check_frame};
use flyd_core::clock::Clock;

/// A frame [`MemoryBus`] accepted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedFrame {
    pub timestamp: Duration,
    pub id: u32,
    pub data: Vec<u8>,
}

struct MemoryState {
    clock: Box<dyn Clock>,
    frames: Vec<RecordedFrame>,
    /// Failures for the next sends, in order (one each).
    scripted: VecDeque<BusError>,
    /// Failure for every send while set (after the scripted ones).
    persistent: Option<BusError>,
    attempts: u64,
}

/// In-memory bus for tests. Clones are handles to the same recording, so a test keeps one
/// handle and gives the other to the code under test.
#[derive(Clone)]
pub struct MemoryBus {
    state: Arc<Mutex<MemoryState>>,
}

impl MemoryBus {
    pub fn new(clock: impl Clock + 'static) -> Self {
        Self {
            state: Arc::new(Mutex::new(MemoryState {
                clock: Box::new(clock),
                frames: Vec::new(),
                scripted: VecDeque::new(),
                persistent: None,
                attempts: 0,
            })),
        }
    }

    fn lock(&self) -> MutexGuard<'_, MemoryState> {
        // A panic while holding the lock cannot leave the state half-updated (every update is
        // a single push or pop), so a poisoned lock is still usable.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Frames sent so far.
    pub fn frames(&self) -> Vec<RecordedFrame> {
        self.lock().frames.clone()
    }

    /// Frames sent so far, clearing the recording.
    pub fn take_frames(&self) -> Vec<RecordedFrame> {
        std::mem::take(&mut self.lock().frames)
    }

    /// Makes the next send fail with `error` (queue several for several sends).
    pub fn fail_next(&self, error: BusError) {
        self.lock().scripted.push_back(error);
    }

    /// Makes every send fail with `error` until called with `None`.
    pub fn set_failing(&self, error: Option<BusError>) {
        self.lock().persistent = error;
    }

    /// Number of `send` calls, failed ones included.
    pub fn attempts(&self) -> u64 {
        self.lock().attempts
    }
}

impl CanBus for MemoryBus {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        let mut state = self.lock();
        state.attempts += 1;
        check_frame(id, data)?;
        if let Some(error) = state.scripted.pop_front() {
            return Err(error);
        }
        if let Some(error) = &state.persistent {
            return Err(error.clone());
        }
        let timestamp = state.clock.now();
        state.frames.push(RecordedFrame {
            timestamp,
            id,
            data: data.to_vec(),
        });
        Ok(())
    }
}

/// Frames pushed by a test (or any producer) into a shared queue.
#[derive(Clone, Default)]
pub struct MemoryRx(Arc<Mutex<VecDeque<ReceivedFrame>>>);

impl MemoryRx {
    pub fn push(&self, id: u32, data: &[u8]) {
        if let Some(frame) = ReceivedFrame::new(id, data) {
            self.0
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push_back(frame);
        }
    }
}

impl CanReceiver for MemoryRx {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        Ok(self
            .0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop_front())
    }
}
