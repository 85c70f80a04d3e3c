//! Boxes laid along a road ([`Road::lay`]): whether one is valid, what encloses it, and where
//! a ray hits it, drawn cell by cell as bent boxes ([`bend`]).

use super::{CELL, CELLS, Hit, Node, Ray, Road, bend};
use crate::world::{Aabb, may_meet, padded};

/// Whether a laid box is one: finite, non-degenerate, its part within it, and in every cell
/// it is drawn in a valid bent box ([`bend::is_valid`]: not reaching a cell's centre of
/// curvature).
pub(in crate::world) fn is_valid(
    road: &Road,
    min: [f64; 3],
    max: [f64; 3],
    part: [f64; 2],
) -> bool {
    let finite = (0..3).all(|a| min[a].is_finite() && max[a].is_finite())
        && part[0].is_finite()
        && part[1].is_finite();
    if !finite || (0..3).any(|a| min[a] >= max[a]) {
        return false;
    }
    let (lo, hi) = (min[2].max(part[0]), max[2].min(part[1]));
    if lo >= hi {
        return false;
    }
    road.cells(lo, hi).all(|(c, [a, b])| {
        b > a && bend::is_valid(road.nodes[c].k, [min[0], min[1], a], [max[0], max[1], b])
    })
}

/// A sphere and a road-frame box enclosing a valid laid box's part.
pub(in crate::world) fn bounds(
    road: &Road,
    min: [f64; 3],
    max: [f64; 3],
    part: [f64; 2],
) -> (bend::Sphere, bend::Aabb) {
    let (lo, hi) = (min[2].max(part[0]), max[2].min(part[1]));
    let (mut a, mut b) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let mut pad: f64 = 0.0;
    let wide = min[0].abs().max(max[0].abs());
    for (c, [s, e]) in road.cells(lo, hi) {
        let n = &road.nodes[c];
        // The arc bulges from its chord by at most its sagitta at the outer offset.
        let k = n.k.abs();
        pad = pad.max((e - s) * (e - s) * k * (1.0 + k * wide) / 8.0);
        for along in [s, e] {
            for offset in [min[0], max[0]] {
                let (x, z) = bend::point(n.k, along, offset);
                let (x, z) = n.place(x, z);
                a = [a[0].min(x), a[1].min(z)];
                b = [b[0].max(x), b[1].max(z)];
            }
        }
    }
    pad += 1e-6;
    let lo = [a[0] - pad, min[1], a[1] - pad];
    let hi = [b[0] + pad, max[1], b[1] + pad];
    let centre = [
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        0.5 * (lo[2] + hi[2]),
    ];
    let half = [hi[0] - centre[0], hi[1] - centre[1], hi[2] - centre[2]];
    let radius = (half[0] * half[0] + half[1] * half[1] + half[2] * half[2]).sqrt();
    ((centre, radius), (lo, hi))
}

/// The nearest hit in front of the ray on a valid laid box's part: in each cell it is drawn in,
/// the bent box of the cell's arc ([`bend::intersect_part`]), its end faces where the box ends.
/// Only hits nearer than `before` are looked for.
pub(in crate::world) fn intersect(
    ray: &Ray,
    road: &Road,
    min: [f64; 3],
    max: [f64; 3],
    part: [f64; 2],
    before: f64,
    cells: &[Aabb],
) -> Option<Hit> {
    let (lo, hi) = (min[2].max(part[0]), max[2].min(part[1]));
    let (first, last) = road.span(lo, hi);
    let mut best: Option<Hit> = None;
    for (j, (c, local)) in road.cells(lo, hi).enumerate() {
        let n = &road.nodes[c];
        let before = best.as_ref().map_or(before, |b| b.t.min(before));
        // A ray that cannot meet the cell's part of the box before `before` needs no arcs.
        if c != 0 && c != CELLS - 1 {
            let cell = cells
                .get(j)
                .copied()
                .unwrap_or_else(|| cell_box(n, min, max));
            if !may_meet(ray, &cell, before) {
                continue;
            }
        }
        let (ox, oz) = n.local(ray.origin[0], ray.origin[2]);
        let (sin, cos) = (n.sin, n.cos);
        let d = ray.dir;
        let local_ray = Ray {
            origin: [ox, ray.origin[1], oz],
            dir: [d[0] * cos + d[2] * sin, d[1], d[2] * cos - d[0] * sin],
        };
        let (cmin, cmax) = Road::in_cell(c, min, max);
        let ends = [c == first && lo == min[2], c == last && hi == max[2]];
        // A later cell's hit counts only if strictly nearer than the best so far.
        let Some(mut hit) =
            bend::intersect_part(&local_ray, n.k, cmin, cmax, (local, ends), before, None)
        else {
            continue;
        };
        let (px, pz) = n.place(hit.point[0], hit.point[2]);
        hit.point = [px, hit.point[1], pz];
        let nv = hit.normal;
        hit.normal = [nv[0] * cos - nv[2] * sin, nv[1], nv[0] * sin + nv[2] * cos];
        best = Some(hit);
    }
    best
}

/// The [`cell_box`] of every cell a laid box is drawn in, in the order [`intersect`] goes
/// through them (none for any other obstacle, or an invalid one): what the renderer computes
/// once a frame rather than once a ray.
pub(crate) fn cell_boxes(o: &super::Obstacle) -> Vec<Aabb> {
    match *o {
        super::Obstacle::Laid {
            road,
            min,
            max,
            part,
            ..
        } if is_valid(road, min, max, part) => {
            let (lo, hi) = (min[2].max(part[0]), max[2].min(part[1]));
            road.cells(lo, hi)
                .map(|(c, _)| cell_box(&road.nodes[c], min, max))
                .collect()
        }
        _ => Vec::new(),
    }
}

/// A road-frame box ([`padded`]) enclosing the part between offsets `min[0]..max[0]` and
/// heights `min[1]..max[1]` of the whole cell from node `n` (not the first or last cell,
/// which run on): its four corners, grown by the arc's sagitta. Cheap: no trigonometry.
fn cell_box(n: &Node, min: [f64; 3], max: [f64; 3]) -> Aabb {
    let (s, c) = n.arc;
    let (mut a, mut b) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for offset in [min[0], max[0]] {
        // bend::point at along 0 and CELL, in the cell's frame.
        let end = if n.k == 0.0 {
            (offset, CELL)
        } else {
            (-(1.0 - c) / n.k + offset * c, s / n.k + offset * s)
        };
        for (x, z) in [(offset, 0.0), end] {
            let (x, z) = n.place(x, z);
            a = [a[0].min(x), a[1].min(z)];
            b = [b[0].max(x), b[1].max(z)];
        }
    }
    let k = n.k.abs();
    let wide = min[0].abs().max(max[0].abs());
    let sag = CELL * CELL * k * (1.0 + k * wide) / 8.0 + 1e-6;
    padded((
        [a[0] - sag, min[1], a[1] - sag],
        [b[0] + sag, max[1], b[1] + sag],
    ))
}
