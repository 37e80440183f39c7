//! Process noise Q_d over one step dt of a linear model: the closed forms of the
//! integrator chains (constant velocity, acceleration, jerk) and Van Loan's
//! discretization of any continuous model x' = F x + G w.
//!
//! | function | Q_d | reference |
//! |---|---|---|
//! | [`discrete_white_noise`] | Gamma var Gamma' (noise held constant over the step) | filterpy `Q_discrete_white_noise`; Bar-Shalom 2001 sec. 6.3.2, 6.3.3 |
//! | [`continuous_white_noise`] | int_0^dt e^{F s} L q L' e^{F' s} ds of a chain | filterpy `Q_continuous_white_noise`; Bar-Shalom 2001 sec. 6.2.2, 6.2.3 |
//! | [`van_loan`], [`van_loan_with_input`] | int_0^dt e^{F s} G Qc G' e^{F' s} ds, any F | filterpy `van_loan_discretization`; Van Loan 1978 |
//!
//! [`integrator_chain_transition`] is the chain's Phi = e^{F dt}, and
//! [`independent_axes`] repeats a one-axis matrix over several independent axes in
//! either state order filterpy offers.
//!
//! **Integrator chain of order N.** The state is a position and its first N - 1
//! derivatives, [p, p', ..., p^(N-1)] (index 0 the position), F has ones on its
//! superdiagonal, and the noise drives the last state (L = e_N):
//!
//! ```text
//! Phi_ij = dt^(j-i) / (j-i)!                                    (j >= i, else 0)
//! Q_ij   = q dt^(a+b+1) / ((a+b+1) a! b!),  a = N-1-i, b = N-1-j   (continuous)
//! ```
//!
//! ```
//! use estim_core::noise::process::{continuous_white_noise, van_loan};
//! use estim_core::nalgebra::Matrix2;
//!
//! // Constant velocity, white acceleration of spectral density 0.5 m^2/s^3, dt = 0.1 s.
//! let f = Matrix2::new(0.0, 1.0, 0.0, 0.0);
//! let density = Matrix2::new(0.0, 0.0, 0.0, 0.5); // G Qc G', G = [0, 1]'
//! let model = van_loan(&f, &density, 0.1)?;
//! let closed = continuous_white_noise::<f64, 2>(0.1, 0.5)?;
//! assert!((model.process_noise - closed).amax() < 1e-15);
//! assert!((model.transition[(0, 1)] - 0.1).abs() < 1e-15);
//! # Ok::<(), estim_core::Error>(())
//! ```
//!
//! References: R. Labbe, filterpy 2.0, `filterpy.common.discretization`;
//! Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking
//! and Navigation*, Wiley, 2001, sec. 6.2 (continuous-time kinematic models) and 6.3
//! (discrete-time ones); C. F. Van Loan, "Computing integrals involving the matrix
//! exponential", IEEE Trans. Automatic Control 23 (3), 395-404, 1978.

use nalgebra::{DMatrix, SMatrix, SVector};

use crate::error::{Error, Result};
use crate::numeric::{check_covariance, check_finite, lit, symmetrize, to_f64};
#[cfg(doc)]
use crate::numeric::{check_symmetric, relative_tolerance};
use crate::scalar::Scalar;

/// The state order of a model made of several independent axes (e.g. 2-D constant
/// velocity: two chains of order 2), for [`independent_axes`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisLayout {
    /// Each axis's derivatives together: [x, x', y, y'] (block diagonal).
    /// filterpy's `order_by_dim=True` (its default).
    ByAxis,
    /// Each derivative's axes together: [x, y, x', y'] (the one-axis matrix
    /// Kronecker the identity). filterpy's `order_by_dim=False`.
    ByDerivative,
}

/// Phi and Q_d of one step of a continuous model, from [`van_loan`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscreteModel<T: Scalar, const N: usize> {
    /// Phi = e^{F dt}.
    pub transition: SMatrix<T, N, N>,
    /// Q_d = int_0^dt e^{F s} G Qc G' e^{F' s} ds, symmetric (its two triangles
    /// averaged), in the state's units squared.
    pub process_noise: SMatrix<T, N, N>,
}

/// The gain Gamma of the discrete white-noise model of an integrator chain of order
/// N = 2, 3 or 4 (the noise's effect on the state over one step dt, filterpy's
/// convention):
///
/// ```text
/// N = 2:  Gamma = [dt^2/2, dt]'                 (white acceleration held over the step)
/// N >= 3: Gamma = [dt^(N-1)/(N-1)!, ..., dt, 1]'  (increment of the last state per step)
/// ```
///
/// N = 2 is Bar-Shalom's discrete white noise acceleration model (sec. 6.3.2): the
/// noise is the acceleration, one derivative beyond the state. N = 3 is the discrete
/// Wiener process acceleration model (sec. 6.3.3) and N = 4 its jerk analogue: the
/// noise is the increment of the last state over the step.
///
/// # Errors
/// [`Error::InvalidParameter`] when N is not 2, 3 or 4 (`name: "N"`) or dt is not
/// finite and positive (`name: "dt"`).
/// [`Error::Overflow`] when a result entry is beyond the scalar's range (e.g.
/// dt = 1e300: dt^2 and higher powers overflow).
pub fn discrete_white_noise_gain<T: Scalar, const N: usize>(dt: T) -> Result<SVector<T, N>> {
    check_order::<N>(2, 4)?;
    check_dt(dt)?;
    // Entry i is dt^k / k!, k = N-1-i for N >= 3, k = N-i for N = 2.
    let top = if N == 2 { N } else { N - 1 };
    finite_result(
        SVector::from_fn(|i, _| power_over_factorial(dt, top - i)),
        "discrete white-noise gain",
    )
}

/// Q_d = Gamma var Gamma' of the discrete (piecewise constant) white-noise model of an
/// integrator chain of order N = 2, 3 or 4, Gamma from [`discrete_white_noise_gain`]:
/// filterpy's `Q_discrete_white_noise(N, dt, var)` (Bar-Shalom 2001 sec. 6.3.2, 6.3.3).
///
/// N = 2 (state [p, p']): `variance` is the variance of the acceleration held
/// constant over each step, in (units of p / s^2)^2; N = 3 and 4: the variance of the
/// increment of the last state (acceleration, jerk) over one step, in its units
/// squared. dt in seconds (or the model's time unit).
///
/// ```
/// use estim_core::noise::process::discrete_white_noise;
/// let q = discrete_white_noise::<f64, 2>(0.1, 2.0)?;
/// assert!((q[(0, 0)] - 0.25 * 1e-4 * 2.0).abs() < 1e-18); // dt^4/4 var
/// assert!((q[(1, 1)] - 1e-2 * 2.0).abs() < 1e-16);        // dt^2 var
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::InvalidParameter`] when N is not 2, 3 or 4, dt is not finite and
/// positive, or `variance` is not finite and >= 0.
/// [`Error::Overflow`] when a result entry is beyond the scalar's range (e.g.
/// dt = 1e300: dt^2 and higher powers overflow).
pub fn discrete_white_noise<T: Scalar, const N: usize>(
    dt: T,
    variance: T,
) -> Result<SMatrix<T, N, N>> {
    check_scale(variance, "variance")?;
    let gamma = discrete_white_noise_gain::<T, N>(dt)?;
    finite_result(
        gamma * gamma.transpose() * variance,
        "discrete white noise Q_d",
    )
}

/// Q_d = int_0^dt e^{F s} L q L' e^{F' s} ds of an integrator chain of order N >= 1
/// driven by continuous white noise on its last state (L = e_N), in closed form:
/// Q_ij = q dt^(a+b+1) / ((a+b+1) a! b!), a = N-1-i, b = N-1-j (module docs). For
/// N = 2, 3, 4 it is filterpy's `Q_continuous_white_noise(N, dt, spectral_density)`
/// (Bar-Shalom 2001 sec. 6.2.2 continuous white noise acceleration, sec. 6.2.3
/// continuous Wiener process acceleration); N = 1 is a random walk, Q = q dt.
///
/// `spectral_density` q is the power spectral density of the white noise driving the
/// last state p^(N-1): in (units of p^(N-1))^2 / s, e.g. m^2/s^3 for the white
/// acceleration of constant velocity (N = 2). Its variance over a step is q dt.
///
/// # Errors
/// [`Error::InvalidParameter`] when N = 0, dt is not finite and positive, or
/// `spectral_density` is not finite and >= 0.
/// [`Error::Overflow`] when a result entry is beyond the scalar's range (e.g.
/// dt = 1e300: dt^2 and higher powers overflow).
pub fn continuous_white_noise<T: Scalar, const N: usize>(
    dt: T,
    spectral_density: T,
) -> Result<SMatrix<T, N, N>> {
    check_order::<N>(1, usize::MAX)?;
    check_dt(dt)?;
    check_scale(spectral_density, "spectral_density")?;
    let q = SMatrix::from_fn(|i, j| {
        let (a, b) = (N - 1 - i, N - 1 - j);
        // dt^a/a! dt^b/b! dt / (a+b+1): the integral of s^(a+b) / (a! b!).
        power_over_factorial(dt, a) * power_over_factorial(dt, b) * dt * spectral_density
            / lit::<T>((a + b + 1) as f64)
    });
    finite_result(q, "continuous white noise Q_d")
}

/// The transition Phi = e^{F dt} of an integrator chain of order N >= 1 (F with ones
/// on its superdiagonal): Phi_ij = dt^(j-i) / (j-i)! for j >= i, 0 below the
/// diagonal. For N = 3: [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]].
///
/// # Errors
/// [`Error::InvalidParameter`] when N = 0 or dt is not finite and positive.
/// [`Error::Overflow`] when a result entry is beyond the scalar's range (e.g.
/// dt = 1e300: dt^2 and higher powers overflow).
pub fn integrator_chain_transition<T: Scalar, const N: usize>(dt: T) -> Result<SMatrix<T, N, N>> {
    check_order::<N>(1, usize::MAX)?;
    check_dt(dt)?;
    let phi = SMatrix::from_fn(|i, j| {
        if j >= i {
            power_over_factorial(dt, j - i)
        } else {
            T::zero()
        }
    });
    finite_result(phi, "integrator chain transition")
}

/// `value` if every entry is finite, else [`Error::Overflow`]: finite inputs (dt,
/// variance) whose powers leave the scalar's range (dt = 1e300 gives dt^4 = inf).
fn finite_result<T: Scalar, const R: usize, const C: usize>(
    value: SMatrix<T, R, C>,
    what: &'static str,
) -> Result<SMatrix<T, R, C>> {
    if crate::gaussian::all_finite(value.as_slice()) {
        Ok(value)
    } else {
        Err(Error::Overflow { what })
    }
}

/// The S x S matrix of S / N independent axes that each have the N x N matrix
/// `per_axis` (a Q_d, a Phi or an F), in the state order `layout`:
///
/// ```text
/// ByAxis        out[(a N + i, b N + j)] = per_axis[(i, j)] if a = b, else 0
/// ByDerivative  out[(i A + a, j A + b)] = per_axis[(i, j)] if a = b, else 0   (A = S / N axes)
/// ```
///
/// filterpy's `block_size = S / N` with `order_by_dim = True` (ByAxis) or `False`
/// (ByDerivative).
///
/// ```
/// use estim_core::noise::process::{discrete_white_noise, independent_axes, AxisLayout};
/// use estim_core::nalgebra::Matrix4;
///
/// // 2-D constant velocity, state [x, y, vx, vy].
/// let q_axis = discrete_white_noise::<f64, 2>(0.5, 1.0)?;
/// let q: Matrix4<f64> = independent_axes(&q_axis, AxisLayout::ByDerivative)?;
/// assert_eq!(q[(0, 2)], q_axis[(0, 1)]); // x with vx
/// assert_eq!(q[(0, 1)], 0.0);            // x with y
/// # Ok::<(), estim_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::Dimension`] when S is not a positive multiple of N (`expected` is the
/// next multiple of N, at least N).
pub fn independent_axes<T: Scalar, const N: usize, const S: usize>(
    per_axis: &SMatrix<T, N, N>,
    layout: AxisLayout,
) -> Result<SMatrix<T, S, S>> {
    if N == 0 || S == 0 || !S.is_multiple_of(N) {
        return Err(Error::Dimension {
            what: "independent axes (state size, a multiple of the per-axis size)",
            expected: N.max(S.div_ceil(N.max(1)) * N),
            got: S,
        });
    }
    let axes = S / N;
    let mut out = SMatrix::<T, S, S>::zeros();
    for axis in 0..axes {
        for j in 0..N {
            for i in 0..N {
                let (row, col) = match layout {
                    AxisLayout::ByAxis => (axis * N + i, axis * N + j),
                    AxisLayout::ByDerivative => (i * axes + axis, j * axes + axis),
                };
                out[(row, col)] = per_axis[(i, j)];
            }
        }
    }
    Ok(out)
}

/// Phi = e^{F dt} and Q_d = int_0^dt e^{F s} G Qc G' e^{F' s} ds of the continuous
/// model x' = F x + G w, E[w(t) w(s)'] = Qc delta(t - s), by Van Loan's method (Van
/// Loan 1978, sec. 4; filterpy's `van_loan_discretization(F, G, dt)` with its unit
/// white noise, i.e. `noise_density` = G G'):
///
/// ```text
/// C = [[-F, G Qc G'], [0, F']] dt       (2N x 2N)
/// e^C = [[., B12], [0, B22]]            Phi = B22',  Q_d = Phi B12
/// ```
///
/// `dynamics` is F (1/s), `noise_density` is G Qc G' (N x N, the spectral density of
/// the noise in state space: state units squared per second), dt > 0 in seconds.
/// The exponential is nalgebra's [`nalgebra::Matrix::exp`] (Padé with scaling and
/// squaring, Higham 2005) of the dynamic 2N x 2N matrix; Q_d is returned symmetrized.
/// It allocates (cold path: once per model, or per step of a time-varying one).
///
/// Accuracy: to round-off relative to the largest entry of Q_d and Phi (measured
/// 1e-15 against the closed forms and filterpy, 4e-14 against a quadrature), not
/// entry by entry: for a small C nalgebra picks a low-degree Padé approximant whose
/// high-order terms are off, so entries that are high powers of dt are too. The
/// position variance of an integrator chain of order 4..6 at dt <= 0.01 is off by
/// 2.5e-3..8.3e-3 of itself (below 1e-16 of the largest entry); use
/// [`continuous_white_noise`] for chains.
///
/// The block e^{-F dt} overflows when F dt has eigenvalues far in the left half
/// plane (a stiff stable F, real part below about -700 in f64) even though Phi and
/// Q_d are finite: such a model is [`Error::NonFinite`]; split dt into shorter steps.
///
/// # Errors
/// - [`Error::InvalidParameter`] (`name: "dt"`) when dt is not finite and positive;
///   (`name: "F dt"`) when the 1-norm of C exceeds T::MAX^(1/12) (4e25 in f64, 1.6e3 in
///   f32), beyond which the exponential's norm estimates overflow.
/// - [`Error::NonFinite`] when F or G Qc G' holds NaN or infinity, or the exponential
///   overflowed (`what: "Van Loan exponential"`).
/// - [`Error::InvalidCovariance`] when G Qc G' is not symmetric to round-off
///   ([`check_symmetric`]) or not positive semidefinite: the smallest eigenvalue of its
///   correlation matrix (unit diagonal) is below -[`relative_tolerance`] (9.3e-10 in
///   f64), or a variance is negative ([`check_covariance`]).
pub fn van_loan<T: Scalar, const N: usize>(
    dynamics: &SMatrix<T, N, N>,
    noise_density: &SMatrix<T, N, N>,
    dt: T,
) -> Result<DiscreteModel<T, N>> {
    check_dt(dt)?;
    check_finite(dynamics.as_slice(), "F (continuous dynamics)")?;
    check_covariance(noise_density, "G Qc G' (continuous noise density)")?;
    let density = symmetrize(noise_density);
    if N == 0 {
        return Ok(DiscreteModel {
            transition: SMatrix::identity(),
            process_noise: SMatrix::zeros(),
        });
    }
    let mut c = DMatrix::<T>::zeros(2 * N, 2 * N);
    for j in 0..N {
        for i in 0..N {
            c[(i, j)] = -dynamics[(i, j)] * dt;
            c[(i, N + j)] = density[(i, j)] * dt;
            c[(N + i, N + j)] = dynamics[(j, i)] * dt;
        }
    }
    // nalgebra's exp squares ceil(log2(norm / 4.25)) times and forms powers up to the
    // 10th for its norm estimates: a norm whose 10th power overflows would make the
    // squaring count infinite.
    let limit = T::max_value()
        .unwrap_or_else(|| lit(f64::MAX))
        .powf(lit(1.0 / 12.0));
    let norm = c
        .column_iter()
        .fold(T::zero(), |m, col| m.max(col.lp_norm(1)));
    if norm > limit || !norm.is_finite() {
        return Err(Error::InvalidParameter {
            name: "F dt",
            reason: format!(
                "the Van Loan block matrix has 1-norm {:e}, above {:e}",
                to_f64(norm),
                to_f64(limit)
            ),
        });
    }
    let e = c.exp();
    let transition = SMatrix::<T, N, N>::from_fn(|i, j| e[(N + j, N + i)]);
    let upper = SMatrix::<T, N, N>::from_fn(|i, j| e[(i, N + j)]);
    let process_noise = symmetrize(&(transition * upper));
    check_finite(transition.as_slice(), "Van Loan exponential")?;
    check_finite(process_noise.as_slice(), "Van Loan exponential")?;
    Ok(DiscreteModel {
        transition,
        process_noise,
    })
}

/// [`van_loan`] of x' = F x + G w with the noise input G (N x P, state units per
/// noise unit) and the noise's spectral density Qc (P x P, noise units squared per
/// second) given apart: Qc is checked (finite, symmetric, positive semidefinite, as
/// [`van_loan`] checks G Qc G'), then G Qc G' is formed and discretized.
///
/// # Errors
/// Those of [`van_loan`]; [`Error::NonFinite`] when G holds NaN or infinity;
/// [`Error::InvalidCovariance`] with `what: "Qc (continuous noise spectral density)"`
/// when Qc is not symmetric positive semidefinite.
pub fn van_loan_with_input<T: Scalar, const N: usize, const P: usize>(
    dynamics: &SMatrix<T, N, N>,
    noise_input: &SMatrix<T, N, P>,
    spectral_density: &SMatrix<T, P, P>,
    dt: T,
) -> Result<DiscreteModel<T, N>> {
    check_finite(noise_input.as_slice(), "G (noise input)")?;
    check_covariance(spectral_density, "Qc (continuous noise spectral density)")?;
    let density = noise_input * symmetrize(spectral_density) * noise_input.transpose();
    van_loan(dynamics, &density, dt)
}

/// dt^k / k!, by k multiplications of dt / m (m = 1..k), exact for k = 0 and 1.
fn power_over_factorial<T: Scalar>(dt: T, k: usize) -> T {
    (1..=k).fold(T::one(), |acc, m| acc * dt / lit::<T>(m as f64))
}

fn check_order<const N: usize>(min: usize, max: usize) -> Result<()> {
    if (min..=max).contains(&N) {
        Ok(())
    } else if max == usize::MAX {
        Err(Error::InvalidParameter {
            name: "N",
            reason: format!("integrator chain order {N} is below {min}"),
        })
    } else {
        Err(Error::InvalidParameter {
            name: "N",
            reason: format!("integrator chain order {N} is outside {min}..={max}"),
        })
    }
}

fn check_dt<T: Scalar>(dt: T) -> Result<()> {
    if dt.is_finite() && dt > T::zero() {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: "dt",
            reason: format!("{} is not a positive finite time step", to_f64(dt)),
        })
    }
}

fn check_scale<T: Scalar>(value: T, name: &'static str) -> Result<()> {
    if value.is_finite() && value >= T::zero() {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name,
            reason: format!("{} is not finite and >= 0", to_f64(value)),
        })
    }
}
