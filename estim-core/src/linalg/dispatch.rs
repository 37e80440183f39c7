//! The one CPU-dispatch mechanism of estim-core: which hand-tuned build of a hot
//! loop may run on this CPU.
//!
//! Three places have a hand-tuned build beside the portable one, and all three ask
//! here:
//!
//! - the linear runner's predict and update, compiled for AVX2 ([`avx2`]);
//! - the fused product of [`super::fused`] (AVX-512F, register-blocked, fused
//!   multiply-adds; [`avx512f`]);
//! - the joint factor of [`super::cholesky`] from 8 states, compiled for AVX-512F
//!   ([`avx512f`]).
//!
//! The answer is computed once per process (a [`OnceLock`]): the CPU's features as
//! `std::arch::is_x86_feature_detected!` reports them, all off on other
//! architectures, and all off when the environment variable `ESTIM_FORCE_PORTABLE`
//! is `1` when first asked, so that the whole test suite can run on the portable
//! path of a CPU that has the features (`ESTIM_FORCE_PORTABLE=1 cargo test`).
//!
//! Unit tests compare the builds in one process with [`with_features`], which
//! overrides the answer on the calling thread only (test builds only).

use std::sync::OnceLock;

/// The hand-tuned builds this CPU may run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Features {
    /// AVX2 (4 f64 lanes): the linear runner's own build.
    pub(crate) avx2: bool,
    /// AVX-512F (8 f64 lanes, with its fused multiply-add): the fused product and
    /// the joint factor's build.
    pub(crate) avx512f: bool,
}

impl Features {
    /// No hand-tuned build: the portable path everywhere.
    pub(crate) const PORTABLE: Self = Self {
        avx2: false,
        avx512f: false,
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
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Features::PORTABLE
    }
}

/// The features the process runs with (computed on the first call).
#[inline(always)]
pub(crate) fn features() -> Features {
    #[cfg(test)]
    if let Some(forced) = OVERRIDE.with(std::cell::Cell::get) {
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
#[cfg(test)]
pub(crate) fn cpu() -> Features {
    detected()
}

#[cfg(test)]
thread_local! {
    static OVERRIDE: std::cell::Cell<Option<Features>> = const { std::cell::Cell::new(None) };
}

/// Run `body` with `features` on this thread (at most what the CPU has), then restore
/// the previous answer.
#[cfg(test)]
pub(crate) fn with_features<R>(features: Features, body: impl FnOnce() -> R) -> R {
    let cpu = detected();
    let allowed = Features {
        avx2: features.avx2 && cpu.avx2,
        avx512f: features.avx512f && cpu.avx512f,
    };
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
