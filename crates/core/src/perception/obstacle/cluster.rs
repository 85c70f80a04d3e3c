//! The clustering of the unique flies into the nearest obstacle (the module docs' step 4):
//! the sampled fly ([`Unique`]), the nearest cluster and its checks, and the small helpers
//! the sample uses (the stride over the population, the cell set, the median absolute
//! deviation, the sortable float bits).

use super::ObstacleConfig;

/// A cluster whose cells' columns spread over fewer image columns than this (4 median absolute
/// deviations) is one vertical edge (see the module docs, step 4).
const MIN_WIDTH_PX: f32 = 4.0;

/// The distinct cells (row << 16 | column) of a cluster, counted in a bit per cell of the
/// image (no sort).
#[derive(Debug, Clone)]
pub(super) struct CellSet {
    bits: Vec<u64>,
    columns: u32,
    rows: u32,
}

impl CellSet {
    /// For images of `(width, height)` pixels in `cell_px` squares.
    pub(super) fn new((width, height): (u32, u32), cell_px: u32) -> Self {
        let cell_px = cell_px.max(1);
        // One more than the image holds: a projection is within [-0.5, size - 0.5).
        let (columns, rows) = (width / cell_px + 1, height / cell_px + 1);
        let n = (columns as usize * rows as usize).div_ceil(64);
        Self {
            bits: vec![0; n],
            columns,
            rows,
        }
    }

    /// How many distinct cells `cells` holds, and whether they span more than one row
    /// (cells past the image count as its last row or column).
    pub(super) fn count(&mut self, cells: impl Iterator<Item = u32> + Clone) -> (usize, bool) {
        let at = |cell: u32| {
            let (row, column) = (
                (cell >> 16).min(self.rows - 1),
                (cell & 0xFFFF).min(self.columns - 1),
            );
            (row, (row * self.columns + column) as usize)
        };
        let (mut distinct, mut low, mut high) = (0, u32::MAX, 0);
        for cell in cells.clone() {
            let (row, i) = at(cell);
            let (word, bit) = (i / 64, 1u64 << (i % 64));
            distinct += usize::from(self.bits[word] & bit == 0);
            self.bits[word] |= bit;
            (low, high) = (low.min(row), high.max(row));
        }
        for cell in cells {
            self.bits[at(cell).1 / 64] = 0;
        }
        (distinct, distinct > 0 && low != high)
    }
}

/// A step through `0..len` that visits every index once before repeating (coprime to it) and
/// jumps far, so that consecutive flies of the population (offspring of the same parents) are
/// not taken together.
pub(super) fn stride_for(len: usize) -> usize {
    const PRIMES: [usize; 4] = [7919, 7907, 7901, 7883];
    if len <= 1 {
        return 1;
    }
    PRIMES
        .iter()
        .map(|&p| p % len)
        .find(|&p| p != 0 && gcd(p, len) == 1)
        .unwrap_or(1)
}

pub(super) fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// The median absolute deviation of `v` (reordered); 0 when empty.
pub(super) fn mad(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let median = *v.select_nth_unstable_by(mid, f32::total_cmp).1;
    for x in v.iter_mut() {
        *x = (*x - median).abs();
    }
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// `x`'s bits as an integer that sorts as [`f32::total_cmp`] orders (negative values with
/// their bits flipped, positive ones with the sign bit set).
pub(super) fn ordered(x: f32) -> u32 {
    let b = x.to_bits();
    if b >> 31 == 1 { !b } else { b | (1 << 31) }
}

/// A sampled fly: its depth, where it is along the path, its left-image cell (row << 16 |
/// column) and position, its lateral offset from the path, its height above the road and its
/// index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Unique {
    pub(super) z: f32,
    /// Distance along the predicted path (straight: `z`).
    pub(super) along: f32,
    pub(super) cell: u32,
    pub(super) u: f32,
    pub(super) v: f32,
    /// Offset from the predicted path, positive right (straight: the vehicle frame's x).
    pub(super) x: f32,
    pub(super) h: f32,
    pub(super) index: u32,
}

/// The nearest cluster of `unique` (sorted by depth): the first depth window (see the module
/// docs, step 4) whose flies within `cluster_width` of one another laterally are at least
/// `min_flies`, over `min_cells` cells and two rows, and wide enough. Puts its flies into
/// `members`; returns the end of its depth window in `unique` and its cell count (`cells` is
/// scratch).
pub(super) fn nearest_cluster(
    unique: &[Unique],
    c: &ObstacleConfig,
    pixels_per_inverse_depth: f64,
    cells: &mut CellSet,
    members: &mut Vec<Unique>,
) -> Option<(usize, usize)> {
    let mut to = 0;
    let width = c.cluster_width as f32;
    // Windows anchored within half a window of one already tested overlap it mostly: the
    // next tested one starts half a window on (one test per half window, not per fly).
    let mut next_anchor = f32::MIN;
    for (from, u) in unique.iter().enumerate() {
        let z = f64::from(u.z);
        let depth =
            (c.cluster_disparity_px * z * z / pixels_per_inverse_depth).max(c.min_cluster_depth);
        let end = (z + depth) as f32;
        to = to.max(from);
        while to < unique.len() && unique[to].z <= end {
            to += 1;
        }
        if to - from < c.min_flies || u.z < next_anchor {
            continue;
        }
        next_anchor = (z + depth / 2.0) as f32;
        // Laterally: the most flies within `cluster_width` of one another.
        members.clear();
        members.extend_from_slice(&unique[from..to]);
        members.sort_unstable_by_key(|u| (u64::from(ordered(u.x)) << 32) | u64::from(u.index));
        let (mut best, mut lo) = ((0, 0), 0);
        for hi in 0..members.len() {
            while members[hi].x - members[lo].x > width {
                lo += 1;
            }
            if hi + 1 - lo > best.1 - best.0 {
                best = (lo, hi + 1);
            }
        }
        if best.1 - best.0 < c.min_flies {
            continue;
        }
        members.truncate(best.1);
        members.drain(..best.0);
        let (distinct, rows) = cells.count(members.iter().map(|u| u.cell));
        // Across: the cluster's width, 4 median absolute deviations of its cells' columns
        // (the width of a uniform spread; robust to a few strays), is MIN_WIDTH_PX or more,
        // and so is that of their lateral positions in metres, `min_width`. Each cell once
        // (its flies' mean): flies pile on a few features, and counted one by one, a car
        // whose unique flies were mostly on one of its vertical edges (14 of 20 on hw-mock's
        // car, the rest on its other edge and plate) had the width of that edge, and was
        // dropped as one.
        let (mut us, mut xs) = ([0f32; 256], [0f32; 256]);
        let mut n = 0;
        for (pile, (su, sx)) in by_cell(members).zip(us.iter_mut().zip(xs.iter_mut())) {
            let mean = |f: fn(&Unique) -> f32| pile.iter().map(f).sum::<f32>() / pile.len() as f32;
            (*su, *sx) = (mean(|u| u.u), mean(|u| u.x));
            n += 1;
        }
        let across = 4.0 * mad(&mut us[..n]) >= MIN_WIDTH_PX
            && f64::from(4.0 * mad(&mut xs[..n])) >= c.min_width;
        if distinct >= c.min_cells && rows && across {
            return Some((to, distinct));
        }
    }
    members.clear();
    None
}

/// Where a cluster is along the path, each left-image cell counted once: the median of its
/// cells' median distances ([`super::Obstacle::centre`]); 0 for none. Reorders `members` (by
/// cell, then distance); `scratch` holds the cells' medians.
pub(super) fn cell_centre(members: &mut [Unique], scratch: &mut Vec<f32>) -> f32 {
    scratch.clear();
    scratch.extend(by_cell(members).map(|pile| pile[pile.len() / 2].along));
    if scratch.is_empty() {
        return 0.0;
    }
    let mid = scratch.len() / 2;
    *scratch.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// `members` by cell, then distance along the path, and each cell's flies in turn: the piles
/// the cell rules count once.
fn by_cell(members: &mut [Unique]) -> impl Iterator<Item = &[Unique]> {
    members.sort_unstable_by_key(|u| (u64::from(u.cell) << 32) | u64::from(ordered(u.along)));
    members.chunk_by(|a, b| a.cell == b.cell)
}

/// Step 4's last rule: whether a cluster's lowest fly is at most `max_bottom` above the road
/// (a cluster floating higher is no obstacle).
pub(super) fn reaches_the_road(members: &[Unique], c: &ObstacleConfig) -> bool {
    let bottom = members.iter().fold(f32::INFINITY, |b, u| b.min(u.h));
    f64::from(bottom) <= c.max_bottom
}
