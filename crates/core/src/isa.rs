//! Instruction sets the hot loops are compiled for, picked at run time.
//!
//! The release build targets the x86-64 baseline (SSE2), so one binary runs on any vehicle PC.
//! The hottest loops (fitness evaluation, frame preparation, the immigrants' projection, the
//! warnings, and the selection, operators, mate index and sharing) are also compiled with AVX2,
//! some with AVX-512 too (one 32-byte window row a vector, compressed index lists), and the
//! CPU chooses at start. Every path gives bit-identical results (integer arithmetic, the same
//! f32 operations in the same order; Rust never fuses a multiply and an add on its own): the
//! choice changes speed, never a fitness, a fly or a frame. Tests compare the paths.
//!
//! # One token, one dispatch
//! An [`Isa`] is a proof: only detection ([`Isa::detect`], [`Isa::available`]) creates one
//! above the baseline, so code that holds an `Isa` may run its [`Level`]'s instructions.
//! `dispatch!` is the one mechanism that turns the proof into code compiled for the level: it
//! defines, for a loop written once as an `#[inline(always)]` body, a `#[target_feature]`
//! function per level and the `match` that picks one. The body gets the level as a constant,
//! so a `match` on it picks a level-specific kernel (intrinsics) at compile time; calling such
//! a kernel is sound because the body runs at that level only inside that level's function.

/// An instruction-set level: a name, which proves nothing (an [`Isa`] does).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Level {
    /// SSE2 (the x86-64 baseline) or portable code.
    Baseline,
    /// AVX2 with BMI1/BMI2 (x86-64-v3 CPUs: Intel since 2013, AMD since 2015).
    Avx2,
    /// AVX-512 F/BW/VL on top of AVX2 (x86-64-v4: Intel server CPUs since 2017, AMD since Zen 4).
    /// The window kernel, the index lists (compress) and the mate index's scan have 512-bit
    /// code; the selection, evaluation, mutation, mate index and sharing are compiled for it;
    /// the rest run their AVX2 code ([`Isa::at_most`]).
    Avx512,
}

/// Proof that this CPU runs [`Isa::level`]'s instructions (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Isa(Level);

impl Isa {
    /// The baseline, which every CPU of the target runs.
    pub const BASELINE: Isa = Isa(Level::Baseline);

    /// The best instruction set this CPU has (std caches the CPUID query).
    pub fn detect() -> Self {
        Self::available().last().copied().unwrap_or(Self::BASELINE)
    }

    /// Every instruction set this CPU has, baseline first, best last (what the tests compare).
    pub fn available() -> &'static [Isa] {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            // x86-64-v3's AVX2 with its bit-manipulation companions (every AVX2 CPU has them).
            let v3 = has!("avx2") && has!("bmi1") && has!("bmi2");
            if v3 && has!("avx512f") && has!("avx512bw") && has!("avx512vl") {
                return &[Isa::BASELINE, Isa(Level::Avx2), Isa(Level::Avx512)];
            }
            if v3 {
                return &[Isa::BASELINE, Isa(Level::Avx2)];
            }
        }
        &[Isa::BASELINE]
    }

    pub fn level(self) -> Level {
        self.0
    }

    /// The name `flyd bench --isa` takes.
    pub fn name(self) -> &'static str {
        match self.0 {
            Level::Baseline => "baseline",
            Level::Avx2 => "avx2",
            Level::Avx512 => "avx512",
        }
    }

    /// The instruction set named `name`, if this CPU has it.
    pub fn by_name(name: &str) -> Option<Isa> {
        Self::available().iter().copied().find(|i| i.name() == name)
    }

    /// The instruction set `level` without detection, for the per-level functions of
    /// `dispatch!` (which run only at their level).
    ///
    /// # Safety
    /// The CPU must have `level`'s features.
    #[doc(hidden)]
    pub(crate) const unsafe fn assumed(level: Level) -> Isa {
        Isa(level)
    }

    /// This instruction set, or `cap` if that is lower: for loops with no code above `cap`
    /// (a CPU that runs a level runs every level below it).
    #[inline(always)]
    pub fn at_most(self, cap: Level) -> Isa {
        Isa(self.0.min(cap))
    }
}

/// Defines a function (or a method) that runs an `#[inline(always)]` body compiled for an
/// [`Isa`]'s level.
///
/// ```text
/// dispatch! {
///     /// Docs of the dispatcher.
///     pub(crate) fn gather_flags(flags: &[bool], set: bool) -> usize;
///     up to Avx512 => gather_flags_at
/// }
/// impl Grid {
///     dispatch! {
///         pub(crate) fn apply_on(self: &mut Grid, pop: &mut Population);
///         up to Avx512 => Grid::apply
///     }
/// }
/// ```
///
/// The first defines `gather_flags(isa: Isa, flags, set)`, which calls
/// `gather_flags_at(isa, flags, set)`; the second a method `apply_on(&mut self, isa: Isa,
/// pop)`, which calls `Grid::apply(self, level, pop)`. The body runs inside a `#[target_feature]` function
/// of the instruction set's level (capped at the level after `up to`: `Avx2` for loops with
/// no AVX-512 code), or directly on the baseline; the level it gets is a constant in each
/// copy, so a `match` on it picks a level-specific kernel at compile time. Generic parameters
/// the per-level functions need go in brackets after the name (`fn compare[const W: usize]`;
/// for a method, those of its `impl`, which the method itself already has).
///
/// The per-level functions take the arguments as their own parameters (a closure capturing
/// them would hide from the optimiser that the references do not alias: measured, the
/// evaluation's first pass stopped vectorising) and are never inlined, so a dispatched loop
/// stays a function of its own even when dispatched from inside another one (the window pass,
/// inlined into the whole evaluation, lost half its registers to the stack).
macro_rules! dispatch {
    // A method (`self: &Type` or `self: &mut Type` first), the instruction set its second
    // parameter.
    (
        $(#[$meta:meta])*
        $vis:vis fn $name:ident $([$($gen:tt)*])? (self: $this:ty $(, $arg:ident: $ty:ty)* $(,)?)
            $(-> $ret:ty)?;
        up to $cap:ident => $body:path
    ) => {
        $(#[$meta])*
        $vis fn $name(self: $this, isa: $crate::isa::Isa $(, $arg: $ty)*) $(-> $ret)? {
            $crate::isa::dispatch!(@levels isa, $cap, $body, [$($($gen)*)?],
                [this: $this $(, $arg: $ty)*], [this], [$($arg),*], [self $(, $arg)*], [self],
                [$($ret)?])
        }
    };
    // A free function, the instruction set its first parameter.
    (
        $(#[$meta:meta])*
        $vis:vis fn $name:ident $([$($gen:tt)*])? ($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?;
        up to $cap:ident => $body:path
    ) => {
        $(#[$meta])*
        $vis fn $name $(<$($gen)*>)? (isa: $crate::isa::Isa, $($arg: $ty),*) $(-> $ret)? {
            $crate::isa::dispatch!(@levels isa, $cap, $body, [$($($gen)*)?],
                [$($arg: $ty),*], [], [$($arg),*], [$($arg),*], [], [$($ret)?])
        }
    };
    // The per-level functions and the match: `params` are the per-level functions' parameters,
    // `pre` what they pass to the body before the level, `args` after it; `call` what the
    // match passes to them, `outer` what it passes to the body before the level on the
    // baseline.
    (
        @levels $isa:ident, $cap:ident, $body:path, [$($gen:tt)*],
        [$($p:ident: $pt:ty),*], [$($pre:ident)?], [$($a:ident),*], [$($c:expr),*],
        [$($outer:expr)?], [$($ret:ty)?]
    ) => {{
        $crate::isa::dispatch!(@level avx2, Avx2, "avx2,bmi1,bmi2", $body, [$($gen)*],
            [$($p: $pt),*], [$($pre)?], [$($a),*], [$($ret)?]);
        $crate::isa::dispatch!(@if $cap {
            $crate::isa::dispatch!(@level avx512, Avx512,
                "avx2,bmi1,bmi2,avx512f,avx512bw,avx512vl", $body, [$($gen)*],
                [$($p: $pt),*], [$($pre)?], [$($a),*], [$($ret)?]);
        });
        match $isa.level() {
            #[cfg(target_arch = "x86_64")]
            $crate::isa::Level::Avx512 => $crate::isa::dispatch!(@call512 $cap, ($($c),*)),
            // SAFETY: an `Isa` at AVX2 proves the CPU has AVX2, BMI1 and BMI2 (`isa.rs`).
            #[cfg(target_arch = "x86_64")]
            $crate::isa::Level::Avx2 => unsafe { avx2($($c),*) },
            _ => $body($($outer,)? $crate::isa::Isa::BASELINE $(, $a)*),
        }
    }};
    // The function `$f` of level `$level` (features `$features`), which calls the body.
    (
        @level $f:ident, $level:ident, $features:literal, $body:path, [$($gen:tt)*],
        [$($p:ident: $pt:ty),*], [$($pre:ident)?], [$($a:ident),*], [$($ret:ty)?]
    ) => {
        /// # Safety
        /// The CPU must have the features this function is compiled with.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        #[inline(never)]
        unsafe fn $f<$($gen)*>($($p: $pt),*) $(-> $ret)? {
            // SAFETY: this function runs only at its level (its own contract).
            let isa = unsafe { $crate::isa::Isa::assumed($crate::isa::Level::$level) };
            $body($($pre,)? isa $(, $a)*)
        }
    };
    (@if Avx512 { $($t:tt)* }) => { $($t)* };
    (@if Avx2 { $($t:tt)* }) => {};
    // SAFETY: an `Isa` at AVX-512 proves the CPU has AVX-512 F/BW/VL, AVX2, BMI1 and BMI2.
    (@call512 Avx512, ($($c:expr),*)) => { unsafe { avx512($($c),*) } };
    // SAFETY: as above (a loop capped at AVX2 runs its AVX2 code there).
    (@call512 Avx2, ($($c:expr),*)) => { unsafe { avx2($($c),*) } };
}
pub(crate) use dispatch;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_ordered_and_capped() {
        let best = Isa::detect();
        assert_eq!(Isa::available().last(), Some(&best));
        assert_eq!(Isa::available()[0], Isa::BASELINE);
        assert!(best.at_most(Level::Avx2).level() <= Level::Avx2);
        assert_eq!(best.at_most(Level::Baseline), Isa::BASELINE);
        for isa in Isa::available() {
            assert_eq!(Isa::by_name(isa.name()), Some(*isa));
        }
        assert_eq!(Isa::by_name("avx1024"), None);
    }
}
