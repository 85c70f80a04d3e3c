//! What stands in the world: obstacles (boxes, cylinders, bent boxes along a bend, boxes laid
//! along a road of changing curvature), their materials and patterns, and the ray
//! intersections the renderer traces them with.

use super::shading::finish;
use super::{NOMINAL_EYE, Ray, T_MIN, bend, footprint, norm, profile, sub};

/// How a surface is textured. Coordinates are object-local (see [`Obstacle`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    /// Band-limited fractal noise: `cell` is the coarsest feature size (metres), `contrast` the
    /// relative brightness swing (0 = flat colour, ~1 = strong).
    Noise { cell: f64, contrast: f64 },
    /// A pedestrian: shoes, jeans, belt, plaid shirt in the material colour, neck, face and hair
    /// (plaid, not horizontal stripes, so the texture constrains horizontal disparity).
    Clothes,
    /// A car body in the material colour with dirt, bumper, number plate, tail lights, windows
    /// and wheels.
    Car,
    /// Brickwork in the material colour, running bond.
    Bricks,
    /// A building facade in the material colour with a grid of windows.
    Facade,
    /// A delineator post in the material colour with a dark band below its top.
    Post,
}

/// Surface colour and pattern. `seed` varies the noise between otherwise equal objects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    pub colour: [u8; 3],
    pub pattern: Pattern,
    pub seed: u64,
}

impl Material {
    /// A car's paint, rear window and lights ([`Obstacle::car`]).
    pub const CAR: Self = Self {
        colour: [45, 85, 150],
        pattern: Pattern::Car,
        seed: 0xCA2,
    };
}

/// An object standing on the road.
///
/// Texture coordinates are object-local: for a box face, `s` runs horizontally across the face
/// from its centre and `h` is the height above the box bottom (top faces: `s` across x, `h`
/// along z); for a cylinder, `s` is the arc length around the axis from the point facing the
/// vehicle (-z) and `h` the height above the road. Moving an obstacle moves its texture with it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Obstacle {
    /// Axis-aligned box between corners `min` and `max` (vehicle frame).
    Box {
        min: [f64; 3],
        max: [f64; 3],
        material: Material,
    },
    /// Vertical cylinder standing on the road: axis at (`x`, `z`), from y = 0 to `height`.
    Cylinder {
        x: f64,
        z: f64,
        radius: f64,
        height: f64,
        material: Material,
    },
    /// A box laid along a road of `curvature` ([`bend`]): `min..max` are road coordinates
    /// (offset from the centre line, height, length along it), the faces and texture
    /// coordinates a [`Obstacle::Box`] spanning them has on a straight road (a wall along a
    /// bend, a car parked on it). Frame: the road's, from where the bend starts.
    Bent {
        curvature: f64,
        min: [f64; 3],
        max: [f64; 3],
        material: Material,
    },
    /// A box laid along a [`profile::Road`] as [`Obstacle::Bent`] is along a bend (road
    /// coordinates `min..max`, the road's frame), drawn only between `part[0]` and `part[1]`
    /// along: a long box is cut into pieces the renderer culls apart
    /// ([`profile::Road::lay`]); texture coordinates and end faces are the whole box's.
    Laid {
        road: &'static profile::Road,
        min: [f64; 3],
        max: [f64; 3],
        part: [f64; 2],
        material: Material,
    },
}

/// Which surface of an obstacle a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Face {
    NegX,
    PosX,
    /// Box face on the top (+y) or bottom (-y).
    Horizontal,
    /// Box face facing the vehicle (normal -z): a car's rear as seen from behind.
    NegZ,
    PosZ,
    /// Cylinder mantle.
    Round,
    /// Cylinder top.
    Cap,
}

/// A ray-surface intersection with texture coordinates.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    pub t: f64,
    pub point: [f64; 3],
    pub normal: [f64; 3],
    pub face: Face,
    /// Horizontal texture coordinate, metres, 0 at the face's centre (see [`Obstacle`]).
    pub s: f64,
    /// Vertical texture coordinate, metres above the object's bottom.
    pub h: f64,
}

/// One rendered sample: colour (before any sensor effect), ground-truth z and ray distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sample {
    pub rgb: [u8; 3],
    pub depth: f32,
    pub t: f64,
}

impl Obstacle {
    /// A pedestrian standing with its body axis at (`x`, `z`): a cylinder of radius 0.25 m and
    /// height 1.75 m in a strongly contrasted plaid shirt. Its nearest surface is at `z - 0.25`.
    pub fn pedestrian(x: f64, z: f64) -> Self {
        Obstacle::Cylinder {
            x,
            z,
            radius: 0.25,
            height: 1.75,
            material: Material {
                colour: [190, 45, 40],
                pattern: Pattern::Clothes,
                seed: 0x9ED0,
            },
        }
    }

    /// A car in the lane ahead, centred on `x`, its rear (the face we see) at distance `z`:
    /// 1.8 m wide, 1.5 m high, 4.2 m long.
    pub fn car(x: f64, z: f64) -> Self {
        Obstacle::Box {
            min: [x - 0.9, 0.0, z],
            max: [x + 0.9, 1.5, z + 4.2],
            material: Material::CAR,
        }
    }

    /// Whether the geometry is usable (finite, non-degenerate). Invalid obstacles are never hit,
    /// so a bad scene renders without them instead of failing or panicking.
    pub fn is_valid(&self) -> bool {
        match *self {
            Obstacle::Box { min, max, .. } => {
                (0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] < max[a])
            }
            Obstacle::Cylinder {
                x,
                z,
                radius,
                height,
                ..
            } => {
                x.is_finite()
                    && z.is_finite()
                    && radius.is_finite()
                    && height.is_finite()
                    && radius > 0.0
                    && height > 0.0
            }
            Obstacle::Bent {
                curvature,
                min,
                max,
                ..
            } => bend::is_valid(curvature, min, max),
            Obstacle::Laid {
                road,
                min,
                max,
                part,
                ..
            } => profile::is_valid(road, min, max, part),
        }
    }

    /// Moves the obstacle by `dz` metres along z (its texture with it).
    pub fn shift_z(&mut self, dz: f64) {
        match self {
            Obstacle::Box { min, max, .. } => {
                min[2] += dz;
                max[2] += dz;
            }
            Obstacle::Cylinder { z, .. } => *z += dz,
            Obstacle::Bent { min, max, .. } => {
                min[2] += dz;
                max[2] += dz;
            }
            Obstacle::Laid { min, max, part, .. } => {
                min[2] += dz;
                max[2] += dz;
                part[0] += dz;
                part[1] += dz;
            }
        }
    }

    /// Footprint on the road: (x_min, x_max, z_min, z_max).
    pub fn footprint(&self) -> (f64, f64, f64, f64) {
        match *self {
            Obstacle::Box { min, max, .. } => (min[0], max[0], min[2], max[2]),
            Obstacle::Cylinder { x, z, radius, .. } => {
                (x - radius, x + radius, z - radius, z + radius)
            }
            Obstacle::Bent {
                curvature,
                min,
                max,
                ..
            } => {
                let (_, (lo, hi)) = bend::bounds(curvature, min, max);
                (lo[0], hi[0], lo[2], hi[2])
            }
            Obstacle::Laid {
                road,
                min,
                max,
                part,
                ..
            } => {
                let (_, (lo, hi)) = profile::bounds(road, min, max, part);
                (lo[0], hi[0], lo[2], hi[2])
            }
        }
    }

    pub fn material(&self) -> &Material {
        match self {
            Obstacle::Box { material, .. }
            | Obstacle::Cylinder { material, .. }
            | Obstacle::Bent { material, .. }
            | Obstacle::Laid { material, .. } => material,
        }
    }

    /// Centre and radius of a sphere enclosing the obstacle (for culling), None if invalid.
    pub(crate) fn bounding_sphere(&self) -> Option<([f64; 3], f64)> {
        if !self.is_valid() {
            return None;
        }
        Some(match *self {
            Obstacle::Box { min, max, .. } => {
                let c = [
                    0.5 * (min[0] + max[0]),
                    0.5 * (min[1] + max[1]),
                    0.5 * (min[2] + max[2]),
                ];
                (c, 0.5 * norm(sub(max, min)))
            }
            Obstacle::Cylinder {
                x,
                z,
                radius,
                height,
                ..
            } => (
                [x, 0.5 * height, z],
                (radius * radius + 0.25 * height * height).sqrt(),
            ),
            Obstacle::Bent {
                curvature,
                min,
                max,
                ..
            } => bend::bounds(curvature, min, max).0,
            Obstacle::Laid {
                road,
                min,
                max,
                part,
                ..
            } => profile::bounds(road, min, max, part).0,
        })
    }

    /// Axis-aligned bounding box (min, max corners), None if invalid.
    pub(crate) fn aabb(&self) -> Option<([f64; 3], [f64; 3])> {
        if !self.is_valid() {
            return None;
        }
        Some(match *self {
            Obstacle::Box { min, max, .. } => (min, max),
            Obstacle::Cylinder {
                x,
                z,
                radius,
                height,
                ..
            } => (
                [x - radius, 0.0, z - radius],
                [x + radius, height, z + radius],
            ),
            Obstacle::Bent {
                curvature,
                min,
                max,
                ..
            } => bend::bounds(curvature, min, max).1,
            Obstacle::Laid {
                road,
                min,
                max,
                part,
                ..
            } => profile::bounds(road, min, max, part).1,
        })
    }

    /// Nearest intersection in front of the ray's origin. Rays starting inside the object see
    /// nothing of it (cameras are never inside obstacles).
    pub(crate) fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !self.is_valid() {
            return None;
        }
        self.intersect_valid(ray)
    }

    /// [`Obstacle::intersect`] for an obstacle already known to be valid (hot loops check once
    /// per obstacle, not once per pixel).
    #[inline]
    pub(crate) fn intersect_valid(&self, ray: &Ray) -> Option<Hit> {
        self.intersect_before(ray, f64::INFINITY)
    }

    /// [`Obstacle::intersect_valid`] if its hit is nearer than `before`, else none: what a ray
    /// that already meets something at `before` needs, and cheaper (a bent or laid box does not
    /// locate the candidates beyond it).
    #[inline]
    pub(crate) fn intersect_before(&self, ray: &Ray, before: f64) -> Option<Hit> {
        self.intersect_prepared(ray, before, None)
    }

    /// [`Obstacle::intersect_before`], with what the renderer computed once a frame for it
    /// (a bent box's end planes, a laid box's cell boxes; [`super::Prepared`]).
    #[inline]
    pub(crate) fn intersect_prepared(
        &self,
        ray: &Ray,
        before: f64,
        prepared: Option<&super::Prepared>,
    ) -> Option<Hit> {
        let planes = prepared.and_then(|p| p.planes.as_ref());
        let cells = prepared.map_or(&[][..], |p| p.cells);
        match *self {
            Obstacle::Box { min, max, .. } => intersect_box(ray, min, max).filter(|h| h.t < before),
            Obstacle::Cylinder {
                x,
                z,
                radius,
                height,
                ..
            } => intersect_cylinder(ray, x, z, radius, height).filter(|h| h.t < before),
            Obstacle::Bent {
                curvature,
                min,
                max,
                ..
            } => bend::intersect(ray, curvature, min, max, before, planes),
            Obstacle::Laid {
                road,
                min,
                max,
                part,
                ..
            } => profile::intersect(ray, road, min, max, part, before, cells),
        }
    }

    /// The colour sample of a hit on this obstacle.
    pub(crate) fn shade(&self, ray: &Ray, hit: &Hit) -> Sample {
        self.shade_from(ray, hit, NOMINAL_EYE)
    }

    /// [`Obstacle::shade`], its texture prefiltered and hazed for a viewpoint at `eye` (the
    /// nominal eye in the frame the ray is in).
    pub(super) fn shade_from(&self, ray: &Ray, hit: &Hit, eye: [f64; 3]) -> Sample {
        let (_, along, dist) = footprint(hit.point, hit.normal, eye);
        let albedo = self.material().albedo(hit, along);
        finish(albedo, hit.normal, dist, ray.at(hit.t)[2], hit.t)
    }
}

fn intersect_box(ray: &Ray, min: [f64; 3], max: [f64; 3]) -> Option<Hit> {
    let (o, d) = (ray.origin, ray.dir);
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis = 0;
    let mut entered_min_face = true;
    for a in 0..3 {
        if d[a] == 0.0 {
            // Parallel to this slab: inside it for every t, or never.
            if o[a] < min[a] || o[a] > max[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let (t0, t1) = ((min[a] - o[a]) * inv, (max[a] - o[a]) * inv);
        let (lo, hi, via_min) = if t0 <= t1 {
            (t0, t1, true)
        } else {
            (t1, t0, false)
        };
        if lo > t_near {
            t_near = lo;
            axis = a;
            entered_min_face = via_min;
        }
        t_far = t_far.min(hi);
    }
    // Written so that NaN (from degenerate input) means "no hit".
    let hits = t_near <= t_far && t_near > T_MIN;
    if !hits {
        return None;
    }
    let p = ray.at(t_near);
    let sign = if entered_min_face { -1.0 } else { 1.0 };
    let mut normal = [0.0; 3];
    normal[axis] = sign;
    let q = sub(p, min);
    let size = sub(max, min);
    let (face, s, h) = match (axis, entered_min_face) {
        (0, true) => (Face::NegX, q[2] - 0.5 * size[2], q[1]),
        (0, false) => (Face::PosX, q[2] - 0.5 * size[2], q[1]),
        (1, _) => (Face::Horizontal, q[0] - 0.5 * size[0], q[2]),
        (_, true) => (Face::NegZ, q[0] - 0.5 * size[0], q[1]),
        (_, false) => (Face::PosZ, q[0] - 0.5 * size[0], q[1]),
    };
    Some(Hit {
        t: t_near,
        point: p,
        normal,
        face,
        s,
        h,
    })
}

fn intersect_cylinder(ray: &Ray, cx: f64, cz: f64, r: f64, height: f64) -> Option<Hit> {
    let (o, d) = (ray.origin, ray.dir);
    let (ox, oz) = (o[0] - cx, o[2] - cz);
    let mut best: Option<Hit> = None;
    let a = d[0] * d[0] + d[2] * d[2];
    if a > 1e-18 {
        let half_b = ox * d[0] + oz * d[2];
        let c = ox * ox + oz * oz - r * r;
        let disc = half_b * half_b - a * c;
        // c > 0: the origin is outside the mantle, so the smaller root is the entry point.
        if disc >= 0.0 && c > 0.0 {
            let t = (-half_b - disc.sqrt()) / a;
            let y = o[1] + t * d[1];
            if t > T_MIN && (0.0..=height).contains(&y) {
                let p = ray.at(t);
                let (nx, nz) = ((p[0] - cx) / r, (p[2] - cz) / r);
                best = Some(Hit {
                    t,
                    point: p,
                    normal: [nx, 0.0, nz],
                    face: Face::Round,
                    // Angle 0 faces the vehicle (-z); arc length keeps texture scale in metres.
                    s: r * nx.atan2(-nz),
                    h: y,
                });
            }
        }
    }
    if d[1] < 0.0 && o[1] > height {
        let t = (height - o[1]) / d[1];
        let p = ray.at(t);
        let (px, pz) = (p[0] - cx, p[2] - cz);
        if t > T_MIN && px * px + pz * pz <= r * r && best.is_none_or(|b| t < b.t) {
            best = Some(Hit {
                t,
                point: p,
                normal: [0.0, 1.0, 0.0],
                face: Face::Cap,
                s: px,
                h: pz,
            });
        }
    }
    best
}
