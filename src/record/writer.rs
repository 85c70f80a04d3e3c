//! The writer thread (`flyd-record`): records off the queue into MCAP files and the live view.
//! The parts are modules of their own: one MCAP file (`mcap_file.rs`), flyd's values as
//! Foxglove's schemas (`scene.rs`), the live server (`live.rs`), what is asked and how a
//! start fails (`options.rs`).
//!
//! - **File.** MCAP with zstd-compressed chunks (`record.compression`), Foxglove protobuf
//!   schemas and flyd's JSON ones ([`super::topics`]), the configuration attached
//!   (`config.toml`) and flyd's metadata (`flyd`: version, seed, flies, flies_every). A new
//!   file starts after `rotate_bytes` of payload or `rotate_after` of time: `NAME.mcap`, then
//!   `NAME.1.mcap`, `NAME.2.mcap`...; each is a complete recording to view (channels,
//!   calibrations and config again), an exact replay starts from the first.
//! - **Write errors** (a full disk, a removed directory) end the recording: logged once as an
//!   error with the file and its cause, `RecordCounters::failed` set, the queue drained
//!   without writing (the producers never notice). Never a fault of the perception.
//! - **Live.** A Foxglove WebSocket server ([`super::LiveOptions`]) on its own one-thread runtime
//!   (`flyd-live`); the same channels, images and flies throttled to `image_period` /
//!   `flies_period` (the rest as recorded). Messages go to connected clients only; a slow
//!   client loses messages in the server's bounded backlog, never stalls this thread.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, RecvTimeoutError};
use foxglove::Encode;
use foxglove::schemas::{CameraCalibration, CompressedImage, FrameTransforms, RawImage};

use super::live::Live;
use super::mcap_file::{McapFile, part_path};
use super::options::{RecordOptions, WriterError};
use super::scene::{calibration, camera_pose, point_cloud, scene, timestamp_of};
use super::topics::Topic;
use super::{FLY_FLOATS, Record, RecordCounters, Returns, nanos};
use crate::source::Side;
use flyd_core::chain::Chain;
use flyd_core::frame::PixelFormat;
use flyd_core::geometry::StereoRig;

/// What the writer did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct WriterReport {
    /// Files written (rotation), in order.
    pub files: Vec<PathBuf>,
    pub messages: u64,
    pub frames: [u64; 2],
    pub failed: bool,
}

/// The live view's address, once it listens (the port when `listen` asked for port 0).
pub struct Writer {
    pub handle: JoinHandle<WriterReport>,
    pub live_addr: Option<SocketAddr>,
}

/// Opens the first file and the live server (errors here are start-up errors), then starts
/// the writer thread, which ends when every [`super::Recorder`] is dropped.
pub fn spawn_writer(
    options: RecordOptions,
    rig: &StereoRig,
    rx: Receiver<Record>,
    returns: Returns,
    counters: Arc<RecordCounters>,
) -> Result<Writer, WriterError> {
    let calibrations = [
        calibration(&rig.left, "left"),
        calibration(&rig.right, "right"),
    ];
    let transforms = FrameTransforms {
        transforms: vec![
            camera_pose(&rig.left, "left"),
            camera_pose(&rig.right, "right"),
        ],
    };
    // A path that cannot be created is a configuration error (flyd does not start); a file
    // that cannot be written (a full disk) is the recorder's fault: flyd drives on without.
    let file = match &options.path {
        Some(path) => match McapFile::create(path.clone(), &options) {
            Ok(file) => Some(file),
            Err(e @ WriterError::Open { .. }) => {
                counters.failed.store(true, Ordering::Relaxed);
                tracing::error!(
                    file = %path.display(),
                    error = %Chain(&e),
                    "recording stopped: cannot write (disk full?); flyd drives on without recording"
                );
                None
            }
            Err(e) => return Err(e),
        },
        None => None,
    };
    let (live, live_addr) = match options.live {
        Some(opts) => {
            let live = Live::start(opts)?;
            let addr = live.addr;
            (Some(live), Some(addr))
        }
        None => (None, None),
    };
    let mut w = WriterLoop {
        options,
        file,
        live,
        calibrations,
        transforms,
        returns,
        counters,
        report: WriterReport::default(),
        parts: 0,
        scratch: Vec::new(),
        last_scene: None,
    };
    if let Some(f) = &w.file {
        w.report.files.push(f.path.clone());
    }
    let handle =
        crate::thread::spawn_named("flyd-record", move || w.run(rx)).map_err(WriterError::Spawn)?;
    Ok(Writer { handle, live_addr })
}

struct WriterLoop {
    options: RecordOptions,
    file: Option<McapFile>,
    live: Option<Live>,
    calibrations: [CameraCalibration; 2],
    /// Both cameras' poses in `base_link` (logged with the calibrations).
    transforms: FrameTransforms,
    returns: Returns,
    counters: Arc<RecordCounters>,
    report: WriterReport,
    parts: u32,
    scratch: Vec<u8>,
    /// Log time of the last scene update.
    last_scene: Option<u64>,
}

/// Scene updates are written at most this often (30 Hz).
const SCENE_PERIOD_NS: u64 = 33_333_333;

impl WriterLoop {
    fn run(mut self, rx: Receiver<Record>) -> WriterReport {
        loop {
            match rx.recv_timeout(Duration::from_millis(200)) {
                Ok(record) => self.handle(record),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            self.rotate_if_due();
        }
        if let Some(file) = self.file.take() {
            let path = file.path.clone();
            if let Err(error) = file.finish() {
                self.fail(&path, &error);
            }
        }
        if let Some(live) = self.live.take() {
            live.stop();
        }
        self.report.failed = self.counters.has_failed();
        tracing::info!(
            files = ?self.report.files,
            messages = self.report.messages,
            frames_left = self.report.frames[0],
            frames_right = self.report.frames[1],
            dropped = self.counters.dropped(),
            flies_skipped = self.counters.flies_skipped.load(Ordering::Relaxed),
            failed = self.report.failed,
            "recording closed"
        );
        self.report
    }

    fn rotate_if_due(&mut self) {
        let Some(file) = &self.file else { return };
        let by_size = self
            .options
            .rotate_bytes
            .is_some_and(|max| file.bytes >= max);
        let by_time = self
            .options
            .rotate_after
            .is_some_and(|max| file.opened.elapsed() >= max);
        if !(by_size || by_time) {
            return;
        }
        let Some(base) = self.options.path.clone() else {
            return;
        };
        self.parts += 1;
        let next = part_path(&base, self.parts);
        if let Some(old) = self.file.take() {
            let old_path = old.path.clone();
            if let Err(error) = old.finish() {
                self.fail(&old_path, &error);
                return;
            }
        }
        match McapFile::create(next.clone(), &self.options) {
            Ok(f) => {
                tracing::info!(file = %next.display(), "recording goes on in a new file");
                self.report.files.push(next);
                self.file = Some(f);
            }
            Err(error) => self.fail(&next, &error),
        }
    }

    /// The recording stops (a write error): logged once, the file dropped.
    fn fail(&mut self, path: &Path, error: &(dyn std::error::Error + 'static)) {
        self.file = None;
        if !self.counters.failed.swap(true, Ordering::Relaxed) {
            tracing::error!(
                file = %path.display(),
                error = %Chain(error),
                "recording stopped: cannot write (disk full?); flyd drives on without recording"
            );
        }
    }

    fn handle(&mut self, record: Record) {
        match record {
            Record::Frame {
                side,
                timestamp,
                format,
                width,
                height,
                len,
                pixels,
            } => {
                let t = nanos(timestamp);
                let (calib_topic, i) = match side {
                    Side::Left => (Topic::LeftCalibration, 0),
                    Side::Right => (Topic::RightCalibration, 1),
                };
                let data =
                    foxglove::bytes::Bytes::copy_from_slice(&pixels[..len.min(pixels.len())]);
                let (topic, image) = match format {
                    Some(format) => {
                        let (encoding, bpp) = match format {
                            PixelFormat::Rgb8 => ("rgb8", 3),
                            PixelFormat::Grey8 => ("mono8", 1),
                        };
                        let topic = [Topic::LeftImage, Topic::RightImage][i];
                        let image = RawImage {
                            timestamp: Some(timestamp_of(t)),
                            frame_id: side.name().to_string(),
                            width,
                            height,
                            encoding: encoding.into(),
                            step: width * bpp,
                            data,
                        };
                        (topic, FrameMsg::Raw(image))
                    }
                    None => {
                        let topic = [Topic::LeftCompressed, Topic::RightCompressed][i];
                        let image = CompressedImage {
                            timestamp: Some(timestamp_of(t)),
                            frame_id: side.name().to_string(),
                            data,
                            format: "jpeg".into(),
                        };
                        (topic, FrameMsg::Jpeg(image))
                    }
                };
                self.returns.frame(pixels);
                self.report.frames[i] += 1;
                let mut calib = self.calibrations[i].clone();
                calib.timestamp = Some(timestamp_of(t));
                let mut transforms = self.transforms.clone();
                for tf in &mut transforms.transforms {
                    tf.timestamp = Some(timestamp_of(t));
                }
                // A file carries both calibrations from its first frame on: a part that
                // rotation ends after one camera's frame still stands alone.
                const CALIBRATIONS: [Topic; 2] = [Topic::LeftCalibration, Topic::RightCalibration];
                let missing = CALIBRATIONS.map(|c| self.file.as_ref().is_some_and(|f| f.needs(c)));
                for (c, topic) in CALIBRATIONS.into_iter().enumerate() {
                    if missing[c] {
                        let mut calib = self.calibrations[c].clone();
                        calib.timestamp = Some(timestamp_of(t));
                        self.write_file(topic, t, &calib);
                    }
                }
                if missing.contains(&true) {
                    self.write_file(Topic::Transforms, t, &transforms);
                }
                match &image {
                    FrameMsg::Raw(m) => self.write_file(topic, t, m),
                    FrameMsg::Jpeg(m) => self.write_file(topic, t, m),
                }
                if let Some(live) = &mut self.live
                    && live.due(topic, t)
                {
                    live.log(calib_topic, t, &calib);
                    live.log(Topic::Transforms, t, &transforms);
                    match &image {
                        FrameMsg::Raw(m) => live.log(topic, t, m),
                        FrameMsg::Jpeg(m) => live.log(topic, t, m),
                    }
                }
            }
            Record::Flies { at, flies, points } => {
                let t = nanos(at);
                let cloud = point_cloud(t, &points[..(flies * FLY_FLOATS).min(points.len())]);
                self.returns.flies(points);
                self.write_file(Topic::Flies, t, &cloud);
                if let Some(live) = &mut self.live
                    && live.due(Topic::Flies, t)
                {
                    live.log(Topic::Flies, t, &cloud);
                }
            }
            Record::Pair { at, event } => self.write_json(Topic::Pair, nanos(at), &event),
            Record::Perception {
                event,
                obstacle,
                confirmed,
            } => {
                let t = event.t_ns;
                self.write_json(Topic::Perception, t, &event);
                // The scene only shows what the perception events say: at most 30 a second.
                if self
                    .last_scene
                    .is_some_and(|last| t >= last && t - last < SCENE_PERIOD_NS)
                {
                    return;
                }
                self.last_scene = Some(t);
                let scene = scene(t, &event, obstacle, confirmed);
                self.write_file(Topic::Scene, t, &scene);
                if let Some(live) = &mut self.live {
                    live.log(Topic::Scene, t, &scene);
                }
            }
            Record::Decision(event) => self.write_json(Topic::Decision, event.t_ns, &event),
            Record::Stats(event) => self.write_json(Topic::Stats, event.t_ns, &event),
            Record::Can {
                sent,
                seq,
                at,
                id,
                len,
                data,
            } => {
                let event = super::can_event(seq, at, id, &data[..usize::from(len.min(8))]);
                let topic = if sent { Topic::CanTx } else { Topic::CanRx };
                self.write_json(topic, event.t_ns, &event);
            }
        }
    }

    fn write_json<T: serde::Serialize>(&mut self, topic: Topic, t: u64, event: &T) {
        self.scratch.clear();
        if serde_json::to_writer(&mut self.scratch, event).is_err() {
            return;
        }
        let data = std::mem::take(&mut self.scratch);
        self.write_bytes(topic, t, &data);
        if let Some(live) = &self.live {
            live.log_bytes(topic, t, &data);
        }
        self.scratch = data;
    }

    fn write_file<T: Encode>(&mut self, topic: Topic, t: u64, msg: &T) {
        if self.file.is_none() {
            return;
        }
        self.scratch.clear();
        if msg.encode(&mut self.scratch).is_err() {
            return;
        }
        let data = std::mem::take(&mut self.scratch);
        self.write_bytes(topic, t, &data);
        self.scratch = data;
    }

    fn write_bytes(&mut self, topic: Topic, t: u64, data: &[u8]) {
        let Some(file) = self.file.as_mut() else {
            return;
        };
        match file.write(topic, t, data) {
            Ok(()) => {
                self.report.messages += 1;
                self.counters.written.fetch_add(1, Ordering::Relaxed);
                self.counters
                    .bytes
                    .fetch_add(data.len() as u64, Ordering::Relaxed);
            }
            Err(error) => {
                let path = file.path.clone();
                self.fail(&path, &error);
            }
        }
    }
}

/// A camera frame as written: packed pixels, or an MJPEG camera's JPEG.
enum FrameMsg {
    Raw(RawImage),
    Jpeg(CompressedImage),
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    /// A writer of 8 x 8 frames into `path` that starts a new part every 30 ms, and its
    /// recorder.
    /// A writer of 8x8 frames rotating after `rotate_bytes` of payload or `rotate_after`.
    fn rotating_writer(
        path: PathBuf,
        config_text: Option<String>,
        (rotate_bytes, rotate_after): (Option<u64>, Option<Duration>),
    ) -> (super::super::Recorder, Writer) {
        let (recorder, rx, returns) = super::super::channel(super::super::RecorderSizes {
            queue: 16,
            width: 8,
            height: 8,
            flies: 4,
            images: true,
            flies_every: 1,
            fps: 10.0,
        });
        let options = RecordOptions {
            path: Some(path),
            rotate_bytes,
            rotate_after,
            compression: true,
            live: None,
            config_text,
            metadata: BTreeMap::new(),
        };
        let rig = crate::mock::mock_rig(320, 240).expect("rig");
        let counters = recorder.counters().clone();
        let writer = spawn_writer(options, &rig, rx, returns, counters).expect("writer");
        (recorder, writer)
    }

    /// Hands a record to the writer with `send`, waits until it is written (a loaded machine
    /// may starve the writer), then for more than the rotation time: the next record starts
    /// a new part whatever the scheduling.
    fn send_then_wait(recorder: &super::super::Recorder, send: impl FnOnce()) {
        let before = recorder.counters().written();
        send();
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while recorder.counters().written() == before && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(Duration::from_millis(50));
    }

    #[test]
    fn rotation_by_time_starts_a_new_complete_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (recorder, writer) = rotating_writer(
            dir.path().join("t.mcap"),
            Some("[cameras]\n".into()),
            (None, Some(Duration::from_millis(30))),
        );
        let stats = |t: u64| super::super::topics::StatsEvent {
            t_ns: t,
            fps_left: 10.0,
            fps_right: 10.0,
            generations_per_sec: 100.0,
            gen_p50_ms: 0.1,
            gen_p99_ms: 0.2,
            generations: t,
            pairs: t,
            snapshots_dropped: 0,
            record_dropped: 0,
        };
        for t in 0..3 {
            send_then_wait(&recorder, || recorder.stats(stats(t)));
        }
        drop(recorder);
        let report = writer.handle.join().expect("writer ends");
        assert!(report.files.len() >= 2, "{report:?}");
        assert_eq!(report.files[1], dir.path().join("t.1.mcap"));
        let mut stats_seen = 0;
        for file in &report.files {
            let data = std::fs::read(file).expect("part");
            let summary = mcap::Summary::read(&data)
                .expect("complete")
                .expect("summary");
            assert_eq!(summary.channels.len(), Topic::ALL.len());
            assert!(
                summary
                    .attachment_indexes
                    .iter()
                    .any(|a| a.name == "config.toml")
            );
            stats_seen += mcap::MessageStream::new(&data).expect("messages").count();
        }
        assert_eq!(stats_seen, 3, "every record in exactly one part");
        assert!(!report.failed);
    }

    #[test]
    fn a_part_holding_one_cameras_frames_still_carries_both_calibrations() {
        let dir = tempfile::tempdir().expect("tempdir");
        // Rotated by size, after every record: by time, a part switched more slowly than the
        // wait between frames on a loaded CI machine (2 parts, not 3).
        let (recorder, writer) = rotating_writer(dir.path().join("c.mcap"), None, (Some(1), None));
        let pixels = [0u8; 8 * 8 * 3];
        for t in 0..3 {
            // The left camera only, as when a part ends between a left and a right frame.
            send_then_wait(&recorder, || {
                recorder.frame(
                    Side::Left,
                    Duration::from_millis(t),
                    (8, 8),
                    flyd_core::frame::Retained::Raw(PixelFormat::Rgb8, &pixels),
                )
            });
        }
        drop(recorder);
        let report = writer.handle.join().expect("writer ends");
        assert!(report.files.len() >= 3, "{report:?}");
        let mut parts_with_frames = 0;
        for file in &report.files {
            let data = std::fs::read(file).expect("part");
            let topics: Vec<String> = mcap::MessageStream::new(&data)
                .expect("messages")
                .filter_map(|m| m.ok().map(|m| m.channel.topic.clone()))
                .collect();
            if !topics.iter().any(|t| t == "/camera/left/image") {
                continue; // the last part may open after the last frame
            }
            parts_with_frames += 1;
            let mut calibrations: Vec<&str> = topics
                .iter()
                .map(String::as_str)
                .filter(|t| t.ends_with("/calibration"))
                .collect();
            calibrations.sort_unstable();
            assert_eq!(
                calibrations,
                ["/camera/left/calibration", "/camera/right/calibration"],
                "{}",
                file.display()
            );
        }
        assert!(
            parts_with_frames >= 2,
            "frames in more than one part: {report:?}"
        );
    }
}
