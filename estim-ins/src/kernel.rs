//! The hand-tuned builds of estim-ins's hot loops (the covariance kernels and the
//! transition of the error model, the mechanization step), and how each build forms a
//! multiply-add.
//!
//! The math is written once, as functions generic over [`MultiplyAdd`]; the
//! [`hand_tuned!`] macro generates from such a function its builds compiled for the
//! CPU features listed and the dispatching function that picks one. Which build may run
//! is asked of estim-core's dispatch ([`estim_core::dispatch::features`]), the one CPU
//! dispatch of the workspace: `ESTIM_FORCE_PORTABLE=1` turns these builds off as it
//! turns off estim-core's, and tests run both paths in one process with
//! `estim_core::dispatch::with_features` (feature `testing`).

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

/// `fn name(args) -> R`, which runs `body::<M>(args)` in the first build of the list
/// that estim-core's dispatch allows on this CPU, else `body::<Separate>(args)` (the
/// portable build). `body` must be generic over one [`MultiplyAdd`] and should be
/// `#[inline(always)]`, so that each build compiles it with its own features.
///
/// The builds (each a safe `#[target_feature]` function nested in `name`, run when the
/// dispatch reports every feature it is compiled with):
///
/// | build | compiled with | multiply-add |
/// |---|---|---|
/// | `avx512_fma` | `avx512f`, `avx2`, `fma` | [`Fused`] |
/// | `avx2_fma` | `avx2`, `fma` | [`Fused`] |
/// | `avx2` | `avx2` | [`Separate`] (the portable build's bits, wider registers) |
///
/// ```text
/// hand_tuned! {
///     /// docs
///     fn propagate(p: &mut Cov, phi: &Cov) = propagate_body in [avx512_fma, avx2_fma];
/// }
/// ```
macro_rules! hand_tuned {
    (
        $(#[$attr:meta])*
        $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?
            = $body:ident in [$($build:ident),+ $(,)?];
    ) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            // The signature and the call as single token trees, to be repeated per build.
            $crate::kernel::hand_tuned!(
                @dispatch [$($arg: $ty),*], ($($arg),*), [$(-> $ret)?], $body, [$($build),+]
            )
        }
    };
    (@dispatch $signature:tt, $call:tt, $ret:tt, $body:ident, [$($build:ident),+]) => {{
        #[cfg(target_arch = "x86_64")]
        {
            let features = ::estim_core::dispatch::features();
            $(
                if $crate::kernel::hand_tuned!(@runs $build, features) {
                    $crate::kernel::hand_tuned!(@build $build, $signature, $ret, $body);
                    // SAFETY: a safe `#[target_feature]` function requires only that the
                    // CPU has the features it is compiled with; estim-core's dispatch
                    // reports each of them present (the `@runs` arm of the build, beside
                    // its `@build` arm), and it never reports a feature the CPU lacks,
                    // even under a test override.
                    return unsafe { $build $call };
                }
            )+
        }
        $body::<$crate::kernel::Separate> $call
    }};
    (@runs avx512_fma, $features:ident) => {
        $features.avx512f && $features.avx2 && $features.fma
    };
    (@build avx512_fma, [$($arg:ident: $ty:ty),*], [$($ret:tt)*], $body:ident) => {
        #[target_feature(enable = "avx512f,avx2,fma")]
        fn avx512_fma($($arg: $ty),*) $($ret)* {
            $body::<$crate::kernel::Fused>($($arg),*)
        }
    };
    (@runs avx2_fma, $features:ident) => {
        $features.avx2 && $features.fma
    };
    (@build avx2_fma, [$($arg:ident: $ty:ty),*], [$($ret:tt)*], $body:ident) => {
        #[target_feature(enable = "avx2,fma")]
        fn avx2_fma($($arg: $ty),*) $($ret)* {
            $body::<$crate::kernel::Fused>($($arg),*)
        }
    };
    (@runs avx2, $features:ident) => {
        $features.avx2
    };
    (@build avx2, [$($arg:ident: $ty:ty),*], [$($ret:tt)*], $body:ident) => {
        #[target_feature(enable = "avx2")]
        fn avx2($($arg: $ty),*) $($ret)* {
            $body::<$crate::kernel::Separate>($($arg),*)
        }
    };
}

pub(crate) use hand_tuned;
