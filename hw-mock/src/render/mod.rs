//! Ray-cast rendering and the sensor model.
//!
//! [`render`] is the reference: it asks the camera for every pixel's ray and traces it against
//! the whole world, no caching. [`CameraRenderer`] produces byte-identical output fast enough
//! for a live 30 fps stereo feed:
//! - each pixel's ray is computed once (rays are static for a calibrated camera);
//! - the static world (road, sky, roadside) is rendered once (once per frame for a moving
//!   vehicle, [`Scene::travelled`]: then each frame costs a full render of it, 5-14 stereo
//!   pairs a second at 640x480 on one core, for offline replay rather than a live feed; see
//!   `hw-mock/README.md` and the `render_bench` example). That render looks for props only
//!   nearer than the road, tries a bent or laid prop only if the ray meets its padded box
//!   (and a laid one cell by cell), with what rays share computed once a frame
//!   ([`crate::world::Prepared`], [`crate::world::Frame`]), and shades the road only where no
//!   prop hides it; on the straight road each pixel's road point, footprint and sky are kept
//!   ([`crate::world::Still`]), leaving only the textures to evaluate;
//! - the noise-free image of the last scene is cached (scenes are compared for equality, not
//!   hashed, so there are no collisions), and a changed scene only re-traces obstacles, and only
//!   in 16x16 pixel tiles whose bounding cone of rays can meet the obstacle's bounding sphere;
//! - per frame only the sensor noise runs: the clean image through the camera's gain/offset is
//!   cached with it, and each frame adds a precomputed field of Gaussian noise read from a
//!   per-frame offset (one saturating byte add per sample).

use crate::RayCamera;
use crate::world::profile::cell_boxes;
use crate::world::{
    Frame, Prepared, Ray, Sample, Scene, Still, background_still, background_valid, cull_bounds,
    trace_scene,
};

mod sensor_model;
mod tile;

pub use sensor_model::{Response, SensorModel};
use sensor_model::{apply_sensor, noise_field, response_table};
use tile::{Bounds, TILE, Tile, in_vehicle_frame, tile_cone};

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
    bg_pose: [u64; 5],
    /// ... and with these obstacles fixed to the road ([`Scene::fixed`]).
    bg_fixed: Vec<crate::world::Obstacle>,
    bg_rgb: Vec<u8>,
    bg_depth: Vec<f32>,
    bg_t: Vec<f64>,
    /// Per pixel, what it sees of road or sky on the straight road's centre line, whatever
    /// the distance driven ([`Still`]): built by the first such scene that has moved (none for
    /// a camera that never drives: 80 bytes a pixel, 25 MB at 640x480).
    still: Vec<Still>,
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
            still: Vec::new(),
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
        // Per prop: its culling bounds in the vehicle frame, and what its rays share.
        let cells: Vec<_> = props.iter().map(cell_boxes).collect();
        let bounds: Vec<_> = props
            .iter()
            .zip(&cells)
            .map(|(p, cells)| {
                let aabb = p.aabb()?;
                // Each piece's culling bounds in the vehicle frame, and its box in the prop's.
                let culls: Vec<_> = cull_bounds(p)
                    .into_iter()
                    .map(|(sphere, aabb)| (in_vehicle_frame(scene, (sphere, aabb)), aabb))
                    .collect();
                Some((culls, Prepared::new(p, aabb, cells)))
            })
            .collect();
        let frame = Frame::of(scene);
        let straight = !scene.is_posed();
        if straight && scene.travelled != 0.0 && self.still.is_empty() {
            // An invalid ray's entry is never read.
            let sky = |r: &StoredRay| {
                r.ray()
                    .map_or(Still::Sky(INVALID_SAMPLE), |r| Still::new(&r))
            };
            self.still = self.rays.iter().map(sky).collect();
        }
        let still = straight && !self.still.is_empty();
        let mut candidates = Vec::with_capacity(props.len());
        let mut chosen = Vec::with_capacity(props.len());
        let mut pieces = Vec::new();
        for tile in &self.tiles {
            candidates.clear();
            chosen.clear();
            pieces.clear();
            for (p, b) in props.iter().zip(&bounds) {
                let Some((culls, prep)) = b else {
                    continue;
                };
                // The box test first: it is the tighter and needs no arc cosine.
                let seen = |((c, r), (lo, hi)): &Bounds| {
                    tile.may_hit_box(*lo, *hi) && tile.may_hit(*c, *r)
                };
                let start = pieces.len();
                pieces.extend(
                    culls
                        .iter()
                        .filter(|(b, _)| seen(b))
                        .map(|(_, piece)| *piece),
                );
                if pieces.len() > start {
                    candidates.push(*p);
                    // A prop of one piece is tested against its own box already.
                    let range = if culls.len() > 1 {
                        start..pieces.len()
                    } else {
                        start..start
                    };
                    chosen.push((*prep, range));
                }
            }
            // The pieces of a long prop this tile may see: a ray must meet one of them.
            let prepared: Vec<Prepared> = chosen
                .iter()
                .map(|(prep, range)| prep.with_pieces(pieces.get(range.clone()).unwrap_or(&[])))
                .collect();
            for v in tile.y0..tile.y1 {
                for u in tile.x0..tile.x1 {
                    let i = v as usize * self.width as usize + u as usize;
                    let s = match self.rays[i].ray() {
                        Some(ray) if still => {
                            let (p, t) = (&candidates, scene.travelled);
                            background_still(&ray, p, &prepared, &self.still[i], t)
                        }
                        Some(ray) => background_valid(&ray, &candidates, &prepared, &frame),
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

/// The vehicle's pose in `scene`, bit for bit, and the road it is on (a road of a profile by
/// its address): a background is rendered again when either changes.
fn pose_bits(scene: &Scene) -> [u64; 5] {
    [
        scene.travelled.to_bits(),
        scene.lateral.to_bits(),
        scene.heading.to_bits(),
        scene.bend.to_bits(),
        scene
            .road
            .map_or(0, |r| std::ptr::from_ref(r).addr() as u64),
    ]
}

#[cfg(test)]
mod tests;
