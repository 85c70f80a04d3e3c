//! Index lists built without branches: the positions of the set flags of a slice.
//!
//! Selection's survivor flags and mutation's coin tosses are coin tosses to a branch
//! predictor, so the lists of their positions are built without branches: every index is
//! written and a cursor advances on a set flag; with AVX2, 8 flags at a time through a
//! left-pack permutation table (AVX2 has no compress instruction); with AVX-512, 16 at a time
//! with a compress and one masked store.

use crate::isa::{Isa, Level, dispatch};

/// Writes `base + j` for every j whose flag is set to the front of `out` and returns how many
/// (at most `out.len()`). Without branches: every index is written and the cursor advances on a
/// set flag, so flags that are coin tosses cost no mispredictions.
#[inline]
pub(super) fn gather(flags: impl Iterator<Item = bool>, base: usize, out: &mut [u32]) -> usize {
    let mut count = 0;
    for (j, f) in flags.enumerate() {
        if let Some(slot) = out.get_mut(count) {
            *slot = (base + j) as u32;
        }
        count += usize::from(f);
    }
    count.min(out.len())
}

dispatch! {
    /// [`gather`] of the flags equal to `set`, on instruction set `isa` (the same list on
    /// each).
    pub(super) fn gather_flags(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize;
    up to Avx512 => gather_flags_at
}

#[inline(always)]
fn gather_flags_at(isa: Isa, flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    match isa.level() {
        // SAFETY: the level is AVX-512 only in `gather_flags`'s AVX-512 function.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { gather_flags_avx512(flags, set, base, out) },
        // SAFETY: as above, for AVX2.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { gather_flags_avx2(flags, set, base, out) },
        _ => gather(flags.iter().map(|&f| f == set), base, out),
    }
}

/// Writes the indices `base + lane` of the set bits of `mask` (16 lanes) at `out`, compressed
/// to the front with one masked store (only the count is written), and returns the count.
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL; `popcount(mask)` u32 must be writable at `out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
#[inline]
pub(super) unsafe fn compress16(mask: u16, base: usize, out: *mut u32) -> usize {
    use std::arch::x86_64::*;
    let c = mask.count_ones();
    // SAFETY: the store writes the `c` lanes of a mask below 2^c; the caller guarantees them.
    unsafe {
        let idx = _mm512_add_epi32(
            _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
            _mm512_set1_epi32(base as i32),
        );
        let packed = _mm512_maskz_compress_epi32(mask, idx);
        _mm512_mask_storeu_epi32(out.cast(), ((1u32 << c) - 1) as u16, packed);
    }
    c as usize
}

/// For each 8-bit mask, the lanes of its set bits packed to the front (then zeros): the
/// permutation that compresses 8 lanes with AVX2, which has no compress instruction.
#[cfg(target_arch = "x86_64")]
static LEFT_PACK: [[u32; 8]; 256] = {
    let mut t = [[0u32; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let (mut lane, mut k) = (0, 0);
        while lane < 8 {
            if m & (1 << lane) != 0 {
                t[m][k] = lane as u32;
                k += 1;
            }
            lane += 1;
        }
        m += 1;
    }
    t
};

/// Writes the indices `base + lane` of the set bits of `mask` (8 lanes) at `out`, all 8 lanes
/// (those past the count are scratch), and returns the count.
///
/// # Safety
/// The CPU must support AVX2; 8 u32 must be writable at `out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
#[inline]
pub(super) unsafe fn left_pack8(mask: u32, base: usize, out: *mut u32) -> usize {
    use std::arch::x86_64::*;
    let m = (mask & 0xff) as usize;
    // SAFETY: the table row is 8 u32; the caller guarantees the store.
    unsafe {
        let perm = _mm256_loadu_si256(LEFT_PACK[m].as_ptr().cast());
        let idx = _mm256_add_epi32(
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
            _mm256_set1_epi32(base as i32),
        );
        _mm256_storeu_si256(out.cast(), _mm256_permutevar8x32_epi32(idx, perm));
    }
    m.count_ones() as usize
}

/// [`gather_flags`] with AVX2: 8 flags at a time, packed with a permutation from
/// [`LEFT_PACK`] and stored whole (the lanes past the count are overwritten next).
///
/// # Safety
/// The CPU must support AVX2 (and BMI1/BMI2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2")]
unsafe fn gather_flags_avx2(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let n = flags.len().min(out.len());
    let full = n / 8 * 8;
    let mut count = 0usize;
    // SAFETY: each load reads 8 bools at `j < full <= flags.len() - 8`; the store writes 8
    // lanes at `count <= j`, so up to j + 8 <= n <= out.len().
    unsafe {
        let want = _mm_set1_epi8(i8::from(set));
        for j in (0..full).step_by(8) {
            let f = _mm_loadl_epi64(flags.as_ptr().add(j).cast());
            let m = _mm_movemask_epi8(_mm_cmpeq_epi8(f, want)) as u32;
            count += left_pack8(m, base + j, out.as_mut_ptr().add(count));
        }
    }
    let tail = flags[full..n].iter().map(|&f| f == set);
    count + gather(tail, base + full, &mut out[count..])
}

/// [`gather_flags`] with AVX-512: 16 flags at a time, their indices compressed into `out`
/// with one masked store.
///
/// # Safety
/// The CPU must support AVX-512 F/BW/VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
unsafe fn gather_flags_avx512(flags: &[bool], set: bool, base: usize, out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let n = flags.len().min(out.len());
    let full = n / 16 * 16;
    let mut count = 0usize;
    // SAFETY: each load reads 16 bools at `j < full <= flags.len() - 16`; the store writes the
    // `popcount` lanes of a mask below 2^popcount at `count`, and count + popcount <= j + 16
    // <= n <= out.len().
    unsafe {
        let want = _mm_set1_epi8(i8::from(set));
        for j in (0..full).step_by(16) {
            let f = _mm_loadu_si128(flags.as_ptr().add(j).cast());
            let m = _mm_cmpeq_epi8_mask(f, want);
            count += compress16(m, base + j, out.as_mut_ptr().add(count));
        }
    }
    let tail = flags[full..n].iter().map(|&f| f == set);
    count + gather(tail, base + full, &mut out[count..])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::isa::Isa;
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{Rng, SeedableRng};

    #[test]
    fn gathered_flags_are_the_same_on_every_instruction_set() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        for n in [0, 1, 15, 16, 17, 33, 2000] {
            let flags: Vec<bool> = (0..n).map(|_| rng.next_u32() % 3 == 0).collect();
            for set in [false, true] {
                let mut want = vec![u32::MAX; n];
                let w = gather(flags.iter().map(|&f| f == set), 7, &mut want);
                for &isa in Isa::available() {
                    let mut got = vec![u32::MAX; n];
                    let g = gather_flags(isa, &flags, set, 7, &mut got);
                    assert_eq!((w, &want[..w]), (g, &got[..g]), "{isa:?} n {n} set {set}");
                }
            }
        }
    }
}
