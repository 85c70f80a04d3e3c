//! The flies, structure-of-arrays: each hot loop streams over one or two fields.

use super::projector::Projector;
use crate::isa::{Isa, dispatch};
use std::ops::Range;

/// The flies, structure-of-arrays: the hot loops stream over one field at a time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Population {
    /// Vehicle-frame coordinates, metres.
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    /// Fitness after the region of interest, before sharing.
    pub raw_fitness: Vec<f32>,
    /// Fitness after sharing: what selection ranks by.
    pub fitness: Vec<f32>,
    /// `raw_fitness / (max(|x|,.5)^2 max(z,1))`.
    pub warning: Vec<f32>,
    /// Projections (continuous pixel coordinates); NaN when the fly is outside an image.
    pub u_left: Vec<f32>,
    pub v_left: Vec<f32>,
    pub u_right: Vec<f32>,
    pub v_right: Vec<f32>,
    /// Sharing cell of the left projection, `u32::MAX` when outside.
    pub(super) cell: Vec<u32>,
    /// Whether the fly's windows matched at its latest evaluation (the kernel's SSD test,
    /// texture or not): what [`super::Engine::ambiguity`] needs of the fly itself.
    pub(super) matched: Vec<bool>,
}

impl Population {
    pub(super) fn with_len(n: usize) -> Self {
        Self {
            x: vec![0.0; n],
            y: vec![0.0; n],
            z: vec![0.0; n],
            raw_fitness: vec![0.0; n],
            fitness: vec![0.0; n],
            warning: vec![0.0; n],
            u_left: vec![f32::NAN; n],
            v_left: vec![f32::NAN; n],
            u_right: vec![f32::NAN; n],
            v_right: vec![f32::NAN; n],
            cell: vec![u32::MAX; n],
            matched: vec![false; n],
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Moves fly `from` into slot `to` (the state that survives a generation).
    #[inline]
    pub(super) fn move_fly(&mut self, to: usize, from: usize) {
        self.x[to] = self.x[from];
        self.y[to] = self.y[from];
        self.z[to] = self.z[from];
        self.raw_fitness[to] = self.raw_fitness[from];
        self.u_left[to] = self.u_left[from];
        self.v_left[to] = self.v_left[from];
        self.u_right[to] = self.u_right[from];
        self.v_right[to] = self.v_right[from];
        self.cell[to] = self.cell[from];
        self.matched[to] = self.matched[from];
    }

    /// Projects flies `r` into both images (NaN where a fly is outside one). Inlined, so the
    /// AVX2 evaluation compiles it 8 flies wide.
    #[inline(always)]
    pub(super) fn project(&mut self, _: Isa, left: &Projector, right: &Projector, r: Range<usize>) {
        let (x, y, z) = (&self.x[r.clone()], &self.y[r.clone()], &self.z[r.clone()]);
        left.project_batch(
            x,
            y,
            z,
            &mut self.u_left[r.clone()],
            &mut self.v_left[r.clone()],
        );
        right.project_batch(x, y, z, &mut self.u_right[r.clone()], &mut self.v_right[r]);
    }

    dispatch! {
        /// [`Population::project`] on instruction set `isa` (the same bits on each; AVX2
        /// projects 8 flies at a time instead of 4).
        pub(super) fn project_on(
            self: &mut Population,
            left: &Projector,
            right: &Projector,
            r: Range<usize>,
        );
        up to Avx2 => Population::project
    }

    /// Indices of the `k` fittest flies, best first (for display and evaluation; allocates).
    pub fn best(&self, k: usize) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.len()).collect();
        idx.sort_by(|&a, &b| self.fitness[b].total_cmp(&self.fitness[a]).then(a.cmp(&b)));
        idx.truncate(k);
        idx
    }
}
