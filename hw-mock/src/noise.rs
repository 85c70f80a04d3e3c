//! Deterministic hashing, value noise and a Gaussian sample table.
//!
//! Nothing here holds RNG state: every value is a pure function of its inputs (seed, lattice
//! point, sample index), so a render is reproducible bit for bit across runs and machines, and
//! any pixel's noise can be computed without generating the ones before it.

/// Weyl increment of splitmix64 (2^64 / golden ratio).
pub(crate) const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;
/// A second odd constant to decorrelate the two lattice axes.
const LATTICE_Y: u64 = 0xC2B2_AE3D_27D4_EB4F;

/// splitmix64's output function applied to `x + gamma`: `splitmix64(s + k * gamma)` for
/// k = 0, 1, ... is exactly the splitmix64 stream seeded with `s`, a well-tested generator.
#[inline]
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(GOLDEN_GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Final mix of a lattice hash (the xor-shift-multiply finaliser of splitmix64, one multiply
/// instead of two: plenty for texture, and it runs four times per noise sample).
#[inline(always)]
fn lattice_mix(z: u64) -> f64 {
    let z = (z ^ (z >> 31)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    let z = z ^ (z >> 29) ^ (z >> 43);
    // Signed conversion: one instruction, where u64 -> f64 needs a fix-up sequence.
    (z >> 11) as i64 as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Uniform value in [0, 1) for an integer lattice point.
#[inline]
pub(crate) fn lattice(seed: u64, ix: i64, iy: i64) -> f64 {
    lattice_mix(lattice_key(splitmix64(seed), ix, iy))
}

/// Pre-mix key of a lattice point for an already mixed seed; neighbours differ by adding the
/// axis constants, so a noise cell's four corners cost four mixes and no further multiplies.
#[inline(always)]
fn lattice_key(mixed_seed: u64, ix: i64, iy: i64) -> u64 {
    mixed_seed
        .wrapping_add((ix as u64).wrapping_mul(GOLDEN_GAMMA))
        .wrapping_add((iy as u64).wrapping_mul(LATTICE_Y))
}

/// `x.floor()` as an integer and as a float. `f64::floor` is a libm call on baseline x86-64
/// (no SSE4.1 `roundsd`), and this runs several times per shaded pixel. `as` saturates (NaN
/// gives 0), so absurd inputs give some value rather than a panic.
#[inline(always)]
pub(crate) fn floor(x: f64) -> (i64, f64) {
    let i = x as i64;
    let i = if (i as f64) > x { i - 1 } else { i };
    (i, i as f64)
}

/// 2-D value noise in [0, 1]: lattice values at integer points, smoothstep-interpolated. Its
/// spectrum is concentrated below 1 cycle per unit, which is what lets [`fbm`] band-limit it.
#[inline]
pub(crate) fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    value_noise_mixed(splitmix64(seed), x, y)
}

/// [`value_noise`] for a seed already passed through [`splitmix64`].
#[inline(always)]
fn value_noise_mixed(mixed_seed: u64, x: f64, y: f64) -> f64 {
    let (ix, fx) = floor(x);
    let (iy, fy) = floor(y);
    let (tx, ty) = (x - fx, y - fy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let k = lattice_key(mixed_seed, ix, iy);
    let a = lattice_mix(k);
    let b = lattice_mix(k.wrapping_add(GOLDEN_GAMMA));
    let c = lattice_mix(k.wrapping_add(LATTICE_Y));
    let d = lattice_mix(k.wrapping_add(GOLDEN_GAMMA).wrapping_add(LATTICE_Y));
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Band-limited fractal value noise in [0, 1] with mean 0.5.
///
/// Octave `i` has cell size `cell / 2^i` and amplitude `persistence^i`. `footprint` is the size of
/// one pixel on the surface (metres, from [`crate::world::footprint`]): an octave whose cell is
/// below two footprints fades to its mean and one below one footprint is skipped, so distant
/// surfaces turn smooth instead of aliasing into per-pixel noise that no stereo matcher could
/// (or should) match.
pub(crate) fn fbm(
    seed: u64,
    x: f64,
    y: f64,
    cell: f64,
    octaves: u32,
    persistence: f64,
    footprint: f64,
) -> f64 {
    // Multiplications by precomputed reciprocals: this runs for every shaded pixel.
    let inv_footprint = 1.0 / footprint;
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut amp = 1.0;
    let mut size = cell;
    let mut freq = 1.0 / cell;
    // One seed mix per call; octaves step away from it by an odd constant (a far-away lattice).
    let mut octave_seed = splitmix64(seed);
    for i in 0..octaves {
        let w = (size * inv_footprint - 1.0).clamp(0.0, 1.0);
        if w > 0.0 {
            let n = value_noise_mixed(octave_seed, x * freq, y * freq);
            sum += amp * (0.5 + w * (n - 0.5));
        } else {
            // This octave and all finer ones are below the footprint: their means.
            let rest = (amp - amp * persistence.powi((octaves - i) as i32)) / (1.0 - persistence);
            let rest = if persistence == 1.0 {
                amp * f64::from(octaves - i)
            } else {
                rest
            };
            sum += 0.5 * rest;
            norm += rest;
            break;
        }
        norm += amp;
        amp *= persistence;
        size *= 0.5;
        freq *= 2.0;
        octave_seed = octave_seed.wrapping_add(0xD6E8_FEB8_6659_FD93);
    }
    if norm > 0.0 { sum / norm } else { 0.5 }
}

/// Fraction of the interval `[x - w/2, x + w/2]` covered by the bands
/// `[start + k*period, start + k*period + len]` (all integers k): the box-filtered indicator of
/// a periodic stripe pattern, exact for any pixel footprint `w`, so dashes, mortar lines and
/// windows stay anti-aliased at every distance.
pub(crate) fn periodic_coverage(x: f64, w: f64, period: f64, start: f64, len: f64) -> f64 {
    // Measure of the bands within [start, start + y] (y may be negative: it is odd-symmetric
    // around `start` up to a constant, which cancels in the difference below).
    let cumulative = |y: f64| {
        let k = floor(y / period).1;
        k * len + (y - k * period).min(len)
    };
    if w.is_nan() || w <= 1e-12 {
        let y = x - start;
        let r = y - period * floor(y / period).1;
        return if r < len { 1.0 } else { 0.0 };
    }
    let a = x - 0.5 * w - start;
    let b = x + 0.5 * w - start;
    ((cumulative(b) - cumulative(a)) / w).clamp(0.0, 1.0)
}

/// Fraction of `[x - w/2, x + w/2]` inside `[lo, hi]` (a single band; `hi` may be infinite).
pub(crate) fn band_coverage(x: f64, w: f64, lo: f64, hi: f64) -> f64 {
    if w.is_nan() || w <= 1e-12 {
        return if x >= lo && x < hi { 1.0 } else { 0.0 };
    }
    let a = (x - 0.5 * w).max(lo);
    let b = (x + 0.5 * w).min(hi);
    ((b - a) / w).clamp(0.0, 1.0)
}

/// Number of entries of the Gaussian table: 12-bit indices, so one 64-bit hash yields 5 samples.
pub(crate) const GAUSS_TABLE_BITS: u32 = 12;
pub(crate) const GAUSS_TABLE_LEN: usize = 1 << GAUSS_TABLE_BITS;

/// Stratified standard-normal samples: entry i is the normal quantile at (i + 0.5) / N. Indexing
/// it with uniform hash bits gives Gaussian-distributed values (truncated at ~3.7 sigma) for the
/// price of a table lookup, which is what keeps per-frame sensor noise cheap.
///
/// Built by integrating the normal density with the trapezoid rule (step 1e-4, error far below
/// 1e-6) and reading each quantile off the running integral: no approximation constants.
pub(crate) fn gaussian_table() -> Box<[f64; GAUSS_TABLE_LEN]> {
    const DX: f64 = 1e-4;
    const START: f64 = -8.0; // the mass below is ~6e-16: nothing
    let pdf = |x: f64| (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let mut t = Box::new([0.0; GAUSS_TABLE_LEN]);
    let mut i = 0;
    let mut cdf = 0.0;
    let mut step = 0u32;
    while i < GAUSS_TABLE_LEN && step < 160_000 {
        let x = START + f64::from(step) * DX;
        let next = cdf + 0.5 * DX * (pdf(x) + pdf(x + DX));
        while i < GAUSS_TABLE_LEN {
            let target = (i as f64 + 0.5) / GAUSS_TABLE_LEN as f64;
            if target > next {
                break;
            }
            t[i] = x + DX * (target - cdf) / (next - cdf);
            i += 1;
        }
        cdf = next;
        step += 1;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_table_holds_normal_quantiles() {
        // Reference quantiles at (i + 0.5) / 4096, computed independently by bisection on erfc.
        let t = gaussian_table();
        for (i, q) in [
            (0, -3.668_329_285_121_323),
            (100, -1.967_963_255_958_387_5),
            (2047, -0.000_305_984_901_580_340_8),
            (3995, 1.967_963_255_958_386_2),
        ] {
            assert!((t[i] - q).abs() < 1e-6, "{i}: {} vs {q}", t[i]);
        }
    }

    #[test]
    fn gaussian_table_has_unit_variance() {
        let t = gaussian_table();
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        let var = t.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / t.len() as f64;
        assert!(mean.abs() < 1e-9);
        // Stratification loses a little variance in the tails (0.99968 exactly).
        assert!((var - 0.999_68).abs() < 1e-4, "{var}");
    }

    #[test]
    fn value_noise_is_bounded_and_continuous() {
        let mut prev = value_noise(7, -3.0, 0.3);
        for i in 1..2000 {
            let x = i as f64 * 0.005 - 3.0;
            let v = value_noise(7, x, 0.3);
            assert!((0.0..=1.0).contains(&v));
            assert!((v - prev).abs() < 0.05, "jump at {x}");
            prev = v;
        }
    }

    #[test]
    fn fbm_fades_to_its_mean_when_footprint_is_large() {
        assert_eq!(fbm(3, 1.3, 2.7, 0.5, 4, 0.6, 10.0), 0.5);
        let v = fbm(3, 1.3, 2.7, 0.5, 4, 0.6, 0.001);
        assert!((0.0..=1.0).contains(&v) && v != 0.5);
    }

    #[test]
    fn coverage_is_a_box_filter() {
        // Dashes of 3 every 9 starting at 0.
        assert_eq!(periodic_coverage(1.0, 0.0, 9.0, 0.0, 3.0), 1.0);
        assert_eq!(periodic_coverage(5.0, 0.0, 9.0, 0.0, 3.0), 0.0);
        assert_eq!(periodic_coverage(-7.0, 0.0, 9.0, 0.0, 3.0), 1.0);
        assert!((periodic_coverage(3.0, 2.0, 9.0, 0.0, 3.0) - 0.5).abs() < 1e-12);
        // A footprint spanning many periods sees the duty cycle.
        assert!((periodic_coverage(0.4, 900.0, 9.0, 0.0, 3.0) - 1.0 / 3.0).abs() < 1e-3);
        assert!((band_coverage(1.0, 0.5, 1.0, f64::INFINITY) - 0.5).abs() < 1e-12);
    }
}
