//! The bottom layer of every pixel: the road plane (y = 0) and the sky, their textures a
//! function of the road-frame point (the sky's of the direction).

use super::shading::{finish, finish_hazed, grain, haze, light, quantise};
use super::{
    KERB_WIDTH, LANE_HALF_WIDTH, NOMINAL_EYE, ROAD_HALF_WIDTH, Ray, SKY_HORIZON, Sample, bend,
    footprint, lerp3, profile, scale3,
};
use crate::noise::{band_coverage, fbm, periodic_coverage, value_noise};

const SKY_ZENITH: [f64; 3] = [100.0, 145.0, 205.0];

const SEED_ASPHALT: u64 = 0xA5F1_A17E;
const SEED_KERB: u64 = 0x0C0B_B1E5;
const SEED_GRASS: u64 = 0x06A5_5E5D;
const SEED_PAINT: u64 = 0x9A17_7E57;
const SEED_SKY: u64 = 0x05C7_C10D;

/// Road-surface albedo at (x, z): asphalt, dashed lane marks at x = +-1.75 (3 m every 9 m,
/// starting at z = 0), solid edge lines, kerb at |x| in [5, 5.25], grass beyond.
pub(super) fn road_albedo(x: f64, z: f64, across: f64, along: f64) -> [f64; 3] {
    road_layers(x, z, along, road_bands(x, across))
}

/// The coverages of [`road_albedo`]'s bands across the road at `x` (none depends on z): the
/// lane marks' (before their dashing), the edge line's, the kerb's and the grass's.
#[inline]
fn road_bands(x: f64, across: f64) -> [f64; 4] {
    let ax = x.abs();
    [
        band_coverage(ax, across, LANE_HALF_WIDTH - 0.06, LANE_HALF_WIDTH + 0.06),
        band_coverage(ax, across, 4.75, 4.9),
        band_coverage(ax, across, ROAD_HALF_WIDTH, ROAD_HALF_WIDTH + KERB_WIDTH),
        band_coverage(ax, across, ROAD_HALF_WIDTH + KERB_WIDTH, f64::INFINITY),
    ]
}

/// [`road_albedo`] of the bands [`road_bands`] gives.
#[inline]
fn road_layers(x: f64, z: f64, along: f64, [marks, edge, kerb_w, grass_w]: [f64; 4]) -> [f64; 3] {
    let dash = marks * periodic_coverage(z, along, 9.0, 0.0, 3.0);
    let c = asphalt(x, z, along);
    let c = over(c, (dash + edge).min(1.0), || paint(x, z));
    let c = over(c, kerb_w, || kerb(x, z, along));
    over(c, grass_w, || grass(x, z, along))
}

/// Surface albedo at road coordinates (x = offset, z = along) of a road of [`profile`]: a
/// single lane, asphalt with solid edge lines at |x| in [1.75, 1.9], asphalt to
/// [`profile::ASPHALT`], a kerb strip to [`profile::KERB_OUTER`], grass beyond; the textures of
/// [`road_albedo`].
fn laid_albedo(x: f64, z: f64, across: f64, along: f64) -> [f64; 3] {
    let ax = x.abs();
    let [e0, e1] = profile::EDGE_LINE;
    let c = asphalt(x, z, along);
    let c = over(c, band_coverage(ax, across, e0, e1), || paint(x, z));
    let kerb_w = band_coverage(ax, across, profile::ASPHALT, profile::KERB_OUTER);
    let c = over(c, kerb_w, || kerb(x, z, along));
    let grass_w = band_coverage(ax, across, profile::KERB_OUTER, f64::INFINITY);
    over(c, grass_w, || grass(x, z, along))
}

/// `layer` painted over `c` with coverage `w`: `lerp3(c, layer, w)`, the layer not evaluated
/// where it does not show. Bit for bit the blend (up to the sign of a zero channel, which
/// shading and quantising cannot tell): `c + (l - c) * 0` is `c` for every finite `l`.
#[inline]
fn over(c: [f64; 3], w: f64, layer: impl FnOnce() -> [f64; 3]) -> [f64; 3] {
    if w == 0.0 { c } else { lerp3(c, layer(), w) }
}

// The textures of the ground at (x, z), each band-limited for footprint `along`.

/// Fine-grained (persistence 0.8: the 2.5 cm octave still counts) so that the near road has
/// the moderate texture real asphalt has, fading to smooth grey with distance.
#[inline]
fn asphalt(x: f64, z: f64, along: f64) -> [f64; 3] {
    let n = fbm(SEED_ASPHALT, x, z, 0.8, 6, 0.8, along);
    let v = 105.0 + 190.0 * (n - 0.5);
    [v, v, v * 1.03]
}

#[inline]
fn kerb(x: f64, z: f64, along: f64) -> [f64; 3] {
    scale3(
        [170.0, 166.0, 158.0],
        grain(SEED_KERB, x, z, 0.3, 0.2, along),
    )
}

#[inline]
fn grass(x: f64, z: f64, along: f64) -> [f64; 3] {
    let g = fbm(SEED_GRASS, x, z, 0.6, 5, 0.7, along);
    [
        70.0 * (0.6 + 0.8 * g),
        108.0 * (0.5 + 1.0 * g),
        45.0 * (0.6 + 0.8 * g),
    ]
}

#[inline]
fn paint(x: f64, z: f64) -> [f64; 3] {
    scale3(
        [228.0, 228.0, 222.0],
        0.92 + 0.16 * value_noise(SEED_PAINT, x * 5.0, z * 5.0),
    )
}

/// Sky colour for a direction: a smooth gradient from a pale horizon to a blue zenith with a
/// faint, very low-frequency cloud tint (the sky must be nearly textureless, as real ones are).
fn sky(dir: [f64; 3]) -> [f64; 3] {
    let e = dir[1].clamp(0.0, 1.0);
    let c = lerp3(SKY_HORIZON, SKY_ZENITH, e.sqrt());
    let az = dir[0].atan2(dir[2]);
    let cloud = value_noise(SEED_SKY, az * 4.0, e * 12.0) - 0.5;
    scale3(c, 1.0 + 0.04 * cloud)
}

/// The road under a ray in the frame it is traced in.
#[derive(Debug, Clone, Copy)]
pub(super) enum Ground {
    /// Straight, the vehicle `travelled` metres down it (its texture comes towards it).
    Straight { travelled: f64 },
    /// Of constant curvature ([`bend`]), in the road frame.
    Bend { curvature: f64 },
    /// Of a curvature profile ([`profile`]), in the road frame.
    Profile(&'static profile::Road),
}

/// How far along `ray` it meets the road plane: infinity if it does not (it sees the sky).
#[inline]
pub(super) fn ground_t(ray: &Ray) -> f64 {
    let (o, d) = (ray.origin, ray.dir);
    if d[1] < 0.0 && o[1] > 0.0 {
        -o[1] / d[1]
    } else {
        f64::INFINITY
    }
}

/// The road plane or the sky, whichever the ray meets: the bottom layer of every pixel. On a
/// straight road the vehicle has driven `travelled` metres along it (the road's texture is
/// fixed to the ground, so it comes towards the cameras).
pub(super) fn ground_or_sky(ray: &Ray, road: Ground, eye: [f64; 3]) -> Sample {
    let (o, d) = (ray.origin, ray.dir);
    if d[1] < 0.0 && o[1] > 0.0 {
        let t = -o[1] / d[1];
        let p = ray.at(t);
        let (across, along, dist) = footprint([p[0], 0.0, p[2]], [0.0, 1.0, 0.0], eye);
        let albedo = match road {
            Ground::Straight { travelled } => road_albedo(p[0], p[2] + travelled, across, along),
            Ground::Bend { curvature } => {
                let (on, offset) = bend::locate(curvature, p[0], p[2]);
                road_albedo(offset, on, across, along)
            }
            Ground::Profile(road) => {
                let (on, offset) = road.locate(p[0], p[2]);
                laid_albedo(offset, on, across, along)
            }
        };
        return finish(albedo, [0.0, 1.0, 0.0], dist, p[2], t);
    }
    let c = sky(d);
    Sample {
        rgb: [quantise(c[0]), quantise(c[1]), quantise(c[2])],
        depth: f32::INFINITY,
        t: f64::INFINITY,
    }
}

/// What a pixel sees of road or sky from a vehicle on the straight road's centre line, unturned
/// ([`super::Scene::is_posed`] false), whatever `travelled`: the ray meets the road at the
/// same vehicle-frame point (only the texture's z moves) and the same sky. Computed once per
/// pixel, it leaves a moving frame only the textures to evaluate, bit for bit as
/// [`ground_or_sky`] does.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Still {
    Sky(Sample),
    Ground {
        /// The vehicle-frame point met, its distance along the ray, and the haze there.
        x: f64,
        z: f64,
        t: f64,
        haze: f64,
        /// The footprint along the road (for the textures) and [`road_bands`].
        along: f64,
        bands: [f64; 4],
    },
}

impl Still {
    pub(crate) fn new(ray: &Ray) -> Self {
        let t = ground_t(ray);
        if t == f64::INFINITY {
            return Self::Sky(ground_or_sky(
                ray,
                Ground::Straight { travelled: 0.0 },
                NOMINAL_EYE,
            ));
        }
        let p = ray.at(t);
        let (across, along, dist) = footprint([p[0], 0.0, p[2]], [0.0, 1.0, 0.0], NOMINAL_EYE);
        Self::Ground {
            x: p[0],
            z: p[2],
            t,
            haze: haze(dist),
            along,
            bands: road_bands(p[0], across),
        }
    }

    /// How far along the ray it meets the road (infinity: the sky).
    #[inline]
    pub(crate) fn t(&self) -> f64 {
        match self {
            Self::Sky(s) => s.t,
            Self::Ground { t, .. } => *t,
        }
    }

    /// [`ground_or_sky`] of the ray on the straight road, the vehicle `travelled` metres down it.
    #[inline]
    pub(crate) fn shade(&self, travelled: f64) -> Sample {
        match *self {
            Self::Sky(s) => s,
            Self::Ground {
                x,
                z,
                t,
                haze,
                along,
                bands,
            } => {
                let albedo = road_layers(x, z + travelled, along, bands);
                finish_hazed(albedo, light([0.0, 1.0, 0.0]), haze, z, t)
            }
        }
    }
}
