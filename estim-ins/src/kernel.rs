//! The builds of the hot loops chosen at run time from the CPU's features, and how each
//! build forms a multiply-add (shared by the covariance kernels of `error_model` and the
//! mechanization).

/// The builds of the hot kernels (the covariance step, the mechanization), chosen once
/// per call from the CPU's features (`is_x86_feature_detected!` caches its answer, so
/// the check costs a load).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kernel {
    /// AVX-512 (8 lanes) with fused multiply-adds.
    #[cfg(target_arch = "x86_64")]
    Avx512Fma,
    /// AVX2 (4 lanes) with fused multiply-adds.
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
    /// The baseline build: products and sums rounded separately.
    Portable,
}

/// Whether `ESTIM_FORCE_PORTABLE=1` asks for the portable build everywhere (read once;
/// estim-core honours the same variable), so tests can run the portable path on a CPU
/// that has the hand-tuned ones.
pub(crate) fn portable_forced() -> bool {
    static FORCED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FORCED.get_or_init(|| std::env::var("ESTIM_FORCE_PORTABLE").is_ok_and(|v| v == "1"))
}

impl Kernel {
    #[inline(always)]
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if !portable_forced() && std::arch::is_x86_feature_detected!("fma") {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Self::Avx512Fma;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Self::Avx2Fma;
            }
        }
        Self::Portable
    }
}

/// How a kernel forms a b + c. Rust never contracts `a * b + c` into a fused
/// multiply-add by itself, and `f64::mul_add` on a CPU without FMA is a slow library
/// call, so the kernels take the choice as a type: [`Fused`] only inside the builds
/// compiled with the `fma` feature, [`Separate`] in the portable one.
pub(crate) trait MultiplyAdd {
    /// a b + c.
    fn multiply_add(a: f64, b: f64, c: f64) -> f64;
}

/// a b + c with the product and the sum rounded separately.
pub(crate) struct Separate;

impl MultiplyAdd for Separate {
    #[inline(always)]
    fn multiply_add(a: f64, b: f64, c: f64) -> f64 {
        a * b + c
    }
}

/// a b + c rounded once (one FMA instruction where the `fma` feature is enabled).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) struct Fused;

impl MultiplyAdd for Fused {
    #[inline(always)]
    fn multiply_add(a: f64, b: f64, c: f64) -> f64 {
        a.mul_add(b, c)
    }
}
