//! Scripted scenarios: sequences of scenes at a fixed frame rate, with the ground truth a
//! reaction-time measurement needs. The vehicle is stationary in all but the `driving*` and
//! `drive-*` ones ([`Scenario::speed_at`]),
//! where road and roadside come towards it ([`Scene::travelled`]); in `drive-30-lane-change`
//! it also turns ([`Scenario::yaw_rate_at`], [`Scene::heading`]); on the `bend-*` roads it
//! follows a constant curvature ([`Scene::on_bend`]), on the `ramp-*` and `s-bend-*` roads one
//! that changes with distance ([`Scene::on_road`], [`crate::world::profile`]). Obstacles are
//! given in the vehicle frame, or fixed to the road ([`Scene::fixed`]). A moving vehicle's frames each cost a full render (5-14 stereo pairs
//! a second at 640x480, `hw-mock/README.md`): those scenarios are for offline replay, not a
//! live mock camera.

use std::sync::LazyLock;

use crate::world::profile::{Road, Segment};
use crate::world::{Material, Obstacle, Scene, bend};

const FPS: f64 = 30.0;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    EmptyRoad,
    Pedestrian4m,
    PedestrianStepsIn,
    CarApproaching,
    /// Down the empty road at `speed` m/s.
    Cruise {
        speed: f64,
    },
    /// At `speed` m/s towards a pedestrian standing in the lane centre `from` metres ahead at
    /// the first frame.
    Approach {
        speed: f64,
        from: f64,
    },
    /// At `speed` m/s down the empty road, moving `lateral` metres to the left between
    /// `from` and `from + duration` seconds: an S-curve of yaw rate
    /// `A sin(2 pi (t - from) / duration)`, `A = 2 pi lateral / (speed duration^2)`.
    LaneChange {
        speed: f64,
        lateral: f64,
        from: f64,
        duration: f64,
    },
    /// At `speed` m/s along the centre line of a road of constant `curvature` (1/m, positive
    /// left), from where the bend starts; with what [`Around`] says stands on it.
    Bend {
        speed: f64,
        curvature: f64,
        around: Around,
    },
    /// At `speed` m/s along the centre line of a road of changing curvature, from its origin;
    /// with what [`Around`] says stands on it.
    Road {
        speed: f64,
        geometry: Geometry,
        around: Around,
    },
}

/// The roads of changing curvature ([`crate::world::profile`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Geometry {
    /// A tight on-ramp to the left: straight 10 m, a clothoid over 20 m into a 25 m radius,
    /// held 25 m, then opening over 60 m to straight.
    Ramp30,
    /// The same with a 50 m radius.
    Ramp40,
    /// An S-bend: a clothoid over 25 m into an 80 m radius to the left, held 5 m, a clothoid
    /// over 25 m through straight into 80 m to the right, held 30 m, a clothoid over 25 m out
    /// to straight.
    SBend40,
}

static RAMP_30: [Segment; 5] = ramp(1.0 / 25.0);
static RAMP_40: [Segment; 5] = ramp(1.0 / 50.0);
static S_BEND_40: [Segment; 5] = [
    Segment::clothoid(25.0, 0.0, 1.0 / 80.0),
    Segment::arc(5.0, 1.0 / 80.0),
    Segment::clothoid(25.0, 1.0 / 80.0, -1.0 / 80.0),
    Segment::arc(30.0, -1.0 / 80.0),
    Segment::clothoid(25.0, -1.0 / 80.0, 0.0),
];

/// An on-ramp bending left into curvature `k` and opening up.
const fn ramp(k: f64) -> [Segment; 5] {
    [
        Segment::straight(10.0),
        Segment::clothoid(20.0, 0.0, k),
        Segment::arc(25.0, k),
        Segment::clothoid(60.0, k, 0.0),
        Segment::straight(40.0),
    ]
}

/// hw-mock's roads of changing curvature by the names the scenarios give them (`ramp-30`,
/// `ramp-40`, `s-bend-40`): the name as stored, and the road.
pub fn road_by_name(name: &str) -> Option<(&'static str, &'static Road)> {
    let (name, geometry) = match name {
        "ramp-30" => ("ramp-30", Geometry::Ramp30),
        "ramp-40" => ("ramp-40", Geometry::Ramp40),
        "s-bend-40" => ("s-bend-40", Geometry::SBend40),
        _ => return None,
    };
    Some((name, geometry.road()))
}

impl Geometry {
    /// The road, built the first time it is asked for.
    fn road(self) -> &'static Road {
        static R30: LazyLock<Road> = LazyLock::new(|| Road::new(&RAMP_30));
        static R40: LazyLock<Road> = LazyLock::new(|| Road::new(&RAMP_40));
        static S40: LazyLock<Road> = LazyLock::new(|| Road::new(&S_BEND_40));
        match self {
            Geometry::Ramp30 => &R30,
            Geometry::Ramp40 => &R40,
            Geometry::SBend40 => &S40,
        }
    }
}

/// What stands on a bend.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Around {
    /// Nothing but the roadside and the guard rail on the outside.
    Empty,
    /// A pedestrian on the centre line, this far along the bend.
    Pedestrian(f64),
    /// A car parked on the outside, its rear this far along the bend, its near side
    /// [`PARKED_GAP`] beyond the centre line (0.5 m outside flyd's default corridor).
    ParkedCar(f64),
    /// A car stopped on the centre line (laid along the road), its rear this far along.
    StoppedCar(f64),
    /// A pedestrian standing at road coordinates (along, offset): offset metres right of the
    /// centre line.
    PedestrianBeside(f64, f64),
}

/// The kerb pedestrian of `ramp-30-pedestrian-on-kerb`: on the inside (left) kerb strip,
/// beyond the edge line, in the bend.
const KERB_PEDESTRIAN: (f64, f64) = (35.0, -2.7);

/// The parked car's near side, metres from the centre line.
const PARKED_GAP: f64 = 1.7;
/// The bends: 60 m radius to the left at 30 km/h, 120 m to the right at 40 km/h (lateral
/// accelerations 1.2 and 1.0 m/s^2, yaw rates 0.14 and 0.09 rad/s).
const BEND_30: f64 = 1.0 / 60.0;
const BEND_40: f64 = -1.0 / 120.0;

/// Frame at which the pedestrian of `pedestrian-steps-in` appears.
const STEP_IN_FRAME: u32 = 30;
/// Where it appears (inside the lane, right of centre) and how fast it walks to the centre.
const STEP_IN_X: f64 = 0.6;
const WALK_SPEED: f64 = 1.4;
/// Range of the approaching car's rear over the scenario, metres.
const CAR_FROM: f64 = 25.0;
const CAR_TO: f64 = 5.0;
/// Speed of the vehicle in `driving`, m/s (29 km/h).
const DRIVING_SPEED: f64 = 8.0;
/// 30 and 40 km/h, the first test speeds of UN R152's pedestrian target.
const KMH_30: f64 = 30.0 / 3.6;
const KMH_40: f64 = 40.0 / 3.6;

/// A named, deterministic sequence of scenes.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    name: &'static str,
    description: &'static str,
    kind: Kind,
    frames: u32,
}

/// The lane change: 2 m to the left over 5 s, from 0.5 s.
const LANE_CHANGE_LATERAL: f64 = 2.0;
const LANE_CHANGE_FROM: f64 = 0.5;
const LANE_CHANGE_DURATION: f64 = 5.0;

const ALL: [Scenario; 24] = [
    Scenario {
        name: "empty-road",
        description: "Nothing in the lane; roadside walls, poles and trees only.",
        kind: Kind::EmptyRoad,
        frames: 150,
    },
    Scenario {
        name: "pedestrian-4m",
        description: "A pedestrian standing in the lane centre, body axis 4 m ahead, from the first frame.",
        kind: Kind::Pedestrian4m,
        frames: 150,
    },
    Scenario {
        name: "pedestrian-steps-in",
        description: "Empty until frame 30; then a pedestrian 4 m ahead at x = 0.6 m walks to the lane centre at 1.4 m/s and stays.",
        kind: Kind::PedestrianStepsIn,
        frames: 150,
    },
    Scenario {
        name: "car-approaching",
        description: "A car in the lane whose rear closes linearly from 25 m to 5 m over the scenario (~4 m/s).",
        kind: Kind::CarApproaching,
        frames: 150,
    },
    Scenario {
        name: "driving",
        description: "The vehicle drives down the empty road at 8 m/s (29 km/h): road and roadside come towards it, nothing in the lane. Offline replay only (full render each frame).",
        kind: Kind::Cruise {
            speed: DRIVING_SPEED,
        },
        frames: 150,
    },
    Scenario {
        name: "driving-to-pedestrian",
        description: "The vehicle drives at 5 m/s towards a pedestrian standing in the lane centre, 30 m ahead at the first frame and 5.2 m at the last. Offline replay only (full render each frame).",
        kind: Kind::Approach {
            speed: 5.0,
            from: 30.0,
        },
        frames: 150,
    },
    Scenario {
        name: "drive-30",
        description: "The empty road at 30 km/h (8.33 m/s) for 5 s. Offline replay only.",
        kind: Kind::Cruise { speed: KMH_30 },
        frames: 150,
    },
    Scenario {
        name: "drive-40",
        description: "The empty road at 40 km/h (11.1 m/s) for 5 s. Offline replay only.",
        kind: Kind::Cruise { speed: KMH_40 },
        frames: 150,
    },
    Scenario {
        name: "drive-30-to-pedestrian",
        description: "At 30 km/h towards a pedestrian in the lane centre, 40 m ahead at the first frame and 7 m at the last (4 s); the stopping distance at 30 km/h (0.5 s, 4 m/s^2, 2 m) is 14.9 m. Offline replay only.",
        kind: Kind::Approach {
            speed: KMH_30,
            from: 40.0,
        },
        frames: 120,
    },
    Scenario {
        name: "drive-40-to-pedestrian",
        description: "At 40 km/h towards a pedestrian in the lane centre, 50 m ahead at the first frame and 6 m at the last (4 s); the stopping distance at 40 km/h (0.5 s, 4 m/s^2, 2 m) is 23.0 m. Offline replay only.",
        kind: Kind::Approach {
            speed: KMH_40,
            from: 50.0,
        },
        frames: 120,
    },
    Scenario {
        name: "drive-30-lane-change",
        description: "At 30 km/h down the empty road, changing lane 2 m to the left between 0.5 s and 5.5 s: yaw rate up to 0.06 rad/s (3.5 deg/s) left then right, heading up to 5.5 deg (the road has no bend: this S-curve is the turning scenario). Offline replay only.",
        kind: Kind::LaneChange {
            speed: KMH_30,
            lateral: LANE_CHANGE_LATERAL,
            from: LANE_CHANGE_FROM,
            duration: LANE_CHANGE_DURATION,
        },
        frames: 180,
    },
    Scenario {
        name: "bend-30",
        description: "At 30 km/h round a 60 m left bend (yaw rate 0.14 rad/s), a guard rail on its outside 5.45 m from the centre line, the roadside laid along it; nothing in the path. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_30,
            curvature: BEND_30,
            around: Around::Empty,
        },
        frames: 120,
    },
    Scenario {
        name: "bend-30-to-pedestrian",
        description: "bend-30 with a pedestrian on the centre line 40 m along the bend at the first frame, 7 m at the last; the stopping distance at 30 km/h is 14.9 m. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_30,
            curvature: BEND_30,
            around: Around::Pedestrian(40.0),
        },
        frames: 120,
    },
    Scenario {
        name: "bend-30-parked-car",
        description: "bend-30 with a car parked on the outside of the bend, its rear 30 m along, its near side 1.7 m right of the centre line: outside the path. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_30,
            curvature: BEND_30,
            around: Around::ParkedCar(30.0),
        },
        frames: 120,
    },
    Scenario {
        name: "bend-40",
        description: "At 40 km/h round a 120 m right bend (yaw rate -0.09 rad/s), a guard rail on its outside; nothing in the path. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_40,
            curvature: BEND_40,
            around: Around::Empty,
        },
        frames: 120,
    },
    Scenario {
        name: "bend-40-to-pedestrian",
        description: "bend-40 with a pedestrian on the centre line 50 m along the bend at the first frame, 6 m at the last; the stopping distance at 40 km/h is 23.0 m. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_40,
            curvature: BEND_40,
            around: Around::Pedestrian(50.0),
        },
        frames: 120,
    },
    Scenario {
        name: "bend-40-parked-car",
        description: "bend-40 with a car parked on the outside of the bend (left), its rear 40 m along, its near side 1.7 m left of the centre line: outside the path. Offline replay only.",
        kind: Kind::Bend {
            speed: KMH_40,
            curvature: BEND_40,
            around: Around::ParkedCar(40.0),
        },
        frames: 120,
    },
    Scenario {
        name: "ramp-30",
        description: "At 30 km/h up a tight on-ramp to the left, a single lane: straight 10 m, a clothoid over 20 m into a 25 m radius (yaw rate up to 0.33 rad/s), held 25 m, then opening over 60 m to straight; delineator posts every 50 m on both kerbs, a guard rail on the outside; nothing in the path (5 s, 41 m). Offline replay only.",
        kind: Kind::Road {
            speed: KMH_30,
            geometry: Geometry::Ramp30,
            around: Around::Empty,
        },
        frames: 150,
    },
    Scenario {
        name: "ramp-30-stopped-car",
        description: "ramp-30 with a car stopped in the lane on the centre line, its rear 40 m along the road at the first frame (in the 25 m radius), 4.2 m at the last; the STOP distance at 30 km/h (9 m/s^2) is 10.0 m. Offline replay only.",
        kind: Kind::Road {
            speed: KMH_30,
            geometry: Geometry::Ramp30,
            around: Around::StoppedCar(40.0),
        },
        frames: 130,
    },
    Scenario {
        name: "ramp-30-pedestrian-on-kerb",
        description: "ramp-30 with a pedestrian standing on the inside (left) kerb strip in the bend, 35 m along at the first frame, 2.7 m left of the centre line (beyond the edge line at 1.9 m): the vehicle passes it at 4.2 s. Offline replay only.",
        kind: Kind::Road {
            speed: KMH_30,
            geometry: Geometry::Ramp30,
            around: Around::PedestrianBeside(KERB_PEDESTRIAN.0, KERB_PEDESTRIAN.1),
        },
        frames: 150,
    },
    Scenario {
        name: "ramp-40",
        description: "At 40 km/h up an on-ramp to the left, a single lane: straight 10 m, a clothoid over 20 m into a 50 m radius (yaw rate up to 0.22 rad/s), held 25 m, then opening over 60 m to straight; delineator posts every 50 m on both kerbs, a guard rail on the outside; nothing in the path (5 s, 55 m). Offline replay only.",
        kind: Kind::Road {
            speed: KMH_40,
            geometry: Geometry::Ramp40,
            around: Around::Empty,
        },
        frames: 150,
    },
    Scenario {
        name: "ramp-40-stopped-car",
        description: "ramp-40 with a car stopped in the lane on the centre line, its rear 50 m along the road at the first frame (in the 50 m radius), 4.1 m at the last; the STOP distance at 40 km/h (9 m/s^2) is 14.4 m. Offline replay only.",
        kind: Kind::Road {
            speed: KMH_40,
            geometry: Geometry::Ramp40,
            around: Around::StoppedCar(50.0),
        },
        frames: 125,
    },
    Scenario {
        name: "s-bend-40",
        description: "At 40 km/h through an S-bend, a single lane: a clothoid over 25 m into an 80 m radius to the left (yaw rate 0.14 rad/s), held 5 m, a clothoid over 25 m through straight into 80 m to the right, held 30 m, a clothoid over 25 m out to straight; delineator posts every 50 m on both kerbs, a guard rail on the outside of each bend; nothing in the path (5 s, 55 m). Offline replay only.",
        kind: Kind::Road {
            speed: KMH_40,
            geometry: Geometry::SBend40,
            around: Around::Empty,
        },
        frames: 150,
    },
    Scenario {
        name: "s-bend-40-to-pedestrian",
        description: "s-bend-40 with a pedestrian on the centre line in its second (right) half, 50 m along the road at the first frame (7.5 m past the inflection), 4.1 m at the last; the vehicle is still turning left when it comes into view; the STOP distance at 40 km/h (9 m/s^2) is 14.4 m. Offline replay only.",
        kind: Kind::Road {
            speed: KMH_40,
            geometry: Geometry::SBend40,
            around: Around::Pedestrian(50.0),
        },
        frames: 125,
    },
];

/// A car (as [`Obstacle::car`]) parked on the outside of a bend of `curvature`, its rear
/// `rear` metres along it, laid along the bend.
fn parked_car(curvature: f64, rear: f64) -> Obstacle {
    let side: f64 = if curvature >= 0.0 { 1.0 } else { -1.0 };
    let (a, b) = (side * PARKED_GAP, side * (PARKED_GAP + 1.8));
    Obstacle::Bent {
        curvature,
        min: [a.min(b), 0.0, rear],
        max: [a.max(b), 1.5, rear + 4.2],
        material: Material::CAR,
    }
}

impl Scenario {
    /// Names accepted by [`Scenario::by_name`].
    pub fn names() -> Vec<&'static str> {
        ALL.iter().map(|s| s.name).collect()
    }

    pub fn by_name(name: &str) -> Option<Self> {
        ALL.iter().find(|s| s.name == name).cloned()
    }

    pub fn name(&self) -> &'static str {
        self.name
    }

    pub fn description(&self) -> &'static str {
        self.description
    }

    pub fn frame_count(&self) -> u32 {
        self.frames
    }

    pub fn fps(&self) -> f64 {
        FPS
    }

    /// Whether [`crate::CameraRenderer`] keeps up with the frame rate at 640x480: false for the
    /// `driving*` scenarios, whose every frame is a full render (offline replay only).
    pub fn live(&self) -> bool {
        !matches!(
            self.kind,
            Kind::Cruise { .. }
                | Kind::Approach { .. }
                | Kind::LaneChange { .. }
                | Kind::Bend { .. }
                | Kind::Road { .. }
        )
    }

    /// The scene at `frame`. Frames past the end hold the last scene, so a consumer that runs
    /// longer than the script sees a still world rather than an error.
    pub fn scene_at(&self, frame: u32) -> Scene {
        let f = frame.min(self.frames.saturating_sub(1));
        let seconds = |from: u32| f64::from(f.saturating_sub(from)) / FPS;
        match self.kind {
            Kind::EmptyRoad => Scene::empty(),
            Kind::Pedestrian4m => Scene::with(vec![Obstacle::pedestrian(0.0, 4.0)]),
            Kind::PedestrianStepsIn => {
                if f < STEP_IN_FRAME {
                    Scene::empty()
                } else {
                    let x = (STEP_IN_X - WALK_SPEED * seconds(STEP_IN_FRAME)).max(0.0);
                    Scene::with(vec![Obstacle::pedestrian(x, 4.0)])
                }
            }
            Kind::CarApproaching => {
                let last = self.frames.saturating_sub(1).max(1);
                let w = f64::from(f) / f64::from(last);
                Scene::with(vec![Obstacle::car(0.0, CAR_FROM + (CAR_TO - CAR_FROM) * w)])
            }
            Kind::Cruise { speed } => Scene::driving(speed * seconds(0), vec![]),
            Kind::Approach { speed, from } => {
                let travelled = speed * seconds(0);
                Scene::driving(travelled, vec![Obstacle::pedestrian(0.0, from - travelled)])
            }
            Kind::LaneChange { .. } => {
                // The pose integrated frame by frame with the motion the vehicle reports, as
                // flyd moves its flies (an arc: the chord at half the turn).
                let (mut x, mut z, mut heading) = (0.0_f64, 0.0_f64, 0.0_f64);
                for k in 0..f {
                    let (d, turn) = (self.speed_at(k) / FPS, self.yaw_rate_at(k) / FPS);
                    let mid = heading + 0.5 * turn;
                    x -= d * mid.sin();
                    z += d * mid.cos();
                    heading += turn;
                }
                Scene::posed(z, x, heading, vec![])
            }
            Kind::Bend {
                speed,
                curvature,
                around,
            } => {
                let along = speed * seconds(0);
                let fixed = match around {
                    Around::ParkedCar(rear) => vec![parked_car(curvature, rear)],
                    _ => vec![],
                };
                let mut scene = Scene::on_bend(curvature, along, 0.0, fixed, vec![]);
                if let Around::Pedestrian(at) = around {
                    let (x, z) = bend::point(curvature, at, 0.0);
                    let [x, _, z] = scene.vehicle_point([x, 0.0, z]);
                    scene.obstacles.push(Obstacle::pedestrian(x, z));
                }
                scene
            }
            Kind::Road {
                speed,
                geometry,
                around,
            } => {
                let road = geometry.road();
                let along = speed * seconds(0);
                let fixed = match around {
                    Around::StoppedCar(rear) => {
                        road.lay([-0.9, 0.0, rear], [0.9, 1.5, rear + 4.2], Material::CAR)
                    }
                    _ => vec![],
                };
                let mut scene = Scene::on_road(road, along, 0.0, fixed, vec![]);
                let standing = match around {
                    Around::Pedestrian(at) => Some((at, 0.0)),
                    Around::PedestrianBeside(at, offset) => Some((at, offset)),
                    _ => None,
                };
                if let Some((at, offset)) = standing {
                    let (x, z) = road.point(at, offset);
                    let [x, _, z] = scene.vehicle_point([x, 0.0, z]);
                    scene.obstacles.push(Obstacle::pedestrian(x, z));
                }
                scene
            }
        }
    }

    /// The vehicle's forward speed at `frame`, m/s: what its wheels would report (0 in the
    /// stationary scenarios, and past the last frame, where the scene holds still).
    pub fn speed_at(&self, frame: u32) -> f64 {
        if frame >= self.frames {
            return 0.0;
        }
        match self.kind {
            Kind::Cruise { speed }
            | Kind::Approach { speed, .. }
            | Kind::LaneChange { speed, .. }
            | Kind::Bend { speed, .. }
            | Kind::Road { speed, .. } => speed,
            _ => 0.0,
        }
    }

    /// The vehicle's yaw rate at `frame`, rad/s (positive turning left): speed times the
    /// road's curvature on a bend or where the vehicle is on a road of changing curvature, the
    /// S-curve of the lane change, 0 otherwise. Held over the frame, as the vehicle's motion
    /// message reports it.
    pub fn yaw_rate_at(&self, frame: u32) -> f64 {
        match self.kind {
            Kind::LaneChange {
                speed,
                lateral,
                from,
                duration,
            } if frame < self.frames => {
                let t = (f64::from(frame) / FPS - from) / duration;
                if (0.0..1.0).contains(&t) {
                    let peak = std::f64::consts::TAU * lateral / (speed * duration * duration);
                    peak * (std::f64::consts::TAU * t).sin()
                } else {
                    0.0
                }
            }
            Kind::Bend {
                speed, curvature, ..
            } if frame < self.frames => speed * curvature,
            Kind::Road {
                speed, geometry, ..
            } if frame < self.frames => {
                speed * geometry.road().curvature(speed * (f64::from(frame) / FPS))
            }
            _ => 0.0,
        }
    }

    /// First frame whose scene has an obstacle in the vehicle's lane
    /// ([`Scene::obstacle_in_lane`]): the start of a reaction-time measurement.
    pub fn first_obstacle_frame(&self) -> Option<u32> {
        (0..self.frames).find(|&f| self.scene_at(f).obstacle_in_lane())
    }
}

#[cfg(test)]
mod tests;
