//! Helpers shared by the tests of this crate and of the crates built on it (feature
//! `test-support`).

use crate::geometry::{Camera, Distortion, Intrinsics, StereoRig, rotation_from_angles};

/// Deterministic byte-level damage to a valid file: what an editor, a truncated copy or a bad
/// merge does. xorshift, so the cases are the same on every run.
pub fn damaged(text: &str, seed: u64) -> String {
    let mut bits = xorshift64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut next = move |n: usize| (bits() % n.max(1) as u64) as usize;
    let mut bytes = text.as_bytes().to_vec();
    const TOKENS: [&str; 15] = [
        "nan", "inf", "-inf", "1e999", "-0", "0", "-1", "1e-320", "\"\"", "[", "=", "\n", "é", "€",
        "\u{feff}",
    ];
    for _ in 0..1 + next(4) {
        let len = bytes.len();
        let at = next(len + 1);
        match next(5) {
            // Overwrite a byte with printable noise.
            0 if len > 0 => bytes[at.min(len - 1)] = b' ' + next(95) as u8,
            // Cut a stretch out (a truncated copy when it reaches the end).
            1 => {
                let end = (at + 1 + next(40)).min(len);
                bytes.drain(at.min(end)..end);
            }
            // Swap a number for a hostile token.
            2 => {
                let token = TOKENS[next(TOKENS.len())].as_bytes();
                let end = (at + next(6)).min(len);
                bytes.splice(at.min(end)..end, token.iter().copied());
            }
            // Duplicate a stretch (a key given twice, a line pasted twice).
            3 => {
                let end = (at + 1 + next(60)).min(len);
                let piece: Vec<u8> = bytes[at.min(end)..end].to_vec();
                bytes.splice(at.min(end)..at.min(end), piece);
            }
            _ => bytes.truncate(at),
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

/// Feeds the damaged copies of `text` for `seeds` to `parse`: each must come back usable (an
/// `Ok` that `check` accepts, given a label for its messages) or as an error whose chain (see
/// [`crate::chain`]) contains `names` (the file), never as a panic. Returns how many of each.
pub fn damage_each<T, E: std::error::Error + 'static>(
    text: &str,
    seeds: std::ops::Range<u64>,
    names: &str,
    parse: impl Fn(&str) -> Result<T, E>,
    check: impl Fn(&T, &str),
) -> (usize, usize) {
    let (mut usable, mut refused) = (0, 0);
    for seed in seeds {
        match parse(&damaged(text, seed)) {
            Ok(value) => {
                check(&value, &format!("damage seed {seed}"));
                usable += 1;
            }
            Err(e) => {
                let message = crate::chain::chain(&e);
                assert!(
                    message.contains(names),
                    "damage seed {seed}: the error does not name {names}: {message}"
                );
                refused += 1;
            }
        }
    }
    (usable, refused)
}

/// A level stereo rig of two 160x120 cameras (f = 130 px), 1 m above the road and 0.3 m apart,
/// with lens distortion `distortion` on both.
pub fn small_rig(distortion: Distortion) -> StereoRig {
    let cam = |x: f64| {
        let intrinsics = Intrinsics {
            fx: 130.0,
            fy: 130.0,
            cx: 79.5,
            cy: 59.5,
        };
        let (rotation, position) = (rotation_from_angles(0.0, 0.0, 0.0), [x, 1.0, 0.0].into());
        Camera::new(160, 120, intrinsics, distortion, rotation, position).expect("a valid camera")
    };
    StereoRig {
        left: cam(-0.15),
        right: cam(0.15),
    }
}

/// Marsaglia's xorshift32 from `seed` (not 0): test data that is the same on every run.
pub fn xorshift32(mut x: u32) -> impl FnMut() -> u32 {
    move || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x
    }
}

/// Marsaglia's xorshift64 (13, 7, 17) from `seed` (not 0).
pub fn xorshift64(mut x: u64) -> impl FnMut() -> u64 {
    move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    }
}
