//! The four model traits: process, measurement, cross-covariance, learned measurement.

use nalgebra::{DMatrix, SMatrix, SVector};

use crate::{Result, Scalar};

/// Propagates a state over `dt` with an input, and linearises that propagation.
///
/// Discrete-time model: x_k = f(x_{k-1}, u) + G w_{k-1}, Cov(G w) = `process_noise`.
/// For a plain (extended) Kalman filter `State` is `SVector<T, N>`; for an
/// error-state filter it is the nominal state and `N` is the size of the error state
/// (see [`ErrorStateModel`]).
///
/// ```
/// use estim_core::nalgebra::{Matrix2, Vector2};
/// use estim_core::{ExtendedKalmanFilter, ProcessModel, Result, StateAndCovariance};
///
/// /// Position and velocity on a line, velocity a random walk of PSD `q`.
/// struct ConstantVelocity { q: f64 }
///
/// impl ProcessModel<f64, 2> for ConstantVelocity {
///     type State = Vector2<f64>;
///     type Input = ();
///     fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
///         Ok(Vector2::new(x[0] + dt * x[1], x[1]))
///     }
///     fn transition(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
///     }
///     fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         // Discretised white-noise acceleration (Bar-Shalom et al. 2001, eq. 6.2.3-8).
///         let (d2, d3) = (dt * dt, dt * dt * dt);
///         Ok(Matrix2::new(d3 / 3.0, d2 / 2.0, d2 / 2.0, dt) * self.q)
///     }
/// }
///
/// let initial = StateAndCovariance::new(Vector2::new(0.0, 1.0), Matrix2::identity())?;
/// let mut ekf = ExtendedKalmanFilter::new(ConstantVelocity { q: 0.1 }, initial);
/// ekf.predict(&(), 0.5)?;
/// assert_eq!(ekf.estimate().state()[0], 0.5);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait ProcessModel<T: Scalar, const N: usize> {
    /// The (nominal) state propagated by [`ProcessModel::propagate`].
    type State: Clone;
    /// The input driving the process (control, IMU sample, `()` if none).
    type Input;

    /// x_k = f(x_{k-1}, u) over `dt`.
    fn propagate(&self, state: &Self::State, input: &Self::Input, dt: T) -> Result<Self::State>;

    /// Discrete transition matrix Phi over `dt` (Jacobian of `propagate` with respect
    /// to the state, or the error-state transition).
    fn transition(
        &self,
        state: &Self::State,
        input: &Self::Input,
        dt: T,
    ) -> Result<SMatrix<T, N, N>>;

    /// Discrete process-noise covariance in state space, Cov(G w) over `dt`.
    fn process_noise(
        &self,
        state: &Self::State,
        input: &Self::Input,
        dt: T,
    ) -> Result<SMatrix<T, N, N>>;

    /// Phi and Q_d together, as the runners ask for them. The default calls
    /// [`ProcessModel::transition`] then [`ProcessModel::process_noise`]; override it
    /// when both share work (e.g. Q_d computed from the same discretised system
    /// matrix as Phi). The result must equal the default's.
    fn transition_and_noise(
        &self,
        state: &Self::State,
        input: &Self::Input,
        dt: T,
    ) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>)> {
        Ok((
            self.transition(state, input, dt)?,
            self.process_noise(state, input, dt)?,
        ))
    }

    /// P_k = Phi P_{k-1} Phi' + Q. Override to exploit the structure of Phi
    /// (e.g. its sparsity); the result must equal this default.
    fn propagate_covariance(
        &self,
        covariance: &SMatrix<T, N, N>,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
    ) -> SMatrix<T, N, N> {
        transition * covariance * transition.transpose() + process_noise
    }

    /// Phi_later Phi_earlier, the transition over two consecutive intervals: the
    /// runners' accumulated transition Phi_acc <- Phi Phi_acc between updates (when
    /// [`crate::FilterConfig::track_accumulated_noise`] is on). Override to exploit the
    /// structure of Phi (as [`ProcessModel::propagate_covariance`]); the result must
    /// equal this default, the dense product.
    fn compose_transitions(
        &self,
        later: &SMatrix<T, N, N>,
        earlier: &SMatrix<T, N, N>,
    ) -> SMatrix<T, N, N> {
        crate::linalg::mul_static(later, earlier)
    }
}

/// A process model whose filter estimates an error around a nominal state.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Vector1};
/// use estim_core::{ErrorStateKalmanFilter, ErrorStateModel, ProcessModel, Result};
///
/// /// A heading (rad) integrated from a gyro rate, wrapped to (-pi, pi];
/// /// convention: true = nominal + error.
/// struct Heading { gyro_noise_psd: f64 }
///
/// fn wrap(a: f64) -> f64 { (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI }
///
/// impl ProcessModel<f64, 1> for Heading {
///     type State = f64;
///     type Input = f64; // measured rate
///     fn propagate(&self, h: &f64, rate: &f64, dt: f64) -> Result<f64> { Ok(wrap(h + rate * dt)) }
///     fn transition(&self, _: &f64, _: &f64, _: f64) -> Result<Matrix1<f64>> { Ok(Matrix1::identity()) }
///     fn process_noise(&self, _: &f64, _: &f64, dt: f64) -> Result<Matrix1<f64>> {
///         Ok(Matrix1::new(self.gyro_noise_psd * dt))
///     }
/// }
///
/// impl ErrorStateModel<f64, 1> for Heading {
///     fn inject(&self, h: &f64, error: &Vector1<f64>) -> Result<f64> { Ok(wrap(h + error[0])) }
/// }
///
/// let mut eskf = ErrorStateKalmanFilter::new(Heading { gyro_noise_psd: 1e-4 }, 3.1, Matrix1::new(0.01))?;
/// eskf.predict(&0.1, 1.0)?; // crosses +pi, wraps
/// assert!(*eskf.nominal() < 0.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait ErrorStateModel<T: Scalar, const N: usize>: ProcessModel<T, N> {
    /// Fold an estimated error into the nominal state (the convention, e.g.
    /// true = nominal + error, is the implementor's and must be documented).
    fn inject(&self, nominal: &Self::State, error: &SVector<T, N>) -> Result<Self::State>;

    /// Jacobian of the error reset applied to the covariance after injection,
    /// P <- J P J'. Identity unless the implementor needs otherwise.
    fn reset_jacobian(&self, _nominal: &Self::State, _error: &SVector<T, N>) -> SMatrix<T, N, N> {
        SMatrix::identity()
    }
}

/// Predicts a measurement of size `M` from a state with `N` (error) states.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix1x2, Vector1, Vector2};
/// use estim_core::{MeasurementModel, Result};
///
/// /// Range to a point at the origin from a 2-D position.
/// struct Range { sigma: f64 }
///
/// impl MeasurementModel<f64, 2, 1> for Range {
///     type State = Vector2<f64>;
///     fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> { Ok(Vector1::new(x.norm())) }
///     fn jacobian(&self, x: &Vector2<f64>) -> Result<Matrix1x2<f64>> {
///         let r = x.norm();
///         if r == 0.0 {
///             return Err(estim_core::Error::Model("range jacobian undefined at the origin".into()));
///         }
///         Ok(x.transpose() / r)
///     }
///     fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
///         Ok(Matrix1::new(self.sigma * self.sigma))
///     }
/// }
///
/// let range = Range { sigma: 0.1 };
/// assert_eq!(range.predict(&Vector2::new(3.0, 4.0))?[0], 5.0);
/// assert!(range.jacobian(&Vector2::zeros()).is_err());
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait MeasurementModel<T: Scalar, const N: usize, const M: usize> {
    /// The state the prediction is made from (full or nominal state).
    type State;

    /// h(x).
    fn predict(&self, state: &Self::State) -> Result<SVector<T, M>>;

    /// H = dh/dx (with respect to the error state for error-state filters).
    fn jacobian(&self, state: &Self::State) -> Result<SMatrix<T, M, N>>;

    /// Measurement-noise covariance R.
    fn noise_covariance(&self, state: &Self::State) -> Result<SMatrix<T, M, M>>;
}

/// What a runner knows when it asks a [`CrossCovariance`] for M_k.
///
/// Time index: M_k = Cov(G w_{k-1}, v_k), the process noise accumulated since the
/// previous update (transported to now) against the current measurement noise.
///
/// A one-step model is exact when one predict separates two updates, or when the
/// measurement noise is correlated with the accumulated noise *as a whole*. When the
/// measurement noise shares only some of the process steps (a window), use a
/// [`crate::WindowedCrossCovariance`]: a fixed share of Q_acc is exact only for
/// Phi = I.
#[derive(Debug, Clone, Copy)]
pub struct CrossCovarianceContext<'a, T: Scalar, S, const N: usize, const M: usize> {
    /// Q_acc: process noise accumulated since the last update, in state space at time k.
    pub accumulated_process_noise: &'a SMatrix<T, N, N>,
    /// Product of the transition matrices since the last update.
    pub accumulated_transition: &'a SMatrix<T, N, N>,
    /// Whether the runner tracks Q_acc and Phi_acc (`FilterConfig::
    /// track_accumulated_noise`); when `false` the two fields above are zero and
    /// identity and a model that needs them must fail with
    /// [`crate::Error::NotTracked`].
    pub accumulation_tracked: bool,
    /// R of the current measurement.
    pub measurement_noise: &'a SMatrix<T, M, M>,
    /// H of the current measurement.
    pub jacobian: &'a SMatrix<T, M, N>,
    /// The measurement y_k.
    pub measurement: &'a SVector<T, M>,
    /// The (nominal) state at time k, before the update.
    pub state: &'a S,
    /// The state covariance at time k, before the update.
    pub covariance: &'a SMatrix<T, N, N>,
}

/// Produces the cross-covariance M_k = Cov(G w_{k-1}, v_k) (N x M) for one update.
///
/// ```
/// use estim_core::nalgebra::SMatrix;
/// use estim_core::{CrossCovariance, CrossCovarianceContext, Result};
///
/// /// The measurement noise contains `gain` times the process noise accumulated
/// /// since the last update, seen through H: v = gain * H (G w) + independent, so
/// /// M = Cov(G w, v) = gain * Q_acc H'.
/// struct SharedNoise { gain: f64 }
///
/// impl<S, const N: usize, const M: usize> CrossCovariance<f64, S, N, M> for SharedNoise {
///     fn cross_covariance(
///         &self,
///         context: &CrossCovarianceContext<'_, f64, S, N, M>,
///     ) -> Result<SMatrix<f64, N, M>> {
///         Ok(context.accumulated_process_noise * context.jacobian.transpose() * self.gain)
///     }
/// }
/// # let _ = SharedNoise { gain: 0.5 };
/// ```
pub trait CrossCovariance<T: Scalar, S, const N: usize, const M: usize> {
    /// M_k for the update described by `context`.
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, T, S, N, M>,
    ) -> Result<SMatrix<T, N, M>>;
}

/// One input stream of a learned measurement: which sensor, how many channels,
/// over what window.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone, PartialEq)]
pub struct InputSpec {
    /// Name of the stream (e.g. `"acc"`, `"gyro"`, `"beams"`).
    pub name: String,
    /// Channels per sample (rows of the input matrix).
    pub channels: usize,
    /// Samples in the window (columns of the input matrix).
    pub window: usize,
    /// Sample rate of the stream in Hz.
    pub sample_rate_hz: f64,
}

/// A measurement whose value comes from a model (e.g. a neural network) fed with
/// windows of raw sensor samples.
///
/// Inputs are one `channels x window` matrix per [`InputSpec`], in the order of
/// [`LearnedMeasurement::input_specs`].
///
/// ```
/// use estim_core::nalgebra::{DMatrix, Matrix1, Vector1};
/// use estim_core::{Error, InputSpec, LearnedMeasurement, Result};
///
/// /// A "model" that averages a 10-sample window of one speed sensor.
/// struct WindowMean { specs: Vec<InputSpec> }
///
/// impl LearnedMeasurement<f64, 1> for WindowMean {
///     fn input_specs(&self) -> &[InputSpec] { &self.specs }
///     fn measure(&self, inputs: &[DMatrix<f64>]) -> Result<Vector1<f64>> {
///         let w = inputs.first().ok_or(Error::Dimension { what: "inputs", expected: 1, got: 0 })?;
///         if w.shape() != (1, 10) {
///             return Err(Error::Dimension { what: "speed window", expected: 10, got: w.len() });
///         }
///         Ok(Vector1::new(w.mean()))
///     }
///     fn noise_covariance(&self) -> Matrix1<f64> { Matrix1::new(0.01 / 10.0) }
///     fn sensitivity(&self, _: &[DMatrix<f64>], directions: &[DMatrix<f64>], products: &mut [Vector1<f64>]) -> Result<bool> {
///         // Linear model: d(mean) along a direction is the mean of the direction
///         // (one stream, so one matrix per direction).
///         for (d, product) in directions.iter().zip(products) {
///             *product = Vector1::new(d.mean());
///         }
///         Ok(true)
///     }
/// }
///
/// let model = WindowMean {
///     specs: vec![InputSpec { name: "speed".into(), channels: 1, window: 10, sample_rate_hz: 10.0 }],
/// };
/// let y = model.measure(&[DMatrix::from_element(1, 10, 2.0)])?;
/// assert_eq!(y[0], 2.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait LearnedMeasurement<T: Scalar, const M: usize> {
    /// The input streams, in the order `measure` expects them.
    fn input_specs(&self) -> &[InputSpec];

    /// Run the model on one set of input windows.
    fn measure(&self, inputs: &[DMatrix<T>]) -> Result<SVector<T, M>>;

    /// Error covariance of the model's output (e.g. from validation residuals).
    fn noise_covariance(&self) -> SMatrix<T, M, M>;

    /// Jacobian-vector products at `inputs`, written into `products`: product i is
    /// d(output) along direction i. The directions lie one after another in
    /// `directions`, each one perturbation matrix per input stream (shaped as the
    /// inputs), so direction i is `directions.chunks_exact(inputs.len()).nth(i)` and
    /// `directions.len() == products.len() * inputs.len()`.
    ///
    /// The caller owns both buffers and reuses them from one update to the next, so
    /// a model that computes in place allocates nothing per update. Returns
    /// `Ok(false)`, `products` untouched, if the model cannot provide them (the
    /// default).
    ///
    /// # Errors
    /// The model's (e.g. buffers of the wrong length, a failed inference).
    fn sensitivity(
        &self,
        _inputs: &[DMatrix<T>],
        _directions: &[DMatrix<T>],
        _products: &mut [SVector<T, M>],
    ) -> Result<bool> {
        Ok(false)
    }
}

/// The process model of the sigma-point filter ([`crate::UnscentedKalmanFilter`]):
/// x_k = f(x_{k-1}, u) + G w_{k-1} with Cov(G w) = `process_noise`, and **no
/// Jacobian**. The filter pushes sigma points through `propagate`; where its
/// bookkeeping needs a transition matrix (Q_acc, the window of a windowed
/// cross-covariance, the observer's events, the smoother) it uses the statistical
/// linearisation of `propagate` from the same sigma points (see
/// [`crate::UnscentedKalmanFilter`]).
///
/// For a state with angles (a heading), [`SigmaPointProcess::residual`] and
/// [`SigmaPointProcess::mean`] say how states differ and how sigma points average
/// (defaults: the plain difference and the weighted mean); `propagate` should wrap
/// its result, the update's x + K nu is not wrapped.
///
/// Every [`ProcessModel`] whose state is `SVector<T, N>` is one (blanket
/// implementation, its Jacobian unused, the default hooks); implement this trait
/// directly for a model that has no Jacobian or has angles (a type that implements
/// [`ProcessModel`] cannot also implement this one).
///
/// ```
/// use estim_core::nalgebra::{Matrix2, Vector2};
/// use estim_core::{Result, SigmaPointProcess};
///
/// /// A pendulum's angle and rate, explicit Euler; no Jacobian written.
/// struct Pendulum { q: f64 }
///
/// impl SigmaPointProcess<f64, 2> for Pendulum {
///     type Input = ();
///     fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
///         Ok(Vector2::new(x[0] + dt * x[1], x[1] - dt * 9.81 * x[0].sin()))
///     }
///     fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(0.0, 0.0, 0.0, self.q * dt))
///     }
/// }
///
/// let x = Pendulum { q: 1e-3 }.propagate(&Vector2::new(0.0, 1.0), &(), 0.1)?;
/// assert_eq!(x, Vector2::new(0.1, 1.0));
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait SigmaPointProcess<T: Scalar, const N: usize> {
    /// The input driving the process (control, IMU sample, `()` if none).
    type Input;

    /// x_k = f(x_{k-1}, u) over `dt`, for any sigma point.
    fn propagate(&self, state: &SVector<T, N>, input: &Self::Input, dt: T)
        -> Result<SVector<T, N>>;

    /// Discrete process-noise covariance in state space, Cov(G w) over `dt`, at the
    /// state before propagation.
    fn process_noise(
        &self,
        state: &SVector<T, N>,
        input: &Self::Input,
        dt: T,
    ) -> Result<SMatrix<T, N, N>>;

    /// a - b, the difference of two states (a propagated sigma point and the
    /// predicted mean). Override it to wrap angle components (a heading) into
    /// (-pi, pi]. Default: `a - b`.
    fn residual(&self, a: &SVector<T, N>, b: &SVector<T, N>) -> SVector<T, N> {
        a - b
    }

    /// The mean of the propagated sigma points with their mean weights (see
    /// [`SigmaPointMeasurement::mean`]). Override it to take the circular mean of
    /// angle components. Default:
    /// [`SigmaPoints::weighted_mean`](crate::sigma_point::SigmaPoints::weighted_mean).
    ///
    /// # Errors
    /// The model's.
    fn mean(&self, points: &crate::sigma_point::SigmaPoints<'_, T, N>) -> Result<SVector<T, N>> {
        Ok(points.weighted_mean())
    }
}

impl<T, P, const N: usize> SigmaPointProcess<T, N> for P
where
    T: Scalar,
    P: ProcessModel<T, N, State = SVector<T, N>> + ?Sized,
{
    type Input = P::Input;

    fn propagate(
        &self,
        state: &SVector<T, N>,
        input: &Self::Input,
        dt: T,
    ) -> Result<SVector<T, N>> {
        ProcessModel::propagate(self, state, input, dt)
    }

    fn process_noise(
        &self,
        state: &SVector<T, N>,
        input: &Self::Input,
        dt: T,
    ) -> Result<SMatrix<T, N, N>> {
        ProcessModel::process_noise(self, state, input, dt)
    }
}

/// The measurement model of the sigma-point filter: y = h(x) + v with Cov(v) = R,
/// **no Jacobian**, and two hooks for measurements that live on a circle (bearings,
/// headings): how two measurements differ ([`SigmaPointMeasurement::residual`]) and
/// how sigma points average ([`SigmaPointMeasurement::mean`]). The defaults are the
/// plain difference and the weighted mean.
///
/// Where the filter's bookkeeping needs H (the [`CrossCovarianceContext`], the window
/// of a windowed cross-covariance, the observer's events, the smoother) it uses the
/// statistical linearisation H~ = P_xy' P^-1 of `predict` about the prior (see
/// [`crate::UnscentedKalmanFilter`]).
///
/// Every [`MeasurementModel`] whose state is `SVector<T, N>` is one (blanket
/// implementation, its Jacobian unused, the default hooks); implement this trait
/// directly for a model without a Jacobian or with angles (a type that implements
/// [`MeasurementModel`] cannot also implement this one).
///
/// ```
/// use std::f64::consts::PI;
/// use estim_core::nalgebra::{Matrix1, Vector1, Vector2};
/// use estim_core::sigma_point::SigmaPoints;
/// use estim_core::{Result, SigmaPointMeasurement};
///
/// fn wrap(a: f64) -> f64 { (a + PI).rem_euclid(2.0 * PI) - PI }
///
/// /// The bearing (rad, in (-pi, pi]) of a 2-D position seen from the origin.
/// struct Bearing { sigma: f64 }
///
/// impl SigmaPointMeasurement<f64, 2, 1> for Bearing {
///     fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
///         Ok(Vector1::new(x[1].atan2(x[0])))
///     }
///     fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
///         Ok(Matrix1::new(self.sigma * self.sigma))
///     }
///     fn residual(&self, a: &Vector1<f64>, b: &Vector1<f64>) -> Vector1<f64> {
///         Vector1::new(wrap(a[0] - b[0]))
///     }
///     fn mean(&self, points: &SigmaPoints<'_, f64, 1>) -> Result<Vector1<f64>> {
///         // Circular mean: the direction of the weighted sum of unit vectors.
///         let (s, c) = points.iter().fold((0.0, 0.0), |(s, c), (w, y)| {
///             (s + w * y[0].sin(), c + w * y[0].cos())
///         });
///         Ok(Vector1::new(s.atan2(c)))
///     }
/// }
///
/// let bearing = Bearing { sigma: 0.01 };
/// let r = bearing.residual(&Vector1::new(3.1), &Vector1::new(-3.1));
/// assert!((r[0] - (6.2 - 2.0 * PI)).abs() < 1e-12); // across the cut, not 6.2
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait SigmaPointMeasurement<T: Scalar, const N: usize, const M: usize> {
    /// h(x), for any sigma point.
    fn predict(&self, state: &SVector<T, N>) -> Result<SVector<T, M>>;

    /// Measurement-noise covariance R, at the prior mean.
    fn noise_covariance(&self, state: &SVector<T, N>) -> Result<SMatrix<T, M, M>>;

    /// a - b, the difference of two measurements (a sigma point and the predicted
    /// measurement, or the measurement and the predicted one: the innovation).
    /// Override it to wrap angle components into (-pi, pi]. Default: `a - b`.
    fn residual(&self, a: &SVector<T, M>, b: &SVector<T, M>) -> SVector<T, M> {
        a - b
    }

    /// The mean of the sigma points mapped through `predict`, with their mean weights
    /// (which sum to one; the centre's may be negative). Override it to take the
    /// circular mean of angle components. Default:
    /// [`SigmaPoints::weighted_mean`](crate::sigma_point::SigmaPoints::weighted_mean).
    ///
    /// # Errors
    /// The model's (e.g. a circular mean whose resultant vanishes).
    fn mean(&self, points: &crate::sigma_point::SigmaPoints<'_, T, M>) -> Result<SVector<T, M>> {
        Ok(points.weighted_mean())
    }
}

impl<T, Mm, const N: usize, const M: usize> SigmaPointMeasurement<T, N, M> for Mm
where
    T: Scalar,
    Mm: MeasurementModel<T, N, M, State = SVector<T, N>> + ?Sized,
{
    fn predict(&self, state: &SVector<T, N>) -> Result<SVector<T, M>> {
        MeasurementModel::predict(self, state)
    }

    fn noise_covariance(&self, state: &SVector<T, N>) -> Result<SMatrix<T, M, M>> {
        MeasurementModel::noise_covariance(self, state)
    }
}
