//! The one CPU-dispatch mechanism of estim: which hand-tuned build of a hot loop may
//! run on this CPU.
//!
//! Every hand-tuned build in the workspace asks here. In estim-core:
//!
//! - the linear runner's predict and update, compiled for AVX2 ([`Features::avx2`]);
//! - the fused product of the private `linalg::fused_product` (AVX-512F,
//!   register-blocked, fused multiply-adds; [`Features::avx512f`]);
//! - the joint factor from 8 states, compiled for AVX-512F ([`Features::avx512f`]);
//! - the products of the run-time-sized filter ([`crate::dynamic`]).
//!
//! Outside it, estim-ins's covariance kernels, transition and mechanization
//! ([`Features::fma`] with AVX2 or AVX-512F).
//!
//! The answer is computed once per process (a [`OnceLock`]): the CPU's features as
//! `std::arch::is_x86_feature_detected!` reports them, all off on other
//! architectures, and all off when the environment variable `ESTIM_FORCE_PORTABLE`
//! is `1` when first asked, so that the whole test suite can run on the portable
//! path of a CPU that has the features (`ESTIM_FORCE_PORTABLE=1 cargo test`).
//!
//! Tests compare the builds in one process with `with_features` (this crate's unit
//! tests, or with the Cargo feature `testing`), which overrides the answer on the
//! calling thread only.

use std::sync::OnceLock;

/// The hand-tuned builds this CPU may run: each field is true when the CPU has the
/// instruction-set extension and the portable path is not forced.
///
/// A build compiled with `#[target_feature(enable = "...")]` may be called only when
/// every feature it enables is true here: that is the whole of the safety argument
/// at each dispatch site.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Features {
    /// AVX2 (4 f64 lanes): the linear runner's own build, and estim-ins's FMA builds
    /// (with [`Features::fma`]).
    pub avx2: bool,
    /// AVX-512F (8 f64 lanes, with its own fused multiply-add): the fused product and
    /// the joint factor's build.
    pub avx512f: bool,
    /// FMA (the 256-bit fused multiply-add): estim-ins's fused builds.
    pub fma: bool,
}

impl Features {
    /// No hand-tuned build: the portable path everywhere.
    pub const PORTABLE: Self = Self {
        avx2: false,
        avx512f: false,
        fma: false,
    };
}

/// Whether `ESTIM_FORCE_PORTABLE` asks for the portable path (exactly `1`).
fn portable_forced() -> bool {
    std::env::var_os("ESTIM_FORCE_PORTABLE").is_some_and(|v| v == "1")
}

/// What the CPU has, before `ESTIM_FORCE_PORTABLE`.
fn detected() -> Features {
    #[cfg(target_arch = "x86_64")]
    {
        Features {
            avx2: std::arch::is_x86_feature_detected!("avx2"),
            avx512f: std::arch::is_x86_feature_detected!("avx512f"),
            fma: std::arch::is_x86_feature_detected!("fma"),
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Features::PORTABLE
    }
}

/// The features the process runs with (computed on the first call; a load and a
/// branch afterwards).
#[inline(always)]
#[must_use]
pub fn features() -> Features {
    #[cfg(any(test, feature = "testing"))]
    if let Some(forced) = overridden() {
        return forced;
    }
    static FEATURES: OnceLock<Features> = OnceLock::new();
    *FEATURES.get_or_init(|| {
        if portable_forced() {
            Features::PORTABLE
        } else {
            detected()
        }
    })
}

/// Whether the AVX2 build may run.
#[inline(always)]
pub(crate) fn avx2() -> bool {
    features().avx2
}

/// Whether the AVX-512F builds may run.
#[inline(always)]
pub(crate) fn avx512f() -> bool {
    features().avx512f
}

/// What the CPU has (ignoring `ESTIM_FORCE_PORTABLE` and overrides): tests use it to
/// know whether a hand-tuned build can run at all.
#[cfg(any(test, feature = "testing"))]
#[must_use]
pub fn cpu() -> Features {
    detected()
}

/// Whether any thread has ever overridden the answer: while none has, [`features`]
/// skips the thread-local look-up (one relaxed load of a static).
#[cfg(any(test, feature = "testing"))]
static EVER_OVERRIDDEN: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

#[cfg(any(test, feature = "testing"))]
thread_local! {
    static OVERRIDE: std::cell::Cell<Option<Features>> = const { std::cell::Cell::new(None) };
}

/// This thread's override, if any.
#[cfg(any(test, feature = "testing"))]
#[inline(always)]
fn overridden() -> Option<Features> {
    if EVER_OVERRIDDEN.load(std::sync::atomic::Ordering::Relaxed) {
        OVERRIDE.with(std::cell::Cell::get)
    } else {
        None
    }
}

/// Run `body` with `features` on this thread (at most what the CPU has, so a
/// hand-tuned build is never chosen on a CPU without it), then restore the previous
/// answer (also when `body` panics). With `Features::PORTABLE` it runs the portable
/// path, with [`cpu`] the hand-tuned builds this CPU has, in the same process; other
/// threads are not affected.
///
/// ```
/// use estim_core::dispatch::{features, with_features, Features};
///
/// with_features(Features::PORTABLE, || assert_eq!(features(), Features::PORTABLE));
/// ```
#[cfg(any(test, feature = "testing"))]
pub fn with_features<R>(features: Features, body: impl FnOnce() -> R) -> R {
    let cpu = detected();
    let allowed = Features {
        avx2: features.avx2 && cpu.avx2,
        avx512f: features.avx512f && cpu.avx512f,
        fma: features.fma && cpu.fma,
    };
    EVER_OVERRIDDEN.store(true, std::sync::atomic::Ordering::Relaxed);
    let previous = OVERRIDE.with(|o| o.replace(Some(allowed)));
    struct Restore(Option<Features>);
    impl Drop for Restore {
        fn drop(&mut self) {
            OVERRIDE.with(|o| o.set(self.0));
        }
    }
    let _restore = Restore(previous);
    body()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_override_is_bounded_by_the_cpu_and_restored() {
        let all = Features {
            avx2: true,
            avx512f: true,
            fma: true,
        };
        with_features(Features::PORTABLE, || {
            assert_eq!(features(), Features::PORTABLE);
            with_features(all, || assert_eq!(features(), cpu()));
            assert_eq!(features(), Features::PORTABLE);
        });
        assert_eq!(
            features(),
            if portable_forced() {
                Features::PORTABLE
            } else {
                cpu()
            }
        );
    }
}
