//! The synthetic world: road, roadside, sky and obstacles, with ray intersection and shading.
//!
//! Everything is in the vehicle frame (metres; x right, y up from the road surface, z forward).
//! Every surface's colour is a pure function of the surface point (world position for the road
//! and sky, object-local coordinates for obstacles) and never of the camera that looks at it, so
//! two cameras see the same texture at the same world point: the property a stereo matcher
//! relies on. The only view-dependent effect, texture prefiltering against aliasing, is computed
//! for a fixed nominal viewpoint ([`NOMINAL_EYE`], [`NOMINAL_FOCAL_PX`]) for the same reason.

/// Half the width of the vehicle's lane: lane marks are centred on x = +-1.75 m.
pub const LANE_HALF_WIDTH: f64 = 1.75;
/// The asphalt ends (and the kerb starts) at |x| = 5 m.
pub const ROAD_HALF_WIDTH: f64 = 5.0;
/// Width of the kerb band beyond the asphalt, metres.
pub const KERB_WIDTH: f64 = 0.25;
/// Obstacles farther than this (z, metres) do not count as "in the lane" for
/// [`Scene::obstacle_in_lane`]: beyond it they are not yet a hazard a test should time.
pub const IN_LANE_MAX_RANGE: f64 = 60.0;
/// Viewpoint for which textures are prefiltered: the simulated rig's centre.
pub const NOMINAL_EYE: [f64; 3] = [0.0, 1.3, 0.0];
/// Focal length (pixels) for which textures are prefiltered: the 640x480 simulated rig's.
pub const NOMINAL_FOCAL_PX: f64 = 520.0;

/// Hits closer than this along a ray are ignored (no self-intersection at the origin).
const T_MIN: f64 = 1e-6;
/// Extinction distance of the aerial haze, metres: distant surfaces fade into the horizon colour
/// so the far road meets the sky without a hard, aliased seam.
const HAZE_DISTANCE: f64 = 400.0;
const SKY_HORIZON: [f64; 3] = [200.0, 208.0, 218.0];

// ---------------------------------------------------------------------------------------------
// Small vector helpers: plain arrays keep the hot loops free of abstraction overhead.

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
#[inline]
fn lerp3(a: [f64; 3], b: [f64; 3], w: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * w,
        a[1] + (b[1] - a[1]) * w,
        a[2] + (b[2] - a[2]) * w,
    ]
}
#[inline]
fn scale3(a: [f64; 3], k: f64) -> [f64; 3] {
    [a[0] * k, a[1] * k, a[2] * k]
}
#[inline]
fn rgb(c: [u8; 3]) -> [f64; 3] {
    [f64::from(c[0]), f64::from(c[1]), f64::from(c[2])]
}

/// A ray in the vehicle frame: origin and unit direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
}

impl Ray {
    /// A ray from `origin` along `direction` (of any length).
    #[cfg(test)]
    pub(crate) fn towards(origin: [f64; 3], direction: [f64; 3]) -> Ray {
        let n = norm(direction);
        let d = direction;
        Ray {
            origin,
            dir: [d[0] / n, d[1] / n, d[2] / n],
        }
    }

    #[inline]
    pub fn at(&self, t: f64) -> [f64; 3] {
        [
            self.origin[0] + t * self.dir[0],
            self.origin[1] + t * self.dir[1],
            self.origin[2] + t * self.dir[2],
        ]
    }
}

mod obstacle;

pub(crate) use obstacle::{Face, Hit, Sample};
pub use obstacle::{Material, Obstacle, Pattern};

/// Pixel footprint on a surface seen from the nominal viewpoint: (across, along, distance).
/// `across` is one pixel's width at that distance; `along` is stretched by the viewing obliquity
/// (capped at 20x), the size to band-limit isotropic textures against.
pub(crate) fn footprint(p: [f64; 3], n: [f64; 3], eye: [f64; 3]) -> (f64, f64, f64) {
    let v = sub(eye, p);
    let d = norm(v).max(1e-3);
    let across = d / NOMINAL_FOCAL_PX;
    let cos = (dot(n, v) / d).abs().max(0.05);
    (across, across / cos, d)
}

pub mod bend;
mod cull;
mod ground;
pub mod profile;
mod shading;

pub(crate) use cull::{Aabb, Prepared, cull_bounds, may_meet, padded};

pub(crate) use ground::Still;
#[cfg(test)]
use ground::road_albedo;
use ground::{Ground, ground_or_sky, ground_t};

/// Colour, depth and distance seen along a ray: road or sky (the vehicle `travelled` metres
/// along the road), then the nearest of `props` and `obstacles` in that order (ties go to the
/// earlier one). The reference every renderer must reproduce exactly.
pub(crate) fn trace(
    ray: &Ray,
    props: &[Obstacle],
    obstacles: &[Obstacle],
    travelled: f64,
) -> Sample {
    trace_from(
        ray,
        props,
        obstacles,
        Ground::Straight { travelled },
        NOMINAL_EYE,
        false,
        None,
    )
}

/// [`trace`] for a viewpoint at `eye` (in the ray's frame).
///
/// The road is met (or not) first, its distance bounding the search of the props, and shaded
/// only if no prop is nearer: the same samples as shading it first, for less. `valid` says the
/// objects are known to be valid ([`Obstacle::is_valid`]; the renderer's culled lists are).
///
/// `prepared`, if given, holds each prop's [`Prepared`]: a bent or laid one (costly to
/// intersect) is tried only if the ray may meet its box first.
fn trace_from(
    ray: &Ray,
    props: &[Obstacle],
    obstacles: &[Obstacle],
    road: Ground,
    eye: [f64; 3],
    valid: bool,
    prepared: Option<&[Prepared]>,
) -> Sample {
    match nearest_prop(ray, props, obstacles, valid, prepared, ground_t(ray)) {
        Some((o, hit)) => o.shade_from(ray, &hit, eye),
        None => ground_or_sky(ray, road, eye),
    }
}

/// The nearest hit nearer than `nearest` on `props` and `obstacles` (ties to the earlier one),
/// as [`trace_from`] looks for it.
#[inline]
fn nearest_prop<'a>(
    ray: &Ray,
    props: &'a [Obstacle],
    obstacles: &'a [Obstacle],
    valid: bool,
    prepared: Option<&[Prepared]>,
    mut nearest: f64,
) -> Option<(&'a Obstacle, Hit)> {
    let mut best_hit: Option<(&Obstacle, Hit)> = None;
    for (i, o) in props.iter().chain(obstacles).enumerate() {
        if !valid && !o.is_valid() {
            continue;
        }
        let prep = prepared.and_then(|p| p.get(i));
        let costly = matches!(o, Obstacle::Bent { .. } | Obstacle::Laid { .. });
        if costly
            && let Some(p) = prep
            && (!may_meet(ray, &p.aabb, nearest)
                || !p.pieces.is_empty() && !p.pieces.iter().any(|b| may_meet(ray, b, nearest)))
        {
            continue;
        }
        if let Some(hit) = o.intersect_prepared(ray, nearest, prep) {
            nearest = hit.t;
            best_hit = Some((o, hit));
        }
    }
    best_hit
}

/// [`background_valid`] for a scene that is not posed ([`Scene::is_posed`]) through a pixel
/// whose [`Still`] is `still`: the same sample, the road's geometry and the sky not traced
/// again.
pub(crate) fn background_still(
    ray: &Ray,
    props: &[Obstacle],
    prepared: &[Prepared],
    still: &Still,
    travelled: f64,
) -> Sample {
    match nearest_prop(ray, props, &[], true, Some(prepared), still.t()) {
        Some((o, hit)) => o.shade_from(ray, &hit, NOMINAL_EYE),
        None => still.shade(travelled),
    }
}

/// The static world (road, sky and `props`, as [`Scene::props`] gives them) along the
/// vehicle-frame `ray` of `scene`. A vehicle turned or off the centre line sees it through the
/// ray in the road's frame ([`Scene::world_ray`]); the sample's depth is still the
/// vehicle-frame z of what it hit.
pub(crate) fn background(ray: &Ray, props: &[Obstacle], scene: &Scene) -> Sample {
    background_of(ray, props, &Frame::of(scene), false, None)
}

/// [`background`] of `props` known to be valid ([`Obstacle::is_valid`]), each with its
/// [`Prepared`] of the same index in `prepared`.
pub(crate) fn background_valid(
    ray: &Ray,
    props: &[Obstacle],
    prepared: &[Prepared],
    frame: &Frame,
) -> Sample {
    background_of(ray, props, frame, true, Some(prepared))
}

/// What [`background`] needs of a scene for every ray of a frame: computed once a frame by the
/// renderer, once a ray by the reference (the same numbers either way).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame<'a> {
    scene: &'a Scene,
    /// For a posed scene: the heading's sine and cosine, the nominal eye in the road's frame.
    posed: Option<((f64, f64), [f64; 3])>,
    road: Ground,
}

impl<'a> Frame<'a> {
    pub(crate) fn of(scene: &'a Scene) -> Self {
        if !scene.is_posed() {
            let road = Ground::Straight {
                travelled: scene.travelled,
            };
            return Self {
                scene,
                posed: None,
                road,
            };
        }
        let turn = scene.heading.sin_cos();
        let road = if let Some(road) = scene.road {
            Ground::Profile(road)
        } else if scene.bend == 0.0 {
            Ground::Straight { travelled: 0.0 }
        } else {
            Ground::Bend {
                curvature: scene.bend,
            }
        };
        let eye = scene.world_point_turned(NOMINAL_EYE, turn);
        Self {
            scene,
            posed: Some((turn, eye)),
            road,
        }
    }
}

fn background_of(
    ray: &Ray,
    props: &[Obstacle],
    frame: &Frame,
    valid: bool,
    prepared: Option<&[Prepared]>,
) -> Sample {
    let Some((turn, eye)) = frame.posed else {
        return trace_from(ray, props, &[], frame.road, NOMINAL_EYE, valid, prepared);
    };
    let world = frame.scene.world_ray_turned(ray, turn);
    let mut s = trace_from(&world, props, &[], frame.road, eye, valid, prepared);
    if s.t.is_finite() {
        s.depth = ray.at(s.t)[2] as f32;
    }
    s
}

/// Colour, depth and distance seen along vehicle-frame `ray` in `scene`: [`background`],
/// then the nearest of the scene's obstacles (vehicle frame; ties go to the static world).
pub(crate) fn trace_scene(ray: &Ray, props: &[Obstacle], scene: &Scene) -> Sample {
    if !scene.is_posed() {
        return trace(ray, props, &scene.obstacles, scene.travelled);
    }
    let mut best = background(ray, props, scene);
    for o in &scene.obstacles {
        if let Some(hit) = o.intersect(ray)
            && hit.t < best.t
        {
            best = o.shade(ray, &hit);
        }
    }
    best
}

/// The roadside as seen after the vehicle has driven `travelled` metres: [`roadside`] moved
/// towards it (textures are object-local, so they move along).
pub fn roadside_at(travelled: f64) -> Vec<Obstacle> {
    let mut v = roadside();
    if travelled != 0.0 {
        for o in &mut v {
            o.shift_z(-travelled);
        }
    }
    v
}

/// The static roadside every scene shares (vehicle frame, deterministic): brick walls on the
/// left at x in [-7.2, -7.0], lamp poles on both sides at |x| = 6.2, trees (trunk and canopy)
/// on the right at x = 7.5 and a building facade at x = 11. Gives flies textured surfaces to land
/// on in an empty road, as the roadsides in the paper's figure 4 do.
pub fn roadside() -> Vec<Obstacle> {
    let mut v = Vec::new();
    let pole = |x: f64, z: f64, seed: u64| Obstacle::Cylinder {
        x,
        z,
        radius: 0.09,
        height: 4.5,
        material: Material {
            colour: [125, 125, 130],
            pattern: Pattern::Noise {
                cell: 0.15,
                contrast: 0.35,
            },
            seed,
        },
    };
    // Brick wall segments with gaps (gateways), each in a slightly different brick colour.
    for k in 0..11u64 {
        let z0 = 6.0 + 8.5 * k as f64;
        let tint = (k % 3) as u8 * 12;
        v.push(Obstacle::Box {
            min: [-7.2, 0.0, z0],
            max: [-7.0, 2.2, z0 + 7.0],
            material: Material {
                colour: [150 + tint, 78 + tint / 2, 58],
                pattern: Pattern::Bricks,
                seed: 0xB1C0 + k,
            },
        });
    }
    for k in 0..7u64 {
        v.push(pole(-6.2, 10.0 + 15.0 * k as f64, 0x9011 + k));
        v.push(pole(6.2, 4.0 + 15.0 * k as f64, 0x9022 + k));
    }
    for k in 0..8u64 {
        let z = 8.0 + 12.0 * k as f64;
        v.push(Obstacle::Cylinder {
            x: 7.5,
            z,
            radius: 0.22,
            height: 2.6,
            material: Material {
                colour: [95, 75, 55],
                pattern: Pattern::Noise {
                    cell: 0.12,
                    contrast: 0.5,
                },
                seed: 0x7EE0 + k,
            },
        });
        v.push(Obstacle::Box {
            min: [6.3, 2.4, z - 1.3],
            max: [8.7, 4.8, z + 1.3],
            material: Material {
                colour: [55, 105, 45],
                pattern: Pattern::Noise {
                    cell: 0.35,
                    contrast: 0.7,
                },
                seed: 0xF01 + k,
            },
        });
    }
    v.push(Obstacle::Box {
        min: [11.0, 0.0, 4.0],
        max: [11.5, 9.5, 130.0],
        material: Material {
            colour: [195, 182, 160],
            pattern: Pattern::Facade,
            seed: 0xFACADE,
        },
    });
    v
}

/// The dynamic part of the world at one instant; the road, sky and [`roadside`] are implied.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    /// Obstacles, in the vehicle frame.
    pub obstacles: Vec<Obstacle>,
    /// Metres the vehicle has driven straight ahead since the start: the road and the roadside
    /// ([`roadside_at`]) come towards it. 0 for a stationary vehicle. With a turn, the
    /// vehicle's position along the road (road frame z).
    pub travelled: f64,
    /// The vehicle's position across the road, metres right of the centre line (road frame x).
    pub lateral: f64,
    /// The vehicle's heading, radians from the road's direction, positive turned left (as a
    /// positive yaw rate turns it).
    pub heading: f64,
    /// The road's curvature, 1/m, positive bending left ([`bend`]; 0: straight). On a bend,
    /// (`lateral`, `travelled`) and `heading` are the vehicle's pose in the road frame of
    /// where the bend starts ([`Scene::on_bend`]), and the roadside is laid along it.
    pub bend: f64,
    /// Obstacles fixed to the road (its frame, as the roadside): traced with the static world,
    /// e.g. a car parked on a bend ([`Obstacle::Bent`]) or stopped on a road of a profile
    /// ([`Obstacle::Laid`]).
    pub fixed: Vec<Obstacle>,
    /// A road of changing curvature ([`profile`]; `bend` is then 0): (`lateral`, `travelled`)
    /// and `heading` are the vehicle's pose in the road's frame ([`Scene::on_road`]), and the
    /// roadside, a guard rail and delineator posts are laid along it.
    pub road: Option<&'static profile::Road>,
}

impl Scene {
    pub fn empty() -> Self {
        Self::default()
    }

    pub fn with(obstacles: Vec<Obstacle>) -> Self {
        Self {
            obstacles,
            ..Self::default()
        }
    }

    /// The vehicle `travelled` metres down the road, with `obstacles` (vehicle frame).
    pub fn driving(travelled: f64, obstacles: Vec<Obstacle>) -> Self {
        Self {
            obstacles,
            travelled,
            ..Self::default()
        }
    }

    /// The vehicle at road-frame position (`lateral`, `travelled`), turned `heading` radians
    /// left, with `obstacles` (vehicle frame).
    pub fn posed(travelled: f64, lateral: f64, heading: f64, obstacles: Vec<Obstacle>) -> Self {
        Self {
            obstacles,
            travelled,
            lateral,
            heading,
            ..Self::default()
        }
    }

    /// The vehicle on a road of curvature `bend`, `along` metres down it and `offset` metres
    /// right of its centre line, heading along it; with `fixed` (road frame) and `obstacles`
    /// (vehicle frame).
    pub fn on_bend(
        bend: f64,
        along: f64,
        offset: f64,
        fixed: Vec<Obstacle>,
        obstacles: Vec<Obstacle>,
    ) -> Self {
        let (x, z) = bend::point(bend, along, offset);
        Self {
            obstacles,
            travelled: z,
            lateral: x,
            heading: bend::heading(bend, along),
            bend,
            fixed,
            road: None,
        }
    }

    /// The vehicle on `road`, `along` metres down it and `offset` metres right of its centre
    /// line, heading along it; with `fixed` (road frame) and `obstacles` (vehicle frame). A
    /// road of one constant segment is the bend of [`Scene::on_bend`] (the same scene).
    pub fn on_road(
        road: &'static profile::Road,
        along: f64,
        offset: f64,
        fixed: Vec<Obstacle>,
        obstacles: Vec<Obstacle>,
    ) -> Self {
        if let Some(k) = road.constant() {
            return Self::on_bend(k, along, offset, fixed, obstacles);
        }
        let (x, z) = road.point(along, offset);
        Self {
            obstacles,
            travelled: z,
            lateral: x,
            heading: road.heading(along),
            bend: 0.0,
            fixed,
            road: Some(road),
        }
    }

    /// Whether the vehicle is off the centre line or turned: the static world is then traced
    /// in the road's frame ([`Scene::world_ray`]); otherwise it comes towards the vehicle as
    /// [`roadside_at`] (bit for bit the renders of a straight drive).
    pub fn is_posed(&self) -> bool {
        self.heading != 0.0
            || self.lateral != 0.0
            || self.bend != 0.0
            || !self.fixed.is_empty()
            || self.road.is_some()
    }

    /// The roadside in the frame its rays are traced in: the road's for a posed vehicle, the
    /// vehicle's otherwise.
    pub fn props(&self) -> Vec<Obstacle> {
        if !self.is_posed() {
            return roadside_at(self.travelled);
        }
        let mut props = if let Some(road) = self.road {
            road.props()
        } else if self.bend == 0.0 {
            roadside()
        } else {
            bend::bent(self.bend, &roadside())
        };
        props.extend_from_slice(&self.fixed);
        props
    }

    /// A vehicle-frame point in the road's frame.
    pub fn world_point(&self, p: [f64; 3]) -> [f64; 3] {
        self.world_point_turned(p, self.heading.sin_cos())
    }

    /// [`Scene::world_point`] for the heading's sine and cosine `(s, c)`.
    #[inline]
    fn world_point_turned(&self, p: [f64; 3], (s, c): (f64, f64)) -> [f64; 3] {
        [
            self.lateral + p[0] * c - p[2] * s,
            p[1],
            self.travelled + p[0] * s + p[2] * c,
        ]
    }

    /// A road-frame point in the vehicle's frame (the inverse of [`Scene::world_point`]).
    pub fn vehicle_point(&self, w: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.heading.sin_cos();
        let (x, z) = (w[0] - self.lateral, w[2] - self.travelled);
        [x * c + z * s, w[1], z * c - x * s]
    }

    /// A vehicle-frame ray in the road's frame.
    pub fn world_ray(&self, r: &Ray) -> Ray {
        self.world_ray_turned(r, self.heading.sin_cos())
    }

    /// [`Scene::world_ray`] for the heading's sine and cosine `(s, c)`.
    #[inline]
    fn world_ray_turned(&self, r: &Ray, (s, c): (f64, f64)) -> Ray {
        let d = r.dir;
        Ray {
            origin: self.world_point_turned(r.origin, (s, c)),
            dir: [d[0] * c - d[2] * s, d[1], d[0] * s + d[2] * c],
        }
    }

    /// Whether any valid obstacle's footprint overlaps the vehicle's lane (|x| < 1.75 m) ahead
    /// of it (0 < z < [`IN_LANE_MAX_RANGE`]).
    pub fn obstacle_in_lane(&self) -> bool {
        self.obstacles.iter().any(|o| {
            let (x0, x1, z0, z1) = o.footprint();
            o.is_valid()
                && x0 < LANE_HALF_WIDTH
                && x1 > -LANE_HALF_WIDTH
                && z1 > 0.0
                && z0 < IN_LANE_MAX_RANGE
        })
    }
}

#[cfg(test)]
mod tests;
