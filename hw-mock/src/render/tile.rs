//! Culling: pixel tiles that share one cone of rays, and the props' bounds in the vehicle
//! frame they are tested against.

use super::StoredRay;
use crate::world::{Ray, Scene};

/// Pixel tiles share one culling cone.
pub(super) const TILE: u32 = 16;

/// A tile of pixels and a cone containing all of its rays.
#[derive(Debug, Clone)]
pub(super) struct Tile {
    pub(super) x0: u32,
    pub(super) y0: u32,
    pub(super) x1: u32,
    pub(super) y1: u32,
    pub(super) apex: [f64; 3],
    /// Largest distance of a ray origin from `apex` (0 for a central camera).
    pub(super) slack: f64,
    pub(super) axis: [f64; 3],
    pub(super) half_angle: f64,
    pub(super) any_ray: bool,
    /// Component-wise bounds of the tile's ray origins and directions (for [`Tile::may_hit_box`]).
    pub(super) o_min: [f64; 3],
    pub(super) o_max: [f64; 3],
    pub(super) d_min: [f64; 3],
    pub(super) d_max: [f64; 3],
}

impl Tile {
    /// Whether any ray of the tile may meet the sphere (conservative).
    pub(super) fn may_hit(&self, centre: [f64; 3], radius: f64) -> bool {
        if !self.any_ray {
            return false;
        }
        // Moving the apex by up to `slack` is covered by growing the sphere by as much.
        let r = radius + self.slack;
        let v = [
            centre[0] - self.apex[0],
            centre[1] - self.apex[1],
            centre[2] - self.apex[2],
        ];
        let d = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if d <= r {
            return true;
        }
        let cos_phi = (v[0] * self.axis[0] + v[1] * self.axis[1] + v[2] * self.axis[2]) / d;
        let phi = cos_phi.clamp(-1.0, 1.0).acos();
        // NaN (a non-finite sphere) compares false: such an obstacle is never drawn, as in the
        // reference, which never hits an invalid obstacle either.
        phi <= self.half_angle + (r / d).asin() + 1e-9
    }
}

impl Tile {
    /// Whether any ray of the tile may meet the axis-aligned box (conservative): interval
    /// arithmetic on the slab test over the tile's bounds of origins and directions. Much tighter
    /// than the bounding sphere for long or thin objects (cars seen from behind, walls, poles).
    pub(super) fn may_hit_box(&self, min: [f64; 3], max: [f64; 3]) -> bool {
        if !self.any_ray {
            return false;
        }
        // Bounds over the tile of the entry and exit parameters, intersected over the axes.
        let mut enter_lo = 0.0f64;
        let mut exit_hi = f64::INFINITY;
        for a in 0..3 {
            let (d1, d2) = (self.d_min[a], self.d_max[a]);
            // Ranges of (min - o) and (max - o) over the tile's origins.
            let near = if d1 > 0.0 {
                min[a] - self.o_max[a]
            } else {
                self.o_min[a] - max[a]
            };
            let far = if d1 > 0.0 {
                max[a] - self.o_min[a]
            } else {
                self.o_max[a] - min[a]
            };
            let (lo_d, hi_d) = if d1 > 0.0 {
                (d1, d2)
            } else if d2 < 0.0 {
                (-d2, -d1)
            } else {
                // Some ray may run parallel to this slab: no bound from this axis.
                continue;
            };
            // Smallest entry: near / (largest |d|) if near >= 0, else near / (smallest |d|).
            let enter = if near >= 0.0 {
                near / hi_d
            } else {
                near / lo_d
            };
            let exit = if far >= 0.0 { far / lo_d } else { far / hi_d };
            enter_lo = enter_lo.max(enter);
            exit_hi = exit_hi.min(exit);
        }
        // NaN bounds (impossible for valid obstacles) compare false and cull.
        enter_lo <= exit_hi
    }
}

/// A prop's culling bounds: its bounding sphere (centre, radius) and axis-aligned box (low,
/// high corners).
pub(super) type Bounds = (([f64; 3], f64), ([f64; 3], [f64; 3]));

/// A prop's culling bounds in the vehicle frame: as they are for a vehicle that is not posed,
/// else the sphere moved and the box around the turned one.
pub(super) fn in_vehicle_frame(scene: &Scene, bounds: Bounds) -> Bounds {
    if !scene.is_posed() {
        return bounds;
    }
    let ((centre, radius), (lo, hi)) = bounds;
    let (mut vlo, mut vhi) = (
        [f64::INFINITY, lo[1], f64::INFINITY],
        [f64::NEG_INFINITY, hi[1], f64::NEG_INFINITY],
    );
    for x in [lo[0], hi[0]] {
        for z in [lo[2], hi[2]] {
            let p = scene.vehicle_point([x, 0.0, z]);
            for a in [0, 2] {
                vlo[a] = vlo[a].min(p[a]);
                vhi[a] = vhi[a].max(p[a]);
            }
        }
    }
    ((scene.vehicle_point(centre), radius), (vlo, vhi))
}

/// The cone (apex, axis, half-angle) containing every valid ray of a tile.
pub(super) fn tile_cone(
    rays: &[StoredRay],
    width: u32,
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
) -> Tile {
    let mut sum_o = [0.0; 3];
    let mut sum_d = [0.0; 3];
    let mut n = 0usize;
    let each = |f: &mut dyn FnMut(&Ray)| {
        for v in y0..y1 {
            for u in x0..x1 {
                if let Some(r) = rays[v as usize * width as usize + u as usize].ray() {
                    f(&r);
                }
            }
        }
    };
    each(&mut |r| {
        for a in 0..3 {
            sum_o[a] += r.origin[a];
            sum_d[a] += r.dir[a];
        }
        n += 1;
    });
    let mut tile = Tile {
        x0,
        y0,
        x1,
        y1,
        apex: [0.0; 3],
        slack: 0.0,
        axis: [0.0, 0.0, 1.0],
        half_angle: std::f64::consts::PI,
        any_ray: n > 0,
        o_min: [0.0; 3],
        o_max: [0.0; 3],
        d_min: [0.0; 3],
        d_max: [0.0; 3],
    };
    if n == 0 {
        return tile;
    }
    let apex = sum_o.map(|v| v / n as f64);
    let len = (sum_d[0] * sum_d[0] + sum_d[1] * sum_d[1] + sum_d[2] * sum_d[2]).sqrt();
    let axis_ok = len > 1e-9 * n as f64;
    let axis = if axis_ok {
        sum_d.map(|v| v / len)
    } else {
        [0.0, 0.0, 1.0]
    };
    let (mut slack, mut half): (f64, f64) = (0.0, 0.0);
    let (mut o_min, mut o_max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let (mut d_min, mut d_max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    each(&mut |r| {
        for a in 0..3 {
            o_min[a] = o_min[a].min(r.origin[a]);
            o_max[a] = o_max[a].max(r.origin[a]);
            d_min[a] = d_min[a].min(r.dir[a]);
            d_max[a] = d_max[a].max(r.dir[a]);
        }
        let dv = [
            r.origin[0] - apex[0],
            r.origin[1] - apex[1],
            r.origin[2] - apex[2],
        ];
        slack = slack.max((dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]).sqrt());
        let c = r.dir[0] * axis[0] + r.dir[1] * axis[1] + r.dir[2] * axis[2];
        half = half.max(c.clamp(-1.0, 1.0).acos());
    });
    // Pixel rays are exact, the bounds are over them: no margin is needed for the rays
    // themselves, a small one absorbs rounding in the interval test.
    let pad = |v: [f64; 3], k: f64| v.map(|x| x + k * (1e-12 + 1e-9 * x.abs()));
    tile.o_min = pad(o_min, -1.0);
    tile.o_max = pad(o_max, 1.0);
    tile.d_min = pad(d_min, -1.0);
    tile.d_max = pad(d_max, 1.0);
    tile.apex = apex;
    // Margins absorb f64 rounding in the cone test.
    tile.slack = slack * (1.0 + 1e-9) + 1e-9;
    tile.axis = axis;
    tile.half_angle = if axis_ok {
        half + 1e-7
    } else {
        std::f64::consts::PI
    };
    tile
}
