//! What a recording holds: its topics, their schemas and the flyd events (JSON).
//!
//! Images, calibrations, flies and the scene use Foxglove's well-known protobuf schemas
//! (`foxglove.RawImage`, `foxglove.CameraCalibration`, `foxglove.PointCloud`,
//! `foxglove.SceneUpdate`), so Foxglove and any MCAP reader with protobuf support show them
//! as they are. flyd's own events are JSON with a JSON schema each: a person reads them with
//! `mcap cat --json`, Python's `json`, or plots their fields in Foxglove.
//!
//! Frames: the flies, the road and the obstacle are published in `base_link`, the usual
//! robotics frame (x forward, y left, z up, right-handed) converted from flyd's vehicle frame
//! (x right, y up from the road, z forward: left-handed): `(X, Y, Z) = (z, -x, y)`.
//!
//! The cameras' frames (`left`, `right`: optical frames, x right, y down, z forward) are
//! placed in `base_link` by `/tf` (`foxglove.FrameTransforms`, from the calibration), so
//! Foxglove's Image panel draws the flies and the scene over the camera images.
//!
//! Log times are the daemon's clock (CLOCK_MONOTONIC, nanoseconds): an image's is the
//! kernel's capture timestamp, an event's the moment it happened.

use foxglove::Encode;
use foxglove::schemas::{
    CameraCalibration, CompressedImage, FrameTransforms, PointCloud, RawImage, SceneUpdate,
};
use serde::{Deserialize, Serialize};

/// Every topic, in the order the channels are declared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    LeftImage,
    RightImage,
    /// An MJPEG camera's frames: its JPEG payloads.
    LeftCompressed,
    RightCompressed,
    LeftCalibration,
    RightCalibration,
    Transforms,
    Flies,
    Scene,
    Pair,
    Perception,
    Decision,
    Stats,
    CanTx,
    CanRx,
}

/// How a topic's messages are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// A Foxglove well-known schema, protobuf.
    Foxglove,
    /// JSON, with the JSON schema of [`Topic::json_schema`].
    Json,
}

impl Topic {
    pub const ALL: [Topic; 15] = [
        Topic::LeftImage,
        Topic::RightImage,
        Topic::LeftCompressed,
        Topic::RightCompressed,
        Topic::LeftCalibration,
        Topic::RightCalibration,
        Topic::Transforms,
        Topic::Flies,
        Topic::Scene,
        Topic::Pair,
        Topic::Perception,
        Topic::Decision,
        Topic::Stats,
        Topic::CanTx,
        Topic::CanRx,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Topic::LeftImage => "/camera/left/image",
            Topic::RightImage => "/camera/right/image",
            Topic::LeftCompressed => "/camera/left/image/compressed",
            Topic::RightCompressed => "/camera/right/image/compressed",
            Topic::LeftCalibration => "/camera/left/calibration",
            Topic::RightCalibration => "/camera/right/calibration",
            Topic::Transforms => "/tf",
            Topic::Flies => "/flyd/flies",
            Topic::Scene => "/flyd/scene",
            Topic::Pair => "/flyd/pair",
            Topic::Perception => "/flyd/perception",
            Topic::Decision => "/flyd/decision",
            Topic::Stats => "/flyd/stats",
            Topic::CanTx => "/can/tx",
            Topic::CanRx => "/can/rx",
        }
    }

    pub fn from_name(name: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.name() == name)
    }

    pub fn encoding(self) -> Encoding {
        match self {
            Topic::LeftImage
            | Topic::RightImage
            | Topic::LeftCompressed
            | Topic::RightCompressed
            | Topic::LeftCalibration
            | Topic::RightCalibration
            | Topic::Transforms
            | Topic::Flies
            | Topic::Scene => Encoding::Foxglove,
            _ => Encoding::Json,
        }
    }

    /// The JSON schema of a JSON topic (`None` for the Foxglove ones): its name and text.
    pub fn json_schema(self) -> Option<(&'static str, String)> {
        let (name, fields): (&str, &[(&str, &str)]) = match self {
            Topic::Pair => ("flyd.Pair", PairEvent::FIELDS),
            Topic::Perception => ("flyd.Perception", PerceptionEvent::FIELDS),
            Topic::Decision => ("flyd.Decision", DecisionEvent::FIELDS),
            Topic::Stats => ("flyd.Stats", StatsEvent::FIELDS),
            Topic::CanTx | Topic::CanRx => ("flyd.CanFrame", CanEvent::FIELDS),
            _ => return None,
        };
        let properties: Vec<String> = fields
            .iter()
            .map(|(field, kind)| format!("\"{field}\":{{\"type\":{kind}}}"))
            .collect();
        Some((
            name,
            format!(
                "{{\"title\":\"{name}\",\"type\":\"object\",\"properties\":{{{}}}}}",
                properties.join(",")
            ),
        ))
    }
}

const NUM: &str = "\"number\"";
const INT: &str = "\"integer\"";
const STR: &str = "\"string\"";
const BOOL: &str = "\"boolean\"";
const OPT_NUM: &str = "[\"number\",\"null\"]";
const OPT_OBJ: &str = "[\"object\",\"null\"]";

/// The vehicle's trusted motion before a new pair: its corridor followed that path, and its
/// flies were moved with it (`Engine::predict`) with `vehicle.predict_flies`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PredictEvent {
    /// m/s
    #[serde(with = "nan_as_null")]
    pub speed: f64,
    /// rad/s
    #[serde(with = "nan_as_null")]
    pub yaw_rate: f64,
    /// seconds since the previous pair
    #[serde(with = "nan_as_null")]
    pub dt: f64,
}

/// `/flyd/pair`: the evolution thread took a new stereo pair; `generation` is the first one
/// run on it (every generation up to the next pair's runs on it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PairEvent {
    pub generation: u64,
    pub pair_id: u64,
    /// Capture timestamps, ns: the log times of the two images.
    pub left_ns: u64,
    pub right_ns: u64,
    pub predict: Option<PredictEvent>,
    /// The right image's row correction it was prepared with, pixels (the calibration's,
    /// or what the daemon measured: `flyd::daemon::rows`); absent in recordings made before
    /// the daemon corrected rows (the configuration's value then).
    #[serde(default)]
    pub right_row_shift_px: Option<f64>,
    /// The vehicle's motion was configured but not trusted before this pair (a motion fault):
    /// its corridor was the fan of `perception.obstacle.fault_yaw_rate`
    /// (`Perception::motion_unknown`); false in recordings made before the fan.
    #[serde(default)]
    pub motion_unknown: bool,
}

impl PairEvent {
    const FIELDS: &'static [(&'static str, &'static str)] = &[
        ("generation", INT),
        ("pair_id", INT),
        ("left_ns", INT),
        ("right_ns", INT),
        ("predict", OPT_OBJ),
        ("right_row_shift_px", OPT_NUM),
        ("motion_unknown", BOOL),
    ];
}

/// `/flyd/perception`: a snapshot the control thread took (what the decider was fed).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PerceptionEvent {
    /// Control-thread event number (shared with decisions and received frames: their order).
    pub seq: u64,
    pub t_ns: u64,
    pub generation: u64,
    pub warming_up: bool,
    #[serde(with = "nan_as_null")]
    pub global_warning: f64,
    /// The confirmed obstacle's distance, m.
    pub obstacle_m: Option<f64>,
    /// The latest obstacle estimate, confirmed or not.
    pub candidate_m: Option<f64>,
    pub candidate_lateral_m: Option<f64>,
    /// The decision's speed then, m/s, and its latency, s.
    #[serde(with = "nan_as_null")]
    pub speed: f64,
    #[serde(with = "nan_as_null")]
    pub latency: f64,
    #[serde(with = "nan_as_null")]
    pub road_height_m: f64,
    #[serde(with = "nan_as_null")]
    pub road_slope_z: f64,
    #[serde(with = "nan_as_null")]
    pub road_slope_x: f64,
    pub road_measured: bool,
    #[serde(with = "nan_as_null")]
    pub matched: f64,
    #[serde(with = "nan_as_null")]
    pub generation_us: f64,
    /// The curvature of the path the corridor followed, 1/m, positive turning left
    /// (`FLYD_Path`): the candidate's distance is along it and its lateral offset from it.
    /// None: straight ahead for want of a trusted motion (and in recordings made before it).
    #[serde(default)]
    pub path_curvature: Option<f64>,
    /// ... and of the arc of the moment, which an obstacle must also be on.
    #[serde(default)]
    pub path_curvature_now: Option<f64>,
    /// How the corridor's curvature changes per metre along it, 1/m^2 (a clothoid,
    /// `flyd_core::path::PredictedPath`); None: an arc (and in recordings made before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path_curvature_rate: Option<f64>,
    /// How far ahead the flies and the obstacle stage searched on this frame, metres: the
    /// configured ranges, or farther at a speed whose SLOW distance lies beyond them
    /// (`flyd_core::perception::range`). None in recordings made before it.
    #[serde(default)]
    pub search_far_m: Option<f64>,
    /// How the candidate moves over the ground along the path, m/s, and that speed's standard
    /// error (`flyd_core::perception::motion`); None before its track has three sightings
    /// (and in recordings made before it).
    #[serde(default)]
    pub candidate_speed_mps: Option<f64>,
    #[serde(default)]
    pub candidate_speed_sigma: Option<f64>,
    /// The confirmed obstacle's speed the decision credited, m/s (0: taken as still); None
    /// without a confirmed obstacle (and in recordings made before it).
    #[serde(default)]
    pub obstacle_speed_mps: Option<f64>,
    /// How the candidate moves across the path, m/s (positive right); None as its speed.
    #[serde(default)]
    pub candidate_lateral_speed_mps: Option<f64>,
    /// The candidate is beside the corridor, predicted to enter it in this many seconds
    /// before the vehicle has passed (`flyd_core::perception::crossing`); None: it is in the
    /// corridor (and in recordings made before it).
    #[serde(default)]
    pub entering_s: Option<f64>,
}

impl PerceptionEvent {
    const FIELDS: &'static [(&'static str, &'static str)] = &[
        ("seq", INT),
        ("t_ns", INT),
        ("generation", INT),
        ("warming_up", BOOL),
        ("global_warning", NUM),
        ("obstacle_m", OPT_NUM),
        ("candidate_m", OPT_NUM),
        ("candidate_lateral_m", OPT_NUM),
        ("speed", NUM),
        ("latency", NUM),
        ("road_height_m", NUM),
        ("road_slope_z", NUM),
        ("road_slope_x", NUM),
        ("road_measured", BOOL),
        ("matched", NUM),
        ("generation_us", NUM),
        ("path_curvature", OPT_NUM),
        ("path_curvature_now", OPT_NUM),
        ("search_far_m", OPT_NUM),
        ("candidate_speed_mps", OPT_NUM),
        ("candidate_speed_sigma", OPT_NUM),
        ("obstacle_speed_mps", OPT_NUM),
        ("candidate_lateral_speed_mps", OPT_NUM),
        ("entering_s", OPT_NUM),
    ];
}

/// Where a command's input came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputFrom {
    /// The worst of the snapshots taken since the previous command.
    Taken,
    /// None taken since: the newest snapshot again, at this command's time (`latest_*`).
    Latest,
    /// No trusted snapshot yet: an invalid input (the fault path).
    Untrusted,
    /// The last command, at shutdown.
    Shutdown,
}

impl From<flyd_core::policy::InputSource> for InputFrom {
    fn from(source: flyd_core::policy::InputSource) -> Self {
        use flyd_core::policy::InputSource;
        match source {
            InputSource::Taken => Self::Taken,
            InputSource::Latest => Self::Latest,
            InputSource::Untrusted => Self::Untrusted,
        }
    }
}

/// `/flyd/decision`: a command the control thread decided and sent.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DecisionEvent {
    pub seq: u64,
    pub t_ns: u64,
    pub from: InputFrom,
    /// With `from = latest`: the snapshot's generation, the speed and latency then.
    pub latest_generation: Option<u64>,
    pub latest_speed: Option<f64>,
    pub latest_latency: Option<f64>,
    /// `FaultBits` as in `FLYD_Status.Faults`.
    pub faults: u32,
    /// CLEAR, SLOW, STOP
    pub command: String8,
    pub reason: String8,
    pub changed: bool,
    #[serde(with = "nan_as_null")]
    pub global_warning: f64,
    pub obstacle_m: Option<f64>,
    /// The obstacle's speed the decision credited, m/s (see [`PerceptionEvent`]).
    #[serde(default)]
    pub obstacle_speed_mps: Option<f64>,
    #[serde(with = "nan_as_null")]
    pub speed: f64,
    pub state: String8,
}

impl DecisionEvent {
    const FIELDS: &'static [(&'static str, &'static str)] = &[
        ("seq", INT),
        ("t_ns", INT),
        ("from", STR),
        ("faults", INT),
        ("command", STR),
        ("reason", STR),
        ("changed", BOOL),
        ("global_warning", NUM),
        ("obstacle_m", OPT_NUM),
        ("obstacle_speed_mps", OPT_NUM),
        ("speed", NUM),
        ("state", STR),
    ];
}

/// `/flyd/stats`: the periodic statistics (as the `stats` log event).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StatsEvent {
    pub t_ns: u64,
    #[serde(with = "nan_as_null")]
    pub fps_left: f64,
    #[serde(with = "nan_as_null")]
    pub fps_right: f64,
    #[serde(with = "nan_as_null")]
    pub generations_per_sec: f64,
    #[serde(with = "nan_as_null")]
    pub gen_p50_ms: f64,
    #[serde(with = "nan_as_null")]
    pub gen_p99_ms: f64,
    pub generations: u64,
    pub pairs: u64,
    pub snapshots_dropped: u64,
    pub record_dropped: u64,
}

impl StatsEvent {
    const FIELDS: &'static [(&'static str, &'static str)] = &[
        ("t_ns", INT),
        ("fps_left", NUM),
        ("fps_right", NUM),
        ("generations_per_sec", NUM),
        ("gen_p50_ms", NUM),
        ("gen_p99_ms", NUM),
        ("generations", INT),
        ("pairs", INT),
        ("snapshots_dropped", INT),
        ("record_dropped", INT),
    ];
}

/// `/can/tx`, `/can/rx`: a classic CAN frame flyd sent (accepted by the bus) or received.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CanEvent {
    /// Control-thread event number (see [`PerceptionEvent::seq`]).
    pub seq: u64,
    pub t_ns: u64,
    /// The CAN ID, `CAN_EFF_FLAG` set for extended IDs.
    pub id: u32,
    /// Payload as upper-case hex, as `candump` writes it.
    pub data: String,
}

impl CanEvent {
    const FIELDS: &'static [(&'static str, &'static str)] =
        &[("seq", INT), ("t_ns", INT), ("id", INT), ("data", STR)];
}

/// A short, `Copy` name (a command, a reason, a state) carried through the queue without
/// allocating; serialised as a JSON string.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct String8 {
    len: u8,
    bytes: [u8; 24],
}

impl String8 {
    /// `text`, cut at 24 bytes (on a character boundary).
    pub fn new(text: &str) -> Self {
        let mut end = text.len().min(24);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0; 24];
        bytes[..end].copy_from_slice(&text.as_bytes()[..end]);
        Self {
            len: end as u8,
            bytes,
        }
    }

    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("")
    }
}

impl std::fmt::Debug for String8 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl std::fmt::Display for String8 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Serialize for String8 {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for String8 {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        Ok(String8::new(&text))
    }
}

/// JSON has no NaN: a NaN (an invalid input, a speed not known) is written as `null` and read
/// back as NaN.
mod nan_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}

/// Upper-case hex of a payload, as candump writes it.
pub fn hex(data: &[u8]) -> String {
    use std::fmt::Write;
    let mut out = String::with_capacity(data.len() * 2);
    for b in data {
        let _ = write!(out, "{b:02X}");
    }
    out
}

/// The Foxglove schema of a topic written with one (images, calibrations, flies, transforms,
/// scene updates).
pub(super) fn foxglove_schema(topic: Topic) -> foxglove::Schema {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_schemas_parse_and_name_every_field() {
        for topic in Topic::ALL {
            let Some((name, text)) = topic.json_schema() else {
                assert_eq!(topic.encoding(), Encoding::Foxglove);
                continue;
            };
            let schema: serde_json::Value = serde_json::from_str(&text).expect(name);
            assert_eq!(schema["title"], name);
            assert!(schema["properties"]["t_ns"].is_object() || topic == Topic::Pair);
        }
    }

    #[test]
    fn topics_round_trip_by_name() {
        for topic in Topic::ALL {
            assert_eq!(Topic::from_name(topic.name()), Some(topic));
        }
        assert_eq!(Topic::from_name("/nope"), None);
    }

    #[test]
    fn string8_cuts_on_a_character_boundary_and_serialises_as_a_string() {
        assert_eq!(String8::new("STOP").as_str(), "STOP");
        let long = "é".repeat(20);
        assert_eq!(String8::new(&long).as_str(), "é".repeat(12));
        assert_eq!(
            serde_json::to_string(&String8::new("OBSTACLE")).expect("json"),
            "\"OBSTACLE\""
        );
        let back: String8 = serde_json::from_str("\"SLOW\"").expect("json");
        assert_eq!(back.as_str(), "SLOW");
    }

    #[test]
    fn hex_is_candump_style() {
        assert_eq!(hex(&[0x0a, 0xff, 0x00]), "0AFF00");
    }
}
