//! Closed-loop cases as data: a road, actors on it with their size, place and motion, the
//! vehicle's speed and what the run must show. A case file is TOML a user writes
//! (`docs/closed-loop.md` in flyd documents the format and how it maps to ASAM OpenSCENARIO);
//! a [`CaseFile`] (deserialised by the caller: flyd reads it with `toml`) gives its [`Case`]s,
//! one a speed ([`CaseFile::cases`]).
//!
//! ```toml
//! [[case]]
//! name = "car-stationary-overlap-50"
//! road = "straight"               # or "ramp-30", "ramp-40", "s-bend-40", or { bend_radius = 60 }
//! speed_kmh = [10, 20, 30, 40]    # one case a speed, named "NAME-30kmh"
//! expect = "no-contact"
//!
//! [[case.actor]]
//! kind = "car"                    # car, pedestrian, plate, post
//! at = 40.0                       # metres along the road from the vehicle's start to its near end
//! overlap = 50                    # percent of the vehicle's width (or `offset`, metres right)
//! ```
//!
//! Geometry: road coordinates, `along` the centre line from where the vehicle starts and
//! `offset` metres right of it (`Scene`'s convention). The vehicle drives on the centre line
//! (its driver steers along the road); its front is [`VehicleBody::front`] metres ahead of the
//! cameras (the vehicle frame's origin). An actor is a box (a car, a steel plate, a post) or a
//! cylinder (a pedestrian) standing on the road; it moves at a constant velocity along and
//! across the road.

use serde::Deserialize;

use crate::scenario::road_by_name;
use crate::vehicle::{BrakeConfig, VehicleConfig};
use crate::world::profile::Road;
use crate::world::{Material, Obstacle, Pattern, Scene, bend};

/// The mock vehicle's body as the contact check sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleBody {
    /// The front bumper, metres ahead of the cameras.
    pub front: f64,
    /// Half the vehicle's width, metres.
    pub half_width: f64,
    /// Its length, metres (the rear is `length - front` behind the cameras).
    pub length: f64,
}

impl Default for VehicleBody {
    /// A mid-size car (1.8 m wide, 4.5 m long) whose cameras sit behind the windscreen, 1.5 m
    /// behind the front bumper.
    fn default() -> Self {
        Self {
            front: 1.5,
            half_width: 0.9,
            length: 4.5,
        }
    }
}

/// The road a case drives on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RoadKind {
    Straight,
    /// A road of constant curvature, 1/m, positive bending left.
    Bend(f64),
    /// One of hw-mock's roads of changing curvature, by name.
    Profile(&'static str, &'static Road),
}

impl RoadKind {
    /// The road's curvature `along` metres on, 1/m.
    pub fn curvature(&self, along: f64) -> f64 {
        match *self {
            RoadKind::Straight => 0.0,
            RoadKind::Bend(k) => k,
            RoadKind::Profile(_, road) => road.curvature(along),
        }
    }
}

/// What an actor is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ActorKind {
    /// A car seen from behind: 1.8 m wide, 1.5 m high, 4.2 m long.
    Car,
    /// A pedestrian: a cylinder 0.5 m across, 1.75 m high.
    Pedestrian,
    /// A steel plate lying on the road (UN R152, FMVSS 127's false-activation target):
    /// 2.4 m wide, 3.7 m long, 25 mm thick.
    Plate,
    /// A delineator post: 0.1 m square, 1 m high.
    Post,
}

impl ActorKind {
    /// Width, height and length, metres.
    pub fn size(self) -> [f64; 3] {
        match self {
            ActorKind::Car => [1.8, 1.5, 4.2],
            ActorKind::Pedestrian => [0.5, 1.75, 0.5],
            ActorKind::Plate => [2.4, 0.025, 3.7],
            ActorKind::Post => [0.1, 1.0, 0.1],
        }
    }
}

const PLATE: Material = Material {
    colour: [120, 122, 126],
    pattern: Pattern::Noise {
        cell: 0.3,
        contrast: 0.35,
    },
    seed: 0x57EE1,
};

const POST: Material = Material {
    colour: [236, 236, 230],
    pattern: Pattern::Post,
    seed: 0xDE12,
};

/// An actor as a case file gives it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorSpec {
    pub kind: ActorKind,
    /// Metres along the road from the vehicle's start (its cameras) to the actor's near end
    /// at the start.
    #[serde(default)]
    pub at: Option<f64>,
    /// Instead of `at`: where the vehicle at its set speed reaches the actor in this many
    /// seconds (Euro NCAP starts its runs 4 s from the target), at least 20 m.
    #[serde(default)]
    pub ttc_s: Option<f64>,
    /// Instead of `at`: the time gap from the vehicle's bumper to the actor at the vehicle's
    /// set speed, seconds (a car followed 1.5 s ahead).
    #[serde(default)]
    pub gap_s: Option<f64>,
    /// It drives the vehicle's way at the vehicle's set speed (a car followed), plus
    /// `speed_kmh`.
    #[serde(default)]
    pub same_speed: bool,
    /// Metres right of the centre line, of the actor's centre (default 0).
    #[serde(default)]
    pub offset: Option<f64>,
    /// Instead of `offset`: how much of the vehicle's width the actor covers, percent, as
    /// Euro NCAP's car-to-car cases give it: 100 centred, 50 shifted right by half the
    /// vehicle's width, -50 shifted left.
    #[serde(default)]
    pub overlap: Option<f64>,
    /// Its speed along the road, km/h (positive: the vehicle's way).
    #[serde(default)]
    pub speed_kmh: f64,
    /// Its speed across the road, km/h (positive: to the right).
    #[serde(default)]
    pub cross_kmh: f64,
    /// Where its motion across the road ends, metres right of the centre line (a pedestrian
    /// who stops at the kerb, a car that cut in and drives on in the lane; default: never).
    #[serde(default)]
    pub cross_until: Option<f64>,
    /// It brakes to a stop at this deceleration, m/s^2 (a car ahead braking) ...
    #[serde(default)]
    pub brake_decel: Option<f64>,
    /// ... from this many seconds after the start (default 0).
    #[serde(default)]
    pub brake_at_s: f64,
}

/// One speed or several.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Speeds {
    One(f64),
    Many(Vec<f64>),
}

/// The road as a case file gives it: a name, or a bend's radius.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum RoadSpec {
    Named(String),
    Bend {
        /// Metres, positive bending left, negative right.
        bend_radius: f64,
    },
}

/// The brake actuator and driver, as a case file may override them.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSpec {
    pub dead_time_s: Option<f64>,
    pub time_constant_s: Option<f64>,
    pub jerk_limit: Option<f64>,
    pub max_decel: Option<f64>,
    pub driver_accel: Option<f64>,
    /// The front bumper, metres ahead of the cameras.
    pub front_m: Option<f64>,
}

/// A case as a case file gives it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseSpec {
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub road: RoadSpec,
    pub speed_kmh: Speeds,
    /// How long the run lasts at most (default: until the vehicle is past the last actor).
    #[serde(default)]
    pub seconds: Option<f64>,
    /// The protocol's steady state before the judged run, seconds (default 0): the driver
    /// drives at the set speed whatever flyd commands, and nothing flyd asks then counts
    /// (Euro NCAP's car-to-car runs start with the vehicle following at a steady speed and
    /// gap; flyd, running long before, knows the car ahead by then).
    #[serde(default)]
    pub warmup_s: Option<f64>,
    /// What the run must show: `no-contact`, `impact-below` (with `impact_kmh`),
    /// `no-activation`, `peak-decel-below` (with `decel`).
    pub expect: String,
    #[serde(default)]
    pub impact_kmh: Option<f64>,
    #[serde(default)]
    pub decel: Option<f64>,
    /// Which camera rig renders it: `mock` (hw-mock's, at `size`) or `vehicle` (a vehicle's
    /// rig like KITTI's: 1242x375, 0.54 m baseline, 1.65 m high).
    #[serde(default)]
    pub rig: Option<String>,
    #[serde(default)]
    pub vehicle: VehicleSpec,
    #[serde(default)]
    pub actor: Vec<ActorSpec>,
}

/// A case file: `[[case]]` tables.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseFile {
    #[serde(rename = "case")]
    pub cases: Vec<CaseSpec>,
}

/// An actor resolved: where it is at the start and how it moves, road coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Actor {
    pub kind: ActorKind,
    /// Near end along the road at the start, metres.
    pub at: f64,
    /// Centre's offset right of the centre line at the start, metres.
    pub offset: f64,
    /// m/s along and across.
    pub speed: f64,
    pub cross: f64,
    /// Where the motion across ends (offset, metres), if it does.
    pub cross_until: Option<f64>,
    /// Braking to a stop: (from, seconds; deceleration, m/s^2).
    pub brake: Option<(f64, f64)>,
}

impl Actor {
    /// (near end along, centre offset) at `time` seconds.
    pub fn place(&self, time: f64) -> (f64, f64) {
        let along = match self.brake {
            Some((from, decel)) if time > from && decel > 0.0 && self.speed > 0.0 => {
                let braking = (time - from).min(self.speed / decel);
                self.at + self.speed * from + self.speed * braking - 0.5 * decel * braking * braking
            }
            _ => self.at + self.speed * time,
        };
        let mut offset = self.offset + self.cross * time;
        if let Some(end) = self.cross_until {
            offset = if self.cross >= 0.0 {
                offset.min(end.max(self.offset))
            } else {
                offset.max(end.min(self.offset))
            };
        }
        (along, offset)
    }

    /// Its speed along the road at `time`, m/s.
    pub fn speed_at(&self, time: f64) -> f64 {
        match self.brake {
            Some((from, decel)) if time > from && self.speed > 0.0 => {
                (self.speed - decel * (time - from)).max(0.0)
            }
            _ => self.speed,
        }
    }
}

/// A case at one speed, ready to run.
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    pub name: String,
    pub description: String,
    pub road: RoadKind,
    /// The driver's set speed, m/s.
    pub speed: f64,
    /// The run's length, seconds.
    pub seconds: f64,
    /// Seconds at the start when the vehicle does not obey flyd (see [`CaseSpec::warmup_s`]).
    pub warmup: f64,
    pub actors: Vec<Actor>,
    pub vehicle: VehicleConfig,
    pub body: VehicleBody,
    pub expect: String,
    pub impact_kmh: Option<f64>,
    pub decel: Option<f64>,
    /// `mock` or `vehicle` (see [`CaseSpec::rig`]).
    pub rig: String,
}

/// A case file that cannot be run, with the case and key at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("case '{case}': {message}")]
pub struct CaseError {
    pub case: String,
    pub message: String,
}

/// Labels a case may carry.
pub const LABELS: [&str; 4] = [
    "no-contact",
    "impact-below",
    "no-activation",
    "peak-decel-below",
];

/// How far an actor is from the vehicle: along the road from its front bumper to the actor's
/// near end, and whether they overlap across the road.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Metres (negative: the bumper is past the actor's near end).
    pub distance: f64,
    /// The actor's speed along the road, m/s.
    pub actor_speed: f64,
    pub kind: ActorKind,
}

impl CaseSpec {
    /// The cases of this spec, one a speed (named `NAME-KMHkmh` when there are several).
    pub fn resolve(&self) -> Result<Vec<Case>, CaseError> {
        let err = |message: String| CaseError {
            case: self.name.clone(),
            message,
        };
        if !LABELS.contains(&self.expect.as_str()) {
            return Err(err(format!(
                "expect = {:?}: must be one of {}",
                self.expect,
                LABELS.join(", ")
            )));
        }
        match (self.expect.as_str(), self.impact_kmh, self.decel) {
            ("impact-below", None, _) => return Err(err("impact-below needs impact_kmh".into())),
            ("peak-decel-below", _, None) => {
                return Err(err("peak-decel-below needs decel".into()));
            }
            _ => {}
        }
        let road = match &self.road {
            RoadSpec::Named(n) if n == "straight" => RoadKind::Straight,
            RoadSpec::Named(n) => match road_by_name(n) {
                Some((name, road)) => RoadKind::Profile(name, road),
                None => {
                    return Err(err(format!(
                        "road = {n:?}: must be \"straight\", \"ramp-30\", \"ramp-40\", \
                         \"s-bend-40\" or {{ bend_radius = METRES }}"
                    )));
                }
            },
            RoadSpec::Bend { bend_radius } => {
                if !(bend_radius.is_finite() && bend_radius.abs() >= 10.0) {
                    return Err(err(format!(
                        "bend_radius = {bend_radius}: must be at least 10 m either way"
                    )));
                }
                RoadKind::Bend(1.0 / bend_radius)
            }
        };
        let rig = self.rig.clone().unwrap_or_else(|| "mock".into());
        if !["mock", "vehicle"].contains(&rig.as_str()) {
            return Err(err(format!(
                "rig = {rig:?}: must be \"mock\" or \"vehicle\""
            )));
        }
        let v = &self.vehicle;
        let d = BrakeConfig::default();
        let vehicle = VehicleConfig {
            brake: BrakeConfig {
                dead_time: v.dead_time_s.unwrap_or(d.dead_time),
                time_constant: v.time_constant_s.unwrap_or(d.time_constant),
                jerk_limit: v.jerk_limit.unwrap_or(d.jerk_limit),
                max_decel: v.max_decel.unwrap_or(d.max_decel),
            },
            driver_accel: v
                .driver_accel
                .unwrap_or(VehicleConfig::default().driver_accel),
        };
        vehicle.validate().map_err(|e| err(e.to_string()))?;
        let mut body = VehicleBody::default();
        if let Some(front) = v.front_m {
            if !(front.is_finite() && (0.0..=4.0).contains(&front)) {
                return Err(err(format!(
                    "vehicle.front_m = {front}: must be within 0..=4"
                )));
            }
            body.front = front;
        }
        let mut actors = Vec::with_capacity(self.actor.len());
        let mut places = Vec::with_capacity(self.actor.len());
        for (i, a) in self.actor.iter().enumerate() {
            let [w, _, _] = a.kind.size();
            let offset = match (a.offset, a.overlap) {
                (Some(_), Some(_)) => {
                    return Err(err(format!("actor {}: offset or overlap, not both", i + 1)));
                }
                (Some(o), None) => o,
                (None, Some(p)) => {
                    if !(p.is_finite() && p != 0.0 && (-100.0..=100.0).contains(&p)) {
                        return Err(err(format!(
                            "actor {}: overlap = {p}: must be within -100..=100 and not 0",
                            i + 1
                        )));
                    }
                    // Centres apart by the half-widths less the overlap's share of the
                    // vehicle's width.
                    let apart = body.half_width + 0.5 * w - p.abs() / 100.0 * 2.0 * body.half_width;
                    apart.max(0.0) * p.signum()
                }
                (None, None) => 0.0,
            };
            let at = match (a.at, a.ttc_s, a.gap_s) {
                (Some(at), None, None) => Place::At(at),
                (None, Some(ttc), None) if ttc.is_finite() && ttc > 0.0 => Place::Ttc(ttc),
                (None, None, Some(gap)) if gap.is_finite() && gap > 0.0 => Place::Gap(gap),
                (None, Some(t), None) | (None, None, Some(t)) => {
                    return Err(err(format!(
                        "actor {}: ttc_s or gap_s = {t}: must be > 0",
                        i + 1
                    )));
                }
                _ => {
                    return Err(err(format!(
                        "actor {}: needs one of `at`, `ttc_s`, `gap_s`",
                        i + 1
                    )));
                }
            };
            let values = [
                offset,
                a.speed_kmh,
                a.cross_kmh,
                a.cross_until.unwrap_or(0.0),
                a.brake_at_s,
            ];
            if let Some(d) = a.brake_decel
                && !(d.is_finite() && (0.1..=12.0).contains(&d))
            {
                return Err(err(format!(
                    "actor {}: brake_decel = {d}: must be within 0.1..=12 m/s^2",
                    i + 1
                )));
            }
            if a.brake_at_s < 0.0 || a.speed_kmh < 0.0 && a.brake_decel.is_some() {
                return Err(err(format!(
                    "actor {}: brake_at_s must be >= 0, and a braking actor drives the \
                     vehicle's way",
                    i + 1
                )));
            }
            let bad_at = matches!(at, Place::At(v) if !(v.is_finite() && v >= 0.0));
            if values.iter().any(|v| !v.is_finite()) || bad_at || offset.abs() > 30.0 {
                return Err(err(format!(
                    "actor {}: at must be >= 0 and offset within 30 m, all finite",
                    i + 1
                )));
            }
            places.push((at, a.same_speed));
            actors.push(Actor {
                kind: a.kind,
                at: 0.0,
                offset,
                speed: a.speed_kmh / 3.6,
                cross: a.cross_kmh / 3.6,
                cross_until: a.cross_until,
                brake: a.brake_decel.map(|d| (a.brake_at_s, d)),
            });
        }
        let speeds = match &self.speed_kmh {
            Speeds::One(s) => vec![*s],
            Speeds::Many(s) => s.clone(),
        };
        if speeds.is_empty() {
            return Err(err("speed_kmh: no speed".into()));
        }
        let mut cases = Vec::with_capacity(speeds.len());
        for kmh in &speeds {
            if !(kmh.is_finite() && (1.0..=130.0).contains(kmh)) {
                return Err(err(format!("speed_kmh = {kmh}: must be within 1..=130")));
            }
            let speed = kmh / 3.6;
            let mut actors = actors.clone();
            for (a, &(place, same)) in actors.iter_mut().zip(&places) {
                a.at = match place {
                    Place::At(at) => at,
                    Place::Ttc(ttc) => (ttc * speed + body.front).max(20.0),
                    Place::Gap(gap) => gap * speed + body.front,
                };
                if same {
                    a.speed += speed;
                }
            }
            // Time to pass the farthest actor (as it stands at the start) at the set speed, and
            // time to stop from it at 1 m/s^2: a run ends before, at contact, at a standstill
            // or once the vehicle is past every actor.
            let farthest = actors
                .iter()
                .map(|a| a.at + a.kind.size()[2])
                .fold(20.0_f64, f64::max);
            let seconds = match self.seconds {
                Some(s) if s.is_finite() && (0.5..=120.0).contains(&s) => s,
                Some(s) => return Err(err(format!("seconds = {s}: must be within 0.5..=120"))),
                None => ((farthest + body.length) / speed + speed + 2.0).clamp(3.0, 40.0),
            };
            let warmup = match self.warmup_s {
                None => 0.0,
                Some(w) if w.is_finite() && w >= 0.0 && w < seconds => w,
                Some(w) => {
                    return Err(err(format!(
                        "warmup_s = {w}: must be >= 0 and shorter than the run ({seconds} s)"
                    )));
                }
            };
            let name = if speeds.len() > 1 {
                format!("{}-{}kmh", self.name, fmt_kmh(*kmh))
            } else {
                self.name.clone()
            };
            cases.push(Case {
                name,
                description: self.description.clone(),
                road,
                speed,
                seconds,
                warmup,
                actors,
                vehicle,
                body,
                expect: self.expect.clone(),
                impact_kmh: self.impact_kmh,
                decel: self.decel,
                rig: rig.clone(),
            });
        }
        Ok(cases)
    }
}

/// Where an actor starts: metres along, or a time to collision at the set speed.
#[derive(Debug, Clone, Copy)]
enum Place {
    At(f64),
    Ttc(f64),
    Gap(f64),
}

fn fmt_kmh(kmh: f64) -> String {
    if kmh.fract() == 0.0 {
        format!("{kmh:.0}")
    } else {
        format!("{kmh}")
    }
}

impl CaseFile {
    /// Every case of the file, resolved (names must be unique).
    pub fn cases(&self) -> Result<Vec<Case>, CaseError> {
        let mut all: Vec<Case> = Vec::new();
        for spec in &self.cases {
            for case in spec.resolve()? {
                if all.iter().any(|c| c.name == case.name) {
                    return Err(CaseError {
                        case: case.name,
                        message: "a second case of that name".into(),
                    });
                }
                all.push(case);
            }
        }
        Ok(all)
    }
}

impl Case {
    /// The scene with the vehicle `along` metres down the road's centre line, the actors
    /// where they are at `time` seconds.
    pub fn scene(&self, along: f64, time: f64) -> Scene {
        let mut fixed = Vec::new();
        let mut boxes = Vec::new();
        let mut people = Vec::new();
        for a in &self.actors {
            let (near, offset) = a.place(time);
            let [w, h, l] = a.kind.size();
            match a.kind {
                ActorKind::Pedestrian => people.push((near + 0.5 * l, offset)),
                kind => {
                    let material = match kind {
                        ActorKind::Car => Material::CAR,
                        ActorKind::Plate => PLATE,
                        _ => POST,
                    };
                    let min = [offset - 0.5 * w, 0.0, near];
                    let max = [offset + 0.5 * w, h, near + l];
                    match self.road {
                        RoadKind::Straight => boxes.push(Obstacle::Box {
                            min: [min[0], min[1], min[2] - along],
                            max: [max[0], max[1], max[2] - along],
                            material,
                        }),
                        RoadKind::Bend(curvature) => fixed.push(Obstacle::Bent {
                            curvature,
                            min,
                            max,
                            material,
                        }),
                        RoadKind::Profile(_, road) => fixed.extend(road.lay(min, max, material)),
                    }
                }
            }
        }
        let mut scene = match self.road {
            RoadKind::Straight => Scene::driving(along, boxes),
            RoadKind::Bend(k) => Scene::on_bend(k, along, 0.0, fixed, Vec::new()),
            RoadKind::Profile(_, road) => Scene::on_road(road, along, 0.0, fixed, Vec::new()),
        };
        for (centre, offset) in people {
            let (x, z) = match self.road {
                RoadKind::Straight => (offset, centre),
                RoadKind::Bend(k) => bend::point(k, centre, offset),
                RoadKind::Profile(_, road) => road.point(centre, offset),
            };
            let [x, _, z] = scene.vehicle_point([x, 0.0, z]);
            scene.obstacles.push(Obstacle::pedestrian(x, z));
        }
        scene
    }

    /// The nearest actor ahead that overlaps the vehicle's width, the vehicle `along` metres
    /// down the road at `time`: how far its near end is from the front bumper. An actor the
    /// vehicle's rear has passed is behind it; a plate is driven over, never touched.
    pub fn nearest(&self, along: f64, time: f64) -> Option<Gap> {
        let front = along + self.body.front;
        let rear = front - self.body.length;
        self.actors
            .iter()
            .filter(|a| a.kind != ActorKind::Plate)
            .filter_map(|a| {
                let (near, offset) = a.place(time);
                let [w, _, l] = a.kind.size();
                let across = (offset - 0.5 * w) < self.body.half_width
                    && (offset + 0.5 * w) > -self.body.half_width;
                (across && near + l > rear).then_some(Gap {
                    distance: near - front,
                    actor_speed: a.speed_at(time),
                    kind: a.kind,
                })
            })
            .min_by(|a, b| a.distance.total_cmp(&b.distance))
    }

    /// Whether the vehicle, `along` metres down the road at `time`, has every actor (there is
    /// one at least) behind its rear.
    pub fn all_passed(&self, along: f64, time: f64) -> bool {
        let rear = along + self.body.front - self.body.length;
        !self.actors.is_empty()
            && self
                .actors
                .iter()
                .all(|a| a.place(time).0 + a.kind.size()[2] < rear)
    }

    /// The vehicle's yaw rate on the centre line `along` metres down the road at `speed`.
    pub fn yaw_rate(&self, along: f64, speed: f64) -> f64 {
        speed * self.road.curvature(along)
    }
}

#[cfg(test)]
mod tests;
