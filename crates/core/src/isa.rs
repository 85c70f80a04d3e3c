//! Instruction sets the hot loops are compiled for, picked at run time.
//!
//! The release build targets the x86-64 baseline (SSE2), so one binary runs on any vehicle PC.
//! The hottest loops (fitness evaluation, frame preparation, the immigrants' projection, the
//! warnings, and the selection, operators, mate index and sharing) are also compiled with AVX2,
//! some with AVX-512 too (one 32-byte window row a vector, compressed index lists), and the
//! CPU chooses at start. Every path gives
//! bit-identical results (integer arithmetic, the same f32 operations in the same order; Rust
//! never fuses a multiply and an add on its own): the choice changes speed, never a fitness, a
//! fly or a frame. Tests compare the paths.

/// An instruction set a hot loop can run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// SSE2 (the x86-64 baseline) or portable code.
    Baseline,
    /// AVX2 with BMI1/BMI2 (x86-64-v3 CPUs: Intel since 2013, AMD since 2015).
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// AVX-512 F/BW/VL on top of AVX2 (x86-64-v4: Intel server CPUs since 2017, AMD since Zen 4).
    /// The window kernel, the index lists (compress) and the mate index's scan have 512-bit
    /// code; the selection, evaluation and sharing are compiled for it; the rest run their AVX2
    /// code.
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Isa {
    /// The best instruction set this CPU has (std caches the CPUID query).
    pub fn detect() -> Self {
        Self::available().last().copied().unwrap_or(Isa::Baseline)
    }

    /// Every instruction set this CPU has, baseline first, best last (what the tests compare).
    pub fn available() -> &'static [Isa] {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            // x86-64-v3's AVX2 with its bit-manipulation companions (every AVX2 CPU has them).
            let v3 = has!("avx2") && has!("bmi1") && has!("bmi2");
            if v3 && has!("avx512f") && has!("avx512bw") && has!("avx512vl") {
                return &[Isa::Baseline, Isa::Avx2, Isa::Avx512];
            }
            if v3 {
                return &[Isa::Baseline, Isa::Avx2];
            }
        }
        &[Isa::Baseline]
    }

    /// The name `flyd bench --isa` takes.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => "avx2",
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => "avx512",
        }
    }

    /// The instruction set named `name`, if this CPU has it.
    pub fn available_by_name(name: &str) -> Option<Isa> {
        Self::available().iter().copied().find(|i| i.name() == name)
    }
}
