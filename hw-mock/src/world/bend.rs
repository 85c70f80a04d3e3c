//! A road of constant curvature: its centre line is the arc of curvature `k` (1/m, positive
//! bending left) from the road frame's origin, tangent to +z. Road coordinates of a point are
//! `(along, offset)`: the arc length to where it is abreast and its signed distance from the
//! centre line (positive right), as flyd's predicted path measures them. A straight road's
//! `(along, offset)` is `(z, x)`.
//!
//! [`bent`] lays the straight roadside along the bend: a box spanning `x` and `z` becomes a
//! [`Obstacle::Bent`] spanning the same offsets and lengths along the arc (a wall follows the
//! bend), a pole or a trunk stands at the same road coordinates.

use super::{Face, Hit, Material, Obstacle, Pattern, Ray, T_MIN};

/// Tolerance of the inside test of a hit on a bent box's surface, metres.
const ON_SURFACE: f64 = 1e-7;

/// Road coordinates `(along, offset)` of the road-frame point `(x, z)` on a road of curvature
/// `k`. `along` is within +-pi / |k| (half the circle either way).
pub fn locate(k: f64, x: f64, z: f64) -> (f64, f64) {
    if k == 0.0 {
        return (z, x);
    }
    (locate_along(k, x, z), locate_offset(k, x, z))
}

/// The along of [`locate`] alone (bit for bit).
#[inline]
fn locate_along(k: f64, x: f64, z: f64) -> f64 {
    if k == 0.0 {
        return z;
    }
    (k.abs() * z).atan2(1.0 + k * x) / k.abs()
}

/// The offset of [`locate`] alone (bit for bit), without its arc tangent.
#[inline]
pub(super) fn locate_offset(k: f64, x: f64, z: f64) -> f64 {
    if k == 0.0 {
        return x;
    }
    // The distance to the circle's centre (-1/k, 0) minus its radius, rationalised so that
    // it holds for either sign of k and for a centre line far away.
    (2.0 * x + k * (x * x + z * z)) / (1.0 + (1.0 + k * x).hypot(k * z))
}

/// The road-frame `(x, z)` of road coordinates `(along, offset)` (the inverse of [`locate`]).
pub fn point(k: f64, along: f64, offset: f64) -> (f64, f64) {
    if k == 0.0 {
        return (offset, along);
    }
    let (sin, cos) = (k * along).sin_cos();
    // The centre line turns left (towards -x) for k > 0; right of it is (cos, sin).
    (-(1.0 - cos) / k + offset * cos, sin / k + offset * sin)
}

/// The centre line's direction `along` metres on, radians turned left from +z.
pub fn heading(k: f64, along: f64) -> f64 {
    k * along
}

/// Whether a bent box is one: finite, non-degenerate, not reaching the bend's centre, and
/// shorter than half the circle either way from the origin (where [`locate`] is single-valued).
pub(super) fn is_valid(k: f64, min: [f64; 3], max: [f64; 3]) -> bool {
    let finite = k.is_finite() && (0..3).all(|a| min[a].is_finite() && max[a].is_finite());
    if !finite || (0..3).any(|a| min[a] >= max[a]) {
        return false;
    }
    if k == 0.0 {
        return true;
    }
    let half_circle = std::f64::consts::PI / k.abs();
    (1.0 + k * min[0]) > 0.0
        && (1.0 + k * max[0]) > 0.0
        && min[2] > -half_circle
        && max[2] < half_circle
}

/// A sphere (centre, radius) enclosing something.
pub(crate) type Sphere = ([f64; 3], f64);
/// An axis-aligned box (low and high corners).
pub(crate) type Aabb = ([f64; 3], [f64; 3]);

/// A sphere and a road-frame box enclosing a valid bent box: the middle of the box, and as
/// far as the longest arc of it plus its width and height.
pub(crate) fn bounds(k: f64, min: [f64; 3], max: [f64; 3]) -> (Sphere, Aabb) {
    let mid = |a: usize| 0.5 * (min[a] + max[a]);
    let (x, z) = point(k, mid(2), mid(0));
    let centre = [x, mid(1), z];
    // The arc at the outer edge is (1 + |k| offset) times the centre line's.
    let stretch = 1.0 + k.abs() * min[0].abs().max(max[0].abs());
    let radius =
        0.5 * (max[2] - min[2]) * stretch + 0.5 * (max[0] - min[0]) + 0.5 * (max[1] - min[1]);
    let lo = [x - radius, min[1], z - radius];
    let hi = [x + radius, max[1], z + radius];
    ((centre, radius), (lo, hi))
}

/// The nearest hit in front of the ray on the bent box `min..max` (road coordinates: offset,
/// height, along) of a road of curvature `k`: the faces and texture coordinates a box has
/// ([`Obstacle`]), laid along the bend. Assumes [`is_valid`].
pub(super) fn intersect(
    ray: &Ray,
    k: f64,
    min: [f64; 3],
    max: [f64; 3],
    before: f64,
    planes: Option<&[EndPlane; 2]>,
) -> Option<Hit> {
    let whole = [min[2], max[2]];
    intersect_part(ray, k, min, max, (whole, [true, true]), before, planes)
}

/// The plane of a bent box's end `along` metres on: through the centre line's point there,
/// normal to its direction (road frame, x and z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct EndPlane {
    point: (f64, f64),
    normal: (f64, f64),
}

/// The [`EndPlane`] `along` metres down a road of curvature `k`.
pub(crate) fn end_plane(k: f64, along: f64) -> EndPlane {
    let point = point(k, along, 0.0);
    let (sin, cos) = heading(k, along).sin_cos();
    EndPlane {
        point,
        normal: (-sin, cos),
    }
}

/// [`intersect`] restricted to the part of the box between `part[0]` and `part[1]` along (within
/// `min[2]..max[2]`): what one piece of a longer box draws ([`super::profile`]). Its end faces
/// (at `min[2]`, `max[2]`) are there only where `ends` says so; texture coordinates are the whole
/// box's.
///
/// Only hits nearer than `before` are looked for (a ray that meets something else first need
/// not locate the candidates beyond it): the nearest hit if it is nearer, else none. `planes`,
/// if given, are [`end_plane`] of `min[2]` and `max[2]`, computed once for many rays.
pub(super) fn intersect_part(
    ray: &Ray,
    k: f64,
    min: [f64; 3],
    max: [f64; 3],
    (part, ends): ([f64; 2], [bool; 2]),
    before: f64,
    planes: Option<&[EndPlane; 2]>,
) -> Option<Hit> {
    let (o, d) = (ray.origin, ray.dir);
    // Candidate surfaces: 0/1 the mantles at offsets min/max, 2/3 the planes at heights
    // min/max, 4/5 the radial planes at min/max along. At most two roots a mantle.
    let mut candidates = [(f64::INFINITY, 0usize); 8];
    let mut n = 0;
    let mut push = |t: f64, face: usize| {
        if t.is_finite() && t > T_MIN && t < before {
            candidates[n] = (t, face);
            n += 1;
        }
    };
    let (cx, cz) = (-1.0 / k, 0.0);
    for (face, offset) in [(0, min[0]), (1, max[0])] {
        if k == 0.0 {
            if d[0] != 0.0 {
                push((offset - o[0]) / d[0], face);
            }
            continue;
        }
        let r = 1.0 / k + offset; // signed radius: |r| is the mantle's
        let (ox, oz) = (o[0] - cx, o[2] - cz);
        let a = d[0] * d[0] + d[2] * d[2];
        if a < 1e-18 {
            continue;
        }
        let half_b = ox * d[0] + oz * d[2];
        let c = ox * ox + oz * oz - r * r;
        let disc = half_b * half_b - a * c;
        if disc >= 0.0 {
            let root = disc.sqrt();
            push((-half_b - root) / a, face);
            push((-half_b + root) / a, face);
        }
    }
    for (face, y) in [(2, min[1]), (3, max[1])] {
        if d[1] != 0.0 {
            push((y - o[1]) / d[1], face);
        }
    }
    for (face, along) in [(4, min[2]), (5, max[2])] {
        if !ends[face - 4] {
            continue;
        }
        let EndPlane {
            point: (px, pz),
            normal: (nx, nz),
        } = planes.map_or_else(|| end_plane(k, along), |p| p[face - 4]);
        let den = nx * d[0] + nz * d[2];
        if den != 0.0 {
            push((nx * (px - o[0]) + nz * (pz - o[2])) / den, face);
        }
    }
    let candidates = &mut candidates[..n];
    // Stable: ties go to the surface pushed first, whichever candidates `before` left out.
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mid = |a: usize| 0.5 * (min[a] + max[a]);
    candidates.iter().find_map(|&(t, face)| {
        let p = ray.at(t);
        let within = |v: f64, a: usize| v >= min[a] - ON_SURFACE && v <= max[a] + ON_SURFACE;
        // Cheapest test first: the height needs no locating, the offset no arc tangent.
        if !within(p[1], 1) {
            return None;
        }
        let offset = locate_offset(k, p[0], p[2]);
        if !within(offset, 0) {
            return None;
        }
        let along = locate_along(k, p[0], p[2]);
        let in_part = along >= part[0] - ON_SURFACE && along <= part[1] + ON_SURFACE;
        if !in_part {
            return None;
        }
        let (sin, cos) = heading(k, along).sin_cos();
        let (right, ahead) = ([cos, 0.0, sin], [-sin, 0.0, cos]);
        let neg = |v: [f64; 3]| [-v[0], -v[1], -v[2]];
        let (face, normal, s, h) = match face {
            0 => (Face::NegX, neg(right), along - mid(2), p[1] - min[1]),
            1 => (Face::PosX, right, along - mid(2), p[1] - min[1]),
            2 => (
                Face::Horizontal,
                [0.0, -1.0, 0.0],
                offset - mid(0),
                along - min[2],
            ),
            3 => (
                Face::Horizontal,
                [0.0, 1.0, 0.0],
                offset - mid(0),
                along - min[2],
            ),
            4 => (Face::NegZ, neg(ahead), offset - mid(0), p[1] - min[1]),
            _ => (Face::PosZ, ahead, offset - mid(0), p[1] - min[1]),
        };
        Some(Hit {
            t,
            point: p,
            normal,
            face,
            s,
            h,
        })
    })
}

/// `props` (a straight road's, [`super::roadside`]) laid along a road of curvature `k`, with a
/// guard rail on the outside of the bend (0.8 m high, 5.45-5.6 m from the centre line, just
/// beyond the kerb).
pub fn bent(k: f64, props: &[Obstacle]) -> Vec<Obstacle> {
    let mut v: Vec<Obstacle> = props
        .iter()
        .map(|o| match *o {
            Obstacle::Box { min, max, material } => Obstacle::Bent {
                curvature: k,
                min,
                max,
                material,
            },
            Obstacle::Cylinder {
                x,
                z,
                radius,
                height,
                material,
            } => {
                let (x, z) = point(k, z, x);
                Obstacle::Cylinder {
                    x,
                    z,
                    radius,
                    height,
                    material,
                }
            }
            laid @ (Obstacle::Bent { .. } | Obstacle::Laid { .. }) => laid,
        })
        .collect();
    let outside: f64 = if k >= 0.0 { 1.0 } else { -1.0 };
    let (inner, outer) = (5.45 * outside, 5.6 * outside);
    v.push(Obstacle::Bent {
        curvature: k,
        min: [inner.min(outer), 0.0, -5.0],
        max: [inner.max(outer), 0.8, 140.0],
        material: Material {
            colour: [165, 168, 172],
            pattern: Pattern::Noise {
                cell: 0.08,
                contrast: 0.45,
            },
            seed: 0x6A2D,
        },
    });
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn road_coordinates_round_trip_either_way() {
        for k in [0.0, 1.0 / 60.0, -1.0 / 120.0] {
            for (along, offset) in [(0.0, 0.0), (12.0, 1.5), (45.0, -5.5), (80.0, 7.0)] {
                let (x, z) = point(k, along, offset);
                let (a, o) = locate(k, x, z);
                assert!(
                    (a - along).abs() < 1e-9 && (o - offset).abs() < 1e-9,
                    "k {k}: ({along}, {offset}) -> ({x}, {z}) -> ({a}, {o})"
                );
            }
        }
        // A left bend turns towards -x.
        let (x, z) = point(0.01, 20.0, 0.0);
        assert!(x < -1.9 && (z - 19.87).abs() < 0.01, "{x} {z}");
    }

    #[test]
    fn a_straight_bent_box_is_the_box() {
        let (min, max) = ([-0.9, 0.0, 10.0], [0.9, 1.5, 14.2]);
        let material = Material::CAR;
        let boxed = Obstacle::Box { min, max, material };
        let bent = Obstacle::Bent {
            curvature: 0.0,
            min,
            max,
            material,
        };
        for (o, d) in [
            ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.3, 1.3, 0.0], [0.05, -0.02, 1.0]),
            ([-3.0, 1.3, 12.0], [1.0, 0.0, 0.1]),
            ([0.0, 3.0, 12.0], [0.0, -1.0, 0.05]),
        ] {
            let r = Ray::towards(o, d);
            let (a, b) = (boxed.intersect(&r), bent.intersect(&r));
            let (a, b) = (a.expect("hits the box"), b.expect("hits the bent box"));
            assert!((a.t - b.t).abs() < 1e-9, "{a:?} vs {b:?}");
            assert_eq!(a.face, b.face);
            assert!((a.s - b.s).abs() < 1e-9 && (a.h - b.h).abs() < 1e-9);
            for i in 0..3 {
                assert!((a.normal[i] - b.normal[i]).abs() < 1e-12, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn the_guard_rail_follows_the_bend() {
        // A 60 m left bend: looking straight ahead from the centre line, the outside guard
        // rail (right) is met where the line of sight leaves the circle of radius R + 5.45
        // round the centre (-R, 0): sqrt((R + 5.45)^2 - R^2) = 26.15 m on.
        let k = 1.0 / 60.0;
        let props = bent(k, &[]);
        let rail = props[0];
        let hit = rail
            .intersect(&Ray::towards([0.0, 0.4, 0.0], [0.0, 0.0, 1.0]))
            .expect("the guard rail is straight ahead");
        let (along, offset) = locate(k, hit.point[0], hit.point[2]);
        assert!((offset - 5.45).abs() < 1e-6, "{offset}");
        assert!((hit.t - 26.15).abs() < 0.01, "{}", hit.t);
        assert!((along - 24.66).abs() < 0.05, "{along}");
        assert_eq!(hit.face, Face::NegX);
        // Looking along the bend's chord 20 m on, the road is clear up to there; a ray above
        // the rail misses it.
        let (x, z) = point(k, 20.0, 0.0);
        let on = rail.intersect(&Ray::towards([0.0, 0.4, 0.0], [x, 0.0, z]));
        assert!(on.is_none_or(|h| h.t > 21.0), "{on:?}");
        assert!(
            rail.intersect(&Ray::towards([0.0, 1.3, 0.0], [0.0, 0.0, 1.0]))
                .is_none()
        );
    }
}
