//! The one conversion of a coordinate to an integer that the evaluation (its windows) and the
//! sharing grid (its cells) both make, in a module of its own so neither imports the other.

/// `x as i32` for the small coordinates of the evaluation. Clamped first (NaN to a bound too),
/// so the unchecked conversion is always defined; values within +-2^24 are unchanged. Unlike a
/// saturating `as`, this vectorises.
#[inline(always)]
pub(super) fn trunc(x: f32) -> i32 {
    const BOUND: f32 = 16_777_216.0;
    // Not `clamp`: it keeps NaN, which must not reach the conversion.
    #[allow(clippy::manual_clamp)]
    let x = x.max(-BOUND).min(BOUND);
    // SAFETY: x is finite and within +-2^24 (the line above; `max` maps NaN to -2^24).
    unsafe { x.to_int_unchecked::<i32>() }
}
