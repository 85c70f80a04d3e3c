//! Shading: light, the obstacles' materials (clothes, cars, bricks, facades) and the final
//! sample, each a pure function of the surface point.

use super::{
    Face, HAZE_DISTANCE, Hit, Material, Pattern, SKY_HORIZON, Sample, dot, lerp3, rgb, scale3,
};
use crate::noise::{band_coverage, fbm, floor, lattice, periodic_coverage};

/// Lambertian light: ambient plus a sun up, to the right and behind the vehicle, so faces that
/// look at the cameras are lit and different faces of a box differ in brightness. Depends only
/// on the surface normal, never on the viewer.
#[inline]
pub(super) fn light(n: [f64; 3]) -> f64 {
    const SUN: [f64; 3] = [0.3996, 0.7992, -0.4496]; // normalised (0.4, 0.8, -0.45)
    0.45 + 0.55 * dot(n, SUN).max(0.0)
}

/// Lights, hazes and quantises an albedo into a sample.
#[inline]
pub(super) fn finish(albedo: [f64; 3], normal: [f64; 3], dist: f64, z: f64, t: f64) -> Sample {
    finish_hazed(albedo, light(normal), haze(dist), z, t)
}

/// How far a surface `dist` metres away has faded into the horizon colour, 0 to 1.
#[inline]
pub(super) fn haze(dist: f64) -> f64 {
    1.0 - (-dist / HAZE_DISTANCE).exp()
}

/// [`finish`] of a [`light`] and a [`haze`] already computed.
#[inline]
pub(super) fn finish_hazed(albedo: [f64; 3], light: f64, haze: f64, z: f64, t: f64) -> Sample {
    let lit = scale3(albedo, light);
    let c = lerp3(lit, SKY_HORIZON, haze);
    Sample {
        rgb: [quantise(c[0]), quantise(c[1]), quantise(c[2])],
        depth: z as f32,
        t,
    }
}

#[inline]
pub(super) fn quantise(v: f64) -> u8 {
    // `as` saturates and maps NaN to 0.
    (v + 0.5).clamp(0.0, 255.0) as u8
}

/// Brightness factor `1 + contrast * k * (n - 0.5)` from band-limited noise, never negative.
#[inline]
pub(super) fn grain(seed: u64, s: f64, h: f64, cell: f64, contrast: f64, fp: f64) -> f64 {
    (1.0 + 4.0 * contrast * (fbm(seed, s, h, cell, 4, 0.6, fp) - 0.5)).max(0.0)
}

impl Material {
    /// Albedo (0..255 scale) of a hit, band-limited for footprint `fp` (metres).
    pub(crate) fn albedo(&self, hit: &Hit, fp: f64) -> [f64; 3] {
        let base = rgb(self.colour);
        let (s, h, seed) = (hit.s, hit.h, self.seed);
        match self.pattern {
            Pattern::Noise { cell, contrast } => {
                scale3(base, grain(seed, s, h, cell, contrast, fp))
            }
            Pattern::Clothes => clothes(base, hit, seed, fp),
            Pattern::Car => car(base, hit, seed, fp),
            Pattern::Bricks => bricks(base, s, h, seed, fp),
            Pattern::Facade => facade(base, s, h, seed, fp),
            Pattern::Post => post(base, hit, seed, fp),
        }
    }
}

/// A delineator post: its colour with a little grain, a dark band from 0.7 to 0.88 m up
/// on its sides (a post is 1 m tall), its top plain.
fn post(body: [f64; 3], hit: &Hit, seed: u64, fp: f64) -> [f64; 3] {
    const BAND: [f64; 3] = [32.0, 32.0, 36.0];
    let body = scale3(body, grain(seed, hit.s, hit.h, 0.05, 0.08, fp));
    if hit.face == Face::Horizontal {
        return body;
    }
    lerp3(body, BAND, band_coverage(hit.h, fp, 0.7, 0.88))
}

/// Blends layers painted over each other: `weights[k]` is the (box-filtered) coverage of layer
/// `k` over everything below it. Only layers that show are evaluated: the topmost fully opaque
/// one hides all below, which is the common case away from region borders and keeps shading to
/// about one texture evaluation per pixel.
#[inline]
pub(super) fn layered<const N: usize>(
    weights: [f64; N],
    layer: impl Fn(usize) -> [f64; 3],
) -> [f64; 3] {
    let first = (0..N).rev().find(|&k| weights[k] >= 1.0).unwrap_or(0);
    let mut c = layer(first);
    for (k, &w) in weights.iter().enumerate().skip(first + 1) {
        if w > 0.0 {
            c = lerp3(c, layer(k), w);
        }
    }
    c
}

pub(super) fn clothes(shirt: [f64; 3], hit: &Hit, seed: u64, fp: f64) -> [f64; 3] {
    const SKIN: [f64; 3] = [215.0, 170.0, 140.0];
    const HAIR: [f64; 3] = [45.0, 32.0, 25.0];
    let (s, h) = (hit.s, hit.h);
    let hair = || scale3(HAIR, grain(seed ^ 3, s, h, 0.05, 0.3, fp));
    if hit.face == Face::Cap {
        return hair();
    }
    let above = |lo: f64| band_coverage(h, fp, lo, f64::INFINITY);
    let region = |k: usize| match k {
        0 => scale3([28.0, 24.0, 22.0], grain(seed, s, h, 0.04, 0.3, fp)),
        1 => {
            let jeans = scale3([50.0, 65.0, 110.0], grain(seed ^ 1, s, h, 0.15, 0.45, fp));
            // Dark seam between the legs, facing the vehicle.
            let seam = band_coverage(s, fp, -0.015, 0.015) * band_coverage(h, fp, 0.0, 0.80);
            lerp3(jeans, [20.0, 25.0, 45.0], seam)
        }
        2 => {
            let buckle = band_coverage(s, fp, -0.035, 0.035);
            lerp3([30.0, 25.0, 20.0], [210.0, 195.0, 120.0], buckle)
        }
        3 => {
            // Plaid: light stripes across, dark stripes up, so both image directions carry
            // texture (horizontal stripes alone would leave horizontal disparity ambiguous).
            let light_stripe = periodic_coverage(s, fp, 0.09, 0.0, 0.03);
            let dark_stripe = periodic_coverage(h, fp, 0.09, 0.0, 0.03);
            let mut plaid = lerp3(shirt, [235.0, 232.0, 220.0], light_stripe);
            plaid = lerp3(plaid, [25.0, 30.0, 60.0], 0.85 * dark_stripe);
            scale3(plaid, grain(seed ^ 2, s, h, 0.1, 0.15, fp))
        }
        4 => scale3(SKIN, 0.9),
        _ => {
            // Head: face towards the vehicle (|s| < 0.2 m of arc), hair behind and on top.
            let face = || {
                let eyes = (band_coverage(s, fp, -0.07, -0.035)
                    + band_coverage(s, fp, 0.035, 0.07))
                    * band_coverage(h, fp, 1.60, 1.62);
                let mouth = band_coverage(s, fp, -0.03, 0.03) * band_coverage(h, fp, 1.55, 1.56);
                let f = lerp3(SKIN, [40.0, 30.0, 30.0], (eyes + mouth).min(1.0));
                lerp3(f, HAIR, band_coverage(h, fp, 1.68, f64::INFINITY))
            };
            let facing = band_coverage(s, fp, -0.2, 0.2);
            layered([1.0, facing], |k| if k == 0 { hair() } else { face() })
        }
    };
    // Shoes, jeans, belt, shirt, neck, head from the feet up, each starting at a height.
    let weights = [
        1.0,
        above(0.09),
        above(0.88),
        above(0.92),
        above(1.45),
        above(1.52),
    ];
    layered(weights, region)
}

pub(super) fn car(paint: [f64; 3], hit: &Hit, seed: u64, fp: f64) -> [f64; 3] {
    let (s, h) = (hit.s, hit.h);
    let body = || {
        // Paint mottled by dirt, darker towards the bottom; one noise evaluation does both.
        let n = fbm(seed, s, h, 0.3, 4, 0.6, fp);
        let dirt = (n - 0.5).max(0.0) * (1.6 - h).clamp(0.3, 1.0);
        scale3(paint, (1.0 + 1.0 * (n - 0.5)) * (1.0 - 1.5 * dirt))
    };
    let glass = || scale3([40.0, 45.0, 58.0], grain(seed ^ 6, s, h, 0.4, 0.5, fp));
    let dark = || scale3([28.0, 28.0, 30.0], grain(seed ^ 7, s, h, 0.08, 0.3, fp));
    let in_s = |lo: f64, hi: f64| band_coverage(s, fp, lo, hi);
    let in_h = |lo: f64, hi: f64| band_coverage(h, fp, lo, hi);
    match hit.face {
        Face::NegZ | Face::PosZ => {
            let weights = [
                1.0,                                                        // underbody
                in_h(0.25, f64::INFINITY),                                  // body
                in_h(0.28, 0.46),                                           // bumper
                in_s(-0.26, 0.26) * in_h(0.50, 0.62),                       // number plate
                (in_s(-0.85, -0.55) + in_s(0.55, 0.85)) * in_h(0.75, 0.92), // tail lights
                in_s(-0.72, 0.72) * in_h(0.98, 1.38),                       // rear window
            ];
            layered(weights, |k| match k {
                0 => dark(),
                1 => body(),
                2 => [60.0, 60.0, 62.0],
                3 => {
                    // Pseudo-random glyphs: strong, fine, unambiguous texture.
                    let glyph = plate_glyph(seed, s, h, fp);
                    lerp3([228.0, 228.0, 220.0], [20.0, 20.0, 25.0], glyph)
                }
                4 => [195.0, 25.0, 22.0],
                _ => glass(),
            })
        }
        Face::NegX | Face::PosX => {
            // Wheels: dark discs with lighter hubs, 0.33 m radius, axles 1.35 m from the middle.
            let r = ((s.abs() - 1.35).powi(2) + (h - 0.33).powi(2)).sqrt();
            let weights = [
                1.0,
                in_s(-1.5, 1.3) * in_h(0.98, 1.38),
                band_coverage(r, fp, 0.0, 0.33),
                band_coverage(r, fp, 0.0, 0.17),
            ];
            layered(weights, |k| match k {
                0 => body(),
                1 => glass(),
                2 => dark(),
                _ => [150.0, 150.0, 155.0],
            })
        }
        _ => body(),
    }
}

/// Ink coverage of the number plate at (s, h): 7 glyphs of 3x5 cells, each bit from a hash.
pub(super) fn plate_glyph(seed: u64, s: f64, h: f64, fp: f64) -> f64 {
    const CELL: f64 = 0.016;
    // Coarser than a cell: the glyphs blur into grey.
    if fp > CELL {
        return 0.4 * (CELL / fp).min(1.0);
    }
    let (gx, gy) = ((s + 0.24) / CELL, (h - 0.52) / CELL);
    if !(0.0..28.0).contains(&gx) || !(0.0..5.0).contains(&gy) {
        return 0.0;
    }
    let char_index = floor(gx / 4.0).0;
    let col = floor(gx).0 - 4 * char_index;
    if col >= 3 {
        return 0.0; // gap between glyphs
    }
    let bit = lattice(seed ^ 0x91A7E, char_index * 3 + col, floor(gy).0);
    if bit < 0.5 { 1.0 } else { 0.0 }
}

pub(super) fn bricks(brick: [f64; 3], s: f64, h: f64, seed: u64, fp: f64) -> [f64; 3] {
    const COURSE: f64 = 0.075;
    const LENGTH: f64 = 0.225;
    const MORTAR: f64 = 0.012;
    let row = floor(h / COURSE).0;
    let offset = if row.rem_euclid(2) == 1 {
        0.5 * LENGTH
    } else {
        0.0
    };
    let col = floor((s + offset) / LENGTH).0;
    // Per-brick tone, faded out once bricks shrink below a pixel.
    let w = (COURSE / fp - 1.0).clamp(0.0, 1.0);
    let tone = 1.0 + w * 0.5 * (lattice(seed, col, row) - 0.5);
    let b = scale3(brick, tone * grain(seed ^ 1, s, h, 0.1, 0.15, fp));
    let mortar_h = periodic_coverage(h, fp, COURSE, 0.0, MORTAR);
    let mortar_v = periodic_coverage(s + offset, fp, LENGTH, 0.0, MORTAR);
    let mortar = 1.0 - (1.0 - mortar_h) * (1.0 - mortar_v);
    lerp3(b, [185.0, 180.0, 170.0], mortar)
}

pub(super) fn facade(plaster: [f64; 3], s: f64, h: f64, seed: u64, fp: f64) -> [f64; 3] {
    let wall = scale3(plaster, grain(seed, s, h, 0.8, 0.2, fp));
    let glass = scale3([50.0, 62.0, 82.0], grain(seed ^ 1, s, h, 0.6, 0.5, fp));
    let window = periodic_coverage(s, fp, 2.6, 0.0, 1.4) * periodic_coverage(h, fp, 3.2, 1.0, 1.4);
    // Window frames: a lighter band just around each window.
    let frame =
        periodic_coverage(s, fp, 2.6, -0.08, 1.56) * periodic_coverage(h, fp, 3.2, 0.92, 1.56);
    let c = lerp3(wall, [225.0, 225.0, 220.0], frame);
    lerp3(c, glass, window)
}
