//! The refresh: on the first generation of a new frame, the flies whose left projection lies
//! where the image changed are re-evaluated before selection. There the previous frame's
//! fitness is the one that is wrong (a fly on the background that an obstacle now hides would
//! survive, and parent the guided breeding, on evidence that is gone); elsewhere the stale
//! fitness still ranks the flies as the new frame would. The flies are evaluated in a batch of
//! their own, so the population's slots are untouched but for their fitness. This room owns
//! the batch and the list of changed flies.

use super::Population;
use super::fitness::Scratch;
use super::immigration::Context;
use super::lists::gather;

#[derive(Debug, Clone)]
pub(super) struct Refresh {
    /// The flies in changed blocks.
    changed: Vec<u32>,
    /// Their copies, evaluated against the new frame.
    batch: Population,
}

impl Refresh {
    pub(super) fn new(flies: usize) -> Self {
        Self {
            changed: vec![0; flies],
            batch: Population::with_len(flies),
        }
    }

    /// Re-evaluates the flies of `pop` where the image changed; `None` when nothing changed
    /// (nothing done), else how many flies were refreshed (their sharing is then stale: the
    /// caller applies it again).
    pub(super) fn run(
        &mut self,
        pop: &mut Population,
        ctx: &Context<'_>,
        scratch: &mut Scratch,
    ) -> Option<usize> {
        if ctx.change.total <= 0.0 {
            return None;
        }
        let n = pop.len();
        let (change, flies) = (ctx.change, &*pop);
        let changed = (0..n).map(|i| change.changed_at(flies.u_left[i], flies.v_left[i]));
        let m = gather(changed, 0, &mut self.changed).min(self.batch.len());
        for (k, &i) in self.changed[..m].iter().enumerate() {
            let i = i as usize;
            self.batch.x[k] = pop.x[i];
            self.batch.y[k] = pop.y[i];
            self.batch.z[k] = pop.z[i];
        }
        ctx.evaluate(&mut self.batch, 0..m, scratch);
        for (k, &i) in self.changed[..m].iter().enumerate() {
            pop.raw_fitness[i as usize] = self.batch.raw_fitness[k];
        }
        Some(m)
    }
}
