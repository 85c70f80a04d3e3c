//! Breeding: the paper's barycentric crossover of two survivors, for every offspring slot.
//!
//! The first parent is drawn among all survivors, or (with probability `guided_breeding`, on
//! a frame that changed) the fittest before sharing of `breeding_tournament` survivors where
//! the image changed; the second from the first one's sharing cell (`local_mating`) or among
//! all survivors. The loop also draws each offspring's mutation coins, which
//! [`super::mutation`] consumes. This room owns the breeders' list, their fitness and the coins.

use super::Population;
use super::change::ChangeMap;
use super::lists::gather;
use super::params::EngineParams;
use super::sampler::unit_f32;
use super::sharing;
use crate::isa::{Isa, dispatch};
use rand::Rng;
use rand::rngs::Xoshiro256PlusPlus;
use std::ops::Range;

/// The breeding loop's own buffers, sized once.
#[derive(Debug, Clone)]
pub(super) struct Breeder {
    /// Survivors in changed blocks: the first parents of guided breeding.
    breeders: Vec<u32>,
    /// Their fitness before sharing (the breeding tournament's key).
    breeder_fitness: Vec<f32>,
    /// Mutation coin tosses of each offspring (16 bits a coordinate), from the latest run.
    coins: Vec<u64>,
}

impl Breeder {
    pub(super) fn new(flies: usize) -> Self {
        let n = flies;
        Self {
            breeders: vec![0; n],
            breeder_fitness: vec![0.0; n],
            coins: vec![0; n],
        }
    }

    /// Fills flies `children` of `pop` with offspring of the survivors `0..children.start`
    /// (the first `keep` flies), on instruction set `isa`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run(
        &mut self,
        isa: Isa,
        pop: &mut Population,
        children: Range<usize>,
        change: &ChangeMap,
        mates: sharing::Picker<'_>,
        params: &EngineParams,
        generator: &mut Xoshiro256PlusPlus,
    ) {
        let keep = children.start;
        // Survivors where the image changed (none on a static scene: then no extra draws).
        let breeders = if params.guided_breeding > 0.0 && change.total > 0.0 {
            let changed = (0..keep).map(|i| change.changed_at(pop.u_left[i], pop.v_left[i]));
            gather(changed, 0, &mut self.breeders)
        } else {
            0
        };
        let tournament = params.breeding_tournament as usize;
        if tournament > 1 {
            for (f, &i) in self
                .breeder_fitness
                .iter_mut()
                .zip(&self.breeders[..breeders])
            {
                *f = pop.raw_fitness[i as usize];
            }
        }
        breed(
            isa,
            &Breeding {
                guided: unit_threshold(params.guided_breeding),
                local: unit_threshold(params.local_mating),
                tournament,
                breeders: &self.breeders[..breeders],
                breeder_fitness: &self.breeder_fitness[..breeders],
                mates,
                cell: &pop.cell[..keep],
            },
            [&mut pop.x, &mut pop.y, &mut pop.z],
            children,
            &mut self.coins,
            generator,
        );
    }

    /// The mutation coins the latest [`Breeder::run`] drew, one word an offspring.
    pub(super) fn coins(&self) -> &[u64] {
        &self.coins
    }
}

/// What the offspring loop reads besides the parents' coordinates.
struct Breeding<'a> {
    /// `bits < guided`: the first parent comes from the breeders (a tournament among them).
    guided: u32,
    /// `bits < local`: the second parent comes from the first one's cell.
    local: u32,
    tournament: usize,
    /// Survivors where the image changed, and their fitness (before sharing).
    breeders: &'a [u32],
    breeder_fitness: &'a [f32],
    mates: sharing::Picker<'a>,
    /// Sharing cell of each parent.
    cell: &'a [u32],
}

dispatch! {
    /// [`breed_with`] compiled for instruction set `isa` (the same offspring on each: integer
    /// and f32 arithmetic only; AVX2 brings BMI2's shifts and rotations for the generator, and
    /// wider registers).
    fn breed(
        b: &Breeding,
        coords: [&mut [f32]; 3],
        children: Range<usize>,
        masks: &mut [u64],
        generator: &mut Xoshiro256PlusPlus,
    );
    up to Avx2 => breed_with
}

/// Writes one crossover offspring into each fly of `children` (of the coordinates `[x, y, z]`)
/// from the survivors `0..children.start`, and its mutation coins to `masks` (from 0). A
/// function of its own over disjoint slices, so the loop keeps the slices' pointers in
/// registers (through `&mut self`, every store could have moved them); parents and children
/// are read and written through one slice a coordinate, which keeps three pointers fewer.
#[inline(always)]
fn breed_with(
    _: Isa,
    b: &Breeding,
    coords: [&mut [f32]; 3],
    children: Range<usize>,
    masks: &mut [u64],
    generator: &mut Xoshiro256PlusPlus,
) {
    // A static scene has no breeders: its loop carries none of the tournament's state.
    if b.breeders.is_empty() || b.breeder_fitness.is_empty() {
        breed_loop::<false>(b, coords, children, masks, generator);
    } else {
        breed_loop::<true>(b, coords, children, masks, generator);
    }
}

#[inline(always)]
fn breed_loop<const GUIDED: bool>(
    b: &Breeding,
    [x, y, z]: [&mut [f32]; 3],
    children: Range<usize>,
    masks: &mut [u64],
    generator: &mut Xoshiro256PlusPlus,
) {
    let n = x.len().min(y.len()).min(z.len());
    let keep = children.start.min(b.cell.len()).min(n);
    let end = children.end.min(n);
    let breeders = b.breeders.len().min(b.breeder_fitness.len());
    let fit = &b.breeder_fitness[..breeders];
    let (cell, mates) = (&b.cell[..keep], b.mates);
    if keep == 0 {
        return;
    }
    // A local copy: the generator's state stays in registers (through the reference, each
    // store to a child could have changed it, so it went through memory on every draw).
    let mut rng = generator.clone();
    for i in keep..end {
        let r = rng.next_u64();
        let mut a = lemire(r as u32, keep);
        if GUIDED {
            let g = rng.next_u64();
            if (g as u32) < b.guided {
                // Tournament: the fittest of `tournament` draws, two per random word.
                let mut best = lemire((g >> 32) as u32, breeders);
                let mut best_f = fit[best];
                let mut bits = 0;
                for k in 1..b.tournament {
                    if k % 2 == 1 {
                        bits = rng.next_u64();
                    }
                    let c = lemire((bits >> (32 * (k % 2))) as u32, breeders);
                    if fit[c] > best_f {
                        (best, best_f) = (c, fit[c]);
                    }
                }
                a = (b.breeders[best] as usize).min(keep - 1);
            }
        }
        let r2 = rng.next_u64();
        let m = if (r2 as u32) < b.local {
            mates
                .pick(cell[a], (r2 >> 32) as u32)
                .unwrap_or(a)
                .min(keep - 1)
        } else {
            lemire((r >> 32) as u32, keep)
        };
        let l = unit_f32(rng.next_u32());
        let c = crossover([x[a], y[a], z[a]], [x[m], y[m], z[m]], l);
        (x[i], y[i], z[i]) = (c[0], c[1], c[2]);
        if let Some(w) = masks.get_mut(i - keep) {
            *w = rng.next_u64();
        }
    }
    *generator = rng;
}

/// Barycentric crossover: `l * a + (1 - l) * b`.
#[inline]
pub(super) fn crossover(a: [f32; 3], b: [f32; 3], l: f32) -> [f32; 3] {
    [
        l * a[0] + (1.0 - l) * b[0],
        l * a[1] + (1.0 - l) * b[1],
        l * a[2] + (1.0 - l) * b[2],
    ]
}

/// Probability `p` in [0, 1] as a threshold on 32 random bits: `bits < threshold` with
/// probability `p` (to within 2^-32).
#[inline]
pub(super) fn unit_threshold(p: f64) -> u32 {
    (p * 4_294_967_296.0).min(u32::MAX as f64) as u32
}

/// Lemire's multiply-shift: 32 random bits to `0..n`, unbiased to within n / 2^32.
#[inline]
fn lemire(bits: u32, n: usize) -> usize {
    ((u64::from(bits) * n as u64) >> 32) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossover_is_barycentric() {
        let (a, b) = ([0.0, 2.0, 4.0], [2.0, 0.0, 8.0]);
        assert_eq!(crossover(a, b, 1.0), a);
        assert_eq!(crossover(a, b, 0.0), b);
        assert_eq!(crossover(a, b, 0.25), [1.5, 0.5, 7.0]);
    }
}
