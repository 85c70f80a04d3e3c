//! Roads as they are built: the curvature a piecewise-linear function of the distance along the
//! centre line (straights, arcs, and the clothoids that lead from one to the next, whose
//! curvature changes linearly with arc length). A profile of one constant segment is a bend of
//! [`super::bend`], and a [`Road`] of it answers with bend's closed forms, bit for bit.
//!
//! Any other profile is integrated once, when its [`Road`] is built, into a table of
//! [`CELLS`] cells of [`CELL`] metres from [`START`] metres along: the heading at every node is
//! the profile's exact integral, and each cell is the arc of the mean curvature over it, from
//! one node to the next (so heading and position are continuous, and the road is that chain
//! of arcs exactly: marks, roadside, guard rail and posts are all laid along the same one).
//! Before the table and after it the first and last cells run on. Road coordinates are those
//! of [`super::bend`]: `(along, offset)`, the arc length to where a point is abreast and its
//! signed distance from the centre line (positive right), in the frame of the road's origin
//! (along 0, tangent to +z).
//!
//! A road-frame point is located through a grid built with the table: each square lists the
//! nodes that may be the nearest to a point in it, and the nearest node's two cells give the
//! point's road coordinates. Nothing is allocated per lookup.
//!
//! The cross-section of these roads is a single lane: solid edge lines ([`EDGE_LINE`]) either
//! side, asphalt to [`ASPHALT`], a kerb strip to [`KERB_OUTER`], grass beyond;
//! delineator posts every [`POST_SPACING`] m on both kerbs, [`POST_OFFSET`] m from the centre
//! line, and a guard rail on the outside of every bend ([`Road::props`]).

use super::{Hit, Material, Obstacle, Pattern, Ray, bend, roadside};

/// Metres of road a cell of the table spans.
pub const CELL: f64 = 1.0;
/// Cells in the table.
pub const CELLS: usize = 512;
/// Where the table starts, metres along (the road behind its origin is in the table too).
pub const START: f64 = -64.0;
/// Where it ends.
pub const END: f64 = START + CELLS as f64 * CELL;
/// Side of a square of the locating grid, metres.
const GRID: f64 = 2.0;
/// How far beyond the centre line's nodes the grid reaches, metres (farther points are located
/// through the nearest square: grass far away, where only the texture's coordinates change).
const GRID_MARGIN: f64 = 40.0;
/// Longest piece a laid box is cut into, metres along (the renderer culls pieces).
const PIECE: f64 = 8.0;

/// The solid edge lines of a laid road, metres from the centre line.
pub const EDGE_LINE: [f64; 2] = [1.75, 1.9];
/// Where the asphalt ends and the kerb strip starts.
pub const ASPHALT: f64 = 2.2;
/// Where the kerb strip ends and the grass starts.
pub const KERB_OUTER: f64 = 3.0;
/// The delineator posts' axis, metres from the centre line: 0.5 m beyond the edge line.
pub const POST_OFFSET: f64 = EDGE_LINE[1] + 0.5;
/// Metres between two posts on a kerb; the first stands [`POST_FIRST`] m along.
pub const POST_SPACING: f64 = 50.0;
pub const POST_FIRST: f64 = 20.0;
/// A post's height, width (across) and depth (along), metres.
pub const POST_SIZE: [f64; 3] = [0.1, 1.0, 0.1];
/// The guard rail's inner and outer faces, metres from the centre line: beyond the kerb.
pub const RAIL: [f64; 2] = [KERB_OUTER + 0.2, KERB_OUTER + 0.35];
/// How far the guard rail runs on before and after a bend, metres.
pub const RAIL_RUN_ON: f64 = 10.0;

/// One piece of a curvature profile: over `length` metres the curvature goes linearly from
/// `from` to `to` (1/m, positive bending left).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub length: f64,
    pub from: f64,
    pub to: f64,
}

impl Segment {
    pub const fn straight(length: f64) -> Self {
        Self {
            length,
            from: 0.0,
            to: 0.0,
        }
    }

    /// An arc of constant `curvature`.
    pub const fn arc(length: f64, curvature: f64) -> Self {
        Self {
            length,
            from: curvature,
            to: curvature,
        }
    }

    /// A clothoid: the curvature from `from` to `to`, linearly with arc length.
    pub const fn clothoid(length: f64, from: f64, to: f64) -> Self {
        Self { length, from, to }
    }

    fn is_valid(&self) -> bool {
        self.length.is_finite() && self.length > 0.0 && self.from.is_finite() && self.to.is_finite()
    }
}

/// A node of the table: the centre line's pose, and the curvature of the cell from it on.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Node {
    x: f64,
    z: f64,
    heading: f64,
    k: f64,
    /// `heading.sin_cos()`, once (every road-frame lookup turns through it).
    sin: f64,
    cos: f64,
    /// `(k * CELL).sin_cos()`: how far the cell's arc turns (for its bounds).
    arc: (f64, f64),
}

impl Node {
    /// A point of the node's frame (x right of the centre line, z along it) in the road's.
    #[inline]
    fn place(&self, x: f64, z: f64) -> (f64, f64) {
        let (sin, cos) = (self.sin, self.cos);
        (self.x + x * cos - z * sin, self.z + x * sin + z * cos)
    }

    /// A road-frame point in the node's frame.
    #[inline]
    fn local(&self, x: f64, z: f64) -> (f64, f64) {
        let (sin, cos) = (self.sin, self.cos);
        let (dx, dz) = (x - self.x, z - self.z);
        (dx * cos + dz * sin, dz * cos - dx * sin)
    }
}

/// The squares of the locating grid and the nodes each lists.
#[derive(Debug, Clone, Default)]
struct Grid {
    x0: f64,
    z0: f64,
    nx: usize,
    nz: usize,
    /// Square `i`'s nodes are `nodes[starts[i]..starts[i + 1]]`.
    starts: Vec<u32>,
    nodes: Vec<u16>,
}

/// A road of a curvature profile, ready to look up (see the module docs).
pub struct Road {
    profile: &'static [Segment],
    /// The profile's curvature when it is one constant segment (none: a straight road).
    constant: Option<f64>,
    nodes: Box<[Node; CELLS + 1]>,
    grid: Grid,
}

impl std::fmt::Debug for Road {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Road")
            .field("profile", &self.profile)
            .finish_non_exhaustive()
    }
}

/// Two roads are one if their profiles are (the table is a function of the profile).
impl PartialEq for Road {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other) || self.profile == other.profile
    }
}

/// The profile's curvature `along` metres on: the first segment's start before it, the last
/// one's end after it.
fn curvature_of(profile: &[Segment], along: f64) -> f64 {
    let Some(first) = profile.first() else {
        return 0.0;
    };
    if along <= 0.0 {
        return first.from;
    }
    let mut s0 = 0.0;
    for seg in profile {
        if along < s0 + seg.length {
            return seg.from + (seg.to - seg.from) * ((along - s0) / seg.length);
        }
        s0 += seg.length;
    }
    profile.last().map_or(0.0, |l| l.to)
}

/// The profile's heading `along` metres on, radians turned left: the integral of its
/// curvature from 0 (exact: quadratic in each segment).
fn heading_of(profile: &[Segment], along: f64) -> f64 {
    let Some(first) = profile.first() else {
        return 0.0;
    };
    if along <= 0.0 {
        return first.from * along;
    }
    let (mut s0, mut heading) = (0.0, 0.0);
    for seg in profile {
        let u = along - s0;
        if u < seg.length {
            return heading + seg.from * u + (seg.to - seg.from) * u * u / (2.0 * seg.length);
        }
        heading += 0.5 * (seg.from + seg.to) * seg.length;
        s0 += seg.length;
    }
    heading + profile.last().map_or(0.0, |l| l.to) * (along - s0)
}

/// Along of node `i`.
#[inline]
fn node_along(i: usize) -> f64 {
    START + i as f64 * CELL
}

impl Road {
    /// The road of `profile` (segments of non-positive or non-finite length, or non-finite
    /// curvature, are left out). Integrates the table and builds the locating grid: a few
    /// tens of milliseconds, once a road.
    pub fn new(profile: &'static [Segment]) -> Self {
        let valid = profile.iter().all(Segment::is_valid);
        let profile: &'static [Segment] = if valid { profile } else { &[] };
        let constant = match profile {
            [] => Some(0.0),
            [one] if one.from == one.to => Some(one.from),
            _ => None,
        };
        let mut nodes = Box::new([Node::default(); CELLS + 1]);
        for (i, n) in nodes.iter_mut().enumerate() {
            let (a, b) = (node_along(i), node_along(i + 1));
            n.heading = heading_of(profile, a);
            n.k = (heading_of(profile, b) - n.heading) / CELL;
            (n.sin, n.cos) = n.heading.sin_cos();
            n.arc = (n.k * CELL).sin_cos();
        }
        // From the origin's node on, and back from it: each node is the last one moved along
        // its cell's arc.
        let origin = ((0.0 - START) / CELL).round() as usize;
        for i in origin..CELLS {
            let (x, z) = bend::point(nodes[i].k, CELL, 0.0);
            let (x, z) = nodes[i].place(x, z);
            (nodes[i + 1].x, nodes[i + 1].z) = (x, z);
        }
        for i in (0..origin).rev() {
            // The cell from node i to i + 1, back from node i + 1.
            let (x, z) = bend::point(nodes[i].k, -CELL, 0.0);
            let (x, z) = nodes[i + 1].place(x, z);
            (nodes[i].x, nodes[i].z) = (x, z);
        }
        let grid = Grid::build(&nodes[..]);
        Self {
            profile,
            constant,
            nodes,
            grid,
        }
    }

    /// The profile.
    pub fn profile(&self) -> &'static [Segment] {
        self.profile
    }

    /// The curvature when the profile is one constant segment (a bend of [`super::bend`]), 0
    /// for no segment (straight).
    pub fn constant(&self) -> Option<f64> {
        self.constant
    }

    /// The profile's length, metres (the road runs on after it).
    pub fn length(&self) -> f64 {
        self.profile.iter().map(|s| s.length).sum()
    }

    /// The profile's curvature `along` metres on, 1/m (what a vehicle on the centre line turns
    /// by: its yaw rate is its speed times this).
    pub fn curvature(&self, along: f64) -> f64 {
        curvature_of(self.profile, along)
    }

    /// The cell `along` falls in (the first and last cells run on before and after the table).
    #[inline]
    fn cell(&self, along: f64) -> usize {
        // `as` saturates, NaN to 0.
        (((along - START) / CELL).floor().max(0.0) as usize).min(CELLS - 1)
    }

    /// The road-frame `(x, z)` of road coordinates `(along, offset)`.
    pub fn point(&self, along: f64, offset: f64) -> (f64, f64) {
        if let Some(k) = self.constant {
            return bend::point(k, along, offset);
        }
        let c = self.cell(along);
        let n = &self.nodes[c];
        let (x, z) = bend::point(n.k, along - node_along(c), offset);
        n.place(x, z)
    }

    /// The centre line's direction `along` metres on, radians turned left from +z.
    pub fn heading(&self, along: f64) -> f64 {
        if let Some(k) = self.constant {
            return bend::heading(k, along);
        }
        let c = self.cell(along);
        let n = &self.nodes[c];
        n.heading + n.k * (along - node_along(c))
    }

    /// Road coordinates `(along, offset)` of the road-frame point `(x, z)`: those of the
    /// nearest point of the centre line (near the road; far from it, of one near by).
    pub fn locate(&self, x: f64, z: f64) -> (f64, f64) {
        if let Some(k) = self.constant {
            return bend::locate(k, x, z);
        }
        let nearest = self.grid.nearest(&self.nodes[..], x, z);
        let mut best: Option<(bool, f64, f64, f64)> = None;
        for c in [nearest.saturating_sub(1), nearest.min(CELLS - 1)] {
            let n = &self.nodes[c];
            let (lx, lz) = n.local(x, z);
            let (along, offset) = bend::locate(n.k, lx, lz);
            const EPS: f64 = 1e-9;
            let proper = (c == 0 || along >= -EPS) && (c == CELLS - 1 || along <= CELL + EPS);
            let better = match best {
                None => true,
                Some((p, _, _, o)) => (proper && !p) || (proper == p && offset.abs() < o.abs()),
            };
            if better {
                best = Some((proper, node_along(c), along, offset));
            }
        }
        best.map_or((z, x), |(_, s0, along, offset)| (s0 + along, offset))
    }

    /// The cells a box spanning `lo..hi` along is drawn in: the cell, and the part of the box
    /// in it in the cell's own coordinates (along from its node).
    fn cells(&self, lo: f64, hi: f64) -> impl Iterator<Item = (usize, [f64; 2])> + '_ {
        let (first, last) = self.span(lo, hi);
        (first..=last).map(move |c| {
            let s0 = node_along(c);
            let a = if c == 0 { lo } else { lo.max(s0) };
            let b = if c == CELLS - 1 {
                hi
            } else {
                hi.min(s0 + CELL)
            };
            (c, [a - s0, b - s0])
        })
    }

    /// The first and last cells of [`Road::cells`].
    #[inline]
    fn span(&self, lo: f64, hi: f64) -> (usize, usize) {
        let first = self.cell(lo);
        let mut last = self.cell(hi);
        if last > first && node_along(last) >= hi {
            last -= 1;
        }
        (first, last)
    }

    /// `(min, max)` of a box in cell `c`'s coordinates.
    #[inline]
    fn in_cell(c: usize, min: [f64; 3], max: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let s0 = node_along(c);
        ([min[0], min[1], min[2] - s0], [max[0], max[1], max[2] - s0])
    }

    /// A box `min..max` (offset, height, along) laid along the road, cut into pieces the
    /// renderer culls apart ([`Obstacle::Laid`]). On a constant road, the [`Obstacle::Bent`] of
    /// [`super::bend`].
    pub fn lay(&'static self, min: [f64; 3], max: [f64; 3], material: Material) -> Vec<Obstacle> {
        if let Some(curvature) = self.constant {
            return vec![Obstacle::Bent {
                curvature,
                min,
                max,
                material,
            }];
        }
        let pieces = ((max[2] - min[2]) / PIECE).ceil().clamp(1.0, 1e4) as usize;
        let step = (max[2] - min[2]) / pieces as f64;
        (0..pieces)
            .map(|i| {
                let a = min[2] + step * i as f64;
                let b = if i + 1 == pieces { max[2] } else { a + step };
                Obstacle::Laid {
                    road: self,
                    min,
                    max,
                    part: [a, b],
                    material,
                }
            })
            .collect()
    }

    /// The stretches where the road bends one way: (from, to, +1 left or -1 right).
    fn bends(&self) -> Vec<(f64, f64, f64)> {
        let mut runs: Vec<(f64, f64, f64)> = Vec::new();
        let mut push = |a: f64, b: f64, sign: f64| match runs.last_mut() {
            Some(last) if last.2 == sign && last.1 == a => last.1 = b,
            _ => runs.push((a, b, sign)),
        };
        let mut s0 = 0.0;
        for seg in self.profile {
            let (a, b) = (s0, s0 + seg.length);
            if seg.from * seg.to < 0.0 {
                let zero = a + seg.length * seg.from / (seg.from - seg.to);
                push(a, zero, seg.from.signum());
                push(zero, b, seg.to.signum());
            } else if seg.from != 0.0 || seg.to != 0.0 {
                push(a, b, (seg.from + seg.to).signum());
            } else {
                push(a, b, 0.0);
            }
            s0 = b;
        }
        // A road that ends bending runs on bending.
        if let Some(last) = runs.last_mut()
            && self.profile.last().is_some_and(|l| l.to != 0.0)
        {
            last.1 = END;
        }
        runs.retain(|r| r.2 != 0.0);
        runs
    }

    /// The static world along the road: the straight road's [`roadside`] laid along it, a
    /// guard rail on the outside of every bend ([`RAIL`], 0.8 m high, from [`RAIL_RUN_ON`] m
    /// before it to as far after) and delineator posts on both kerbs. On a constant road,
    /// [`super::bend::bent`] (the bends of today, bit for bit).
    pub fn props(&'static self) -> Vec<Obstacle> {
        if let Some(k) = self.constant {
            return bend::bent(k, &roadside());
        }
        let mut v = Vec::new();
        for o in roadside() {
            match o {
                Obstacle::Box { min, max, material } => v.extend(self.lay(min, max, material)),
                Obstacle::Cylinder {
                    x,
                    z,
                    radius,
                    height,
                    material,
                } => {
                    let (x, z) = self.point(z, x);
                    v.push(Obstacle::Cylinder {
                        x,
                        z,
                        radius,
                        height,
                        material,
                    });
                }
                other => v.push(other),
            }
        }
        for (a, b, side) in self.bends() {
            let (inner, outer) = (RAIL[0] * side, RAIL[1] * side);
            let (from, to) = ((a - RAIL_RUN_ON).max(START), (b + RAIL_RUN_ON).min(END));
            v.extend(self.lay(
                [inner.min(outer), 0.0, from],
                [inner.max(outer), 0.8, to],
                RAIL_MATERIAL,
            ));
        }
        for (along, offset) in self.posts() {
            let [w, h, d] = POST_SIZE;
            v.extend(self.lay(
                [offset - 0.5 * w, 0.0, along - 0.5 * d],
                [offset + 0.5 * w, h, along + 0.5 * d],
                POST_MATERIAL,
            ));
        }
        v
    }

    /// Where the delineator posts stand: `(along, offset)` of their axes, both kerbs.
    pub fn posts(&self) -> impl Iterator<Item = (f64, f64)> {
        (0..)
            .map(|i| POST_FIRST + POST_SPACING * f64::from(i))
            .take_while(|&s| s < END - CELL)
            .flat_map(|s| [(s, -POST_OFFSET), (s, POST_OFFSET)])
    }
}

/// The guard rail's galvanised steel (as [`super::bend::bent`]'s).
const RAIL_MATERIAL: Material = Material {
    colour: [165, 168, 172],
    pattern: Pattern::Noise {
        cell: 0.08,
        contrast: 0.45,
    },
    seed: 0x6A2D,
};

/// A delineator post: white with a dark band.
const POST_MATERIAL: Material = Material {
    colour: [236, 236, 230],
    pattern: Pattern::Post,
    seed: 0xDE11,
};

mod grid;
mod laid;
pub(crate) use laid::cell_boxes;
pub(super) use laid::{bounds, intersect, is_valid};

#[cfg(test)]
mod tests;
