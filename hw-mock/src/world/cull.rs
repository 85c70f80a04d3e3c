//! What lets a ray skip a costly prop: a padded box around it, tested before the prop, and
//! what the renderer computes once a frame for each prop instead of once a ray.

use super::{Obstacle, Ray, bend};

/// An axis-aligned box: low and high corners.
pub(crate) type Aabb = ([f64; 3], [f64; 3]);

/// `b` grown on every side by more than any rounding of a hit on what it encloses (hits are
/// accepted up to 1e-7 m off a surface): the bound [`may_meet`] tests against.
pub(crate) fn padded(b: Aabb) -> Aabb {
    let pad = |v: f64, k: f64| v + k * (1e-6 + 1e-9 * v.abs());
    (b.0.map(|v| pad(v, -1.0)), b.1.map(|v| pad(v, 1.0)))
}

/// Whether `ray` may meet something inside the (padded, [`padded`]) box `b` before distance
/// `before`: the slab test, conservative (a NaN bound never rules a ray out). False only if
/// every point of the ray up to `before` is outside the box.
#[inline]
pub(crate) fn may_meet(ray: &Ray, b: &Aabb, before: f64) -> bool {
    let (mut enter, mut exit) = (0.0f64, before);
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.dir[a]);
        if d == 0.0 {
            if o < b.0[a] || o > b.1[a] {
                return false;
            }
            continue;
        }
        let inv = 1.0 / d;
        let (t0, t1) = ((b.0[a] - o) * inv, (b.1[a] - o) * inv);
        let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
        enter = enter.max(t0);
        exit = exit.min(t1);
    }
    // Incomparable (NaN) keeps the ray.
    enter.partial_cmp(&exit) != Some(std::cmp::Ordering::Greater)
}

/// What the renderer computes once a frame for each prop of a tile, so that its rays need not:
/// a [`padded`] box enclosing it (in the frame it is traced in), a bent box's end planes, and
/// a laid box's cell boxes ([`super::profile::cell_boxes`]; empty for other kinds).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prepared<'a> {
    pub(crate) aabb: Aabb,
    pub(crate) planes: Option<[bend::EndPlane; 2]>,
    pub(crate) cells: &'a [Aabb],
    /// [`padded`] boxes of pieces of a long prop ([`cull_bounds`]): if any, a ray that meets
    /// none of them misses the prop.
    pub(crate) pieces: &'a [Aabb],
}

impl<'a> Prepared<'a> {
    /// For a valid prop enclosed by `aabb` (unpadded), its `cells` those
    /// [`super::profile::cell_boxes`] gives.
    pub(crate) fn new(prop: &Obstacle, aabb: Aabb, cells: &'a [Aabb]) -> Self {
        let planes = match *prop {
            Obstacle::Bent {
                curvature: k,
                min,
                max,
                ..
            } => Some([bend::end_plane(k, min[2]), bend::end_plane(k, max[2])]),
            _ => None,
        };
        Self {
            aabb: padded(aabb),
            planes,
            cells,
            pieces: &[],
        }
    }

    /// The same, with `pieces`.
    pub(crate) fn with_pieces<'b>(&self, pieces: &'b [Aabb]) -> Prepared<'b>
    where
        'a: 'b,
    {
        Prepared {
            aabb: self.aabb,
            planes: self.planes,
            cells: self.cells,
            pieces,
        }
    }
}

/// Longest stretch of a bent box culled as one, metres along: a long one (the facade and the
/// guard rail of a bend run 126 and 145 m) is culled piece by piece, each by its own bounds,
/// instead of by the bounds of its whole arc, which take in much of the road ahead.
const CULL_PIECE: f64 = 8.0;

/// Bounding spheres and [`padded`] boxes (in the prop's frame) that together enclose a valid
/// prop: its own ([`Obstacle::bounding_sphere`], [`Obstacle::aabb`]), or for a long bent box
/// those of its pieces of at most [`CULL_PIECE`] metres along.
pub(crate) fn cull_bounds(prop: &Obstacle) -> Vec<(([f64; 3], f64), Aabb)> {
    let Some((sphere, aabb)) = prop.bounding_sphere().zip(prop.aabb()) else {
        return Vec::new();
    };
    if let Obstacle::Bent {
        curvature: k,
        min,
        max,
        ..
    } = *prop
    {
        let length = max[2] - min[2];
        if length > CULL_PIECE {
            let pieces = (length / CULL_PIECE).ceil().min(1e4) as usize;
            let step = length / pieces as f64;
            return (0..pieces)
                .map(|i| {
                    let a = min[2] + step * i as f64;
                    let b = if i + 1 == pieces { max[2] } else { a + step };
                    let (sphere, aabb) = bend::bounds(k, [min[0], min[1], a], [max[0], max[1], b]);
                    (sphere, padded(aabb))
                })
                .collect();
        }
    }
    vec![(sphere, padded(aabb))]
}
