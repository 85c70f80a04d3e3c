//! Where new flies come from: uniform over the left image and uniform in inverse depth (the
//! quantity stereo resolves uniformly), inside the search range and the road region of
//! interest, kept when both cameras see them (see the engine's module docs).

use super::EngineError;
use super::params::EngineParams;
use super::projector::Projector;
use crate::frame::BLOCK;
use crate::geometry::StereoRig;
use rand::Rng;

/// Left-camera sampling domain for new flies.
#[derive(Debug, Clone)]
pub(super) struct Sampler {
    /// Undistorted normalised bounds of the left image.
    xn: (f32, f32),
    yn: (f32, f32),
    /// Inverse depth range.
    pub(super) inv_depth: (f32, f32),
    /// Undistorted normalised bounds (x0, x1, y0, y1) of each 16x16 block of the left image.
    pub(super) blocks: Vec<[f32; 4]>,
    /// Road region of interest as (min height, max height) above `road`: new flies are drawn
    /// inside it.
    heights: Option<(f32, f32)>,
    /// The road the heights are measured from: `[height, slope_z, slope_x]`
    /// ([`crate::road_plane::RoadPlane`]).
    pub(super) road: [f32; 3],
    /// Vehicle from left camera: `p_vehicle = m * p_cam + c`.
    m: [f32; 9],
    c: [f32; 3],
    /// The corridor the corridor immigrants scan ([`super::Engine::set_corridor`]).
    pub(super) corridor: Option<Corridor>,
}

/// The band along the vehicle's path where an obstacle counts (vehicle frame, metres; heights
/// above the road): the corridor immigrants probe depths only where their ray crosses it
/// ([`super::EngineParams::corridor_immigrants`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corridor {
    /// Half-width either side of the path.
    pub half_width: f32,
    /// Lowest and highest point above the road.
    pub min_height: f32,
    pub max_height: f32,
    /// How far ahead.
    pub max_distance: f32,
    /// The path's curvature, 1/m, positive turning left ([`crate::path::PredictedPath`]);
    /// 0: the straight box ahead.
    pub curvature: f32,
    /// Beside it, out to this far off the path either side, the watch immigrants scan
    /// ([`super::EngineParams::watch_immigrants`]); at most `half_width`: none.
    pub watch_half_width: f32,
}

impl Corridor {
    /// The vehicle-frame `(x, z)` of the point `along` metres along the path and `offset`
    /// metres right of it: [`crate::path::PredictedPath::point_at`] in the engine's f32.
    #[inline]
    fn at(&self, along: f32, offset: f32) -> (f32, f32) {
        let k = self.curvature;
        if k == 0.0 {
            return (offset, along);
        }
        // The arc's point (left bends towards -x) plus the offset along its right normal.
        let (sin, cos) = (k * along).sin_cos();
        (-(1.0 - cos) / k + offset * cos, sin / k + offset * sin)
    }
}

/// Attempts to draw a fly visible in both images before giving up on that slot.
pub(super) const SAMPLE_ATTEMPTS: usize = 16;

/// A uniform f32 in [0, 1) from 24 random bits.
#[inline]
pub(super) fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[inline]
pub(super) fn lerp((a, b): (f32, f32), t: f32) -> f32 {
    a + (b - a) * t
}

impl Sampler {
    /// Whether a new fly at `p` lies in the region of interest (always true without one).
    #[inline]
    pub(super) fn in_roi(&self, p: &[f32; 3]) -> bool {
        let h = p[1] - (self.road[0] + self.road[1] * p[2] + self.road[2] * p[0]);
        self.heights.is_none_or(|(lo, hi)| h >= lo && h <= hi)
    }

    #[inline]
    pub(super) fn point<R: Rng>(&self, xn: f32, yn: f32, rng: &mut R) -> [f32; 3] {
        self.at(xn, yn, 1.0 / lerp(self.inv_depth, unit_f32(rng.next_u32())))
    }

    /// A point in left-image block `b` (uniform over its normalised bounds), uniform in inverse
    /// depth.
    #[inline]
    pub(super) fn candidate_in_block<R: Rng>(&self, rng: &mut R, b: usize) -> [f32; 3] {
        match self.in_block(rng, b) {
            Some((xn, yn)) => self.point(xn, yn, rng),
            None => self.candidate(rng),
        }
    }

    /// A point of left-image block `b`, uniform over its normalised bounds.
    #[inline]
    pub(super) fn in_block<R: Rng>(&self, rng: &mut R, b: usize) -> Option<(f32, f32)> {
        let &[x0, x1, y0, y1] = self.blocks.get(b)?;
        let r = rng.next_u64();
        Some((
            lerp((x0, x1), unit_f32(r as u32)),
            lerp((y0, y1), unit_f32((r >> 32) as u32)),
        ))
    }

    /// The inverse-depth range of the left camera's ray through normalised `(xn, yn)` inside
    /// the search range and the road region of interest; `None` when no point qualifies.
    #[inline]
    pub(super) fn ray_range(&self, xn: f32, yn: f32) -> Option<(f32, f32)> {
        self.ray_range_in(xn, yn, self.inv_depth, self.heights, self.road)
    }

    /// The inverse-depth range of the ray through `(xn, yn)` within `inv_depth` and, if given,
    /// the `heights` above `road`; `None` when no point qualifies.
    #[inline]
    pub(super) fn ray_range_in(
        &self,
        xn: f32,
        yn: f32,
        inv_depth: (f32, f32),
        heights: Option<(f32, f32)>,
        road: [f32; 3],
    ) -> Option<(f32, f32)> {
        let (mut near, mut far) = (1.0 / inv_depth.1, 1.0 / inv_depth.0);
        if let Some((lo, hi)) = heights {
            // Height above the road along the ray: h(d) = c + d * k, where y(d) = c_y + d k_y,
            // x(d), z(d) likewise, and the road rises by slope_z z + slope_x x.
            let along = |row: usize| self.m[row] * xn + self.m[row + 1] * yn + self.m[row + 2];
            let [r0, rz, rx] = road;
            let k = along(3) - rz * along(6) - rx * along(0);
            let c = self.c[1] - r0 - rz * self.c[2] - rx * self.c[0];
            if k.abs() < 1e-6 {
                if c < lo || c > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - c) / k, (hi - c) / k);
                near = near.max(a.min(b));
                far = far.min(a.max(b));
            }
        }
        (near < far).then(|| (1.0 / far, 1.0 / near))
    }

    /// The inverse-depth range of the ray through `(xn, yn)` inside the search range and
    /// `corridor` (its width, its heights above the road, its length) near `drawn_along`
    /// metres along its path (where the ray's point was drawn); `None` when the ray misses it.
    pub(super) fn ray_range_in_corridor(
        &self,
        xn: f32,
        yn: f32,
        corridor: &Corridor,
        drawn_along: f32,
    ) -> Option<(f32, f32)> {
        let heights = Some((corridor.min_height, corridor.max_height));
        let (lo, hi) = self.ray_range_in(xn, yn, self.inv_depth, heights, self.road)?;
        let (mut near, mut far) = (1.0 / hi, 1.0 / lo);
        let along = |row: usize| self.m[row] * xn + self.m[row + 1] * yn + self.m[row + 2];
        // Across: the offset from the path, A + d B along the ray, within the half-width. On
        // a curved path, from the path's tangent where the point was drawn (`along`): the
        // probes lie around that point's depth.
        let (mut a0, mut b0) = (self.c[0], along(0));
        if corridor.curvature != 0.0 {
            let (px, pz) = corridor.at(drawn_along, 0.0);
            let (sin, cos) = (corridor.curvature * drawn_along).sin_cos();
            a0 = cos * (self.c[0] - px) + sin * (self.c[2] - pz);
            b0 = cos * along(0) + sin * along(6);
        }
        let hw = corridor.half_width;
        if b0.abs() < 1e-6 {
            if a0.abs() > hw {
                return None;
            }
        } else {
            let (a, b) = ((-hw - a0) / b0, (hw - a0) / b0);
            near = near.max(a.min(b));
            far = far.min(a.max(b));
        }
        // Ahead: z(d) = c_z + d k_z no farther than its length.
        let kz = along(6);
        if kz > 1e-6 {
            far = far.min((corridor.max_distance - self.c[2]) / kz);
        } else if self.c[2] > corridor.max_distance {
            return None;
        }
        (near < far).then(|| (1.0 / far, 1.0 / near))
    }

    /// A vehicle-frame point uniform in the corridor (across the path, in height above the
    /// road, and along it from the search range's nearest depth), with its distance along the
    /// path; `None` without a corridor. `beside`: in the band watched either side of it
    /// instead (`None` without one).
    #[inline]
    pub(super) fn corridor_point<R: Rng>(
        &self,
        rng: &mut R,
        beside: bool,
    ) -> Option<([f32; 3], f32)> {
        let c = self.corridor?;
        let r = rng.next_u64();
        let offset = if beside {
            if c.watch_half_width <= c.half_width {
                return None;
            }
            // Either side, uniform across the band: the sign from the draw's lowest bit.
            let u = unit_f32(r as u32);
            let side = if r & 1 == 0 { 1.0 } else { -1.0 };
            side * lerp((c.half_width, c.watch_half_width), u)
        } else {
            lerp((-c.half_width, c.half_width), unit_f32(r as u32))
        };
        let along = lerp(
            (1.0 / self.inv_depth.1, c.max_distance),
            unit_f32((r >> 32) as u32),
        );
        let (x, z) = c.at(along, offset);
        let h = lerp((c.min_height, c.max_height), unit_f32(rng.next_u32()));
        let [r0, rz, rx] = self.road;
        Some(([x, r0 + rz * z + rx * x + h, z], along))
    }

    /// Depth of vehicle-frame point `p` along the left camera's optical axis.
    #[inline]
    pub(super) fn depth_of(&self, p: &[f32; 3]) -> f32 {
        // p = m cam + c, m a rotation: cam = m^T (p - c); the depth is its z.
        let d = [p[0] - self.c[0], p[1] - self.c[1], p[2] - self.c[2]];
        self.m[2] * d[0] + self.m[5] * d[1] + self.m[8] * d[2]
    }

    /// The point `scale` times as far from the left camera as `p`, on the same ray.
    #[inline]
    pub(super) fn along_ray(&self, p: &[f32; 3], scale: f32) -> [f32; 3] {
        let c = &self.c;
        [
            c[0] + (p[0] - c[0]) * scale,
            c[1] + (p[1] - c[1]) * scale,
            c[2] + (p[2] - c[2]) * scale,
        ]
    }

    /// The point at depth `d` along the left camera's ray through normalised `(xn, yn)`.
    #[inline]
    pub(super) fn at(&self, xn: f32, yn: f32, d: f32) -> [f32; 3] {
        let cam = [xn * d, yn * d, d];
        let m = &self.m;
        [
            m[0] * cam[0] + m[1] * cam[1] + m[2] * cam[2] + self.c[0],
            m[3] * cam[0] + m[4] * cam[1] + m[5] * cam[2] + self.c[1],
            m[6] * cam[0] + m[7] * cam[1] + m[8] * cam[2] + self.c[2],
        ]
    }

    /// A point uniform over the left image's normalised bounds and uniform in inverse depth
    /// (possibly outside one of the images: callers check).
    #[inline]
    pub(super) fn candidate<R: Rng>(&self, rng: &mut R) -> [f32; 3] {
        let r = rng.next_u64();
        let xn = lerp(self.xn, unit_f32(r as u32));
        let yn = lerp(self.yn, unit_f32((r >> 32) as u32));
        self.point(xn, yn, rng)
    }

    /// Advances `rng` past the draws of one [`Sampler::candidate`] (tested to agree).
    #[inline]
    pub(super) fn skip_candidate<R: Rng>(rng: &mut R) {
        rng.next_u64();
        rng.next_u32();
    }

    pub(super) fn new(rig: &StereoRig, params: &EngineParams) -> Result<Self, EngineError> {
        let cam = &rig.left;
        let (w, h) = (cam.width() as f64, cam.height() as f64);
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        // The undistorted image of the border bounds the left field of view.
        let steps = 64;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            for (u, v) in [
                (t * (w - 1.0), 0.0),
                (t * (w - 1.0), h - 1.0),
                (0.0, t * (h - 1.0)),
                (w - 1.0, t * (h - 1.0)),
            ] {
                let (xn, yn) = cam
                    .normalised_from_pixel(u, v)
                    .ok_or(EngineError::NotInvertible)?;
                x0 = x0.min(xn);
                x1 = x1.max(xn);
                y0 = y0.min(yn);
                y1 = y1.max(yn);
            }
        }
        let cols = (w as usize).div_ceil(BLOCK);
        let rows = (h as usize).div_ceil(BLOCK);
        let mut blocks = Vec::with_capacity(cols * rows);
        for by in 0..rows {
            for bx in 0..cols {
                let (u0, v0) = ((bx * BLOCK) as f64 - 0.5, (by * BLOCK) as f64 - 0.5);
                let (u1, v1) = (
                    (u0 + BLOCK as f64).min(w - 0.5),
                    (v0 + BLOCK as f64).min(h - 0.5),
                );
                let (mut b, mut ok) = ([f32::MAX, f32::MIN, f32::MAX, f32::MIN], true);
                for (u, v) in [(u0, v0), (u1, v0), (u0, v1), (u1, v1)] {
                    match cam.normalised_from_pixel(u, v) {
                        Some((xn, yn)) => {
                            b = [
                                b[0].min(xn as f32),
                                b[1].max(xn as f32),
                                b[2].min(yn as f32),
                                b[3].max(yn as f32),
                            ]
                        }
                        None => ok = false,
                    }
                }
                // A block the model cannot invert falls back to the whole image.
                blocks.push(if ok {
                    b
                } else {
                    [x0 as f32, x1 as f32, y0 as f32, y1 as f32]
                });
            }
        }
        let far = Self::far(params);
        let heights = params
            .roi
            .map(|roi| (roi.min_height as f32, roi.max_height as f32));
        let origin = cam.vehicle_from_camera(&nalgebra::Point3::origin());
        let ex = cam.vehicle_from_camera(&nalgebra::Point3::new(1.0, 0.0, 0.0)) - origin;
        let ey = cam.vehicle_from_camera(&nalgebra::Point3::new(0.0, 1.0, 0.0)) - origin;
        let ez = cam.vehicle_from_camera(&nalgebra::Point3::new(0.0, 0.0, 1.0)) - origin;
        Ok(Self {
            xn: (x0 as f32, x1 as f32),
            yn: (y0 as f32, y1 as f32),
            inv_depth: ((1.0 / far) as f32, (1.0 / params.min_depth) as f32),
            blocks,
            heights,
            road: [0.0; 3],
            m: [
                ex.x as f32,
                ey.x as f32,
                ez.x as f32,
                ex.y as f32,
                ey.y as f32,
                ez.y as f32,
                ex.z as f32,
                ey.z as f32,
                ez.z as f32,
            ],
            c: [origin.x as f32, origin.y as f32, origin.z as f32],
            corridor: None,
        })
    }

    /// The farthest depth new flies are drawn at: with a road region of interest, within it
    /// (flies outside it get the penalised fitness anyway, so drawing them there only wastes
    /// evaluations).
    fn far(params: &EngineParams) -> f64 {
        match &params.roi {
            Some(roi) => params.max_depth.min(roi.max_ahead),
            None => params.max_depth,
        }
    }

    /// Draws new flies up to `params`' farthest depth from now on.
    pub(super) fn set_far(&mut self, params: &EngineParams) {
        self.inv_depth.0 = (1.0 / Self::far(params)) as f32;
    }

    /// A new random fly (see the module docs); the flag says whether both cameras see it.
    pub(super) fn sample_fly<R: Rng>(
        &self,
        rng: &mut R,
        left: &Projector,
        right: &Projector,
    ) -> ([f32; 3], bool) {
        let mut p = [0.0; 3];
        for _ in 0..SAMPLE_ATTEMPTS {
            p = self.candidate(rng);
            if self.in_roi(&p)
                && left.project(p[0], p[1], p[2]).is_some()
                && right.project(p[0], p[1], p[2]).is_some()
            {
                return (p, true);
            }
        }
        (p, false)
    }
}
