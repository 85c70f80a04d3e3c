//! The road's spatial index: the nodes of the centre line binned in a grid of `GRID`-metre
//! cells, so that a point finds its nearest node without a search of them all.

use super::{GRID, GRID_MARGIN, Grid, Node};

impl Grid {
    pub(super) fn build(nodes: &[Node]) -> Self {
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
    pub(super) fn nearest(&self, nodes: &[Node], x: f64, z: f64) -> usize {
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
