//! The writer thread (`flyd-record`): records off the queue into MCAP files and the live view.
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
//! - **Live.** A Foxglove WebSocket server ([`LiveOptions`]) on its own one-thread runtime
//!   (`flyd-live`); the same channels, images and flies throttled to `image_period` /
//!   `flies_period` (the rest as recorded). Messages go to connected clients only; a slow
//!   client loses messages in the server's bounded backlog, never stalls this thread.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError};
use foxglove::schemas::{
    CameraCalibration, Color, CompressedImage, CubePrimitive, FrameTransform, FrameTransforms,
    PackedElementField, PointCloud, Pose, Quaternion, RawImage, SceneEntity, SceneUpdate,
    Timestamp, Vector3, packed_element_field::NumericType,
};
use foxglove::{Encode, PartialMetadata};

use super::topics::{Encoding, Topic};
use super::{FLY_FLOATS, Record, RecordCounters, Returns, nanos};
use crate::source::Side;
use flyd_core::chain::Chain;
use flyd_core::frame::PixelFormat;
use flyd_core::geometry::{Camera, StereoRig};

/// Where and how to record (the resolved `[record]` and `[live]` tables).
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The MCAP file (`None`: the live view only).
    pub path: Option<PathBuf>,
    pub rotate_bytes: Option<u64>,
    pub rotate_after: Option<Duration>,
    pub compression: bool,
    pub live: Option<LiveOptions>,
    /// Attached as `config.toml`.
    pub config_text: Option<String>,
    /// flyd's metadata record.
    pub metadata: BTreeMap<String, String>,
}

/// The live view (`[live]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveOptions {
    pub listen: SocketAddr,
    /// At most one image per camera, and one population, this often.
    pub image_period: Duration,
    pub flies_period: Duration,
}

#[derive(Debug, thiserror::Error)]
pub enum WriterError {
    #[error("recording {path}")]
    Open {
        path: String,
        #[source]
        error: mcap::McapError,
    },
    #[error("recording {path}")]
    Create {
        path: String,
        #[source]
        error: std::io::Error,
    },
    #[error("live view on {listen}")]
    Live {
        listen: SocketAddr,
        #[source]
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("cannot start thread flyd-record")]
    Spawn(#[source] std::io::Error),
}

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

/// `drive.mcap` -> `drive.1.mcap`.
fn part_path(base: &Path, part: u32) -> PathBuf {
    let stem = base.file_stem().map_or_else(
        || "recording".to_string(),
        |s| s.to_string_lossy().into_owned(),
    );
    base.with_file_name(format!("{stem}.{part}.mcap"))
}

/// One open MCAP file.
struct McapFile {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    channels: [u16; Topic::ALL.len()],
    sequence: [u32; Topic::ALL.len()],
    /// Calibrations written in this file (each file carries them).
    calibrated: [bool; 2],
    bytes: u64,
    opened: Instant,
}

impl McapFile {
    fn create(path: PathBuf, options: &RecordOptions) -> Result<Self, WriterError> {
        let shown = path.display().to_string();
        let open = |error| WriterError::Open {
            path: shown.clone(),
            error,
        };
        let file = File::create(&path).map_err(|error| WriterError::Create {
            path: shown.clone(),
            error,
        })?;
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .library(format!("flyd {}", env!("CARGO_PKG_VERSION")))
            .compression(options.compression.then_some(mcap::Compression::Zstd))
            .compression_level(1)
            .chunk_size(Some(4 << 20))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(open)?;
        let mut channels = [0; Topic::ALL.len()];
        for (i, topic) in Topic::ALL.into_iter().enumerate() {
            let (name, encoding, data, message_encoding) = match topic.encoding() {
                Encoding::Foxglove => {
                    let schema = foxglove_schema(topic);
                    (
                        schema.name,
                        schema.encoding,
                        schema.data.into_owned(),
                        "protobuf",
                    )
                }
                Encoding::Json => {
                    let (name, text) = topic.json_schema().unwrap_or(("", String::new()));
                    (
                        name.to_string(),
                        "jsonschema".to_string(),
                        text.into_bytes(),
                        "json",
                    )
                }
            };
            let schema = writer.add_schema(&name, &encoding, &data).map_err(open)?;
            channels[i] = writer
                .add_channel(schema, topic.name(), message_encoding, &BTreeMap::new())
                .map_err(open)?;
        }
        writer
            .write_metadata(&mcap::records::Metadata {
                name: "flyd".into(),
                metadata: options.metadata.clone(),
            })
            .map_err(open)?;
        if let Some(text) = &options.config_text {
            writer
                .attach(&mcap::Attachment {
                    log_time: 0,
                    create_time: 0,
                    name: "config.toml".into(),
                    media_type: "application/toml".into(),
                    data: std::borrow::Cow::Borrowed(text.as_bytes()),
                })
                .map_err(open)?;
        }
        Ok(Self {
            path,
            writer,
            channels,
            sequence: [0; Topic::ALL.len()],
            calibrated: [false; 2],
            bytes: 0,
            opened: Instant::now(),
        })
    }

    /// Whether this file still lacks the calibration of `topic`'s camera.
    fn needs(&self, topic: Topic) -> bool {
        match topic {
            Topic::LeftCalibration => !self.calibrated[0],
            Topic::RightCalibration => !self.calibrated[1],
            _ => false,
        }
    }

    fn write(&mut self, topic: Topic, t: u64, data: &[u8]) -> Result<(), mcap::McapError> {
        let i = index(topic);
        self.sequence[i] = self.sequence[i].wrapping_add(1);
        self.writer.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: self.channels[i],
                sequence: self.sequence[i],
                log_time: t,
                publish_time: t,
            },
            data,
        )?;
        match topic {
            Topic::LeftCalibration => self.calibrated[0] = true,
            Topic::RightCalibration => self.calibrated[1] = true,
            _ => {}
        }
        self.bytes += data.len() as u64;
        Ok(())
    }

    fn finish(mut self) -> Result<(), mcap::McapError> {
        self.writer.finish()?;
        let mut inner = self.writer.into_inner();
        std::io::Write::flush(&mut inner)?;
        inner
            .into_inner()
            .map_err(|e| mcap::McapError::Io(e.into_error()))?
            .sync_all()?;
        Ok(())
    }
}

fn index(topic: Topic) -> usize {
    Topic::ALL.iter().position(|t| *t == topic).unwrap_or(0)
}

fn foxglove_schema(topic: Topic) -> foxglove::Schema {
    let schema = match topic {
        Topic::LeftImage | Topic::RightImage => RawImage::get_schema(),
        Topic::LeftCompressed | Topic::RightCompressed => CompressedImage::get_schema(),
        Topic::LeftCalibration | Topic::RightCalibration => CameraCalibration::get_schema(),
        Topic::Flies => PointCloud::get_schema(),
        Topic::Transforms => FrameTransforms::get_schema(),
        _ => SceneUpdate::get_schema(),
    };
    // The well-known schemas always have one.
    schema.unwrap_or_else(|| foxglove::Schema::new("", "", Vec::new()))
}

fn timestamp_of(ns: u64) -> Timestamp {
    Timestamp::new(
        u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
        (ns % 1_000_000_000) as u32,
    )
}

/// flyd's vehicle frame (x right, y up, z forward) into `base_link` (x forward, y left, z up).
fn base_link(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x: z, y: -x, z: y }
}

/// A camera's calibration as `foxglove.CameraCalibration` (plumb_bob distortion).
fn calibration(camera: &Camera, frame_id: &str) -> CameraCalibration {
    let k = camera.intrinsics();
    let d = camera.distortion();
    CameraCalibration {
        timestamp: None,
        frame_id: frame_id.into(),
        width: camera.width(),
        height: camera.height(),
        distortion_model: "plumb_bob".into(),
        d: vec![d.k1, d.k2, d.p1, d.p2, d.k3],
        k: vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![
            k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    }
}

/// Where `camera`'s optical frame (`frame_id`: x right, y down, z forward) is in `base_link`.
fn camera_pose(camera: &Camera, frame_id: &str) -> FrameTransform {
    use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
    // vehicle (x right, y up, z forward) -> base_link (x forward, y left, z up)
    let a = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    let (m, _) = camera.camera_from_vehicle_affine();
    // p_cam = M p_vehicle + t, p_vehicle = A^T b: b = A M^T p_cam + A c.
    let r = a * m.transpose();
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let c = camera.centre();
    FrameTransform {
        timestamp: None,
        parent_frame_id: "base_link".into(),
        child_frame_id: frame_id.into(),
        translation: Some(base_link(c.x, c.y, c.z)),
        rotation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// The flies as a point cloud in `base_link`: x, y, z, fitness, warning (float32).
fn point_cloud(t: u64, points: &[f32]) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * 4);
    for fly in points.chunks_exact(FLY_FLOATS) {
        let [x, y, z, fitness, warning] = [fly[0], fly[1], fly[2], fly[3], fly[4]];
        for v in [z, -x, y, fitness, warning] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let field = |name: &str, i: u32| PackedElementField {
        name: name.into(),
        offset: 4 * i,
        r#type: NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(timestamp_of(t)),
        frame_id: "base_link".into(),
        pose: Some(identity_pose()),
        point_stride: 4 * FLY_FLOATS as u32,
        fields: vec![
            field("x", 0),
            field("y", 1),
            field("z", 2),
            field("fitness", 3),
            field("warning", 4),
        ],
        data: data.into(),
    }
}

fn identity_pose() -> Pose {
    Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// The road estimate (a 3.5 m x 40 m slab, tilted as measured) and the obstacle (a box from
/// its bottom to its top, red when confirmed, amber otherwise).
fn scene(
    t: u64,
    event: &super::topics::PerceptionEvent,
    obstacle: Option<[f64; 4]>,
    confirmed: bool,
) -> SceneUpdate {
    let ts = Some(timestamp_of(t));
    let lifetime = foxglove::schemas::Duration::try_from(Duration::from_millis(500)).ok();
    // Pitch about the lateral axis (y in base_link), roll about forward (x), small angles.
    let pitch = -event.road_slope_z.atan();
    let roll = event.road_slope_x.atan();
    let (sp, cp) = ((pitch / 2.0).sin(), (pitch / 2.0).cos());
    let (sr, cr) = ((roll / 2.0).sin(), (roll / 2.0).cos());
    let road = CubePrimitive {
        pose: Some(Pose {
            position: Some(base_link(
                0.0,
                event.road_height_m + 20.0 * event.road_slope_z,
                20.0,
            )),
            orientation: Some(Quaternion {
                x: sr * cp,
                y: cr * sp,
                z: -sr * sp,
                w: cr * cp,
            }),
        }),
        size: Some(Vector3 {
            x: 40.0,
            y: 3.5,
            z: 0.02,
        }),
        color: Some(Color {
            r: 0.3,
            g: 0.6,
            b: 1.0,
            a: if event.road_measured { 0.35 } else { 0.15 },
        }),
    };
    let mut entities = vec![SceneEntity {
        timestamp: ts,
        frame_id: "base_link".into(),
        id: "road".into(),
        lifetime,
        cubes: vec![road],
        ..SceneEntity::default()
    }];
    if let Some([distance, lateral, bottom, top]) = obstacle {
        let height = (top - bottom).max(0.1);
        entities.push(SceneEntity {
            timestamp: ts,
            frame_id: "base_link".into(),
            id: "obstacle".into(),
            lifetime,
            cubes: vec![CubePrimitive {
                pose: Some(Pose {
                    position: Some(base_link(lateral, bottom + height / 2.0, distance + 0.25)),
                    ..identity_pose()
                }),
                size: Some(Vector3 {
                    x: 0.5,
                    y: 0.8,
                    z: height,
                }),
                color: Some(if confirmed {
                    Color {
                        r: 1.0,
                        g: 0.1,
                        b: 0.1,
                        a: 0.7,
                    }
                } else {
                    Color {
                        r: 1.0,
                        g: 0.7,
                        b: 0.0,
                        a: 0.5,
                    }
                }),
            }],
            ..SceneEntity::default()
        });
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// The live view: a Foxglove WebSocket server and its channels.
struct Live {
    runtime: tokio::runtime::Runtime,
    /// Holds the channels and the server's sinks (the channels only weakly refer to it).
    _context: Arc<foxglove::Context>,
    server: foxglove::WebSocketServerHandle,
    addr: SocketAddr,
    channels: Vec<(Topic, Arc<foxglove::RawChannel>)>,
    options: LiveOptions,
    /// Last log time sent on the throttled topics: left, right, flies.
    last: [Option<u64>; 3],
}

impl Live {
    fn start(options: LiveOptions) -> Result<Self, WriterError> {
        let listen = options.listen;
        let err =
            |error: Box<dyn std::error::Error + Send + Sync>| WriterError::Live { listen, error };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .max_blocking_threads(1)
            .thread_name("flyd-live")
            .enable_all()
            .build()
            .map_err(|e| err(e.into()))?;
        let context = foxglove::Context::new();
        let mut channels = Vec::new();
        for topic in Topic::ALL {
            let builder = context.channel_builder(topic.name());
            let builder = match topic.encoding() {
                Encoding::Foxglove => builder
                    .message_encoding("protobuf")
                    .schema(foxglove_schema(topic)),
                Encoding::Json => {
                    let (name, text) = topic.json_schema().unwrap_or(("", String::new()));
                    builder
                        .message_encoding("json")
                        .schema(foxglove::Schema::new(name, "jsonschema", text.into_bytes()))
                }
            };
            channels.push((topic, builder.build_raw().map_err(|e| err(e.into()))?));
        }
        let server = foxglove::WebSocketServer::new()
            .name(format!("flyd {}", env!("CARGO_PKG_VERSION")))
            .bind(listen.ip().to_string(), listen.port())
            .context(&context)
            .tokio_runtime(runtime.handle());
        let server = runtime
            .block_on(server.start())
            .map_err(|e| err(e.into()))?;
        let addr = SocketAddr::new(listen.ip(), server.port());
        if !listen.ip().is_loopback() {
            tracing::warn!(
                listen = %addr,
                "live view listens beyond this machine (live.listen is not a loopback \
                 address): anyone on that network sees the cameras"
            );
        }
        tracing::info!(listen = %addr, "live view: open ws://{addr} in Foxglove");
        Ok(Self {
            runtime,
            _context: context,
            server,
            addr,
            channels,
            options,
            last: [None; 3],
        })
    }

    /// Whether a throttled topic may send at `t` (and, if so, counts it as sent).
    fn due(&mut self, topic: Topic, t: u64) -> bool {
        let (i, period) = match topic {
            Topic::LeftImage | Topic::LeftCompressed => (0, self.options.image_period),
            Topic::RightImage | Topic::RightCompressed => (1, self.options.image_period),
            Topic::Flies => (2, self.options.flies_period),
            _ => return true,
        };
        let period = nanos(period);
        match self.last[i] {
            Some(last) if t.saturating_sub(last) < period && t >= last => false,
            _ => {
                self.last[i] = Some(t);
                true
            }
        }
    }

    fn channel(&self, topic: Topic) -> Option<&Arc<foxglove::RawChannel>> {
        self.channels
            .iter()
            .find(|(t, _)| *t == topic)
            .map(|(_, c)| c)
    }

    fn log<T: Encode>(&self, topic: Topic, t: u64, msg: &T) {
        let Some(channel) = self.channel(topic) else {
            return;
        };
        if !channel.has_sinks() {
            return;
        }
        let mut data = Vec::new();
        if msg.encode(&mut data).is_ok() {
            self.log_bytes(topic, t, &data);
        }
    }

    fn log_bytes(&self, topic: Topic, t: u64, data: &[u8]) {
        if let Some(channel) = self.channel(topic)
            && channel.has_sinks()
        {
            channel.log_with_meta(data, PartialMetadata { log_time: Some(t) });
        }
    }

    fn stop(self) {
        let Live {
            runtime, server, ..
        } = self;
        runtime.block_on(server.stop().wait());
        runtime.shutdown_timeout(Duration::from_millis(500));
    }
}

#[cfg(test)]
mod tests {
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

    #[test]
    fn parts_are_numbered_beside_the_first_file() {
        assert_eq!(
            part_path(Path::new("/var/lib/flyd/drive.mcap"), 2),
            PathBuf::from("/var/lib/flyd/drive.2.mcap")
        );
    }

    #[test]
    fn the_point_cloud_is_in_base_link() {
        let cloud = point_cloud(5, &[1.0, 0.5, 10.0, 3.0, 0.25]);
        let f: Vec<f32> = cloud
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(f, vec![10.0, -1.0, 0.5, 3.0, 0.25]);
        assert_eq!(cloud.point_stride, 20);
    }

    #[test]
    fn a_camera_pose_maps_its_optical_axis_forward_and_its_centre_into_base_link() {
        let rig = crate::mock::mock_rig(320, 240).expect("rig");
        let tf = camera_pose(&rig.left, "left");
        let q = tf.rotation.expect("rotation");
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q.w, q.x, q.y, q.z,
        ));
        // The optical axis (camera z) points along base_link x (forward), image down along -z.
        let forward = q * nalgebra::Vector3::z();
        let down = q * nalgebra::Vector3::y();
        assert!(forward.x > 0.95, "{forward:?}");
        assert!(down.z < -0.95, "{down:?}");
        let t = tf.translation.expect("translation");
        let c = rig.left.centre();
        assert_eq!((t.x, t.y, t.z), (c.z, -c.x, c.y));
    }
}
