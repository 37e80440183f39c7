//! The four model traits: process, measurement, cross-covariance, learned measurement.

use nalgebra::{DMatrix, SMatrix, SVector};

use crate::{Result, Scalar};

/// Propagates a state over `dt` with an input, and linearises that propagation.
///
/// Discrete-time model: x_k = f(x_{k-1}, u) + G w_{k-1}, Cov(G w) = `process_noise`.
/// For a plain (extended) Kalman filter `State` is `SVector<T, N>`; for an
/// error-state filter it is the nominal state and `N` is the size of the error state
/// (see [`ErrorStateModel`]).
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
}

/// A process model whose filter estimates an error around a nominal state.
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
#[derive(Debug, Clone, Copy)]
pub struct CrossCovarianceContext<'a, T: Scalar, S, const N: usize, const M: usize> {
    /// Q_acc: process noise accumulated since the last update, in state space at time k.
    pub accumulated_process_noise: &'a SMatrix<T, N, N>,
    /// Product of the transition matrices since the last update.
    pub accumulated_transition: &'a SMatrix<T, N, N>,
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
pub trait CrossCovariance<T: Scalar, S, const N: usize, const M: usize> {
    /// M_k for the update described by `context`.
    fn cross_covariance(
        &self,
        context: &CrossCovarianceContext<'_, T, S, N, M>,
    ) -> Result<SMatrix<T, N, M>>;
}

/// One input stream of a learned measurement: which sensor, how many channels,
/// over what window.
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
pub trait LearnedMeasurement<T: Scalar, const M: usize> {
    /// The input streams, in the order `measure` expects them.
    fn input_specs(&self) -> &[InputSpec];

    /// Run the model on one set of input windows.
    fn measure(&self, inputs: &[DMatrix<T>]) -> Result<SVector<T, M>>;

    /// Error covariance of the model's output (e.g. from validation residuals).
    fn noise_covariance(&self) -> SMatrix<T, M, M>;

    /// Jacobian-vector products: for each direction (one perturbation matrix per
    /// input stream), d(output) along it. `None` if the model cannot provide them.
    fn sensitivity(
        &self,
        _inputs: &[DMatrix<T>],
        _directions: &[Vec<DMatrix<T>>],
    ) -> Result<Option<Vec<SVector<T, M>>>> {
        Ok(None)
    }
}
