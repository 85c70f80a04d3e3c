//! Ray-cast rendering and the sensor model.
//!
//! [`render`] is the reference: it asks the camera for every pixel's ray and traces it against
//! the whole world, no caching. [`CameraRenderer`] produces byte-identical output fast enough
//! for a live 30 fps stereo feed:
//! - each pixel's ray is computed once (rays are static for a calibrated camera);
//! - the static world (road, sky, roadside) is rendered once (once per frame for a moving
//!   vehicle, [`Scene::travelled`]: then each frame costs a full render, a few frames a second
//!   at 640x480, for offline replay rather than a live feed);
//! - the noise-free image of the last scene is cached (scenes are compared for equality, not
//!   hashed, so there are no collisions), and a changed scene only re-traces obstacles, and only
//!   in 16x16 pixel tiles whose bounding cone of rays can meet the obstacle's bounding sphere;
//! - per frame only the sensor noise runs: the clean image through the camera's gain/offset is
//!   cached with it, and each frame adds a precomputed field of Gaussian noise read from a
//!   per-frame offset (one saturating byte add per sample).

use crate::RayCamera;
use crate::noise::{GAUSS_TABLE_LEN, GOLDEN_GAMMA, gaussian_table, splitmix64};
use crate::world::{Ray, Sample, Scene, background, trace_scene};

/// Why a render could not be done. Rendering never panics; it reports these instead.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    #[error("RGB buffer holds {got} bytes but a {width}x{height} RGB8 image needs {expected}")]
    RgbBufferSize {
        expected: usize,
        got: usize,
        width: u32,
        height: u32,
    },
    #[error("depth buffer holds {got} values but a {width}x{height} image needs {expected}")]
    DepthBufferSize {
        expected: usize,
        got: usize,
        width: u32,
        height: u32,
    },
    #[error("camera size {width}x{height} is empty or too large to render")]
    BadCameraSize { width: u32, height: u32 },
    #[error("camera index {0} is unknown: 0 is the left camera, 1 the right")]
    UnknownCamera(u8),
    #[error("sensor model is invalid: {0}")]
    BadSensor(&'static str),
}

/// Linear radiometric response of one camera: `out = gain * in + offset` (grey levels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Response {
    pub gain: f64,
    pub offset: f64,
}

/// What the simulated image sensors do to the noise-free render.
///
/// Output = clamp(round(gain * clean + offset + noise), 0, 255) per channel, where noise is
/// Gaussian with standard deviation `noise_sigma` grey levels, independent per pixel, channel,
/// frame and camera, and a pure function of (`seed`, frame, camera index, sample index): the same
/// inputs always give the same bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    pub seed: u64,
    /// Standard deviation of the additive noise, grey levels (0 disables noise).
    pub noise_sigma: f64,
    /// Response of camera 0 (left) and camera 1 (right).
    pub response: [Response; 2],
}

impl Default for SensorModel {
    /// ~2 grey levels of noise; the right camera a little brighter than the left (gain 1.06,
    /// offset +5), as two real cameras of the same model differ: matchers must cope with it.
    fn default() -> Self {
        Self {
            seed: 0x5EED_F1E5,
            noise_sigma: 2.0,
            response: [
                Response {
                    gain: 1.0,
                    offset: 0.0,
                },
                Response {
                    gain: 1.06,
                    offset: 5.0,
                },
            ],
        }
    }
}

impl SensorModel {
    /// Identical, noiseless, unit-response cameras: the output is the clean render itself.
    pub fn ideal() -> Self {
        let unit = Response {
            gain: 1.0,
            offset: 0.0,
        };
        Self {
            seed: 0,
            noise_sigma: 0.0,
            response: [unit, unit],
        }
    }

    fn check(&self, camera_index: u8) -> Result<Response, RenderError> {
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return Err(RenderError::BadSensor(
                "noise_sigma must be finite and >= 0",
            ));
        }
        let r = *self
            .response
            .get(usize::from(camera_index))
            .ok_or(RenderError::UnknownCamera(camera_index))?;
        if !(r.gain.is_finite() && r.offset.is_finite()) {
            return Err(RenderError::BadSensor("gain and offset must be finite"));
        }
        Ok(r)
    }

    /// Hash key of one camera's frame: every (seed, frame, camera) gets its own noise stream.
    fn frame_key(&self, frame: u32, camera_index: u8) -> u64 {
        splitmix64(self.seed ^ splitmix64((u64::from(frame) << 8) | u64::from(camera_index)))
    }
}

/// The response `round(gain * v + offset)`, saturated to a byte, for every input level.
fn response_table(r: Response) -> [u8; 256] {
    let mut t = [0; 256];
    for (v, e) in t.iter_mut().enumerate() {
        *e = (r.gain * v as f64 + r.offset).round().clamp(0.0, 255.0) as u8;
    }
    t
}

/// Samples in a noise field: a power of two above the samples of a 1280x1024 RGB frame.
const FIELD_BITS: u32 = 22;
const FIELD_LEN: usize = 1 << FIELD_BITS;

/// A field of Gaussian noise in grey levels, N(0, sigma^2) rounded to integers and saturated
/// to +-127: quantiles of the normal distribution (a 4096-entry table) drawn by a fixed
/// splitmix64 stream. Built once per camera and sigma; each frame reads it from its own
/// offset (see [`apply_sensor`]).
fn noise_field(sigma: f64) -> Vec<i8> {
    let unit = gaussian_table();
    let mut levels = [0i8; GAUSS_TABLE_LEN];
    for (l, u) in levels.iter_mut().zip(unit.iter()) {
        *l = (u * sigma).round().clamp(-127.0, 127.0) as i8;
    }
    let mut field = vec![0i8; FIELD_LEN];
    let mut stream: u64 = 0x6e6f_6973_655f_6669; // "noise_fi": any fixed seed
    // Five 12-bit draws per hash.
    for five in field.chunks_mut(5) {
        let h = splitmix64(stream);
        stream = stream.wrapping_add(GOLDEN_GAMMA);
        for (k, f) in five.iter_mut().enumerate() {
            *f = levels[((h >> (12 * k)) as usize) & (GAUSS_TABLE_LEN - 1)];
        }
    }
    field
}

/// Applies the sensor noise to an image already through the camera's response (`sensed`):
/// sample `k` gets `field[(offset + k) mod FIELD_LEN]`, the offset drawn from `key` (every
/// seed, frame and camera gets its own). Frames see the same noise sequence shifted by a
/// random offset: independent for the flies, which never compare a frame with another at the
/// same offset difference, and one saturating byte add per sample (SIMD).
fn apply_sensor(sensed: &[u8], out: &mut [u8], field: Option<&[i8]>, key: u64) {
    let Some(field) = field else {
        out.copy_from_slice(sensed);
        return;
    };
    let mut at = (splitmix64(key) as usize) & (FIELD_LEN - 1);
    for (src, dst) in sensed.chunks(FIELD_LEN).zip(out.chunks_mut(FIELD_LEN)) {
        // At most two contiguous runs of the field per chunk (it wraps once).
        let first = src.len().min(FIELD_LEN - at);
        let (s0, s1) = src.split_at(first);
        let (d0, d1) = dst.split_at_mut(first);
        for (s, d, run) in [(s0, d0, at), (s1, d1, 0)] {
            for ((o, &c), &n) in d.iter_mut().zip(s).zip(&field[run..]) {
                *o = (i16::from(c) + i16::from(n)).clamp(0, 255) as u8;
            }
        }
        at = (at + src.len()) & (FIELD_LEN - 1);
    }
}

fn check_buffers(
    width: u32,
    height: u32,
    rgb: &[u8],
    depth: Option<&[f32]>,
) -> Result<usize, RenderError> {
    let pixels = pixel_count(width, height)?;
    let expected = pixels * 3;
    if rgb.len() != expected {
        return Err(RenderError::RgbBufferSize {
            expected,
            got: rgb.len(),
            width,
            height,
        });
    }
    if let Some(d) = depth
        && d.len() != pixels
    {
        return Err(RenderError::DepthBufferSize {
            expected: pixels,
            got: d.len(),
            width,
            height,
        });
    }
    Ok(pixels)
}

fn pixel_count(width: u32, height: u32) -> Result<usize, RenderError> {
    let n = usize::try_from(u64::from(width) * u64::from(height) * 3)
        .map_err(|_| RenderError::BadCameraSize { width, height })?;
    if n == 0 {
        return Err(RenderError::BadCameraSize { width, height });
    }
    Ok(n / 3)
}

/// A pixel's ray as stored: f32 halves the memory of the per-camera ray table, and both render
/// paths go through this rounding so they trace bit-identical rays.
#[derive(Debug, Clone, Copy)]
struct StoredRay {
    o: [f32; 3],
    d: [f32; 3],
}

impl StoredRay {
    const INVALID: Self = Self {
        o: [f32::NAN; 3],
        d: [f32::NAN; 3],
    };

    fn from_camera(cam: &dyn RayCamera, u: u32, v: u32) -> Self {
        let Some((o, d)) = cam.ray(f64::from(u), f64::from(v)) else {
            return Self::INVALID;
        };
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if n.is_nan() || n <= 0.0 || o.iter().chain(&d).any(|v| !v.is_finite()) {
            return Self::INVALID;
        }
        Self {
            o: o.map(|v| v as f32),
            d: d.map(|v| (v / n) as f32),
        }
    }

    #[inline]
    fn ray(&self) -> Option<Ray> {
        if self.d[0].is_nan() {
            return None;
        }
        Some(Ray {
            origin: self.o.map(f64::from),
            dir: self.d.map(f64::from),
        })
    }
}

/// Colour and depth of pixels whose ray the camera model cannot produce.
const INVALID_SAMPLE: Sample = Sample {
    rgb: [0, 0, 0],
    depth: f32::NAN,
    t: f64::NEG_INFINITY, // nothing is ever nearer, so obstacles never overwrite it
};

/// Renders one frame through `cam` without any caching: the reference implementation (and a
/// convenient one-shot render); use [`CameraRenderer`] for repeated frames.
///
/// `rgb` receives the image, RGB8 interleaved, row-major, `width * height * 3` bytes. `depth`, if
/// given (`width * height` values), receives the ground truth: the vehicle-frame z of the surface
/// point each pixel centre sees, `f32::INFINITY` for sky, NaN where the camera has no ray.
pub fn render(
    scene: &Scene,
    cam: &dyn RayCamera,
    sensor: &SensorModel,
    frame: u32,
    camera_index: u8,
    rgb: &mut [u8],
    mut depth: Option<&mut [f32]>,
) -> Result<(), RenderError> {
    let (width, height) = cam.size();
    check_buffers(width, height, rgb, depth.as_deref())?;
    let response = sensor.check(camera_index)?;
    let props = scene.props();
    let mut clean = vec![0u8; rgb.len()];
    let mut i = 0;
    for v in 0..height {
        for u in 0..width {
            let s = match StoredRay::from_camera(cam, u, v).ray() {
                Some(ray) => trace_scene(&ray, &props, scene),
                None => INVALID_SAMPLE,
            };
            clean[3 * i..3 * i + 3].copy_from_slice(&s.rgb);
            if let Some(d) = depth.as_deref_mut() {
                d[i] = s.depth;
            }
            i += 1;
        }
    }
    let response = response_table(response);
    let sensed: Vec<u8> = clean.iter().map(|&c| response[usize::from(c)]).collect();
    let field = (sensor.noise_sigma > 0.0).then(|| noise_field(sensor.noise_sigma));
    apply_sensor(
        &sensed,
        rgb,
        field.as_deref(),
        sensor.frame_key(frame, camera_index),
    );
    Ok(())
}

/// Pixel tiles share one culling cone.
const TILE: u32 = 16;

/// A tile of pixels and a cone containing all of its rays.
#[derive(Debug, Clone)]
struct Tile {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    apex: [f64; 3],
    /// Largest distance of a ray origin from `apex` (0 for a central camera).
    slack: f64,
    axis: [f64; 3],
    half_angle: f64,
    any_ray: bool,
    /// Component-wise bounds of the tile's ray origins and directions (for [`Tile::may_hit_box`]).
    o_min: [f64; 3],
    o_max: [f64; 3],
    d_min: [f64; 3],
    d_max: [f64; 3],
}

impl Tile {
    /// Whether any ray of the tile may meet the sphere (conservative).
    fn may_hit(&self, centre: [f64; 3], radius: f64) -> bool {
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
    fn may_hit_box(&self, min: [f64; 3], max: [f64; 3]) -> bool {
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

/// Fast repeated rendering through one static camera; see the module docs for how.
///
/// Output is byte-identical to [`render`] for the same inputs.
pub struct CameraRenderer {
    width: u32,
    height: u32,
    rays: Vec<StoredRay>,
    tiles: Vec<Tile>,
    /// The static world (road, sky, roadside) alone, the vehicle at pose `bg_pose`
    /// ([`pose_bits`]).
    bg_pose: [u64; 4],
    /// ... and with these obstacles fixed to the road ([`Scene::fixed`]).
    bg_fixed: Vec<crate::world::Obstacle>,
    bg_rgb: Vec<u8>,
    bg_depth: Vec<f32>,
    bg_t: Vec<f64>,
    /// Noise-free render of `cached_scene`.
    cached_scene: Option<Scene>,
    /// Per tile: whether the clean buffers differ from the background there (an obstacle was
    /// drawn). A scene change restores only those tiles instead of copying ~4.5 MB.
    dirty: Vec<bool>,
    clean_rgb: Vec<u8>,
    clean_depth: Vec<f32>,
    clean_t: Vec<f64>,
    /// `clean_rgb` through the camera response of `sensed_for` (gain and offset bits).
    sensed: Vec<u8>,
    sensed_for: Option<(u64, u64)>,
    /// Noise field for the sigma (bits) it was built for.
    noise: Option<(u64, Vec<i8>)>,
}

impl std::fmt::Debug for CameraRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CameraRenderer")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("cached_scene", &self.cached_scene)
            .finish_non_exhaustive()
    }
}

impl CameraRenderer {
    /// Precomputes every pixel's ray and renders the static world. Costs about one reference
    /// render (tenths of a second at 640x480); done once per camera.
    pub fn new(cam: &dyn RayCamera) -> Result<Self, RenderError> {
        let (width, height) = cam.size();
        let pixels = pixel_count(width, height)?;
        let mut rays = Vec::with_capacity(pixels);
        for v in 0..height {
            for u in 0..width {
                rays.push(StoredRay::from_camera(cam, u, v));
            }
        }
        let mut tiles = Vec::new();
        for y0 in (0..height).step_by(TILE as usize) {
            for x0 in (0..width).step_by(TILE as usize) {
                let (x1, y1) = ((x0 + TILE).min(width), (y0 + TILE).min(height));
                tiles.push(tile_cone(&rays, width, x0, y0, x1, y1));
            }
        }
        let mut r = Self {
            width,
            height,
            rays,
            tiles,
            bg_pose: pose_bits(&Scene::default()),
            bg_fixed: Vec::new(),
            bg_rgb: vec![0; pixels * 3],
            bg_depth: vec![0.0; pixels],
            bg_t: vec![0.0; pixels],
            cached_scene: None,
            dirty: Vec::new(),
            clean_rgb: Vec::new(),
            clean_depth: Vec::new(),
            clean_t: Vec::new(),
            sensed: Vec::new(),
            sensed_for: None,
            noise: None,
        };
        r.render_background(&Scene::default());
        r.dirty = vec![false; r.tiles.len()];
        r.clean_rgb.clone_from(&r.bg_rgb);
        r.clean_depth.clone_from(&r.bg_depth);
        r.clean_t.clone_from(&r.bg_t);
        Ok(r)
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn render_background(&mut self, scene: &Scene) {
        self.bg_pose = pose_bits(scene);
        self.bg_fixed.clone_from(&scene.fixed);
        let props = scene.props();
        let bounds: Vec<_> = props
            .iter()
            .map(|p| {
                p.bounding_sphere()
                    .zip(p.aabb())
                    .map(|b| in_vehicle_frame(scene, b))
            })
            .collect();
        let mut candidates = Vec::with_capacity(props.len());
        for tile in &self.tiles {
            candidates.clear();
            candidates.extend(props.iter().zip(&bounds).filter_map(|(p, b)| {
                let ((c, r), (lo, hi)) = (*b)?;
                (tile.may_hit(c, r) && tile.may_hit_box(lo, hi)).then_some(*p)
            }));
            for v in tile.y0..tile.y1 {
                for u in tile.x0..tile.x1 {
                    let i = v as usize * self.width as usize + u as usize;
                    let s = match self.rays[i].ray() {
                        Some(ray) => background(&ray, &candidates, scene),
                        None => INVALID_SAMPLE,
                    };
                    self.bg_rgb[3 * i..3 * i + 3].copy_from_slice(&s.rgb);
                    self.bg_depth[i] = s.depth;
                    self.bg_t[i] = s.t;
                }
            }
        }
    }

    /// The noise-free render of `scene` and its ground-truth depth (see [`render`]), re-traced
    /// only if the scene differs from the last one.
    pub fn clean(&mut self, scene: &Scene) -> (&[u8], &[f32]) {
        if self.cached_scene.as_ref() != Some(scene) {
            self.trace_scene(scene);
        }
        (&self.clean_rgb, &self.clean_depth)
    }

    fn trace_scene(&mut self, scene: &Scene) {
        if pose_bits(scene) != self.bg_pose || scene.fixed != self.bg_fixed {
            // The vehicle moved: a new background, and every tile restored from it.
            self.render_background(scene);
            self.dirty.fill(true);
        }
        let w = self.width as usize;
        for (tile, dirty) in self.tiles.iter().zip(&mut self.dirty) {
            if !std::mem::take(dirty) {
                continue;
            }
            for v in tile.y0 as usize..tile.y1 as usize {
                let row = v * w + tile.x0 as usize..v * w + tile.x1 as usize;
                let rgb = 3 * row.start..3 * row.end;
                self.clean_rgb[rgb.clone()].copy_from_slice(&self.bg_rgb[rgb]);
                self.clean_depth[row.clone()].copy_from_slice(&self.bg_depth[row.clone()]);
                self.clean_t[row.clone()].copy_from_slice(&self.bg_t[row]);
            }
        }
        // Obstacle by obstacle with a distance buffer: the nearest wins, ties to the earlier
        // one, exactly as in `trace`.
        for o in &scene.obstacles {
            let Some(((centre, radius), (lo, hi))) = o.bounding_sphere().zip(o.aabb()) else {
                continue; // invalid: never drawn, as in `trace`
            };
            let tiles = self.tiles.iter().zip(&mut self.dirty);
            for (tile, dirty) in
                tiles.filter(|(t, _)| t.may_hit(centre, radius) && t.may_hit_box(lo, hi))
            {
                *dirty = true;
                for v in tile.y0..tile.y1 {
                    for u in tile.x0..tile.x1 {
                        let i = v as usize * self.width as usize + u as usize;
                        let Some(ray) = self.rays[i].ray() else {
                            continue;
                        };
                        let Some(hit) = o.intersect_valid(&ray) else {
                            continue;
                        };
                        if hit.t < self.clean_t[i] {
                            let s = o.shade(&ray, &hit);
                            self.clean_rgb[3 * i..3 * i + 3].copy_from_slice(&s.rgb);
                            self.clean_depth[i] = s.depth;
                            self.clean_t[i] = s.t;
                        }
                    }
                }
            }
        }
        self.cached_scene = Some(scene.clone());
        self.sensed_for = None;
    }

    /// Renders one frame of `scene` as seen by camera `camera_index` (0 left, 1 right) into
    /// `rgb` and optionally `depth`; same contract and output as [`render`].
    pub fn render(
        &mut self,
        scene: &Scene,
        sensor: &SensorModel,
        frame: u32,
        camera_index: u8,
        rgb: &mut [u8],
        depth: Option<&mut [f32]>,
    ) -> Result<(), RenderError> {
        check_buffers(self.width, self.height, rgb, depth.as_deref())?;
        let response = sensor.check(camera_index)?;
        if self.cached_scene.as_ref() != Some(scene) {
            self.trace_scene(scene);
        }
        let response_bits = (response.gain.to_bits(), response.offset.to_bits());
        if self.sensed_for != Some(response_bits) {
            let table = response_table(response);
            self.sensed.clear();
            self.sensed
                .extend(self.clean_rgb.iter().map(|&c| table[usize::from(c)]));
            self.sensed_for = Some(response_bits);
        }
        let sigma_bits = sensor.noise_sigma.to_bits();
        let field = if sensor.noise_sigma > 0.0 {
            if self
                .noise
                .as_ref()
                .is_none_or(|(bits, _)| *bits != sigma_bits)
            {
                self.noise = Some((sigma_bits, noise_field(sensor.noise_sigma)));
            }
            self.noise.as_ref().map(|(_, t)| t.as_slice())
        } else {
            None
        };
        apply_sensor(
            &self.sensed,
            rgb,
            field,
            sensor.frame_key(frame, camera_index),
        );
        if let Some(d) = depth {
            d.copy_from_slice(&self.clean_depth);
        }
        Ok(())
    }
}

/// The vehicle's pose in `scene`, bit for bit: a background is rendered again when it moves.
fn pose_bits(scene: &Scene) -> [u64; 4] {
    [
        scene.travelled.to_bits(),
        scene.lateral.to_bits(),
        scene.heading.to_bits(),
        scene.bend.to_bits(),
    ]
}

/// A prop's culling bounds: its bounding sphere (centre, radius) and axis-aligned box (low,
/// high corners).
type Bounds = (([f64; 3], f64), ([f64; 3], [f64; 3]));

/// A prop's culling bounds in the vehicle frame: as they are for a vehicle that is not posed,
/// else the sphere moved and the box around the turned one.
fn in_vehicle_frame(scene: &Scene, bounds: Bounds) -> Bounds {
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
fn tile_cone(rays: &[StoredRay], width: u32, x0: u32, y0: u32, x1: u32, y1: u32) -> Tile {
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
