//! The newest-frame ring between one camera's capture thread and the evolution thread.
//!
//! Three preallocated [`Slot`]s (a triple buffer, from the `triple_buffer` crate) rotate between
//! the two threads: one the capture thread writes into, one the evolution thread reads, and one
//! "back" slot holding the newest published frame. Publishing swaps the write slot with the back
//! slot; fetching swaps the read slot with the back slot when it holds something new.
//!
//! # Promises
//! - **The capture side never blocks and never allocates**: [`FrameWriter::slot`] hands out the
//!   write slot in place (the [`crate::source::FrameSource`] prepares the image straight into
//!   it), [`FrameWriter::publish`] is one atomic swap. No lock anywhere.
//! - **The newest frame is always available**: a fetch always gets the last published frame.
//! - **Old frames are overwritten**: a frame published while the previous one was never fetched
//!   replaces it; the writer counts it in [`RingCounters::dropped`].
//! - The reader owns its slot until its next fetch, and may *swap* the image out of it
//!   ([`FrameReader::slot_mut`]) into a [`flyd_core::frame::StereoFrame`]: zero copy. The image it
//!   swaps in goes back into the rotation and is overwritten by a later capture.
//!
//! # Memory ordering
//! The slots are plain memory; the only shared atomic is the crate's back-slot index (with a
//! "dirty" bit). `publish` swaps it with `AcqRel`: the *release* half orders every write to the
//! slot (pixels, metadata) before the index that hands it over, and the *acquire* half orders
//! the producer's later writes into the slot it gets back after the consumer's release of it.
//! The consumer's fetch is the mirror image (`AcqRel` swap after an `Acquire` load of the dirty
//! bit). So a slot is only ever accessed by the one thread whose index names it, and each hand
//! over is a release/acquire pair: the reader sees a frame entirely, never torn. The counters
//! here are statistics only (`Relaxed`): nothing is synchronised through them.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use triple_buffer::{Input, Output, TripleBuffer};

use crate::source::FrameMeta;
use flyd_core::frame::{FrameError, PreparedImage};
use flyd_core::sensor::ImageHealth;

/// One frame and what is known about it.
#[derive(Debug, Clone)]
pub struct Slot {
    pub image: PreparedImage,
    /// Capture time and device sequence, from the source.
    pub meta: FrameMeta,
    /// When the capture thread got it (daemon clock).
    pub arrival: Duration,
    /// What the sensor checks measured on it (the capture thread's [`ImageCheck`]).
    ///
    /// [`ImageCheck`]: flyd_core::sensor::ImageCheck
    pub health: ImageHealth,
    /// Publication number, from 1: gaps between fetches are overwritten frames.
    pub published: u64,
}

/// Counts shared by both ends (statistics, `Relaxed`).
#[derive(Debug, Default)]
pub struct RingCounters {
    published: AtomicU64,
    dropped: AtomicU64,
}

impl RingCounters {
    /// Frames published by the capture thread.
    pub fn published(&self) -> u64 {
        self.published.load(Ordering::Relaxed)
    }
    /// Frames overwritten before the reader fetched them.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// The capture thread's end.
pub struct FrameWriter {
    input: Input<Slot>,
    counters: Arc<RingCounters>,
    published: u64,
}

/// The evolution thread's end.
pub struct FrameReader {
    output: Output<Slot>,
    counters: Arc<RingCounters>,
    /// Publication number of the slot the reader holds (0: nothing fetched yet).
    current: u64,
}

/// A ring of three `width` x `height` frames (allocated here, once).
pub fn frame_ring(width: u32, height: u32) -> Result<(FrameWriter, FrameReader), FrameError> {
    Ok(frame_ring_of(PreparedImage::new(width, height)?))
}

/// A ring whose three slots hold copies of `image` (its size, and whether it keeps its
/// pixels: [`PreparedImage::retain_pixels`]).
pub fn frame_ring_of(image: PreparedImage) -> (FrameWriter, FrameReader) {
    let slot = Slot {
        image,
        meta: FrameMeta {
            timestamp: Duration::ZERO,
            sequence: 0,
        },
        arrival: Duration::ZERO,
        health: ImageHealth::default(),
        published: 0,
    };
    let (input, output) = TripleBuffer::new(&slot).split();
    let counters = Arc::new(RingCounters::default());
    (
        FrameWriter {
            input,
            counters: counters.clone(),
            published: 0,
        },
        FrameReader {
            output,
            counters,
            current: 0,
        },
    )
}

impl FrameWriter {
    /// The slot to fill. Its content is stale (any earlier frame): overwrite all of it.
    pub fn slot(&mut self) -> &mut Slot {
        self.input.input_buffer_mut()
    }

    /// Hands the filled slot to the reader (never blocks); returns `true` when this overwrote
    /// a frame the reader had not fetched (counted as a drop).
    pub fn publish(&mut self) -> bool {
        self.published += 1;
        self.input.input_buffer_mut().published = self.published;
        let overwrote = self.input.publish();
        self.counters.published.fetch_add(1, Ordering::Relaxed);
        if overwrote {
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
        overwrote
    }

    pub fn counters(&self) -> &Arc<RingCounters> {
        &self.counters
    }
}

impl FrameReader {
    /// Takes the newest published frame if there is one the reader does not hold yet; returns
    /// whether it did. The previously held slot goes back to the writer.
    pub fn fetch(&mut self) -> bool {
        if self.output.update() {
            self.current = self.output.output_buffer().published;
            true
        } else {
            false
        }
    }

    /// Whether a frame newer than the held one is waiting (one atomic load; takes nothing).
    pub fn pending(&self) -> bool {
        self.output.updated()
    }

    /// The held slot (`None` before the first fetch).
    pub fn slot(&self) -> Option<&Slot> {
        (self.current > 0).then(|| self.output.output_buffer())
    }

    /// The held slot, mutably (to swap its image out).
    pub fn slot_mut(&mut self) -> Option<&mut Slot> {
        (self.current > 0).then(|| self.output.output_buffer_mut())
    }

    pub fn counters(&self) -> &Arc<RingCounters> {
        &self.counters
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thread::spawn_named;
    use flyd_core::frame::PixelFormat;

    /// A frame that identifies `seq` in a way photometric normalisation keeps: the columns left
    /// of `1 + seq % (width - 1)` are dark, the others bright, on every row.
    fn pixels(seq: u64, width: u32, height: u32) -> Vec<u8> {
        let edge = 1 + (seq % u64::from(width - 1)) as u32;
        (0..width * height)
            .map(|i| if i % width < edge { 20 } else { 230 })
            .collect()
    }

    /// The `seq % (width - 1)` a frame shows; panics if its rows disagree (a torn frame).
    fn shown(img: &PreparedImage) -> u64 {
        let edge = |y| (0..img.width()).find(|&x| img.colour(x, y)[0] > 128);
        let first = edge(0).expect("a bright column");
        for y in 1..img.height() {
            assert_eq!(
                edge(y),
                Some(first),
                "torn frame: row {y} differs from row 0"
            );
        }
        u64::from(first - 1)
    }

    fn fill(writer: &mut FrameWriter, seq: u64) {
        let slot = writer.slot();
        let (w, h) = (slot.image.width(), slot.image.height());
        slot.image
            .prepare(PixelFormat::Grey8, &pixels(seq, w, h))
            .expect("same size");
        slot.meta = FrameMeta {
            timestamp: Duration::from_millis(seq),
            sequence: seq,
        };
        slot.arrival = Duration::from_millis(seq);
    }

    #[test]
    fn reader_gets_the_newest_and_drops_are_counted() {
        let (mut w, mut r) = frame_ring(16, 16).expect("ring");
        assert!(!r.fetch(), "nothing published yet");
        assert!(r.slot().is_none());

        fill(&mut w, 1);
        assert!(!w.publish());
        assert!(r.fetch());
        assert_eq!(r.slot().map(|s| s.meta.sequence), Some(1));
        assert!(!r.fetch(), "no newer frame: keep holding the same one");
        assert_eq!(r.slot().map(|s| s.meta.sequence), Some(1));

        for seq in 2..=4 {
            fill(&mut w, seq);
            w.publish();
        }
        assert_eq!(w.counters().dropped(), 2, "frames 2 and 3 were overwritten");
        assert!(r.fetch());
        let slot = r.slot().expect("slot");
        assert_eq!(slot.meta.sequence, 4);
        assert_eq!(slot.published, 4);
        assert_eq!(shown(&slot.image), 4);
        assert_eq!(r.counters().published(), 4);
    }

    #[test]
    fn image_can_be_swapped_out_of_the_reader_slot() {
        let (mut w, mut r) = frame_ring(16, 16).expect("ring");
        fill(&mut w, 7);
        w.publish();
        r.fetch();
        let mut mine = PreparedImage::new(16, 16).expect("image");
        std::mem::swap(&mut mine, &mut r.slot_mut().expect("slot").image);
        assert_eq!(shown(&mine), 7);
        // The swapped-in image circulates back to the writer and is overwritten.
        for seq in 2..6 {
            fill(&mut w, seq);
            w.publish();
            r.fetch();
            assert_eq!(r.slot().map(|s| shown(&s.image)), Some(seq));
        }
    }

    /// Two threads hammering the ring: every fetched frame is whole (all pixels and the
    /// metadata agree), frames arrive in order, and published = fetched + dropped + held back.
    #[test]
    fn stress_two_threads_never_see_a_torn_frame() {
        const FRAMES: u64 = 3000;
        let (mut w, mut r) = frame_ring(32, 16).expect("ring");
        let producer = spawn_named("test-ring-producer", move || {
            for seq in 1..=FRAMES {
                let px = pixels(seq, 32, 16);
                let slot = w.slot();
                slot.image
                    .prepare(PixelFormat::Grey8, &px)
                    .expect("same size");
                slot.meta = FrameMeta {
                    timestamp: Duration::from_micros(seq),
                    sequence: seq,
                };
                w.publish();
                if seq % 64 == 0 {
                    std::thread::yield_now();
                }
            }
            w.counters().dropped()
        })
        .expect("spawn");

        let mut fetched = 0u64;
        let mut last = 0u64;
        loop {
            if r.fetch() {
                let slot = r.slot().expect("slot");
                let seq = slot.meta.sequence;
                assert!(seq > last, "frames go forward: {seq} after {last}");
                assert_eq!(slot.published, seq, "publication number matches the frame");
                assert_eq!(
                    shown(&slot.image),
                    seq % 31,
                    "frame {seq}: pixels and metadata agree"
                );
                last = seq;
                fetched += 1;
            } else if producer.is_finished() {
                // The final frame may still be pending: one more fetch settles it.
                if !r.fetch() {
                    break;
                }
                let seq = r.slot().expect("slot").meta.sequence;
                assert!(seq > last);
                last = seq;
                fetched += 1;
            }
        }
        let dropped = producer.join().expect("producer");
        assert_eq!(last, FRAMES, "the newest frame is always available");
        assert_eq!(
            fetched + dropped,
            FRAMES,
            "every frame fetched or counted as dropped"
        );
        assert!(fetched > 1);
    }
}
