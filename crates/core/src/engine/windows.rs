//! The window comparison, the evaluation's pass 2 and its hottest loop: for each fly, the
//! product of the gradient bytes at its two windows' centres and the sum of squared
//! differences of the windows (rows -3, 0, +3 of a 7x7 window by default, the right rows
//! interpolated at sub-pixel disparity).
//!
//! Each row is compared with one fixed-width load of 16 or 32 bytes (4 bytes per pixel,
//! [`crate::frame`]) under a byte mask that drops the gradient byte, unused channels and the
//! bytes past the window. Fixed widths let the compiler turn each row into a handful of SIMD
//! instructions on any x86-64 (SSE2 baseline), with no `unsafe`; the AVX2 and AVX-512 kernels
//! give the same integers with fewer instructions (AVX-512: a whole 32-byte row in one vector)
//! and trust their caller's single bounds check a window.

use crate::frame::BPP;
use crate::isa::{Isa, Level, dispatch};

/// Byte mask of one neighbourhood row loaded as `W` bytes: the window's colour channels.
/// A compile-time constant in the kernel, so masking costs one vector AND.
pub(super) const fn mask<const W: usize>(radius: usize, channels: usize) -> [u8; W] {
    let mut m = [0u8; W];
    let mut k = 0;
    while k < W {
        if k < (2 * radius + 1) * BPP && k % BPP < channels {
            m[k] = 0xff;
        }
        k += 1;
    }
    m
}

/// [`mask`] as one bit per byte (the AVX-512 kernel's lane mask).
pub(super) const fn mask_bits<const W: usize>(radius: usize, channels: usize) -> u64 {
    let bytes = mask::<W>(radius, channels);
    let mut m = 0u64;
    let mut k = 0;
    while k < W && k < 64 {
        if bytes[k] != 0 {
            m |= 1 << k;
        }
        k += 1;
    }
    m
}

/// [`mask`] widened to 16-bit lanes (what the AVX2 kernel compares in).
pub(super) const fn mask16<const W: usize>(radius: usize, channels: usize) -> [i16; W] {
    let bytes = mask::<W>(radius, channels);
    let mut m = [0i16; W];
    let mut k = 0;
    while k < W {
        m[k] = if bytes[k] != 0 { -1 } else { 0 };
        k += 1;
    }
    m
}

/// The window comparison of one evaluation (its pass 2): for each fly, the product of the
/// gradient bytes at the two windows' centres and the SSD of the windows.
#[derive(Clone, Copy)]
pub(super) struct Windows<'a, const W: usize> {
    /// Image data, bytes between compared rows, offset of the centre's gradient byte.
    pub(super) left: (&'a [u8], usize, usize),
    pub(super) right: (&'a [u8], usize, usize),
    /// Rows compared.
    pub(super) n_rows: usize,
    pub(super) mask: &'a [u8; W],
    pub(super) mask16: &'a [i16; W],
    pub(super) mask_bits: u64,
}

impl<'a, const W: usize> Windows<'a, W> {
    dispatch! {
        /// [`Windows::run`] on instruction set `isa`, in a function of its own: inlined into
        /// the whole evaluation, its loop lost half its registers to the stack.
        pub(super) fn compare['a, const W: usize](
            self: &Windows<'a, W>,
            lo: &[u32],
            ro: &[u32],
            ts: &[u16],
            grads: &mut [i32],
            ssds: &mut [i32],
        );
        up to Avx512 => Windows::unrolled
    }

    /// The default neighbourhood's three compared rows get an instantiation of their own
    /// (rows and prefetches fully unrolled).
    #[inline(always)]
    fn unrolled(
        &self,
        isa: Isa,
        lo: &[u32],
        ro: &[u32],
        ts: &[u16],
        grads: &mut [i32],
        ssds: &mut [i32],
    ) {
        match self.n_rows {
            3 => Windows { n_rows: 3, ..*self }.run(isa, lo, ro, ts, grads, ssds),
            _ => self.run(isa, lo, ro, ts, grads, ssds),
        }
    }

    /// Fills `grads` (`gl * gr`) and `ssds` for the flies at offsets `lo`, `ro` with sub-pixel
    /// weights `ts` (/128); `ssds` is -1 for a fly not compared: a window that would reach
    /// past an image's buffer, which is how pass 1 marks a fly outside an image (`lo` MAX).
    #[inline(always)]
    fn run(
        &self,
        isa: Isa,
        lo: &[u32],
        ro: &[u32],
        ts: &[u16],
        grads: &mut [i32],
        ssds: &mut [i32],
    ) {
        let ((ld, lstep, gl_at), (rd, rstep, gr_at)) = (self.left, self.right);
        let n_rows = self.n_rows;
        let last = n_rows.saturating_sub(1);
        // Bytes a window needs from its first one: every compared row (the right one a pixel
        // wider, for the interpolation) and the centre's gradient byte. One bounds check per
        // window and image, instead of one per load.
        let lneed = (last * lstep + W).max(gl_at + 1);
        let rneed = (last * rstep + W + 2 * BPP).max(gr_at + BPP + 1);
        let (Some(lmax), Some(rmax)) = (ld.len().checked_sub(lneed), rd.len().checked_sub(rneed))
        else {
            ssds.fill(-1);
            return;
        };
        let len = lo.len().min(ro.len()).min(ts.len());
        let (grads, ssds) = (&mut grads[..len], &mut ssds[..len]);
        for i in 0..len {
            // The windows are scattered over two images larger than L2: the rows of the fly a
            // few places ahead are fetched while this one is compared.
            if let (Some(&a), Some(&b)) = (lo.get(i + PREFETCH_AHEAD), ro.get(i + PREFETCH_AHEAD)) {
                for j in 0..n_rows {
                    prefetch::<W>(ld, a as usize + j * lstep);
                    prefetch::<W>(rd, b as usize + j * rstep);
                }
            }
            let (l, r) = (lo[i] as usize, ro[i] as usize);
            ssds[i] = -1;
            if (l > lmax) | (r > rmax) {
                continue;
            }
            // The right gradient is the one of the pixel nearest to the right window's centre
            // (at `t` / 128 of a pixel past `r`'s): the window's own pixel, taken whatever the
            // fraction, pulled every fly half a pixel of disparity short of the match.
            // SAFETY: l <= lmax = ld.len() - lneed and gl_at < lneed, so l + gl_at < ld.len();
            // r <= rmax = rd.len() - rneed and gr_at + BPP < rneed, the same there.
            let (gl, g0, g1) = unsafe {
                (
                    *ld.get_unchecked(l + gl_at),
                    *rd.get_unchecked(r + gr_at),
                    *rd.get_unchecked(r + gr_at + BPP),
                )
            };
            let t = u32::from(ts[i].min(128));
            let gr = (u32::from(g0) * (128 - t) + u32::from(g1) * t + 64) >> 7;
            // t = 128 is all of the next pixel: the same bytes as t = 0 one pixel on (the SIMD
            // kernels need t < 128; `rneed` has room for the pixel more).
            let (rw, t) = if ts[i] >= 128 {
                (r + BPP, 0)
            } else {
                (r, ts[i])
            };
            // SAFETY: l <= lmax < ld.len() and rw <= r + BPP <= rmax + BPP < rd.len() (checked
            // above against `lneed`, `rneed`).
            let (lp, rp) = unsafe { (ld.as_ptr().add(l), rd.as_ptr().add(rw)) };
            let (m16, bits) = (self.mask16, self.mask_bits);
            let ssd = match isa.level() {
                // SAFETY: the level is AVX-512 only in `compare`'s AVX-512 function; the
                // windows lie inside the buffers (checked above against `lneed`, `rneed`).
                #[cfg(target_arch = "x86_64")]
                Level::Avx512 => unsafe {
                    avx512::ssd::<W>(lp, lstep, rp, rstep, n_rows, m16, bits, t)
                },
                // SAFETY: as above, for AVX2.
                #[cfg(target_arch = "x86_64")]
                Level::Avx2 => unsafe { avx2::ssd::<W>(lp, lstep, rp, rstep, n_rows, m16, t) },
                _ => ssd::<W>(ld, l, lstep, rd, rw, rstep, n_rows, self.mask, t),
            };
            grads[i] = i32::from(gl) * gr as i32;
            // At most 255^2 per sample, or the baseline's u32::MAX / 2 = i32::MAX for a
            // window off the buffer: inside an i32.
            ssds[i] = ssd as i32;
        }
    }
}

/// How many flies ahead the evaluation prefetches windows. The two images (2.5 MB at 640x480)
/// mostly sit in L2/L3: a short distance only starts the loads a little earlier, and a long
/// one evicted lines before use (`flyd bench`, interleaved: 2 or 3 ahead 147-148 us, 8 ahead
/// 151, 16 ahead 153, none 155).
const PREFETCH_AHEAD: usize = 2;

/// Hints the cache lines of a `W + BPP`-byte window row starting at `data[at]` (a hint only:
/// an address outside `data` is never dereferenced).
#[inline(always)]
fn prefetch<const W: usize>(data: &[u8], at: usize) {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse"))]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = data.as_ptr().wrapping_add(at).cast::<i8>();
        // SAFETY: a prefetch is a hint that never dereferences its address (it cannot fault),
        // and SSE is part of the x86-64 baseline (checked by the cfg above).
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(p);
            _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(W + BPP - 1));
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse")))]
    let _ = (data, at);
}

/// Sum of squared differences of `rows` rows of `W` bytes under `mask`, the right row being
/// interpolated between its pixel and the next one with weight `t / 128`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn ssd<const W: usize>(
    l: &[u8],
    lo: usize,
    ls: usize,
    r: &[u8],
    ro: usize,
    rs: usize,
    rows: usize,
    mask: &[u8; W],
    t: u16,
) -> u32 {
    let mut acc = 0u32;
    for j in 0..rows {
        let (Some(a), Some(b0), Some(b1)) = (
            l.get(lo + j * ls..).and_then(|s| s.first_chunk::<W>()),
            r.get(ro + j * rs..).and_then(|s| s.first_chunk::<W>()),
            r.get(ro + j * rs + BPP..)
                .and_then(|s| s.first_chunk::<W>()),
        ) else {
            // Unreachable with the padded layout; fail as a mismatch rather than panic.
            return u32::MAX / 2;
        };
        acc += row_ssd(a, b0, b1, t, mask);
    }
    acc
}

/// Squared differences of one row, SSE2 (baseline on every x86-64): per 16 bytes, the right
/// bytes are blended `(b0 (128 - t) + b1 t + 64) >> 7` in 16 bits, the mask zeroes what is not
/// compared, and one `pmaddwd` per half squares and sums.
#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
#[inline(always)]
fn row_ssd<const W: usize>(a: &[u8; W], b0: &[u8; W], b1: &[u8; W], t: u16, mask: &[u8; W]) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is enabled for this build (checked by the cfg above; it is part of the x86-64
    // baseline), and every load reads 16 bytes through a pointer taken from a `&[u8; 16]`.
    unsafe {
        let zero = _mm_setzero_si128();
        let w1 = _mm_set1_epi16(t as i16);
        let w0 = _mm_set1_epi16(128 - t as i16);
        let half = _mm_set1_epi16(64);
        let chunk = |a: &[u8; 16], b0: &[u8; 16], b1: &[u8; 16], m: &[u8; 16]| {
            let vm = _mm_loadu_si128(m.as_ptr().cast());
            let va = _mm_and_si128(_mm_loadu_si128(a.as_ptr().cast()), vm);
            let v0 = _mm_loadu_si128(b0.as_ptr().cast());
            let v1 = _mm_loadu_si128(b1.as_ptr().cast());
            let blend = |x0: __m128i, x1: __m128i| {
                let s = _mm_add_epi16(_mm_mullo_epi16(x0, w0), _mm_mullo_epi16(x1, w1));
                _mm_srli_epi16(_mm_add_epi16(s, half), 7)
            };
            let blo = blend(_mm_unpacklo_epi8(v0, zero), _mm_unpacklo_epi8(v1, zero));
            let bhi = blend(_mm_unpackhi_epi8(v0, zero), _mm_unpackhi_epi8(v1, zero));
            let vb = _mm_and_si128(_mm_packus_epi16(blo, bhi), vm);
            let lo = _mm_sub_epi16(_mm_unpacklo_epi8(va, zero), _mm_unpacklo_epi8(vb, zero));
            let hi = _mm_sub_epi16(_mm_unpackhi_epi8(va, zero), _mm_unpackhi_epi8(vb, zero));
            _mm_add_epi32(_mm_madd_epi16(lo, lo), _mm_madd_epi16(hi, hi))
        };
        // W is 16 or 32 (a compile-time constant): one or two chunks, no loop.
        let (Some(a0), Some(b00), Some(b10), Some(m0)) = (
            a.first_chunk::<16>(),
            b0.first_chunk::<16>(),
            b1.first_chunk::<16>(),
            mask.first_chunk::<16>(),
        ) else {
            return 0;
        };
        let mut sum = chunk(a0, b00, b10, m0);
        if W == 32
            && let (Some(a1), Some(b01), Some(b11), Some(m1)) = (
                a.last_chunk::<16>(),
                b0.last_chunk::<16>(),
                b1.last_chunk::<16>(),
                mask.last_chunk::<16>(),
            )
        {
            sum = _mm_add_epi32(sum, chunk(a1, b01, b11, m1));
        }
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32(sum, 0b01_00_11_10));
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32(sum, 0b10_11_00_01));
        _mm_cvtsi128_si32(sum) as u32
    }
}

/// The SSD with AVX2: each 16 bytes of a row widened to 16-bit lanes in one load, the right
/// row interpolated as `b0 + (((b1 - b0) t + 64) >> 7)` with one `vpmulhrsw` (the same integer
/// as the SSE2 blend `(b0 (128 - t) + b1 t + 64) >> 7`), masked, squared and summed by
/// `vpmaddwd`.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::BPP;
    use std::arch::x86_64::*;

    /// The result of [`super::ssd`] for the windows at `l` and `r` (rows `ls`, `rs` bytes
    /// apart); `mask` is the byte mask widened to lanes. W is 16 or 32 (0 otherwise), and
    /// `t < 128` (t << 8 inside an i16; pass 2 maps 128 to 0 one pixel on).
    ///
    /// # Safety
    /// The CPU must support AVX2; for every `j < rows`, `W` bytes at `l + j * ls` and
    /// `W + BPP` bytes at `r + j * rs` must be readable.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) unsafe fn ssd<const W: usize>(
        l: *const u8,
        ls: usize,
        r: *const u8,
        rs: usize,
        rows: usize,
        mask: &[i16; W],
        t: u16,
    ) -> u32 {
        debug_assert!(t < 128);
        if !(W == 16 || W == 32) {
            return 0;
        }
        // SAFETY: every load below reads 16 bytes inside a window row the caller guarantees
        // readable; AVX2 is enabled for this function.
        unsafe {
            let tw = _mm256_set1_epi16((t << 8) as i16);
            let m0 = _mm256_loadu_si256(mask.as_ptr().cast());
            let m1 = _mm256_loadu_si256(mask.as_ptr().add(W - 16).cast());
            let widen = |p: *const u8| _mm256_cvtepu8_epi16(_mm_loadu_si128(p.cast()));
            let half = |a: *const u8, b: *const u8, m: __m256i| {
                let (va, b0, b1) = (widen(a), widen(b), widen(b.add(BPP)));
                let vb = _mm256_add_epi16(b0, _mm256_mulhrs_epi16(_mm256_sub_epi16(b1, b0), tw));
                let d = _mm256_and_si256(_mm256_sub_epi16(va, vb), m);
                _mm256_madd_epi16(d, d)
            };
            let mut acc = _mm256_setzero_si256();
            for j in 0..rows {
                let (a, b) = (l.add(j * ls), r.add(j * rs));
                acc = _mm256_add_epi32(acc, half(a, b, m0));
                if W == 32 {
                    acc = _mm256_add_epi32(acc, half(a.add(16), b.add(16), m1));
                }
            }
            let s = _mm_add_epi32(
                _mm256_castsi256_si128(acc),
                _mm256_extracti128_si256::<1>(acc),
            );
            let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
            let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
            _mm_cvtsi128_si32(s) as u32
        }
    }
}

/// The SSD with AVX-512 (BW): a whole 32-byte row widened to 32 lanes in one load, the same
/// interpolation as [`avx2::ssd`], the mask applied by a zero-masked subtraction: a third of
/// the AVX2 kernel's instructions. 16-byte rows take the AVX2 kernel.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::BPP;
    use std::arch::x86_64::*;

    /// Same contract and result as [`super::avx2::ssd`]; `keep` has a bit per lane of `mask`
    /// that is set (the same mask as bits).
    ///
    /// # Safety
    /// As [`super::avx2::ssd`], and the CPU must support AVX-512 F/BW/VL.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn ssd<const W: usize>(
        l: *const u8,
        ls: usize,
        r: *const u8,
        rs: usize,
        rows: usize,
        mask: &[i16; W],
        keep: u64,
        t: u16,
    ) -> u32 {
        if W != 32 {
            // SAFETY: the caller's guarantees are those of the AVX2 kernel.
            return unsafe { super::avx2::ssd::<W>(l, ls, r, rs, rows, mask, t) };
        }
        debug_assert!(t < 128);
        // SAFETY: every load below reads 32 bytes (W) inside a window row the caller
        // guarantees readable; the features are enabled for this function.
        unsafe {
            let tw = _mm512_set1_epi16((t << 8) as i16);
            let keep = keep as __mmask32;
            let widen = |p: *const u8| _mm512_cvtepu8_epi16(_mm256_loadu_si256(p.cast()));
            let mut acc = _mm512_setzero_si512();
            for j in 0..rows {
                let (a, b) = (l.add(j * ls), r.add(j * rs));
                let (va, b0, b1) = (widen(a), widen(b), widen(b.add(BPP)));
                let vb = _mm512_add_epi16(b0, _mm512_mulhrs_epi16(_mm512_sub_epi16(b1, b0), tw));
                let d = _mm512_maskz_sub_epi16(keep, va, vb);
                acc = _mm512_add_epi32(acc, _mm512_madd_epi16(d, d));
            }
            _mm512_reduce_add_epi32(acc) as u32
        }
    }
}

/// Portable version of the row kernel (the reference the SSE2 one is tested against).
#[cfg_attr(all(target_arch = "x86_64", target_feature = "sse2"), allow(dead_code))]
#[inline(always)]
fn row_ssd_portable<const W: usize>(
    a: &[u8; W],
    b0: &[u8; W],
    b1: &[u8; W],
    t: u16,
    mask: &[u8; W],
) -> u32 {
    let mut s = 0u32;
    for k in 0..W {
        let b = ((b0[k] as u16 * (128 - t) + b1[k] as u16 * t + 64) >> 7) as u8;
        let d = (a[k] & mask[k]) as i32 - (b & mask[k]) as i32;
        s += (d * d) as u32;
    }
    s
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
use row_ssd_portable as row_ssd;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::isa::Isa;

    #[test]
    fn masks_cover_the_window_and_skip_the_gradient() {
        let m: [u8; 16] = mask(1, 3);
        assert_eq!(
            m,
            [
                255, 255, 255, 0, 255, 255, 255, 0, 255, 255, 255, 0, 0, 0, 0, 0
            ]
        );
        let m: [u8; 32] = mask(3, 1);
        let on: Vec<usize> = (0..32).filter(|&k| m[k] != 0).collect();
        assert_eq!(on, vec![0, 4, 8, 12, 16, 20, 24]);
    }

    #[test]
    fn ssd_counts_only_masked_bytes() {
        let l = vec![10u8; 64];
        let mut r = vec![10u8; 64];
        r[3] = 200; // gradient byte: ignored
        r[13] = 200; // beyond the 3-pixel window: ignored
        r[5] = 13; // counted: 3^2
        r[16] = 8; // second row, first byte: 2^2
        let m: [u8; 16] = mask(1, 3);
        // t = 0: no interpolation.
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 2, &m, 0), 13);
    }

    #[test]
    fn interpolation_halfway_between_pixels() {
        let l = vec![30u8; 64];
        // Right row: pixel values 20, 40, 20, 40, ... halfway blends are 30 = the left row.
        let r: Vec<u8> = (0..64)
            .map(|k| if (k / 4) % 2 == 0 { 20 } else { 40 })
            .collect();
        let m: [u8; 16] = mask(1, 3);
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 1, &m, 64), 0);
        assert_eq!(ssd::<16>(&l, 0, 16, &r, 0, 16, 1, &m, 0), 9 * 100);
    }

    /// The SIMD kernel of `isa` on the windows at `lo`, `ro`, bounds-checked like the
    /// evaluation's pass 2 (the kernels trust their caller).
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn simd_ssd<const W: usize>(
        isa: Isa,
        (l, lo, ls): (&[u8], usize, usize),
        (r, ro, rs): (&[u8], usize, usize),
        rows: usize,
        (radius, channels): (usize, usize),
        t: u16,
    ) -> u32 {
        assert!(rows > 0 && t < 128);
        assert!(lo + (rows - 1) * ls + W <= l.len() && ro + (rows - 1) * rs + W + BPP <= r.len());
        let m16 = mask16::<W>(radius, channels);
        let (lp, rp) = (l[lo..].as_ptr(), r[ro..].as_ptr());
        let bits = mask_bits::<W>(radius, channels);
        match isa.level() {
            Level::Baseline => panic!("not a SIMD kernel"),
            // SAFETY: `isa` proves the CPU has AVX2, and the windows were checked to lie
            // inside the buffers just above.
            Level::Avx2 => unsafe { avx2::ssd::<W>(lp, ls, rp, rs, rows, &m16, t) },
            // SAFETY: as above, with AVX-512.
            Level::Avx512 => unsafe { avx512::ssd::<W>(lp, ls, rp, rs, rows, &m16, bits, t) },
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn simd_ssd_matches_the_baseline_one() {
        let isas = &Isa::available()[1..];
        if isas.is_empty() {
            println!("SKIP simd_ssd_matches_the_baseline_one: this CPU has no AVX2");
            return;
        }
        let mut next = crate::test_support::xorshift32(0x2545_f491);
        let mut byte = || next() as u8;
        let (l, r): (Vec<u8>, Vec<u8>) = (0..4096).map(|_| (byte(), byte())).unzip();
        for &isa in isas {
            for t in 0..128u16 {
                for (lo, ro) in [(0, 0), (5, 17), (300, 1200), (1000, 3)] {
                    let m = mask::<32>(3, 3);
                    let want = ssd::<32>(&l, lo, 640, &r, ro, 640, 3, &m, t);
                    let got = simd_ssd::<32>(isa, (&l, lo, 640), (&r, ro, 640), 3, (3, 3), t);
                    assert_eq!(got, want, "{isa:?} t {t} lo {lo} ro {ro}");
                    let m = mask::<32>(2, 1);
                    let want = ssd::<32>(&l, lo, 640, &r, ro, 640, 5, &m, t);
                    let got = simd_ssd::<32>(isa, (&l, lo, 640), (&r, ro, 640), 5, (2, 1), t);
                    assert_eq!(got, want, "{isa:?} t {t} lo {lo} ro {ro}");
                    let m = mask::<16>(1, 1);
                    let want = ssd::<16>(&l, lo, 64, &r, ro, 64, 3, &m, t);
                    let got = simd_ssd::<16>(isa, (&l, lo, 64), (&r, ro, 64), 3, (1, 1), t);
                    assert_eq!(got, want, "{isa:?} t {t} lo {lo} ro {ro}");
                }
            }
        }
    }

    #[test]
    fn full_weight_on_the_next_pixel_is_that_pixel() {
        // What pass 2 rests on when it maps t = 128 to t = 0 one pixel on.
        let (l, r): (Vec<u8>, Vec<u8>) = (0..4096u32)
            .map(|k| ((k * 7 % 251) as u8, (k * 13 % 241) as u8))
            .unzip();
        let m = mask::<32>(3, 3);
        for ro in [0, 17, 1200] {
            assert_eq!(
                ssd::<32>(&l, 40, 640, &r, ro, 640, 3, &m, 128),
                ssd::<32>(&l, 40, 640, &r, ro + BPP, 640, 3, &m, 0)
            );
        }
    }

    #[test]
    fn windows_past_the_buffer_are_not_compared() {
        let (ld, rd) = (vec![7u8; 4096], vec![9u8; 4096]);
        let (mask, mask16) = (mask::<32>(3, 3), mask16::<32>(3, 3));
        let windows = Windows {
            left: (&ld[..], 3 * 640, 640 * 3 + 15),
            right: (&rd[..], 3 * 640, 640 * 3 + 15),
            n_rows: 3,
            mask: &mask,
            mask16: &mask16,
            mask_bits: mask_bits::<32>(3, 3),
        };
        // In range; the left window past the end; the right one; a fly outside (pass 1's mark).
        let lo = [0, 4096 - 2 * 1920 - 31, 0, u32::MAX];
        let ro = [0, 0, 4096 - 2 * 1920 - 35, 0];
        for isa in Isa::available() {
            let (mut grads, mut ssds) = ([0; 4], [0; 4]);
            windows.compare(*isa, &lo, &ro, &[0; 4], &mut grads, &mut ssds);
            // 7 pixels x 3 channels x 3 rows of (9 - 7)^2.
            assert_eq!(ssds, [63 * 4, -1, -1, -1], "{isa:?}");
            assert_eq!(grads[0], 63, "{isa:?}");
        }
    }

    #[test]
    fn simd_row_kernel_matches_the_portable_one() {
        let mut next = crate::test_support::xorshift32(0x9e37_79b9);
        let mut byte = || next() as u8;
        for t in [0u16, 1, 37, 64, 127, 128] {
            let (mut a, mut b0, mut b1) = ([0u8; 32], [0u8; 32], [0u8; 32]);
            for k in 0..32 {
                (a[k], b0[k], b1[k]) = (byte(), byte(), byte());
            }
            let m: [u8; 32] = mask(3, 3);
            assert_eq!(
                row_ssd(&a, &b0, &b1, t, &m),
                row_ssd_portable(&a, &b0, &b1, t, &m)
            );
            let m: [u8; 32] = mask(2, 1);
            assert_eq!(
                row_ssd(&a, &b0, &b1, t, &m),
                row_ssd_portable(&a, &b0, &b1, t, &m)
            );
        }
    }
}
