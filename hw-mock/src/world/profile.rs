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
}

impl Node {
    /// A point of the node's frame (x right of the centre line, z along it) in the road's.
    #[inline]
    fn place(&self, x: f64, z: f64) -> (f64, f64) {
        let (sin, cos) = self.heading.sin_cos();
        (self.x + x * cos - z * sin, self.z + x * sin + z * cos)
    }

    /// A road-frame point in the node's frame.
    #[inline]
    fn local(&self, x: f64, z: f64) -> (f64, f64) {
        let (sin, cos) = self.heading.sin_cos();
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

impl Grid {
    fn build(nodes: &[Node]) -> Self {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for n in nodes {
            lo = [lo[0].min(n.x), lo[1].min(n.z)];
            hi = [hi[0].max(n.x), hi[1].max(n.z)];
        }
        let (x0, z0) = (lo[0] - GRID_MARGIN, lo[1] - GRID_MARGIN);
        let count = |span: f64| {
            ((span + 2.0 * GRID_MARGIN) / GRID)
                .ceil()
                .clamp(1.0, 4096.0)
        };
        let (nx, nz) = (count(hi[0] - lo[0]) as usize, count(hi[1] - lo[1]) as usize);
        let mut starts = Vec::with_capacity(nx * nz + 1);
        let mut list = Vec::new();
        let mut dist = vec![0.0; nodes.len()];
        // A point of a square is within half its diagonal of the centre: a node farther from
        // the centre than the nearest one plus the diagonal is never the nearest to it.
        let reach = GRID * std::f64::consts::SQRT_2 + 1e-9;
        for iz in 0..nz {
            for ix in 0..nx {
                let cx = x0 + (ix as f64 + 0.5) * GRID;
                let cz = z0 + (iz as f64 + 0.5) * GRID;
                let mut nearest = f64::INFINITY;
                for (d, n) in dist.iter_mut().zip(nodes) {
                    *d = (n.x - cx).hypot(n.z - cz);
                    nearest = nearest.min(*d);
                }
                starts.push(list.len() as u32);
                list.extend(
                    dist.iter()
                        .enumerate()
                        .filter(|&(_, &d)| d <= nearest + reach)
                        .map(|(i, _)| i as u16),
                );
            }
        }
        starts.push(list.len() as u32);
        Self {
            x0,
            z0,
            nx,
            nz,
            starts,
            nodes: list,
        }
    }

    /// The node nearest to `(x, z)` (through the nearest square outside the grid).
    #[inline]
    fn nearest(&self, nodes: &[Node], x: f64, z: f64) -> usize {
        let index = |v: f64, n: usize| ((v / GRID).floor().max(0.0) as usize).min(n - 1);
        let square = index(z - self.z0, self.nz) * self.nx + index(x - self.x0, self.nx);
        let list = &self.nodes[self.starts[square] as usize..self.starts[square + 1] as usize];
        let mut best = (f64::INFINITY, 0usize);
        for &i in list {
            let n = &nodes[usize::from(i)];
            let d = (n.x - x) * (n.x - x) + (n.z - z) * (n.z - z);
            if d < best.0 {
                best = (d, usize::from(i));
            }
        }
        best.1
    }
}

/// Whether a laid box is one: finite, non-degenerate, its part within it, and in every cell
/// it is drawn in a valid bent box ([`bend::is_valid`]: not reaching a cell's centre of
/// curvature).
pub(super) fn is_valid(road: &Road, min: [f64; 3], max: [f64; 3], part: [f64; 2]) -> bool {
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
pub(super) fn bounds(
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
pub(super) fn intersect(
    ray: &Ray,
    road: &Road,
    min: [f64; 3],
    max: [f64; 3],
    part: [f64; 2],
) -> Option<Hit> {
    let (lo, hi) = (min[2].max(part[0]), max[2].min(part[1]));
    let (first, last) = road.span(lo, hi);
    let mut best: Option<Hit> = None;
    for (c, local) in road.cells(lo, hi) {
        let n = &road.nodes[c];
        let (ox, oz) = n.local(ray.origin[0], ray.origin[2]);
        let (sin, cos) = n.heading.sin_cos();
        let d = ray.dir;
        let local_ray = Ray {
            origin: [ox, ray.origin[1], oz],
            dir: [d[0] * cos + d[2] * sin, d[1], d[2] * cos - d[0] * sin],
        };
        let (cmin, cmax) = Road::in_cell(c, min, max);
        let ends = [c == first && lo == min[2], c == last && hi == max[2]];
        let Some(mut hit) = bend::intersect_part(&local_ray, n.k, cmin, cmax, local, ends) else {
            continue;
        };
        if best.as_ref().is_some_and(|b| b.t <= hit.t) {
            continue;
        }
        let (px, pz) = n.place(hit.point[0], hit.point[2]);
        hit.point = [px, hit.point[1], pz];
        let nv = hit.normal;
        hit.normal = [nv[0] * cos - nv[2] * sin, nv[1], nv[0] * sin + nv[2] * cos];
        best = Some(hit);
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Face;

    static ARC: [Segment; 3] = [
        Segment::straight(20.0),
        Segment::arc(60.0, 1.0 / 40.0),
        Segment::straight(100.0),
    ];
    static CLOTHOID: [Segment; 1] = [Segment::clothoid(60.0, 0.0, 1.0 / 300.0)];
    static CONSTANT: [Segment; 1] = [Segment::arc(100.0, 1.0 / 60.0)];
    static S_BEND: [Segment; 3] = [
        Segment::clothoid(25.0, 0.0, 1.0 / 80.0),
        Segment::clothoid(25.0, 1.0 / 80.0, -1.0 / 80.0),
        Segment::clothoid(25.0, -1.0 / 80.0, 0.0),
    ];

    fn leak(profile: &'static [Segment]) -> &'static Road {
        Box::leak(Box::new(Road::new(profile)))
    }

    #[test]
    fn an_arc_integrates_to_its_circle() {
        let road = leak(&ARC);
        let k = 1.0 / 40.0;
        for along in [-10.0, 0.0, 10.0, 20.0, 20.5, 33.3, 60.0, 79.5] {
            let (x, z) = road.point(along, 0.0);
            let (ex, ez) = if along <= 20.0 {
                (0.0, along)
            } else {
                let (x, z) = bend::point(k, along - 20.0, 0.0);
                (x, z + 20.0)
            };
            assert!(
                (x - ex).abs() < 1e-9 && (z - ez).abs() < 1e-9,
                "{along}: ({x}, {z}) vs ({ex}, {ez})"
            );
            let heading = (along - 20.0).max(0.0) * k;
            assert!((road.heading(along) - heading).abs() < 1e-12, "{along}");
            assert_eq!(road.curvature(along), if along < 20.0 { 0.0 } else { k });
        }
        // Off the centre line too, and back.
        for (along, offset) in [
            (30.0, 1.5),
            (70.0, -5.5),
            (120.0, 3.0),
            (5.0, -2.0),
            (-20.0, 4.0),
        ] {
            let (x, z) = road.point(along, offset);
            let (a, o) = road.locate(x, z);
            assert!(
                (a - along).abs() < 1e-9 && (o - offset).abs() < 1e-9,
                "({along}, {offset}) -> ({a}, {o})"
            );
        }
    }

    #[test]
    fn a_small_angle_clothoid_is_the_cubic() {
        // k = c s: heading c s^2 / 2, and for a small angle x = -c s^3 / 6 (left), z = s.
        let road = leak(&CLOTHOID);
        let c = 1.0 / 300.0 / 60.0;
        for s in [5.0, 17.5, 30.0, 45.25, 60.0] {
            let (x, z) = road.point(s, 0.0);
            // Exact at the nodes, the cells' arcs in between (within c CELL^2 / 8).
            let heading = c * s * s / 2.0;
            let within = if s.fract() == 0.0 {
                1e-12
            } else {
                1.01 * c * CELL * CELL / 8.0
            };
            assert!((road.heading(s) - heading).abs() <= within, "{s}");
            assert!((road.curvature(s) - c * s).abs() < 1e-15, "{s}");
            // The next terms: x + c^3 s^7 / 336, z - c^2 s^5 / 40; the chain of arcs is within
            // a millimetre of the clothoid.
            let (ex, ez) = (-c * s.powi(3) / 6.0, s);
            let (tx, tz) = (c.powi(3) * s.powi(7) / 336.0, c * c * s.powi(5) / 40.0);
            assert!((x - ex).abs() < tx + 1e-3, "{s}: x {x} vs {ex}");
            assert!((z - ez).abs() < tz + 1e-3, "{s}: z {z} vs {ez}");
        }
        // After the profile the road runs on at its last curvature.
        assert_eq!(road.curvature(100.0), 1.0 / 300.0);
    }

    #[test]
    fn a_constant_profile_is_the_bend() {
        let road = leak(&CONSTANT);
        let k = 1.0 / 60.0;
        assert_eq!(road.constant(), Some(k));
        for (along, offset) in [(0.0, 0.0), (12.0, 1.5), (45.0, -5.5), (80.0, 7.0)] {
            assert_eq!(road.point(along, offset), bend::point(k, along, offset));
            assert_eq!(road.heading(along), bend::heading(k, along));
            let (x, z) = bend::point(k, along, offset);
            assert_eq!(road.locate(x, z), bend::locate(k, x, z));
        }
        assert_eq!(road.props(), bend::bent(k, &roadside()));
        assert_eq!(
            road.lay([-0.9, 0.0, 10.0], [0.9, 1.5, 14.2], Material::CAR),
            vec![Obstacle::Bent {
                curvature: k,
                min: [-0.9, 0.0, 10.0],
                max: [0.9, 1.5, 14.2],
                material: Material::CAR
            }]
        );
    }

    #[test]
    fn road_coordinates_round_trip_on_an_s_bend() {
        let road = leak(&S_BEND);
        assert_eq!(road.curvature(37.5), 0.0);
        assert!(road.heading(75.0).abs() < 1e-12, "{}", road.heading(75.0));
        for along in (-30..200).map(|i| f64::from(i) * 0.7) {
            for offset in [-6.0, -2.7, 0.0, 0.3, 1.8, 4.0] {
                let (x, z) = road.point(along, offset);
                let (a, o) = road.locate(x, z);
                assert!(
                    (a - along).abs() < 1e-8 && (o - offset).abs() < 1e-8,
                    "({along}, {offset}) -> ({x}, {z}) -> ({a}, {o})"
                );
            }
        }
    }

    #[test]
    fn posts_stand_on_both_kerbs_every_fifty_metres() {
        let road = leak(&S_BEND);
        let posts: Vec<_> = road.posts().collect();
        assert_eq!(
            &posts[..4],
            &[(20.0, -2.4), (20.0, 2.4), (70.0, -2.4), (70.0, 2.4)]
        );
        assert!(posts.iter().all(|p| p.0 < END));
        // Laid as thin boxes: a ray down onto a post's top meets it there, 1 m up, and a
        // horizontal ray from the centre line towards it meets its inner face 2.35 m across.
        let props = road.props();
        for &(along, offset) in &posts[..4] {
            let (x, z) = road.point(along, offset);
            let top = props
                .iter()
                .filter_map(|o| o.intersect(&Ray::towards([x, 3.0, z], [0.0, -1.0, 0.0])))
                .min_by(|a, b| a.t.total_cmp(&b.t))
                .expect("the post is there");
            assert!((top.point[1] - 1.0).abs() < 1e-9, "{top:?}");
            assert_eq!(top.face, Face::Horizontal);
            let (cx, cz) = road.point(along, 0.0);
            let (tx, tz) = road.point(along, offset.signum() * 3.0);
            let side = props
                .iter()
                .filter_map(|o| o.intersect(&Ray::towards([cx, 0.5, cz], [tx - cx, 0.0, tz - cz])))
                .min_by(|a, b| a.t.total_cmp(&b.t))
                .expect("the post's side");
            assert!((side.t - 2.35).abs() < 1e-6, "{side:?}");
            let (a, o) = road.locate(side.point[0], side.point[2]);
            assert!((a - along).abs() < 1e-6 && (o.abs() - 2.35).abs() < 1e-6);
        }
        // Between posts the same ray reaches the guard rail (outside of the left bend: right).
        let (cx, cz) = road.point(30.0, 0.0);
        let (tx, tz) = road.point(30.0, 4.0);
        let rail = props
            .iter()
            .filter_map(|o| o.intersect(&Ray::towards([cx, 0.5, cz], [tx - cx, 0.0, tz - cz])))
            .min_by(|a, b| a.t.total_cmp(&b.t))
            .expect("the guard rail");
        assert!((rail.t - RAIL[0]).abs() < 1e-6, "{rail:?}");
        // Every piece is valid and its bounds hold it.
        for o in &props {
            assert!(o.is_valid(), "{o:?}");
        }
    }

    #[test]
    fn a_laid_box_is_one_box_across_its_pieces() {
        // A wall 30 m long along the S-bend, cut into pieces: rays from the centre line meet
        // its face at its offset wherever they look, and no cut shows as a face.
        let road = leak(&S_BEND);
        let wall = road.lay(
            [4.0, 0.0, 5.0],
            [4.2, 2.0, 35.0],
            Material {
                colour: [150, 150, 150],
                pattern: Pattern::Bricks,
                seed: 1,
            },
        );
        assert!(wall.len() > 1);
        for i in 0..=120 {
            let along = 5.5 + 0.24 * f64::from(i);
            let (cx, cz) = road.point(along, 0.0);
            let (tx, tz) = road.point(along, 4.1);
            let hit = wall
                .iter()
                .filter_map(|o| o.intersect(&Ray::towards([cx, 1.0, cz], [tx - cx, 0.0, tz - cz])))
                .min_by(|a, b| a.t.total_cmp(&b.t))
                .expect("the wall");
            assert_eq!(hit.face, Face::NegX, "{along}");
            assert!((hit.t - 4.0).abs() < 1e-6, "{along}: {hit:?}");
            assert!((hit.s - (along - 20.0)).abs() < 1e-6, "{along}: {hit:?}");
        }
        // Its end faces are where it ends.
        let (cx, cz) = road.point(2.0, 4.1);
        let (tx, tz) = road.point(6.0, 4.1);
        let end = wall
            .iter()
            .filter_map(|o| o.intersect(&Ray::towards([cx, 1.0, cz], [tx - cx, 0.0, tz - cz])))
            .min_by(|a, b| a.t.total_cmp(&b.t))
            .expect("the wall's end");
        assert_eq!(end.face, Face::NegZ);
        let (a, _) = road.locate(end.point[0], end.point[2]);
        assert!((a - 5.0).abs() < 1e-6, "{a}");
    }
}
