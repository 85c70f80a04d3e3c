use super::stream::{BufferQueue, wait_for_buffer};
use super::*;
use std::path::Path;
use std::time::Instant;
use v4l::buffer::Metadata;

fn config(device: &str) -> V4l2Config {
    V4l2Config {
        device: device.into(),
        width: 640,
        height: 480,
        fps: 30,
        format: CaptureFormat::Yuyv,
    }
}

#[test]
fn config_parses_and_rejects_unknown_keys() {
    let parse = |rest: &str| {
        let text = format!("device = \"/dev/video0\"\nwidth = 640\nheight = 480\nfps = 30\n{rest}");
        toml::from_str::<V4l2Config>(&text)
    };
    let c = parse("format = \"MJPG\"").unwrap();
    assert_eq!(c.format, CaptureFormat::Mjpg);
    assert_eq!(c.device, Path::new("/dev/video0"));
    c.validate().unwrap();
    let err = parse("format = \"YUYV\"\ncolour = true").unwrap_err();
    assert!(err.to_string().contains("colour"), "{err}");
    let err = parse("format = \"H264\"").unwrap_err();
    assert!(err.to_string().contains("H264"), "{err}");
}

#[test]
fn config_validation_names_the_key() {
    let check = |edit: fn(&mut V4l2Config), key: &str| {
        let mut c = config("/dev/video0");
        edit(&mut c);
        assert_eq!(c.validate().unwrap_err().key, key);
    };
    check(|c| c.device = PathBuf::new(), "device");
    check(|c| c.width = 4, "width");
    check(|c| c.height = 100_000, "height");
    check(|c| c.width = 641, "width");
    check(|c| c.fps = 0, "fps");
    let mut grey_odd = config("/dev/video0");
    grey_odd.format = CaptureFormat::Grey;
    grey_odd.width = 641;
    grey_odd.validate().unwrap();
}

#[test]
fn format_mismatch_names_device_and_both_formats() {
    let c = config("/dev/video3");
    let mut got = Negotiated {
        width: 640,
        height: 480,
        fourcc: *b"YUYV",
        stride: 1280,
        size_image: 614_400,
    };
    check_format("/dev/video3", &c, &got).unwrap();
    got.fourcc = *b"MJPG";
    let msg = check_format("/dev/video3", &c, &got)
        .unwrap_err()
        .to_string();
    assert_eq!(
        msg,
        "device /dev/video3: asked for 640x480 YUYV, the driver accepted 640x480 MJPG"
    );
    got = Negotiated {
        width: 320,
        height: 240,
        fourcc: *b"YUYV",
        ..got
    };
    let err = check_format("/dev/video3", &c, &got).unwrap_err();
    assert!(matches!(err, SourceError::Format { .. }));
    assert!(err.to_string().contains("320x240 YUYV"), "{err}");
}

#[test]
fn frame_rate_check() {
    check_frame_rate("cam", 30, 1, 30).unwrap();
    check_frame_rate("cam", 30, 1001, 30000).unwrap();
    let err = check_frame_rate("cam", 30, 1, 15).unwrap_err().to_string();
    assert!(err.contains("30 fps") && err.contains("1/15"), "{err}");
    assert!(check_frame_rate("cam", 30, 0, 0).is_err());
}

#[test]
fn capability_check_rejects_metadata_nodes() {
    let capture = CAP_VIDEO_CAPTURE | CAP_STREAMING;
    check_capabilities(capture | CAP_DEVICE_CAPS, capture).unwrap();
    check_capabilities(capture, 0).unwrap(); // old driver without device_caps
    // uvcvideo's second node: the device captures, this node only has metadata.
    let meta_capture = 0x0080_0000;
    let err =
        check_capabilities(capture | CAP_DEVICE_CAPS, meta_capture | CAP_STREAMING).unwrap_err();
    assert!(err.contains("metadata"), "{err}");
    assert!(check_capabilities(CAP_VIDEO_CAPTURE | CAP_DEVICE_CAPS, CAP_VIDEO_CAPTURE).is_err());
}

#[test]
fn payload_is_cut_to_bytesused() {
    let buf = [1u8, 2, 3, 4, 5, 6];
    assert_eq!(payload(&buf, 4).unwrap(), &[1, 2, 3, 4]);
    assert_eq!(payload(&buf, 6).unwrap(), &buf);
    assert!(payload(&buf, 7).unwrap_err().contains("exceeds"));
    assert!(payload(&buf, 0).is_err());
}

#[test]
fn timestamps_come_from_the_kernel_only_when_monotonic_and_sane() {
    let now = Duration::from_secs(1000);
    let mono = BUF_FLAG_TIMESTAMP_MONOTONIC | 0x0001_0000; // + TSTAMP_SRC_SOE
    assert_eq!(
        frame_timestamp(mono, 999, 250_000, now),
        (Duration::from_micros(999_250_000), true)
    );
    // Unknown clock, copied (mem2mem) timestamps, garbage, the future: the dequeue time.
    assert_eq!(frame_timestamp(0, 999, 0, now), (now, false));
    assert_eq!(frame_timestamp(0x4000, 999, 0, now), (now, false));
    assert_eq!(frame_timestamp(mono, -1, 0, now), (now, false));
    assert_eq!(frame_timestamp(mono, 999, 1_000_000, now), (now, false));
    assert_eq!(frame_timestamp(mono, 1001, 0, now), (now, false));
}

#[test]
fn poll_timeouts_round_up_and_fit_v4l() {
    assert_eq!(poll_timeout(Duration::ZERO), Duration::from_millis(1));
    assert_eq!(
        poll_timeout(Duration::from_micros(1500)),
        Duration::from_millis(2)
    );
    assert_eq!(
        poll_timeout(Duration::from_millis(100)),
        Duration::from_millis(100)
    );
    assert_eq!(
        poll_timeout(Duration::from_secs(u64::MAX)),
        Duration::from_millis(i32::MAX as u64)
    );
}

#[test]
fn io_errors_map_to_timeout_or_reopen() {
    let t = Duration::from_millis(100);
    let timed_out = io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF");
    assert!(matches!(
        classify("/dev/video0", "capture", &timed_out, t),
        SourceError::Timeout(d) if d == t
    ));
    let gone = classify(
        "/dev/video0",
        "capture",
        &io::Error::from_raw_os_error(libc::ENODEV),
        t,
    );
    assert!(!gone.is_transient());
    let msg = gone.to_string();
    assert!(
        msg.contains("/dev/video0") && msg.contains("unplugged"),
        "{msg}"
    );
    for errno in [libc::EIO, libc::EPIPE, libc::EINVAL] {
        assert!(matches!(
            classify("d", "capture", &io::Error::from_raw_os_error(errno), t),
            SourceError::Disconnected { .. }
        ));
    }
    assert!(matches!(
        open_error(
            "d",
            "VIDIOC_QUERYCAP",
            &io::Error::from_raw_os_error(libc::ENOTTY)
        ),
        SourceError::Format { .. }
    ));
    let denied = open_error("d", "open", &io::Error::from_raw_os_error(libc::EACCES));
    assert!(denied.to_string().contains("group video"), "{denied}");
}

/// What happens during one wait of the model camera.
#[derive(Debug, Clone, Copy)]
enum Event {
    /// A frame with this sequence number fills the oldest queued buffer.
    Frame(u32),
    /// Nothing arrives: the poll times out.
    Nothing,
    /// A signal interrupts the poll.
    Interrupted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Owner {
    User,
    Kernel,
}

/// A strict model of a V4L2 capture queue behind `v4l` 0.14's mmap stream: QBUF of a buffer
/// the kernel owns is EINVAL, as in videobuf2; `next_with` and `dequeue` do what `v4l`'s
/// `next()` and `dequeue()` do, including remembering the last dequeued index.
struct ModelQueue {
    owner: Vec<Owner>,
    /// Kernel-owned buffers in the order they were queued (filled first in, first out).
    queued: std::collections::VecDeque<usize>,
    meta: Vec<Metadata>,
    active: bool,
    /// `v4l`'s `arena_index`: the buffer the next `next()` requeues.
    last: usize,
    events: std::collections::VecDeque<Event>,
}

impl ModelQueue {
    fn new(events: &[Event]) -> Self {
        Self {
            owner: vec![Owner::User; 4],
            queued: Default::default(),
            meta: vec![Metadata::default(); 4],
            active: false,
            last: 0,
            events: events.iter().copied().collect(),
        }
    }
    fn qbuf(&mut self, i: usize) -> io::Result<()> {
        if self.owner[i] != Owner::User {
            return Err(io::Error::from_raw_os_error(libc::EINVAL));
        }
        self.owner[i] = Owner::Kernel;
        self.queued.push_back(i);
        Ok(())
    }
    fn dqbuf(&mut self) -> io::Result<usize> {
        match self.events.pop_front().unwrap_or(Event::Nothing) {
            Event::Nothing => Err(io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF")),
            Event::Interrupted => Err(io::Error::from_raw_os_error(libc::EINTR)),
            Event::Frame(sequence) => {
                // With no buffer queued the driver drops the frame.
                let Some(i) = self.queued.pop_front() else {
                    return Err(io::Error::new(io::ErrorKind::TimedOut, "VIDIOC_DQBUF"));
                };
                self.owner[i] = Owner::User;
                self.meta[i] = Metadata {
                    bytesused: 1,
                    sequence,
                    ..Metadata::default()
                };
                Ok(i)
            }
        }
    }
}

impl BufferQueue for ModelQueue {
    fn set_timeout(&mut self, _: Duration) {}
    fn dequeue(&mut self) -> io::Result<()> {
        self.last = self.dqbuf()?;
        Ok(())
    }
    fn next_with<R>(&mut self, f: &mut impl FnMut(&[u8], &Metadata) -> R) -> io::Result<R> {
        if !self.active {
            for i in 0..self.owner.len() {
                self.qbuf(i)?;
            }
            self.active = true;
        } else {
            self.qbuf(self.last)?;
        }
        self.last = self.dqbuf()?;
        Ok(f(&[0], &self.meta[self.last]))
    }
}

/// One `next_frame`-like call per entry: the sequence delivered, or the error kind.
fn run_capture_loop(events: &[Event], calls: usize) -> Vec<Result<u32, io::ErrorKind>> {
    let mut queue = ModelQueue::new(events);
    let mut resync = false;
    (0..calls)
        .map(|_| {
            let deadline = Instant::now() + Duration::from_secs(5);
            wait_for_buffer(&mut queue, &mut resync, deadline, &mut |_, meta| {
                meta.sequence
            })
            .map_err(|e| e.kind())
        })
        .collect()
}

#[test]
fn the_model_reproduces_v4l_requeueing_after_a_timeout() {
    // Calling v4l's next() again after a timed-out wait: QBUF of a buffer the kernel
    // already owns, EINVAL, however many frames then arrive.
    use Event::*;
    let mut queue = ModelQueue::new(&[Frame(0), Nothing, Frame(1), Frame(2)]);
    let mut seq = |_: &[u8], m: &Metadata| m.sequence;
    assert_eq!(queue.next_with(&mut seq).unwrap(), 0);
    assert_eq!(
        queue.next_with(&mut seq).unwrap_err().kind(),
        io::ErrorKind::TimedOut
    );
    for _ in 0..3 {
        let err = queue.next_with(&mut seq).unwrap_err();
        assert_eq!(err.raw_os_error(), Some(libc::EINVAL));
    }
}

#[test]
fn capture_loop_recovers_after_timeouts() {
    use Event::*;
    use io::ErrorKind::TimedOut;
    let got = run_capture_loop(
        &[
            Frame(0),
            Nothing,
            Frame(1), // taken back by the resync dequeue: dropped
            Frame(2),
            Nothing,
            Nothing,  // the resync dequeue itself times out: still resyncing
            Frame(3), // dropped by the resync
            Frame(4),
            Frame(5),
        ],
        7,
    );
    assert_eq!(
        got,
        [
            Ok(0),
            Err(TimedOut),
            Ok(2),
            Err(TimedOut),
            Err(TimedOut),
            Ok(4),
            Ok(5)
        ]
    );
}

#[test]
fn capture_loop_recovers_from_a_timeout_before_the_first_frame() {
    use Event::*;
    let got = run_capture_loop(&[Nothing, Frame(0), Frame(1), Frame(2)], 3);
    assert_eq!(got, [Err(io::ErrorKind::TimedOut), Ok(1), Ok(2)]);
}

#[test]
fn capture_loop_retries_interrupted_waits_within_the_call() {
    use Event::*;
    // EINTR in the wait: retried in the same call, after taking a buffer back.
    let got = run_capture_loop(&[Frame(0), Interrupted, Frame(1), Frame(2), Frame(3)], 2);
    assert_eq!(got, [Ok(0), Ok(2)]);
    // EINTR in the resync dequeue itself.
    let got = run_capture_loop(&[Nothing, Interrupted, Frame(0), Frame(1)], 2);
    assert_eq!(got, [Err(io::ErrorKind::TimedOut), Ok(1)]);
}

#[test]
fn capture_loop_never_requeues_a_kernel_buffer() {
    // Every pattern of up to 8 events, through 8 calls: no EINVAL ever reaches the caller
    // (it would mean a QBUF of a buffer the kernel owns), and every frame delivered is
    // newer than the last.
    use Event::*;
    let choices = [Frame(0), Nothing, Interrupted];
    for pattern in 0..3usize.pow(8) {
        let mut seq = 0;
        let events: Vec<Event> = (0..8)
            .map(|k| match choices[pattern / 3usize.pow(k) % 3] {
                Frame(_) => {
                    seq += 1;
                    Frame(seq)
                }
                e => e,
            })
            .collect();
        let mut last = 0;
        for r in run_capture_loop(&events, 8) {
            match r {
                Ok(s) => {
                    assert!(s > last, "{events:?}");
                    last = s;
                }
                Err(kind) => assert_eq!(kind, io::ErrorKind::TimedOut, "{events:?}"),
            }
        }
    }
}

#[test]
fn opening_a_missing_node_names_the_path() {
    let path = "/dev/video-flyd-test-does-not-exist";
    let err = V4l2Source::open(config(path)).unwrap_err();
    assert!(matches!(err, SourceError::Disconnected { .. }), "{err:?}");
    let msg = Chain(&err).to_string();
    assert!(msg.contains(path), "{msg}");
    assert!(msg.contains("No such file"), "{msg}");
}

#[test]
fn opening_something_that_is_not_v4l2_is_a_format_error() {
    // /dev/null opens read-write like a camera node but knows no V4L2 ioctl.
    let err = V4l2Source::open(config("/dev/null")).unwrap_err();
    assert!(matches!(err, SourceError::Format { .. }), "{err:?}");
    assert!(err.to_string().contains("not a V4L2 device"), "{err}");
    let file = tempfile::NamedTempFile::new().unwrap();
    let err = V4l2Source::open(config(file.path().to_str().unwrap())).unwrap_err();
    assert!(err.to_string().contains("not a V4L2 device"), "{err}");
}

#[test]
fn a_closed_source_reports_disconnected_and_reopen_retries() {
    let path = "/dev/video-flyd-test-does-not-exist";
    let mut source = V4l2Source::new(config(path), PixelFormat::Rgb8);
    assert!(!source.is_open());
    assert_eq!(source.name(), path);
    assert_eq!(source.size(), (640, 480));
    let mut out = PreparedImage::new(640, 480).unwrap();
    let err = source
        .next_frame(&mut out, Duration::from_millis(10))
        .unwrap_err();
    assert!(matches!(err, SourceError::Disconnected { .. }));
    assert!(err.to_string().contains(path));
    assert!(source.reopen().is_err());
    assert!(!source.is_open());
    source.close().unwrap();
}

#[test]
fn a_bad_config_fails_before_touching_the_device() {
    let mut c = config("/dev/null");
    c.width = 641;
    let err = Chain(&V4l2Source::open(c).unwrap_err()).to_string();
    assert!(err.contains("width") && err.contains("641"), "{err}");
}

/// Says loudly that a test did not run: written to the stderr stream itself, which the test
/// harness does not capture, so it shows in every `cargo test` run.
fn skip(reason: &str) {
    use std::io::Write;
    let _ = writeln!(io::stderr(), "SKIP: {reason}");
}

/// Streams from a real camera when there is one (a rig, or a machine with `vivid` loaded).
/// `FLYD_TEST_VIDEO` picks the node (default /dev/video0).
#[test]
fn real_device_streams_monotonic_frames() {
    let path = std::env::var("FLYD_TEST_VIDEO").unwrap_or_else(|_| "/dev/video0".into());
    if !Path::new(&path).exists() {
        skip(&format!(
            "real_device_streams_monotonic_frames: no {path} on this machine (no V4L2 \
                 here); the open/convert paths are covered by the other tests and the VM \
                 suite's v4l2loopback cameras; run this one where vivid is loaded"
        ));
        return;
    }
    for format in [CaptureFormat::Yuyv, CaptureFormat::Grey] {
        // Drivers offer different rates per size (vivid's webcam input caps larger sizes
        // lower): take the first one granted exactly.
        let mut refusals = Vec::new();
        let mut opened = None;
        for fps in [30, 25, 15, 10] {
            let mut c = config(&path);
            c.format = format;
            c.fps = fps;
            match V4l2Source::open(c) {
                Ok(s) => {
                    opened = Some(s);
                    break;
                }
                Err(SourceError::Format { reason, .. }) => refusals.push(reason),
                Err(e) => panic!("{e}"),
            }
        }
        let Some(mut source) = opened else {
            skip(&format!(
                "{path} cannot do 640x480 {format}: {}",
                refusals.join("; ")
            ));
            continue;
        };
        let mut out = PreparedImage::new(640, 480).unwrap();
        let mut last: Option<FrameMeta> = None;
        for _ in 0..10 {
            let meta = source
                .next_frame(&mut out, Duration::from_secs(2))
                .unwrap_or_else(|e| panic!("{format}: {e}"));
            assert!(meta.timestamp <= monotonic_now());
            if let Some(prev) = last {
                assert!(meta.timestamp > prev.timestamp, "{prev:?} then {meta:?}");
                assert!(meta.sequence > prev.sequence, "{prev:?} then {meta:?}");
            }
            last = Some(meta);
        }
        // A timeout shorter than a frame period leaves the stream usable (the resync path,
        // v4l's requeue-after-timeout bug). Drain ready frames until one wait times out.
        let timed_out = (0..20).any(|_| {
            matches!(
                source.next_frame(&mut out, Duration::from_micros(1)),
                Err(SourceError::Timeout(_))
            )
        });
        assert!(timed_out, "a 1 ms wait never timed out at <= 30 fps");
        source
            .next_frame(&mut out, Duration::from_secs(2))
            .expect("a frame after a timeout");
        source.reopen().expect("reopen");
        source
            .next_frame(&mut out, Duration::from_secs(2))
            .expect("a frame after reopen");
        source.close().expect("clean teardown");
    }
}
