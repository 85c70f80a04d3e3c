use super::*;

fn sizes(queue: usize) -> RecorderSizes {
    RecorderSizes {
        queue,
        width: 4,
        height: 2,
        flies: 3,
        images: true,
        flies_every: 2,
        fps: 16.0,
    }
}

#[test]
fn a_full_queue_drops_and_counts_and_the_buffer_returns_to_its_pool() {
    let (recorder, rx, returns) = channel(sizes(1));
    let px = [7u8; 24];
    let frame = Retained::Raw(PixelFormat::Rgb8, &px);
    recorder.frame(Side::Left, Duration::ZERO, (4, 2), frame);
    recorder.frame(Side::Right, Duration::ZERO, (4, 2), frame);
    assert_eq!(recorder.counters().dropped(), 1);
    let Ok(Record::Frame {
        side, len, pixels, ..
    }) = rx.try_recv()
    else {
        panic!("a frame");
    };
    assert_eq!((side, len, &pixels[..len]), (Side::Left, 24, &px[..]));
    returns.frame(pixels);
    // Every buffer is back: 32 frames can be taken again, none was lost to the drop.
    let mut taken = 0;
    while recorder.frames.take().is_some() {
        taken += 1;
    }
    assert_eq!(taken, 32);
}

#[test]
fn flies_are_copied_every_nth_generation_only() {
    let (recorder, rx, _returns) = channel(sizes(8));
    let (x, rest) = ([1.0, 2.0, 3.0], [0.5; 3]);
    let fields = FlyFields {
        x: &x,
        y: &rest,
        z: &[10.0; 3],
        fitness: &[4.0; 3],
        warning: &[0.1; 3],
    };
    assert!(!recorder.flies_due(3), "generation 3 is not due at every 2");
    assert!(recorder.flies_due(4));
    recorder.fly_fields(Duration::ZERO, fields);
    let Ok(Record::Flies { flies, points, .. }) = rx.try_recv() else {
        panic!("flies");
    };
    assert_eq!(flies, 3);
    assert_eq!(&points[5..10], &[2.0, 0.5, 10.0, 4.0, 0.1]);
}

#[test]
fn a_frame_larger_than_the_pool_buffers_is_dropped_not_cut() {
    let (recorder, rx, _returns) = channel(sizes(8));
    let frame = Retained::Raw(PixelFormat::Rgb8, &[0; 192]);
    recorder.frame(Side::Left, Duration::ZERO, (8, 8), frame);
    assert!(rx.try_recv().is_err());
    assert_eq!(recorder.counters().dropped(), 1);
}
