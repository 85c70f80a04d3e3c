//! Recording and the live view: what flyd saw, found, decided and sent, as MCAP files and
//! over the Foxglove WebSocket protocol.
//!
//! ```text
//!  capture threads --frames--\
//!  evolution thread --pairs, flies-->  bounded queue (try_send)  -->[flyd-record]--> MCAP file(s)
//!  control thread --snapshots, decisions, CAN tx/rx, stats--/            writer   \-> Foxglove WS
//! ```
//!
//! - The real-time threads hand [`Record`]s to the writer thread through one bounded queue
//!   with `try_send`; big payloads (images, flies) travel in buffers taken from pools filled at
//!   start, so a producer never allocates and never waits. A full queue or an empty pool drops
//!   the record: counted ([`RecordCounters`]), logged once per episode, never a delay.
//! - The writer ([`writer`]) encodes and writes; a write error (a full disk) stops the
//!   recording with an error log and [`RecordCounters::failed`] set: a fault of the recorder,
//!   never of the perception (the daemon drives on).
//! - The topics and their schemas are in [`topics`]; [`read`] reads a recording back for
//!   `flyd replay --mcap`.
//!
//! What is recorded makes a replay exact: every frame as the capture thread prepared it (the
//! packed pixels given to `PreparedImage::prepare`), every new pair with the first generation
//! run on it and the motion its flies were moved with, every snapshot the decider was fed with
//! the speed and latency then, every command with its faults, and every CAN frame. The
//! configuration's text is attached (`config.toml`).

mod live;
mod mcap_file;
pub mod options;
pub mod read;
pub mod recording_bus;
mod scene;
pub mod topics;
pub mod writer;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};

use crate::source::Side;
use flyd_core::engine::Population;
use flyd_core::frame::{PixelFormat, Retained};
use topics::{CanEvent, DecisionEvent, PairEvent, PerceptionEvent, StatsEvent};

pub use options::{LiveOptions, RecordOptions, WriterError};
pub use writer::spawn_writer;

/// Floats per fly in a [`Record::Flies`] buffer: x, y, z (vehicle frame), fitness, warning.
pub const FLY_FLOATS: usize = 5;

/// One thing to record, as the real-time threads hand it over.
#[derive(Debug)]
pub enum Record {
    /// A camera frame as prepared (`pixels` is a pool buffer: `pixels[..len]`): its packed
    /// pixels (`format`), or an MJPEG camera's JPEG (`format` is `None`).
    Frame {
        side: Side,
        timestamp: Duration,
        format: Option<PixelFormat>,
        width: u32,
        height: u32,
        len: usize,
        pixels: Vec<u8>,
    },
    /// The population after a generation (`points` is a pool buffer, [`FLY_FLOATS`] a fly).
    Flies {
        at: Duration,
        flies: usize,
        points: Vec<f32>,
    },
    Pair {
        at: Duration,
        event: PairEvent,
    },
    Perception {
        event: PerceptionEvent,
        /// The latest obstacle estimate (for the scene), vehicle frame: distance, lateral,
        /// bottom, top.
        obstacle: Option<[f64; 4]>,
        confirmed: bool,
    },
    Decision(DecisionEvent),
    Stats(StatsEvent),
    Can {
        sent: bool,
        seq: u64,
        at: Duration,
        id: u32,
        len: u8,
        data: [u8; 8],
    },
}

/// What the recorder did, read by the stats and at the end (`Relaxed`: statistics).
#[derive(Debug, Default)]
pub struct RecordCounters {
    pub written: AtomicU64,
    /// Records dropped: the queue was full, or no buffer was free (a replay of the recording
    /// stops where one is missing).
    pub dropped: AtomicU64,
    /// Populations not recorded because the writer was still busy with the previous ones
    /// (they only show the flies; a replay does not need them).
    pub flies_skipped: AtomicU64,
    /// Bytes handed to the file(s), uncompressed payloads.
    pub bytes: AtomicU64,
    /// The recording stopped on a write error.
    pub failed: AtomicBool,
    /// A drop episode is being logged (reset when a record passes again).
    dropping: AtomicBool,
}

impl RecordCounters {
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
    pub fn written(&self) -> u64 {
        self.written.load(Ordering::Relaxed)
    }
    pub fn has_failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }
}

/// A bounded pool of equally sized buffers, filled at start.
#[derive(Debug, Clone)]
struct Pool<T> {
    free: Receiver<Vec<T>>,
    back: Sender<Vec<T>>,
}

impl<T: Clone + Default> Pool<T> {
    fn new(buffers: usize, len: usize) -> Self {
        let (back, free) = crossbeam_channel::bounded(buffers);
        for _ in 0..buffers {
            // Cannot fail: the channel holds `buffers` items.
            let _ = back.try_send(vec![T::default(); len]);
        }
        Self { free, back }
    }

    fn take(&self) -> Option<Vec<T>> {
        self.free.try_recv().ok()
    }

    /// Puts a buffer back (dropped if the pool is somehow full: never blocks).
    fn give(&self, buffer: Vec<T>) {
        let _ = self.back.try_send(buffer);
    }
}

/// The real-time threads' handle on the recorder: cheap to clone, never blocks.
#[derive(Debug, Clone)]
pub struct Recorder {
    queue: Sender<Record>,
    frames: Pool<u8>,
    flies: Pool<f32>,
    counters: Arc<RecordCounters>,
    /// Record the images (`record.images`).
    images: bool,
    /// Record the flies every this many generations (`record.flies_every`).
    flies_every: u64,
    /// Wait for room instead of dropping (an offline run: a replay that records).
    wait: bool,
}

/// What the writer thread gets besides the queue: the pools to give buffers back to.
pub struct Returns {
    frames: Pool<u8>,
    flies: Pool<f32>,
}

impl Returns {
    pub fn frame(&self, buffer: Vec<u8>) {
        self.frames.give(buffer);
    }
    pub fn flies(&self, buffer: Vec<f32>) {
        self.flies.give(buffer);
    }
}

/// Queue and pool sizes of a recorder.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecorderSizes {
    /// Records in the queue at most.
    pub queue: usize,
    pub width: u32,
    pub height: u32,
    pub flies: usize,
    pub images: bool,
    pub flies_every: u64,
    /// Camera frames per second (the frame pool holds a second of both cameras).
    pub fps: f64,
}

/// A recorder's handle and the writer's end of its queue.
pub fn channel(sizes: RecorderSizes) -> (Recorder, Receiver<Record>, Returns) {
    let (queue, rx) = crossbeam_channel::bounded(sizes.queue);
    // A second of both cameras in flight (at least 8 frames): a writer stalled that long by
    // the disk or a busy core drops nothing. The buffers are zeroed pages until first used.
    let frame_len = sizes.width as usize * sizes.height as usize * 3;
    let second = (2.0 * sizes.fps.clamp(1.0, 120.0)).ceil() as usize;
    let frames = Pool::new(if sizes.images { second.max(8) } else { 0 }, frame_len);
    let flies = Pool::new(8, sizes.flies * FLY_FLOATS);
    let recorder = Recorder {
        queue,
        frames: frames.clone(),
        flies: flies.clone(),
        counters: Arc::new(RecordCounters::default()),
        images: sizes.images,
        flies_every: sizes.flies_every.max(1),
        wait: false,
    };
    (recorder, rx, Returns { frames, flies })
}

/// A recording written by an offline run (`flyd replay --record`): the writer thread as the
/// daemon's, but its producers wait for room instead of dropping (nothing real-time waits on
/// them).
pub struct OfflineRecorder {
    pub recorder: Recorder,
    writer: writer::Writer,
}

impl OfflineRecorder {
    pub fn start(
        path: &std::path::Path,
        rig: &flyd_core::geometry::StereoRig,
        sizes: RecorderSizes,
        config_text: Option<String>,
        metadata: std::collections::BTreeMap<String, String>,
    ) -> Result<Self, WriterError> {
        let (mut recorder, rx, returns) = channel(sizes);
        recorder.wait = true;
        let options = RecordOptions {
            path: Some(path.to_path_buf()),
            rotate_bytes: None,
            rotate_after: None,
            compression: true,
            live: None,
            config_text,
            metadata,
        };
        let writer = spawn_writer(options, rig, rx, returns, recorder.counters().clone())?;
        if recorder.counters().has_failed() {
            return Err(WriterError::Create {
                path: path.display().to_string(),
                error: std::io::Error::other("the file cannot be written"),
            });
        }
        Ok(Self { recorder, writer })
    }

    /// Waits for the writer to write everything and close the file.
    pub fn finish(self) -> Result<writer::WriterReport, WriterError> {
        let Self { recorder, writer } = self;
        let failed = recorder.counters().clone();
        drop(recorder);
        let report = writer
            .handle
            .join()
            .map_err(|_| WriterError::Spawn(std::io::Error::other("flyd-record panicked")))?;
        if failed.has_failed() {
            return Err(WriterError::Create {
                path: report
                    .files
                    .first()
                    .map_or_else(String::new, |p| p.display().to_string()),
                error: std::io::Error::other("a write failed (see the log)"),
            });
        }
        Ok(report)
    }
}

impl Recorder {
    pub fn counters(&self) -> &Arc<RecordCounters> {
        &self.counters
    }

    /// Whether the flies of `generation` are due.
    pub fn flies_due(&self, generation: u64) -> bool {
        generation.is_multiple_of(self.flies_every)
    }

    /// Hands `record` over without waiting; a full queue drops it (counted, logged once per
    /// episode). Returns the record when it was not taken (its buffer goes back to a pool).
    fn send(&self, record: Record) -> Option<Record> {
        if self.wait {
            return self.queue.send(record).err().map(|e| e.into_inner());
        }
        match self.queue.try_send(record) {
            Ok(()) => {
                if self.counters.dropping.swap(false, Ordering::Relaxed) {
                    tracing::info!(dropped = self.counters.dropped(), "recorder keeps up again");
                }
                None
            }
            Err(TrySendError::Full(r) | TrySendError::Disconnected(r)) => {
                self.dropped();
                Some(r)
            }
        }
    }

    fn dropped(&self) {
        let c = &self.counters;
        c.dropped.fetch_add(1, Ordering::Relaxed);
        if !c.dropping.swap(true, Ordering::Relaxed) && !c.has_failed() {
            tracing::warn!(
                dropped = c.dropped(),
                "recorder queue full: records are dropped (the disk or the live view is too \
                 slow); the perception is not delayed (logged once until it keeps up)"
            );
        }
    }

    /// A frame as prepared: what `PreparedImage::prepare` was given, or the JPEG it was
    /// decoded from ([`PreparedImage::pixels`](flyd_core::frame::PreparedImage::pixels)).
    pub fn frame(
        &self,
        side: Side,
        timestamp: Duration,
        (width, height): (u32, u32),
        frame: Retained<'_>,
    ) {
        let (format, pixels) = match frame {
            Retained::Raw(format, pixels) => (Some(format), pixels),
            Retained::Jpeg(jpeg) => (None, jpeg),
        };
        if !self.images {
            return;
        }
        let taken = if self.wait {
            self.frames.free.recv().ok()
        } else {
            self.frames.take()
        };
        let Some(mut buffer) = taken else {
            self.dropped();
            return;
        };
        let Some(to) = buffer.get_mut(..pixels.len()) else {
            self.frames.give(buffer);
            self.dropped();
            return;
        };
        to.copy_from_slice(pixels);
        let record = Record::Frame {
            side,
            timestamp,
            format,
            width,
            height,
            len: pixels.len(),
            pixels: buffer,
        };
        if let Some(Record::Frame { pixels, .. }) = self.send(record) {
            self.frames.give(pixels);
        }
    }

    /// The population after `generation`, if due.
    pub fn flies(&self, generation: u64, at: Duration, population: &Population) {
        if self.flies_due(generation) {
            self.fly_fields(at, population.into());
        }
    }

    fn fly_fields(&self, at: Duration, p: FlyFields<'_>) {
        let taken = if self.wait {
            self.flies.free.recv().ok()
        } else {
            self.flies.take()
        };
        let Some(mut buffer) = taken else {
            self.counters.flies_skipped.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let n = p.len().min(buffer.len() / FLY_FLOATS);
        for (i, fly) in buffer.chunks_exact_mut(FLY_FLOATS).take(n).enumerate() {
            fly.copy_from_slice(&[p.x[i], p.y[i], p.z[i], p.fitness[i], p.warning[i]]);
        }
        let record = Record::Flies {
            at,
            flies: n,
            points: buffer,
        };
        let refused = if self.wait {
            self.queue.send(record).err().map(|e| e.into_inner())
        } else {
            self.queue.try_send(record).err().map(|e| match e {
                TrySendError::Full(r) | TrySendError::Disconnected(r) => r,
            })
        };
        match refused {
            None => {}
            Some(r) => {
                self.counters.flies_skipped.fetch_add(1, Ordering::Relaxed);
                if let Record::Flies { points, .. } = r {
                    self.flies.give(points);
                }
            }
        }
    }

    pub fn pair(&self, at: Duration, event: PairEvent) {
        self.send(Record::Pair { at, event });
    }

    pub fn perception(&self, event: PerceptionEvent, obstacle: Option<[f64; 4]>, confirmed: bool) {
        self.send(Record::Perception {
            event,
            obstacle,
            confirmed,
        });
    }

    pub fn decision(&self, event: DecisionEvent) {
        self.send(Record::Decision(event));
    }

    pub fn stats(&self, event: StatsEvent) {
        self.send(Record::Stats(event));
    }

    /// A CAN frame sent (accepted by the bus) or received; `data` is at most 8 bytes.
    pub fn can(&self, sent: bool, seq: u64, at: Duration, id: u32, data: &[u8]) {
        let mut bytes = [0; 8];
        let len = data.len().min(8);
        bytes[..len].copy_from_slice(&data[..len]);
        self.send(Record::Can {
            sent,
            seq,
            at,
            id,
            len: len as u8,
            data: bytes,
        });
    }
}

/// The fields of the flies a recording keeps.
#[derive(Debug, Clone, Copy)]
struct FlyFields<'a> {
    x: &'a [f32],
    y: &'a [f32],
    z: &'a [f32],
    fitness: &'a [f32],
    warning: &'a [f32],
}

impl FlyFields<'_> {
    fn len(&self) -> usize {
        [self.y, self.z, self.fitness, self.warning]
            .iter()
            .fold(self.x.len(), |n, f| n.min(f.len()))
    }
}

impl<'a> From<&'a Population> for FlyFields<'a> {
    fn from(p: &'a Population) -> Self {
        Self {
            x: &p.x,
            y: &p.y,
            z: &p.z,
            fitness: &p.fitness,
            warning: &p.warning,
        }
    }
}

/// What a snapshot (a generation's outcome) says, as recorded: `generation_time` is the
/// generation's wall time.
#[derive(Debug, Clone, Copy)]
pub struct Observed<'a> {
    pub generation: u64,
    pub warming_up: bool,
    pub global_warning: f64,
    pub matched: f64,
    pub generation_time: Duration,
    pub road: &'a flyd_core::perception::RoadEstimate,
    pub tracked: &'a flyd_core::perception::Tracked,
    /// The paths the corridor followed (none: straight, no trusted motion).
    pub path: Option<flyd_core::path::PathEstimate>,
    /// How far ahead the frame was searched, metres.
    pub search_far: f64,
}

impl Recorder {
    /// A snapshot fed to the decider as `input`, at `t` (control-thread event `seq`).
    pub fn snapshot(
        &self,
        seq: u64,
        t: Duration,
        o: Observed<'_>,
        input: &flyd_core::decision::DecisionInput,
    ) {
        let candidate = o.tracked.obstacle;
        let plane = o.road.plane;
        let event = PerceptionEvent {
            seq,
            t_ns: nanos(t),
            generation: o.generation,
            warming_up: o.warming_up,
            global_warning: o.global_warning,
            obstacle_m: input.obstacle,
            candidate_m: candidate.map(|c| c.distance),
            candidate_lateral_m: candidate.map(|c| c.lateral),
            speed: input.speed,
            latency: input.latency,
            road_height_m: plane.height,
            road_slope_z: plane.slope_z,
            road_slope_x: plane.slope_x,
            road_measured: o.road.measured(),
            matched: o.matched,
            generation_us: o.generation_time.as_secs_f64() * 1e6,
            path_curvature: o.path.map(|p| p.held.curvature),
            path_curvature_now: o.path.map(|p| p.now.curvature),
            path_curvature_rate: o.path.map(|p| p.held.rate).filter(|r| *r != 0.0),
            search_far_m: Some(o.search_far),
            candidate_speed_mps: o.tracked.motion.map(|m| m.speed),
            candidate_speed_sigma: o.tracked.motion.map(|m| m.speed_sigma),
            obstacle_speed_mps: input.obstacle.map(|_| input.credited()),
            candidate_lateral_speed_mps: o.tracked.motion.map(|m| m.lateral_speed),
            entering_s: o.tracked.entering,
        };
        let obstacle = candidate.map(|c| [c.distance, c.lateral, c.bottom, c.top]);
        self.perception(event, obstacle, o.tracked.confirmed);
    }

    /// A command decided at `t` from `input` (which came `from` there; `latest`: the
    /// snapshot's generation and input when it was the newest one again).
    #[allow(clippy::too_many_arguments)]
    pub fn command(
        &self,
        seq: u64,
        t: Duration,
        from: topics::InputFrom,
        latest: Option<(u64, flyd_core::decision::DecisionInput)>,
        faults: flyd_core::status::FaultBits,
        state: flyd_core::status::State,
        input: &flyd_core::decision::DecisionInput,
        decision: &flyd_core::decision::Decision,
    ) {
        self.decision(DecisionEvent {
            seq,
            t_ns: nanos(t),
            from,
            latest_generation: latest.map(|(g, _)| g),
            latest_speed: latest.map(|(_, i)| i.speed),
            latest_latency: latest.map(|(_, i)| i.latency),
            faults: u32::from(faults.bits()),
            command: topics::String8::new(decision.command.name()),
            reason: topics::String8::new(decision.reason.name()),
            changed: decision.changed,
            global_warning: input.global_warning,
            obstacle_m: input.obstacle,
            obstacle_speed_mps: input.obstacle.map(|_| input.credited()),
            speed: input.speed,
            state: topics::String8::new(state.name()),
        });
    }
}

/// A [`CanEvent`] of a recorded frame.
pub fn can_event(seq: u64, at: Duration, id: u32, data: &[u8]) -> CanEvent {
    CanEvent {
        seq,
        t_ns: nanos(at),
        id,
        data: topics::hex(data),
    }
}

/// A clock time in nanoseconds (saturating).
pub fn nanos(t: Duration) -> u64 {
    u64::try_from(t.as_nanos()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests;
