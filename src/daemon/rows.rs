//! The right camera's rows, measured now and then while flyd runs, off the real-time path.
//!
//! A rectified pair's residual row offset ([`flyd_core::rectification`]) turns into disparity
//! errors on slanted edges; a mount that shifts, or a calibration made for another unit,
//! shows up as one. Once after the warm-up and then every [`PERIOD`], the evolution thread
//! copies the newest pair into a spare frame allocated at start (a memcpy, no allocation) and
//! hands it to the `flyd-rows` worker if that is idle; the worker (SCHED_IDLE: only on a core
//! nothing else wants) measures (15-19 ms of CPU at 320x240; `took_ms` in its log, which
//! includes the waits for an idle core), logs, and gives the frame back. The first measure is
//! logged at INFO; a residual beyond [`WARN_PX`] at WARN, with the value to put in the rig
//! file, once until it comes back under.
//!
//! On a rectified rig with `rectification.measure` on (the default), each measure the worker
//! accepts ([`RowCorrection::decide`], the policy `flyd replay` applies on a first frame:
//! refused with too few corners, at the edge of the offsets tried, or beyond
//! `MAX_RIGHT_ROW_OFFSET`; then the value in force stands) becomes the right camera's row
//! correction: the worker stores it in a [`SharedRowShift`] that the right capture thread
//! gives every frame it prepares from then on. The calibration's value is the prior. Each
//! pair's correction is recorded with the pair (`/flyd/pair`, `right_row_shift_px`), so
//! that `flyd replay --mcap` prepares the very same images.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use flyd_core::frame::{FrameError, PreparedImage, StereoFrame};
use flyd_core::rectification::{RowCorrection, RowOffset, residual_row_offset};

use crate::thread::spawn_named;

/// Time between two measures.
pub const PERIOD: Duration = Duration::from_secs(60);
/// A residual worth correcting, pixels (a tenth of a pixel is what the measure resolves; a
/// quarter already moves a slanted edge's disparity by most of a pixel).
pub const WARN_PX: f64 = 0.25;
/// The worker's thread name.
pub const THREAD: &str = "flyd-rows";

/// The right camera's row correction in force, pixels: written by the `flyd-rows` worker,
/// read by the right capture thread before each prepare (one atomic word, the f64's bits).
#[derive(Debug, Clone, Default)]
pub struct SharedRowShift(Arc<AtomicU64>);

impl SharedRowShift {
    pub fn new(px: f64) -> Self {
        Self(Arc::new(AtomicU64::new(px.to_bits())))
    }

    pub fn get(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }

    pub fn set(&self, px: f64) {
        self.0.store(px.to_bits(), Ordering::Relaxed);
    }
}

/// What the worker does with a measure.
#[derive(Debug, Clone)]
pub struct RowsPolicy {
    /// `rectification.measure`: apply accepted measures (else only log them).
    pub measure: bool,
    /// The rig is rectified ([`flyd_core::geometry::StereoRig::is_rectified`]): a measure
    /// means something only then.
    pub rectified: bool,
    /// Where an applied correction goes.
    pub shift: SharedRowShift,
}

/// The evolution thread's end: hands pairs to the worker.
pub struct RowsMonitor {
    to_worker: Sender<StereoFrame>,
    back: Receiver<StereoFrame>,
    /// The spare frame, when the worker is not holding it.
    spare: Option<StereoFrame>,
    /// When the next measure is due (`None`: the first pair after the warm-up).
    next: Option<Duration>,
}

impl RowsMonitor {
    /// A monitor for `width` x `height` pairs and its worker thread, which matches corners up
    /// to `max_disparity` px, reports against the correction the measured frame was prepared
    /// with, and corrects as `policy` says.
    pub fn start(
        width: u32,
        height: u32,
        max_disparity: u32,
        policy: RowsPolicy,
    ) -> Result<(Self, JoinHandle<()>), RowsError> {
        let spare = StereoFrame::new(
            PreparedImage::new(width, height)?,
            PreparedImage::new(width, height)?,
            0,
        );
        let (to_worker, jobs) = crossbeam_channel::bounded::<StereoFrame>(1);
        let (done, back) = crossbeam_channel::bounded::<StereoFrame>(1);
        let handle = spawn_named(THREAD, move || {
            idle_priority();
            let mut log = RowsLog::default();
            for frame in jobs {
                let started = std::time::Instant::now();
                let measured = residual_row_offset(&frame, max_disparity);
                let applied_px = frame.right.row_shift();
                // A rig that is not rectified is measured all the same (the log says how far
                // off it is), never corrected.
                let decided =
                    RowCorrection::decide(applied_px, policy.measure, policy.rectified, measured);
                match decided.refused {
                    None => {
                        policy.shift.set(decided.applied_px);
                        log.corrected(&decided, started.elapsed());
                    }
                    Some(why) => log.report(measured, applied_px, why, started.elapsed()),
                }
                if done.send(frame).is_err() {
                    break;
                }
            }
        })
        .map_err(RowsError::Spawn)?;
        let monitor = Self {
            to_worker,
            back,
            spare: Some(spare),
            next: None,
        };
        Ok((monitor, handle))
    }

    /// On a new pair after the warm-up, at `now`: a copy of `frame` for the worker when a
    /// measure is due and the worker is idle. Never blocks.
    pub fn offer(&mut self, now: Duration, frame: &StereoFrame) {
        if self.spare.is_none() {
            self.spare = self.back.try_recv().ok();
        }
        if self.next.is_some_and(|next| now < next) {
            return;
        }
        let Some(mut spare) = self.spare.take() else {
            return;
        };
        if !(spare.left.copy_from(&frame.left) && spare.right.copy_from(&frame.right)) {
            // Another size than the rings' (cannot happen): no measure.
            self.spare = Some(spare);
            return;
        }
        spare.id = frame.id;
        self.next = Some(now + PERIOD);
        match self.to_worker.try_send(spare) {
            Ok(()) => {}
            Err(TrySendError::Full(f) | TrySendError::Disconnected(f)) => self.spare = Some(f),
        }
    }
}

/// Puts the calling thread under SCHED_IDLE: the measure runs only on a core no other
/// thread wants (the capture and evolution threads keep theirs), however long it then takes.
fn idle_priority() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 names the calling thread; `param` is a valid, initialised sched_param
    // (SCHED_IDLE takes priority 0) that the call only reads.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
    if rc != 0 {
        tracing::debug!(
            error = %std::io::Error::last_os_error(),
            "rectification monitor keeps the normal priority"
        );
    }
}

/// Why the monitor could not start.
#[derive(Debug, thiserror::Error)]
pub enum RowsError {
    #[error("rectification monitor frames")]
    Frame(#[from] FrameError),
    #[error("cannot start thread {THREAD}")]
    Spawn(#[source] std::io::Error),
}

/// What the worker has said so far.
#[derive(Debug, Default)]
struct RowsLog {
    measured: bool,
    warned: bool,
}

impl RowsLog {
    /// A measure applied: the right camera's rows are corrected from now on.
    fn corrected(&mut self, c: &RowCorrection, took: Duration) {
        let level_info = !self.measured || c.measured_px.is_some_and(|m| m.abs() > WARN_PX);
        let took_ms = took.as_secs_f64() * 1e3;
        if level_info {
            tracing::info!(
                prior_px = c.prior_px,
                residual_px = c.measured_px,
                corners = c.corners,
                applied_px = c.applied_px,
                took_ms,
                "rectification: right image rows measured and corrected"
            );
        } else {
            tracing::debug!(
                prior_px = c.prior_px,
                residual_px = c.measured_px,
                applied_px = c.applied_px,
                "rectification: right image rows measured and corrected"
            );
        }
        self.measured = true;
        self.warned = false;
    }

    /// A measure not applied (`why`: the policy's reason), or none made.
    fn report(&mut self, offset: Option<RowOffset>, applied_px: f64, why: &str, took: Duration) {
        let took_ms = took.as_secs_f64() * 1e3;
        let Some(m) = offset else {
            if !self.measured {
                tracing::info!(
                    "rectification: too few corners matched to measure the right image's rows"
                );
            }
            return;
        };
        let off = m.residual_px.abs() > WARN_PX;
        if off && !self.warned {
            tracing::warn!(
                residual_px = m.residual_px,
                corners = m.corners,
                applied_px,
                took_ms,
                suggested_px = applied_px + m.residual_px,
                not_corrected = why,
                "rectification: the right image's rows are off the calibration; set \
                 rectification.right_row_offset_px in the rig file to suggested_px"
            );
        } else if !off && self.warned {
            tracing::info!(
                residual_px = m.residual_px,
                corners = m.corners,
                "rectification: the right image's rows agree with the calibration again"
            );
        } else if !self.measured {
            tracing::info!(
                residual_px = m.residual_px,
                corners = m.corners,
                applied_px,
                took_ms,
                not_corrected = why,
                "rectification: right image rows measured"
            );
        }
        self.warned = off;
        self.measured = true;
    }
}
