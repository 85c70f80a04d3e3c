//! Where replayed frames come from: one stereo pair, a folder of pairs, or a hw-mock scenario.

use std::path::{Path, PathBuf};

use std::time::Duration;

use flyd_core::calib::Calibration;
use flyd_core::decision::Decision;
use flyd_core::frame::{PixelFormat, StereoFrame};
use flyd_core::geometry::StereoRig;
use flyd_core::kinematics::VehicleMotion;
use image::RgbImage;

use super::{LoadedImage, ReplayError, load_image};
use crate::mock::MockStereo;

/// Where replayed frames come from.
pub trait FrameFeed {
    fn rig(&self) -> &StereoRig;
    /// How many frames there are.
    fn frames(&self) -> u64;
    /// Puts frame `index` into `frame` (prepared) and `left` (the left image as captured, for
    /// the overlay).
    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError>;
    /// The frame at which the first obstacle appears, when the feed knows it (a scenario).
    fn first_obstacle(&self) -> Option<u64> {
        None
    }
    /// Whether the feed shows the same images as every frame (a still pair): the sensor
    /// checks then do not take the repetition for a frozen camera.
    fn still(&self) -> bool {
        false
    }
    /// The name of frame `index` (its left file, for a sequence).
    fn frame_name(&self, index: u64) -> String {
        index.to_string()
    }
    /// The vehicle's motion from frame `index` to the next, when the feed knows it (a
    /// scenario's own speed, as its VCU would send it).
    fn motion(&self, _index: u64) -> Option<VehicleMotion> {
        None
    }
    /// Where [`FrameFeed::motion`] comes from, when the feed knows it.
    fn motion_source(&self) -> Option<String> {
        None
    }
    /// The command decided at `time` on the frames' clock (every command, from the first):
    /// a feed whose vehicle obeys ([`super::closed_loop`]) acts on it; the others film on.
    fn obey(&mut self, _time: Duration, _decision: &Decision) {}
    /// What the perception tracked at `time` (every generation): a feed that knows the truth
    /// ([`super::closed_loop`]) compares how the tracked obstacle moves with how it really does.
    fn tracked(&mut self, _time: Duration, _tracked: &flyd_core::perception::Tracked) {}
    /// Whether the feed has nothing more to show (a closed loop's vehicle touched an actor or
    /// stood still): the replay ends there.
    fn finished(&self) -> bool {
        false
    }
    /// A closed loop's outcome.
    fn closed_loop(&self) -> Option<super::closed_loop::ClosedLoopReport> {
        None
    }
}

/// A feed whose calibration's right camera is turned by a yaw, its images unchanged: what a
/// knocked camera, or a calibration gone wrong, shows flyd (`flyd replay --right-yaw-error`).
pub struct Miscalibrated {
    inner: Box<dyn FrameFeed>,
    rig: StereoRig,
}

impl Miscalibrated {
    /// `inner` with its right camera turned right by `yaw_deg` degrees.
    pub fn new(inner: Box<dyn FrameFeed>, yaw_deg: f64) -> Result<Self, ReplayError> {
        if !(yaw_deg.is_finite() && yaw_deg.abs() <= 10.0) {
            return Err(ReplayError::Usage(format!(
                "right yaw error {yaw_deg} degrees: must be within -10..=10"
            )));
        }
        let mut rig = inner.rig().clone();
        let r = &rig.right;
        let turn = flyd_core::geometry::rotation_from_angles(0.0, yaw_deg, 0.0);
        rig.right = flyd_core::geometry::Camera::new(
            r.width(),
            r.height(),
            *r.intrinsics(),
            *r.distortion(),
            turn * r.rotation().matrix(),
            r.centre(),
        )
        .map_err(|e| ReplayError::Usage(format!("right yaw error {yaw_deg} degrees: {e}")))?;
        Ok(Self { inner, rig })
    }
}

impl FrameFeed for Miscalibrated {
    fn rig(&self) -> &StereoRig {
        &self.rig
    }
    fn frames(&self) -> u64 {
        self.inner.frames()
    }
    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        self.inner.load(index, frame, left)
    }
    fn first_obstacle(&self) -> Option<u64> {
        self.inner.first_obstacle()
    }
    fn still(&self) -> bool {
        self.inner.still()
    }
    fn frame_name(&self, index: u64) -> String {
        self.inner.frame_name(index)
    }
    fn motion(&self, index: u64) -> Option<VehicleMotion> {
        self.inner.motion(index)
    }
    fn motion_source(&self) -> Option<String> {
        self.inner.motion_source()
    }
    fn obey(&mut self, time: Duration, decision: &Decision) {
        self.inner.obey(time, decision);
    }
    fn tracked(&mut self, time: Duration, tracked: &flyd_core::perception::Tracked) {
        self.inner.tracked(time, tracked);
    }
    fn finished(&self) -> bool {
        self.inner.finished()
    }
    fn closed_loop(&self) -> Option<super::closed_loop::ClosedLoopReport> {
        self.inner.closed_loop()
    }
}

/// One stereo pair, evaluated again and again (the paper's setting): one frame, or the same
/// images as several frames ([`PairFeed::repeated`]), as a still camera films a still scene.
pub struct PairFeed {
    rig: StereoRig,
    left: LoadedImage,
    right: LoadedImage,
    frames: u64,
}

impl PairFeed {
    /// The pair `left`, `right` and its calibration (which must describe their sizes).
    pub fn load(
        left: &Path,
        right: &Path,
        calibration: &Path,
    ) -> Result<(Self, Calibration), ReplayError> {
        let cal = flyd_core::calib::load(calibration)?;
        let (l, r) = (load_image(left)?, load_image(right)?);
        for (which, img, cam, path) in [
            ("left", &l.rgb, &cal.rig.left, left),
            ("right", &r.rgb, &cal.rig.right, right),
        ] {
            check_size(which, img, cam, path, calibration)?;
        }
        let feed = Self {
            rig: cal.rig.clone(),
            left: l,
            right: r,
            frames: 1,
        };
        Ok((feed, cal))
    }

    /// The pair as `frames` frames of a still video (at least 1).
    pub fn repeated(self, frames: u64) -> Self {
        Self {
            frames: frames.max(1),
            ..self
        }
    }
}

impl FrameFeed for PairFeed {
    fn rig(&self) -> &StereoRig {
        &self.rig
    }

    fn frames(&self) -> u64 {
        self.frames
    }

    fn still(&self) -> bool {
        true
    }

    fn load(
        &mut self,
        _: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        prepare_pair(frame, &self.left, &self.right)?;
        left.clone_from(&self.left.rgb);
        Ok(())
    }
}

/// A hw-mock scenario rendered through the mock rig.
pub struct ScenarioFeed {
    mock: MockStereo,
    first_obstacle: Option<u64>,
}

impl ScenarioFeed {
    pub fn new(name: &str, width: u32, height: u32) -> Result<Self, ReplayError> {
        let scenario =
            hw_mock::Scenario::by_name(name).ok_or_else(|| ReplayError::UnknownScenario {
                name: name.to_string(),
                known: hw_mock::Scenario::names().join(", "),
            })?;
        let first_obstacle = scenario.first_obstacle_frame().map(u64::from);
        Ok(Self {
            mock: MockStereo::new(scenario, width, height)?,
            first_obstacle,
        })
    }
}

impl ScenarioFeed {
    /// The scenario's frame rate.
    pub fn fps(&self) -> f64 {
        self.mock.scenario().fps()
    }
}

impl FrameFeed for ScenarioFeed {
    fn rig(&self) -> &StereoRig {
        self.mock.rig()
    }

    fn frames(&self) -> u64 {
        self.mock.scenario().frame_count() as u64
    }

    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        let (l, r) = self.mock.frame(index)?;
        super::show_rendered(frame, left, l, r)
    }

    fn first_obstacle(&self) -> Option<u64> {
        self.first_obstacle
    }

    fn motion_source(&self) -> Option<String> {
        Some(format!("scenario {}", self.mock.scenario().name()))
    }

    fn motion(&self, index: u64) -> Option<VehicleMotion> {
        let s = self.mock.scenario();
        let f = u32::try_from(index).unwrap_or(u32::MAX);
        Some(VehicleMotion {
            speed: s.speed_at(f),
            yaw_rate: s.yaw_rate_at(f),
        })
    }
}

/// Image files of a sequence folder, in name order.
fn images_in(dir: &Path) -> Result<Vec<PathBuf>, ReplayError> {
    let entries = std::fs::read_dir(dir).map_err(|source| ReplayError::Io {
        path: dir.display().to_string(),
        source,
    })?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| ReplayError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let path = entry.path();
        let image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()));
        if image && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// A folder of stereo pairs, replayed in name order: `left/` + `right/`, or KITTI raw's
/// `image_02/data` + `image_03/data`. Left and right files pair by name.
pub struct SequenceFeed {
    rig: StereoRig,
    calibration: PathBuf,
    pairs: Vec<(PathBuf, PathBuf)>,
    /// The vehicle's motion from each frame to the next (from the folder's `poses.txt`, or
    /// a candump log: [`SequenceFeed::with_motion`]), and where it came from.
    motion: Option<(String, Vec<Option<VehicleMotion>>)>,
}

/// The poses file a sequence folder may hold ([`super::poses`]).
pub const SEQUENCE_POSES: &str = "poses.txt";

/// The layouts [`SequenceFeed::open`] knows, as (left, right) folders.
pub const SEQUENCE_LAYOUTS: [(&str, &str); 2] =
    [("left", "right"), ("image_02/data", "image_03/data")];

impl SequenceFeed {
    /// The sequence in `dir`, whose pairs `calibration` describes (every image its size),
    /// filmed at `fps`; with the vehicle's motion when `dir` holds a `poses.txt` (KITTI
    /// odometry: one pose a frame).
    pub fn open(
        dir: &Path,
        calibration: &Path,
        fps: f64,
    ) -> Result<(Self, Calibration), ReplayError> {
        let cal = flyd_core::calib::load(calibration)?;
        let Some((l, r)) = SEQUENCE_LAYOUTS
            .iter()
            .map(|(l, r)| (dir.join(l), dir.join(r)))
            .find(|(l, r)| l.is_dir() && r.is_dir())
        else {
            return Err(ReplayError::SequenceLayout {
                dir: dir.display().to_string(),
            });
        };
        let (left, right) = (images_in(&l)?, images_in(&r)?);
        let name = |p: &PathBuf| p.file_name().map(|n| n.to_os_string());
        let mut pairs = Vec::with_capacity(left.len());
        for file in &left {
            let partner = right
                .iter()
                .find(|p| name(p) == name(file))
                .ok_or_else(|| ReplayError::SequenceUnpaired {
                    file: file.display().to_string(),
                    dir: r.display().to_string(),
                })?;
            pairs.push((file.clone(), partner.clone()));
        }
        if let Some(extra) = right
            .iter()
            .find(|p| !left.iter().any(|f| name(f) == name(p)))
        {
            return Err(ReplayError::SequenceUnpaired {
                file: extra.display().to_string(),
                dir: l.display().to_string(),
            });
        }
        if pairs.is_empty() {
            return Err(ReplayError::SequenceEmpty {
                dir: l.display().to_string(),
            });
        }
        let poses = dir.join(SEQUENCE_POSES);
        let motion = if poses.is_file() {
            let motion = motion_from_poses(&poses, pairs.len(), fps)?;
            Some((
                format!("poses {}", poses.display()),
                motion.into_iter().map(Some).collect(),
            ))
        } else {
            None
        };
        let feed = Self {
            rig: cal.rig.clone(),
            calibration: calibration.to_path_buf(),
            pairs,
            motion,
        };
        Ok((feed, cal))
    }
}

impl SequenceFeed {
    /// The sequence with `motion` (one a frame; `None` where it is not known) from `source`
    /// instead of its poses.
    pub fn with_motion(self, source: String, motion: Vec<Option<VehicleMotion>>) -> Self {
        Self {
            motion: Some((source, motion)),
            ..self
        }
    }
}

impl FrameFeed for SequenceFeed {
    fn rig(&self) -> &StereoRig {
        &self.rig
    }

    fn frames(&self) -> u64 {
        self.pairs.len() as u64
    }

    fn load(
        &mut self,
        index: u64,
        frame: &mut StereoFrame,
        left: &mut RgbImage,
    ) -> Result<(), ReplayError> {
        let i = usize::try_from(index)
            .unwrap_or(usize::MAX)
            .min(self.pairs.len().saturating_sub(1));
        let (l, r) = &self.pairs[i];
        let (li, ri) = (load_image(l)?, load_image(r)?);
        for (which, img, cam, path) in [
            ("left", &li.rgb, &self.rig.left, l),
            ("right", &ri.rgb, &self.rig.right, r),
        ] {
            check_size(which, img, cam, path, &self.calibration)?;
        }
        prepare_pair(frame, &li, &ri)?;
        *left = li.rgb;
        Ok(())
    }

    fn motion(&self, index: u64) -> Option<VehicleMotion> {
        let (_, motion) = self.motion.as_ref()?;
        let i = usize::try_from(index).unwrap_or(usize::MAX);
        motion.get(i).or(motion.last()).copied().flatten()
    }

    fn motion_source(&self) -> Option<String> {
        self.motion.as_ref().map(|(source, _)| source.clone())
    }

    fn frame_name(&self, index: u64) -> String {
        usize::try_from(index)
            .ok()
            .and_then(|i| self.pairs.get(i))
            .and_then(|(l, _)| l.file_name())
            .map_or_else(|| index.to_string(), |n| n.to_string_lossy().into_owned())
    }
}

/// The motion from each of `frames` frames to the next (the last repeats the one before),
/// from the poses in `path`, `fps` frames a second.
fn motion_from_poses(
    path: &Path,
    frames: usize,
    fps: f64,
) -> Result<Vec<VehicleMotion>, ReplayError> {
    let text = std::fs::read_to_string(path).map_err(|source| ReplayError::Io {
        path: path.display().to_string(),
        source,
    })?;
    let poses = super::poses::parse(&text).map_err(|source| ReplayError::Poses {
        path: path.display().to_string(),
        source,
    })?;
    if poses.len() < frames {
        return Err(ReplayError::PosesCount {
            path: path.display().to_string(),
            poses: poses.len(),
            frames,
        });
    }
    let dt = 1.0 / fps;
    let mut motion: Vec<VehicleMotion> = poses[..frames]
        .windows(2)
        .map(|w| super::poses::motion_between(&w[0], &w[1], dt))
        .collect();
    motion.push(motion.last().copied().unwrap_or(VehicleMotion::STANDSTILL));
    Ok(motion)
}

/// An image of another size than its camera: an error naming both.
/// The pair into `frame`: in grey when both files are grey (a grey camera's frames, or the
/// luma a YUYV camera is compared in: `cameras.channels = "luma"`), else in RGB.
fn prepare_pair(
    frame: &mut StereoFrame,
    left: &LoadedImage,
    right: &LoadedImage,
) -> Result<(), ReplayError> {
    match (&left.luma, &right.luma) {
        (Some(l), Some(r)) => {
            frame.left.prepare(PixelFormat::Grey8, l)?;
            frame.right.prepare(PixelFormat::Grey8, r)?;
        }
        _ => {
            frame.left.prepare(PixelFormat::Rgb8, left.rgb.as_raw())?;
            frame.right.prepare(PixelFormat::Rgb8, right.rgb.as_raw())?;
        }
    }
    Ok(())
}

fn check_size(
    which: &'static str,
    img: &RgbImage,
    cam: &flyd_core::geometry::Camera,
    image: &Path,
    calibration: &Path,
) -> Result<(), ReplayError> {
    if img.dimensions() == (cam.width(), cam.height()) {
        return Ok(());
    }
    Err(ReplayError::ImageSize {
        which,
        image: image.display().to_string(),
        calibration: calibration.display().to_string(),
        got_w: img.width(),
        got_h: img.height(),
        want_w: cam.width(),
        want_h: cam.height(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use flyd_core::frame::PreparedImage;

    /// Two grey files are compared in grey (as the daemon compares a grey camera's frames, or
    /// a YUYV camera's luma); a grey file beside a colour one, in colour.
    #[test]
    fn a_pair_of_grey_files_is_compared_in_grey() {
        let dir = tempfile::tempdir().expect("tempdir");
        let rig = dir.path().join("rig.toml");
        std::fs::copy(
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/vm/config/mock-rig-320x240.toml"
            ),
            &rig,
        )
        .expect("rig");
        let grey: Vec<u8> = (0..320 * 240).map(|i| (i * 7 % 251) as u8).collect();
        let colour: Vec<u8> = grey.iter().flat_map(|&g| [g, g / 2, 255 - g]).collect();
        let file = |name: &str, colour_type, pixels: &[u8]| {
            let path = dir.path().join(name);
            image::save_buffer(&path, pixels, 320, 240, colour_type).expect("png");
            path
        };
        let (gl, gr) = (
            file("gl.png", image::ExtendedColorType::L8, &grey),
            file("gr.png", image::ExtendedColorType::L8, &grey),
        );
        let cr = file("cr.png", image::ExtendedColorType::Rgb8, &colour);
        let channels = |left: &Path, right: &Path| {
            let (mut feed, _) = PairFeed::load(left, right, &rig).expect("loads");
            let image = || PreparedImage::new(320, 240).expect("image");
            let mut frame = StereoFrame::new(image(), image(), 0);
            let mut overlay = RgbImage::new(1, 1);
            feed.load(0, &mut frame, &mut overlay).expect("prepares");
            assert_eq!(overlay.dimensions(), (320, 240), "the overlay is RGB");
            (frame.left.channels(), frame.right.channels())
        };
        assert_eq!(channels(&gl, &gr), (1, 1));
        assert_eq!(channels(&gl, &cr), (3, 3));
    }
}
