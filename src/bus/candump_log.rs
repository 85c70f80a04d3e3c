//! candump logs: [`CandumpLogBus`] writes every frame sent as a `candump -l` line (a file,
//! stdout; replayable with `canplayer`), [`CandumpReplayRx`] replays a recorded drive's log as
//! received frames on the clock.

use std::collections::VecDeque;
use std::io::{self, Write};
use std::time::Duration;

use flyd_core::can::bus::{BusError, CanBus, CanReceiver, ReceivedFrame, check_frame};
use flyd_core::can::candump::{format_candump_line, parse_candump_line};
use flyd_core::clock::Clock;

use super::classify;

/// Writes every frame as a `candump -l` line, flushed at once (a crash loses no frame, and a
/// pipe to `canplayer` or a viewer sees frames live).
pub struct CandumpLogBus<W: Write + Send, C: Clock> {
    out: W,
    iface: String,
    clock: C,
}

impl<W: Write + Send, C: Clock> CandumpLogBus<W, C> {
    /// `iface` is the interface name written into each line (what `canplayer` replays onto,
    /// unless remapped with `canplayer vcan0=can0`).
    pub fn new(out: W, iface: impl Into<String>, clock: C) -> Self {
        Self {
            out,
            iface: iface.into(),
            clock,
        }
    }

    /// Writes one frame with an explicit timestamp (for callers that already hold one).
    pub fn write_frame_at(
        &mut self,
        timestamp: Duration,
        id: u32,
        data: &[u8],
    ) -> Result<(), BusError> {
        check_frame(id, data)?;
        let mut line = format_candump_line(timestamp, &self.iface, id, data);
        line.push('\n');
        self.out
            .write_all(line.as_bytes())
            .and_then(|()| self.out.flush())
            .map_err(|e| classify(&e))
    }

    pub fn get_ref(&self) -> &W {
        &self.out
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}

impl<W: Write + Send, C: Clock> CanBus for CandumpLogBus<W, C> {
    fn send(&mut self, id: u32, data: &[u8]) -> Result<(), BusError> {
        let now = self.clock.now();
        self.write_frame_at(now, id, data)
    }
}

/// Frames of a candump log (`candump -l` / `-L` lines, as `canplayer` reads them), released
/// on the clock at their times relative to the first frame: a recorded drive's bus replayed
/// into flyd without a kernel. Frames of every ID are returned; the caller picks.
pub struct CandumpReplayRx<C: Clock> {
    frames: VecDeque<(Duration, ReceivedFrame)>,
    clock: C,
    start: Duration,
}

/// Why a candump log could not be read as input.
#[derive(Debug, thiserror::Error)]
pub enum ReplayLogError {
    #[error("reading {path}")]
    Read {
        path: String,
        #[source]
        error: io::Error,
    },
    #[error("{path}:{line}: not a candump line")]
    Line {
        path: String,
        line: usize,
        #[source]
        error: flyd_core::can::candump::CandumpParseError,
    },
}

impl<C: Clock> CandumpReplayRx<C> {
    /// Reads the whole log now (at most the text-file limit, [`flyd_core::textfile`]); its
    /// first frame is due at `clock.now()`.
    pub fn open(path: &std::path::Path, clock: C) -> Result<Self, ReplayLogError> {
        let shown = path.display().to_string();
        let text = flyd_core::textfile::read(path).map_err(|error| ReplayLogError::Read {
            path: shown.clone(),
            error,
        })?;
        Self::parse(&text, clock).map_err(|(line, error)| ReplayLogError::Line {
            path: shown,
            line,
            error,
        })
    }

    /// The log's text; errors carry the 1-based line.
    pub fn parse(
        text: &str,
        clock: C,
    ) -> Result<Self, (usize, flyd_core::can::candump::CandumpParseError)> {
        let mut frames = VecDeque::new();
        let mut first = None;
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let (t, _iface, id, data) = parse_candump_line(line).map_err(|e| (i + 1, e))?;
            let t0 = *first.get_or_insert(t);
            let at = Duration::try_from_secs_f64((t - t0).max(0.0)).unwrap_or(Duration::ZERO);
            if let Some(frame) = ReceivedFrame::new(id, &data) {
                frames.push_back((at, frame));
            }
        }
        let start = clock.now();
        Ok(Self {
            frames,
            clock,
            start,
        })
    }

    /// Frames not yet released.
    pub fn remaining(&self) -> usize {
        self.frames.len()
    }

    /// The frames not yet released, each with its time from the log's first frame.
    pub fn into_frames(self) -> impl Iterator<Item = (Duration, ReceivedFrame)> {
        self.frames.into_iter()
    }
}

impl<C: Clock + Send> CanReceiver for CandumpReplayRx<C> {
    fn try_recv(&mut self) -> Result<Option<ReceivedFrame>, BusError> {
        let elapsed = self.clock.now().saturating_sub(self.start);
        match self.frames.front() {
            Some(&(at, frame)) if at <= elapsed => {
                self.frames.pop_front();
                Ok(Some(frame))
            }
            _ => Ok(None),
        }
    }
}
