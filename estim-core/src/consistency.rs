//! Consistency tools: NEES, NIS, chi-square bounds for Monte Carlo averages, and a
//! seeded parallel Monte Carlo helper.
//!
//! For a consistent filter the NEES e' P^-1 e of an N-state estimate error e is
//! chi-square(N); the average over R independent runs, times R, is chi-square(N R).
//! Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and
//! Navigation*, 2001, sec. 5.4.2.

/// The generator [`monte_carlo`] hands each run (re-exported so callers need not
/// guess its version).
#[cfg(feature = "consistency")]
pub use rand_chacha;

use nalgebra::{SMatrix, SVector};
#[cfg(feature = "consistency")]
use rand::SeedableRng;
#[cfg(feature = "consistency")]
use rand_chacha::ChaCha8Rng;
#[cfg(feature = "consistency")]
use rayon::prelude::*;
#[cfg(feature = "consistency")]
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

use crate::gaussian::{check_finite, check_symmetric};
use crate::scalar::to_f64;
use crate::{Error, Result, Scalar};

/// Normalised estimation error squared e' P^-1 e, e = truth - estimate.
///
/// Computed scale-free: with D = diag(P), e' P^-1 e = w' C^-1 w where w = D^-1/2 e and
/// C = D^-1/2 P D^-1/2 (unit diagonal), so a covariance of 1e300 or 1e-300 (any units)
/// gives the same number as its rescaled twin; only a NEES that is itself beyond the
/// scalar's range is an error.
///
/// ```
/// use estim_core::consistency::nees;
/// use estim_core::nalgebra::{Matrix2, Vector2};
///
/// let p = Matrix2::new(2.0, 0.5, 0.5, 1.0);
/// let e = Vector2::new(0.3, -1.2);
/// let unit = nees(&e, &p)?;
/// // The same error and covariance in units 1e150 times smaller.
/// let tiny: f64 = nees(&(e * 1e-150), &(p * 1e-300))?;
/// assert!((tiny - unit).abs() <= 1e-14 * unit);
/// // Not symmetric: refused, not read from one triangle.
/// assert!(nees(&e, &Matrix2::new(2.0, 0.5, -0.5, 1.0)).is_err());
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::NonFinite`] for non-finite input; [`Error::InvalidCovariance`] if P is not
/// symmetric ([`crate::numeric::check_symmetric`]) or not positive definite (a
/// variance <= 0, or no Cholesky factor of C); [`Error::Overflow`] when the NEES
/// itself is beyond the scalar's range.
pub fn nees<T: Scalar, const N: usize>(
    error: &SVector<T, N>,
    covariance: &SMatrix<T, N, N>,
) -> Result<T> {
    quadratic_form(error, covariance, "state covariance")
}

/// Normalised innovation squared nu' S^-1 nu, computed as [`nees`] (scale-free).
///
/// # Errors
/// As [`nees`].
pub fn nis<T: Scalar, const M: usize>(
    innovation: &SVector<T, M>,
    innovation_covariance: &SMatrix<T, M, M>,
) -> Result<T> {
    quadratic_form(innovation, innovation_covariance, "innovation covariance")
}

fn quadratic_form<T: Scalar, const N: usize>(
    v: &SVector<T, N>,
    c: &SMatrix<T, N, N>,
    what: &'static str,
) -> Result<T> {
    check_finite(v.as_slice(), "error vector")?;
    check_finite(c.as_slice(), what)?;
    check_symmetric(c, what)?;
    let not_positive_definite = || Error::InvalidCovariance {
        what,
        reason: "not positive definite".into(),
    };
    if (0..N).any(|i| c[(i, i)] <= T::zero()) {
        return Err(not_positive_definite());
    }
    // Scale-free (see `nees`): divide by each standard deviation in turn, never by a
    // product of two, so that neither overflows nor underflows.
    let sd = c.diagonal().map(|d| d.sqrt());
    let w = SVector::<T, N>::from_fn(|i, _| v[i] / sd[i]);
    let half = crate::scalar::lit::<T>(0.5);
    let correlation =
        SMatrix::<T, N, N>::from_fn(|i, j| (c[(i, j)] + c[(j, i)]) * half / sd[i] / sd[j]);
    let chol = correlation.cholesky().ok_or_else(not_positive_definite)?;
    let value = w.dot(&chol.solve(&w));
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::Overflow {
            what: "normalised squared error (NEES or NIS)",
        })
    }
}

/// Two-sided probability interval of an average of chi-square variables.
#[cfg(feature = "consistency")]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChiSquareBand {
    /// Lower bound.
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// Probability mass inside [lower, upper].
    pub probability: f64,
}

#[cfg(feature = "consistency")]
impl ChiSquareBand {
    /// Whether `value` lies inside the band (bounds included).
    pub fn contains(&self, value: f64) -> bool {
        value >= self.lower && value <= self.upper
    }
}

/// Two-sided band of probability `probability` for the average of `runs` independent
/// chi-square(`dof`) values: [chi2_{dof runs}((1-p)/2), chi2_{dof runs}((1+p)/2)] / runs.
///
/// `chi_square_band(2, 200, 0.95)` is the 95 % band of the average NEES of a 2-state
/// filter over 200 Monte Carlo runs. Above [`WILSON_HILFERTY_DOF`] total degrees of
/// freedom the quantiles are Wilson-Hilferty's (microseconds at any size).
///
/// ```
/// use estim_core::consistency::chi_square_band;
///
/// let band = chi_square_band(2, 50, 0.95)?; // Bar-Shalom et al. 2001, sec. 5.4.2
/// assert!((band.lower - 1.5).abs() < 0.02 && (band.upper - 2.6).abs() < 0.02);
/// let huge = chi_square_band(1, 1 << 52, 0.95)?; // fast: Wilson-Hilferty
/// assert!(huge.contains(1.0) && huge.upper - huge.lower < 1e-6);
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::InvalidParameter`] for `dof` or `runs` zero, `dof * runs` overflowing
/// `usize` or beyond 2^53 (not exact as an `f64` degree of freedom), or `probability`
/// outside (0, 1).
#[cfg(feature = "consistency")]
pub fn chi_square_band(dof: usize, runs: usize, probability: f64) -> Result<ChiSquareBand> {
    if dof == 0 || runs == 0 {
        return Err(Error::InvalidParameter {
            name: "dof, runs",
            reason: format!("both must be positive (dof {dof}, runs {runs})"),
        });
    }
    if !(probability > 0.0 && probability < 1.0) {
        return Err(Error::InvalidParameter {
            name: "probability",
            reason: format!("{probability} is not in (0, 1)"),
        });
    }
    // Checked: dof * runs can overflow usize, and above 2^53 the f64 degree of freedom
    // would silently round.
    let total = dof
        .checked_mul(runs)
        .filter(|t| *t <= 1usize << 53)
        .ok_or_else(|| Error::InvalidParameter {
            name: "dof, runs",
            reason: format!("dof * runs = {dof} * {runs} overflows (limit 2^53)"),
        })? as f64;
    let tail = (1.0 - probability) / 2.0;
    Ok(ChiSquareBand {
        lower: chi_square_quantile(total, tail)? / runs as f64,
        upper: chi_square_quantile(total, 1.0 - tail)? / runs as f64,
        probability,
    })
}

#[cfg(feature = "consistency")]
/// Degrees of freedom above which [`chi_square_band`] (and the gate's
/// [`crate::Gate::Nis`] threshold) take the chi-square quantile from the
/// Wilson-Hilferty approximation instead of statrs's inversion of the CDF, whose cost
/// grows with the degrees of freedom (30 s at 2^52). Just above the threshold, 2^20 + 1
/// dof, the two agree to 2.6e-9 relative for bands of probability 0.5 to 0.999999
/// (`tests/not_a_covariance.rs`), 3.2e-10 at 2^22; the approximation's error falls
/// as the degrees of freedom grow.
pub const WILSON_HILFERTY_DOF: usize = 1 << 20;

#[cfg(feature = "consistency")]
/// The `probability` quantile of chi-square(`dof`): statrs up to
/// [`WILSON_HILFERTY_DOF`], beyond it Wilson & Hilferty (1931): chi2_p(k) =
/// k (1 - 2/(9k) + z_p sqrt(2/(9k)))^3, z_p the standard normal quantile.
pub(crate) fn chi_square_quantile(dof: f64, probability: f64) -> Result<f64> {
    let value = if dof > WILSON_HILFERTY_DOF as f64 {
        wilson_hilferty(dof, probability)?
    } else {
        ChiSquared::new(dof)
            .map_err(|e| Error::InvalidParameter {
                name: "dof",
                reason: format!("chi-square with {dof} degrees of freedom: {e}"),
            })?
            .inverse_cdf(probability)
    };
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::Overflow {
            what: "chi-square quantile",
        })
    }
}

#[cfg(feature = "consistency")]
/// Wilson & Hilferty (1931), "The distribution of chi-square", PNAS 17 (12): the cube
/// root of chi2(k) / k is nearly normal with mean 1 - 2/(9k) and variance 2/(9k).
fn wilson_hilferty(dof: f64, probability: f64) -> Result<f64> {
    let normal = Normal::new(0.0, 1.0).map_err(|e| Error::InvalidParameter {
        name: "dof",
        reason: e.to_string(),
    })?;
    let z = normal.inverse_cdf(probability);
    let a = 2.0 / (9.0 * dof);
    Ok(dof * (1.0 - a + z * a.sqrt()).powi(3))
}

/// Run `run(index, rng)` for index 0..runs in parallel (rayon), each with its own
/// `ChaCha8Rng::seed_from_u64(index)`; results in index order, identical whatever
/// the number of threads.
#[cfg(feature = "consistency")]
pub fn monte_carlo<R, F>(runs: usize, run: F) -> Vec<R>
where
    R: Send,
    F: Fn(usize, &mut ChaCha8Rng) -> R + Sync,
{
    (0..runs)
        .into_par_iter()
        .map(|i| {
            let mut rng = ChaCha8Rng::seed_from_u64(i as u64);
            run(i, &mut rng)
        })
        .collect()
}

/// Average per time step of equally long per-run series (e.g. NEES of each run):
/// `series[run][step]` -> `mean[step]`.
///
/// # Errors
/// [`Error::Dimension`] if the runs differ in length, [`Error::InvalidParameter`] if
/// there are none, [`Error::NonFinite`] if a value is not finite.
pub fn average_over_runs<T: Scalar>(series: &[Vec<T>]) -> Result<Vec<f64>> {
    let first = series.first().ok_or_else(|| Error::InvalidParameter {
        name: "series",
        reason: "no runs".into(),
    })?;
    let steps = first.len();
    let mut mean = vec![0.0; steps];
    for run in series {
        if run.len() != steps {
            return Err(Error::Dimension {
                what: "Monte Carlo run length",
                expected: steps,
                got: run.len(),
            });
        }
        check_finite(run, "Monte Carlo series")?;
        for (m, v) in mean.iter_mut().zip(run) {
            *m += to_f64(*v);
        }
    }
    let n = series.len() as f64;
    mean.iter_mut().for_each(|m| *m /= n);
    Ok(mean)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Vector2};
    #[cfg(feature = "consistency")]
    use rand::RngExt;

    #[test]
    #[cfg(feature = "consistency")]
    fn band_rejects_overflowing_sizes() {
        for (dof, runs) in [(usize::MAX, 2), (1 << 40, 1 << 40), ((1 << 53) + 1, 1)] {
            assert!(matches!(
                chi_square_band(dof, runs, 0.95),
                Err(Error::InvalidParameter {
                    name: "dof, runs",
                    ..
                })
            ));
        }
    }

    #[test]
    #[cfg(feature = "consistency")]
    fn band_matches_published_quantiles() {
        // One run of dof 2: the 2.5 % and 97.5 % quantiles of chi-square(2) are
        // -2 ln(0.975) and -2 ln(0.025) (closed form for 2 dof).
        let b = chi_square_band(2, 1, 0.95).unwrap();
        assert!((b.lower - (-2.0 * 0.975f64.ln())).abs() < 1e-9);
        assert!((b.upper - (-2.0 * 0.025f64.ln())).abs() < 1e-9);
        // Bar-Shalom et al. 2001, example of sec. 5.4.2: N = 50 runs, n = 2 states,
        // 95 % band of the average NEES is [1.5, 2.6].
        let b = chi_square_band(2, 50, 0.95).unwrap();
        assert!(
            (b.lower - 1.5).abs() < 0.02 && (b.upper - 2.6).abs() < 0.02,
            "{b:?}"
        );
        assert!(chi_square_band(0, 5, 0.95).is_err());
        assert!(chi_square_band(2, 5, 1.0).is_err());
    }

    #[test]
    fn nees_matches_explicit_inverse() {
        let p = Matrix2::<f64>::new(2.0, 0.5, 0.5, 1.0);
        let e = Vector2::new(0.3, -1.2);
        let expected = (e.transpose() * p.try_inverse().unwrap() * e)[0];
        assert!((nees(&e, &p).unwrap() - expected).abs() < 1e-12);
        assert!(nees(&e, &Matrix2::new(1.0, 2.0, 2.0, 1.0)).is_err());
        assert!(nis(&Vector2::new(f64::NAN, 0.0), &p).is_err());
    }

    #[test]
    #[cfg(feature = "consistency")]
    fn monte_carlo_is_deterministic_and_ordered() {
        let a = monte_carlo(64, |i, rng| (i, rng.random::<u64>()));
        let b = monte_carlo(64, |i, rng| (i, rng.random::<u64>()));
        assert_eq!(a, b);
        for (k, (i, v)) in a.iter().enumerate() {
            assert_eq!(k, *i);
            let mut rng = ChaCha8Rng::seed_from_u64(k as u64);
            assert_eq!(*v, rng.random::<u64>());
        }
    }

    #[test]
    fn average_over_runs_checks_lengths() {
        let m = average_over_runs(&[vec![1.0, 2.0], vec![3.0, 4.0]]).unwrap();
        assert_eq!(m, vec![2.0, 3.0]);
        assert!(average_over_runs(&[vec![1.0], vec![1.0, 2.0]]).is_err());
        assert!(average_over_runs::<f64>(&[]).is_err());
    }
}
