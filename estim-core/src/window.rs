//! Exact cross-covariance when a measurement's noise shares many process steps and
//! other sensors' updates lie inside its window (consider-state bookkeeping).
//!
//! ## The problem
//!
//! Between updates a runner predicts with e_j = Phi_j e_{j-1} + G_j w_j. A measurement
//! y = H x_k + v whose noise v shares the process-noise samples of its *window* (the
//! last L steps before the update, e.g. the IMU samples a network consumed) has
//!
//! ```text
//! D_j = Cov(G_j w_j, v)                      (N x M, zero outside the window)
//! ```
//!
//! and the exact M = Cov(e_k, v) is the carried recursion over the window
//! (DESIGN.md, "Multi-rate and several sensors"):
//!
//! ```text
//! C <- Phi_j C + D_j                          on each predict j of the window
//! C <- J (I - K_A H_A) C                      on another sensor A's update (J: reset)
//! M  = C                                      at v's own update
//! ```
//!
//! An update of A inside the window also observed part of v (v is a consider state
//! augmented to the error state over its window): with S_A and innovation nu_A of A,
//!
//! ```text
//! E[v | y_A]   = C_a' H_A' S_A^-1 nu_A              (mean, accumulated over updates)
//! Var(v | y_A) = R - C_a' H_A' S_A^-1 H_A C_a       (conditional covariance)
//! ```
//!
//! (joint-Gaussian conditioning of [e; v] on y_A; Simon 2006 sec. 7.1 for the one-step
//! case, Bar-Shalom, Li & Kirubarajan 2001 sec. 8.3 for the augmented state). The
//! update of v then uses innovation y - h(x) - E\[v\], R replaced by Var(v | ...), and
//! M = C: the posterior equals joint-Gaussian conditioning of the stacked
//! [x_0; w_1..w_K; v; other sensors' noises] (tested in `tests/windowed.rs`).
//!
//! ## Shape
//!
//! - A runner with `FilterConfig::window_capacity(L_max) > 0` records, per predict,
//!   the step's transition, the state before it, its input and dt, and, per accepted
//!   update, J (I - K H), H' S^-1 H and H' S^-1 nu (fixed N x N / N sizes, whatever the
//!   sensor's M). Memory is bounded by L_max steps; records are allocated once.
//! - A [`WindowedCrossCovariance`] states its window length L and, at its update,
//!   hands the runner D_j for every step of the window ([`StepWindow`] gives it each
//!   step's state, input, dt and transition, so no Phi is recomputed outside the
//!   filter and nothing is kept between updates).
//! - The runner computes C, Var(v | ...) and E[v | ...] in one pass over the window
//!   (cost L N^2 M) and applies the correlated update.
//!
//! ## Invariants
//!
//! - Steps before the window and updates before its first step are not part of v.
//! - Distinct measurements' noises are uncorrelated *a priori*; the correlation that
//!   intervening updates create is what the bookkeeping carries. An update inside the
//!   window whose own noise was correlated with the process noise (M != 0) could make
//!   the two measurement noises correlated with each other (coloured noise, e.g. a
//!   window longer than the update interval): it is refused with
//!   [`crate::Error::ColouredMeasurementNoise`], never approximated.
//! - A window longer than the steps recorded is
//!   [`crate::Error::WindowUnavailable`].
//! - Rejected (gated) updates observed nothing and are not recorded.

use std::collections::VecDeque;

use nalgebra::{SMatrix, SVector};

use crate::gaussian::check_finite;
use crate::linalg::mul_static;
use crate::{Error, Result, Scalar};

/// One recorded process step, as a [`WindowedCrossCovariance`] sees it.
#[derive(Debug)]
pub struct ProcessStep<'a, T: Scalar, S, U, const N: usize> {
    /// Position of the step in the window, 0 = oldest.
    pub position: usize,
    /// The (nominal) state before the step (the point Phi and Q_d were evaluated at).
    pub state: &'a S,
    /// The step's input (`()` for the linear filter).
    pub input: &'a U,
    /// The step's dt (`None` for the linear filter).
    pub dt: Option<T>,
    /// The step's transition Phi_j (e_j = Phi_j e_{j-1} + G_j w_j).
    pub transition: &'a SMatrix<T, N, N>,
    /// The step's process noise Q_j = Cov(G_j w_j).
    pub process_noise: &'a SMatrix<T, N, N>,
}

/// Produces D_j = Cov(G_j w_j, v) for every process step of a measurement's window.
///
/// Sign convention (the one place it is stated): the runners' error state is
/// `true = estimate + error` (for the error-state filter, `true = nominal + error`),
/// so D_j is the covariance between the noise *as it enters the error e_j* and the
/// measurement noise v = y - h(true). For a sensor sample fed both to the process (as
/// its input u, so the nominal integrates u_measured = u_true + n) and to the model
/// producing y: the error receives -B_j n (B_j = d f / d u), and v receives +J_j n
/// (J_j = d y / d u), so D_j = -B_j Cov(n) J_j'. `tests/windowed.rs` fails on the
/// opposite sign.
///
/// ```
/// use estim_core::nalgebra::{Matrix1, Matrix2x1, Vector1, Vector2, Matrix2};
/// use estim_core::{ExtendedKalmanFilter, FilterConfig, MeasurementModel, ProcessModel, Result, StateAndCovariance, WindowedCrossCovariance};
/// use estim_core::window::StepWindow;
///
/// /// Position/velocity driven by a measured acceleration (input); the acceleration
/// /// noise (variance `q` per sample) enters the velocity error with a minus sign.
/// struct Cart { q: f64 }
/// impl ProcessModel<f64, 2> for Cart {
///     type State = Vector2<f64>;
///     type Input = f64;
///     fn propagate(&self, x: &Vector2<f64>, a: &f64, dt: f64) -> Result<Vector2<f64>> {
///         Ok(Vector2::new(x[0] + dt * x[1], x[1] + dt * a))
///     }
///     fn transition(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(1.0, dt, 0.0, 1.0))
///     }
///     fn process_noise(&self, _: &Vector2<f64>, _: &f64, dt: f64) -> Result<Matrix2<f64>> {
///         Ok(Matrix2::new(0.0, 0.0, 0.0, dt * dt * self.q))
///     }
/// }
/// /// A speed "sensor" that averages the last 5 integrated accelerations (shares their noise).
/// struct Speed;
/// impl MeasurementModel<f64, 2, 1> for Speed {
///     type State = Vector2<f64>;
///     fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> { Ok(Vector1::new(x[1])) }
///     fn jacobian(&self, _: &Vector2<f64>) -> Result<estim_core::nalgebra::Matrix1x2<f64>> {
///         Ok(estim_core::nalgebra::Matrix1x2::new(0.0, 1.0))
///     }
///     fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> { Ok(Matrix1::new(0.01)) }
/// }
/// /// v = 0.2 sum of the window's velocity increments' noise (+ independent part):
/// /// D_j = Cov(G_j w_j, v) = [0; 0.2 dt^2 q] per step.
/// struct SharedAcc { q: f64 }
/// impl WindowedCrossCovariance<f64, Vector2<f64>, f64, 2, 1> for SharedAcc {
///     fn window_steps(&self) -> usize { 5 }
///     fn step_cross_covariances(
///         &self,
///         window: &StepWindow<'_, f64, Vector2<f64>, f64, 2>,
///         sink: &mut dyn FnMut(&Matrix2x1<f64>) -> Result<()>,
///     ) -> Result<()> {
///         for step in window.iter() {
///             let dt = step.dt.unwrap_or(1.0);
///             sink(&Matrix2x1::new(0.0, 0.2 * dt * dt * self.q))?;
///         }
///         Ok(())
///     }
/// }
///
/// let config = FilterConfig::builder().window_capacity(5).build()?;
/// let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity())?;
/// let mut ekf = ExtendedKalmanFilter::new(Cart { q: 0.01 }, initial).with_config(config);
/// for _ in 0..5 {
///     ekf.predict(&0.1, 0.1)?;
/// }
/// let report = ekf.update_windowed(&Speed, &Vector1::new(0.06), &SharedAcc { q: 0.01 })?;
/// assert!((report.cross_covariance[(1, 0)] - 5.0 * 0.2 * 0.01 * 0.01).abs() < 1e-15);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait WindowedCrossCovariance<T: Scalar, S, U, const N: usize, const M: usize> {
    /// L >= 1: the measurement noise shares the process noise of the last L predicts
    /// before the update.
    fn window_steps(&self) -> usize;

    /// Call `sink(D_j)` once per step of `window`, oldest first (exactly
    /// `window.len()` times), with D_j = Cov(G_j w_j, v) in the runner's error
    /// convention (see the trait docs).
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, T, S, U, N>,
        sink: &mut dyn FnMut(&SMatrix<T, N, M>) -> Result<()>,
    ) -> Result<()>;

    /// Optional shortcut, used only when no other update lies inside the window:
    /// M = sum_j Phi(k, j+1) D_j computed by the model itself (e.g. from
    /// [`StepWindow::for_each_transport`] and Jacobian-vector products, when the
    /// per-step D_j would cost more). `None` (default): the runner uses
    /// [`WindowedCrossCovariance::step_cross_covariances`].
    fn transported_cross_covariance(
        &self,
        _window: &StepWindow<'_, T, S, U, N>,
    ) -> Result<Option<SMatrix<T, N, M>>> {
        Ok(None)
    }
}

/// A recorded predict.
#[derive(Debug, Clone)]
struct StepRecord<T: Scalar, S, U, const N: usize> {
    /// 1-based count of predicts since the filter started.
    index: u64,
    state: S,
    input: U,
    dt: Option<T>,
    transition: SMatrix<T, N, N>,
    process_noise: SMatrix<T, N, N>,
}

/// A recorded accepted update, in sizes independent of its measurement size.
#[derive(Debug, Clone)]
struct UpdateRecord<T: Scalar, const N: usize> {
    /// Index of the predict it followed (0 = before any predict).
    after_step: u64,
    /// J (I - K H).
    transform: SMatrix<T, N, N>,
    /// H' S^-1 H.
    information: SMatrix<T, N, N>,
    /// H' S^-1 nu.
    weighted_innovation: SVector<T, N>,
    /// Whether its own noise was correlated with the process noise (M != 0).
    correlated: bool,
}

/// The steps and updates a runner keeps for windowed cross-covariances.
#[derive(Debug, Clone)]
pub(crate) struct History<T: Scalar, S, U, const N: usize> {
    capacity: usize,
    steps_done: u64,
    steps: VecDeque<StepRecord<T, S, U, N>>,
    updates: VecDeque<UpdateRecord<T, N>>,
}

impl<T: Scalar, S, U, const N: usize> History<T, S, U, N> {
    pub(crate) fn new(capacity: usize) -> Self {
        Self {
            capacity,
            steps_done: 0,
            steps: VecDeque::with_capacity(capacity),
            updates: VecDeque::with_capacity(if capacity > 0 { capacity + 4 } else { 0 }),
        }
    }

    pub(crate) fn is_enabled(&self) -> bool {
        self.capacity > 0
    }

    pub(crate) fn len(&self) -> usize {
        self.steps.len()
    }

    /// Record one predict (nothing when the capacity is 0).
    pub(crate) fn push_step(
        &mut self,
        state: &S,
        input: &U,
        dt: Option<T>,
        transition: &SMatrix<T, N, N>,
        process_noise: &SMatrix<T, N, N>,
    ) where
        S: Clone,
        U: Clone,
    {
        self.steps_done += 1;
        if self.capacity == 0 {
            return;
        }
        if self.steps.len() == self.capacity {
            self.steps.pop_front();
        }
        self.steps.push_back(StepRecord {
            index: self.steps_done,
            state: state.clone(),
            input: input.clone(),
            dt,
            transition: *transition,
            process_noise: *process_noise,
        });
        // Updates before the oldest kept step can lie in no window any more.
        let oldest = self.steps.front().map_or(self.steps_done, |s| s.index);
        while self.updates.front().is_some_and(|u| u.after_step < oldest) {
            self.updates.pop_front();
        }
    }

    /// Record an accepted update (nothing when the capacity is 0).
    pub(crate) fn push_update(
        &mut self,
        transform: SMatrix<T, N, N>,
        information: SMatrix<T, N, N>,
        weighted_innovation: SVector<T, N>,
        correlated: bool,
    ) {
        if self.capacity == 0 {
            return;
        }
        self.updates.push_back(UpdateRecord {
            after_step: self.steps_done,
            transform,
            information,
            weighted_innovation,
            correlated,
        });
    }

    /// The last `steps` steps and the updates among them.
    pub(crate) fn window(&self, steps: usize) -> Result<StepWindow<'_, T, S, U, N>> {
        if steps == 0 || steps > self.steps.len() {
            return Err(Error::WindowUnavailable {
                needed: steps,
                available: self.steps.len(),
                capacity: self.capacity,
            });
        }
        let start = self.steps.len() - steps;
        let first_index = self.steps[start].index;
        let first_update = self
            .updates
            .iter()
            .position(|u| u.after_step >= first_index)
            .unwrap_or(self.updates.len());
        Ok(StepWindow {
            steps: &self.steps,
            start,
            updates: &self.updates,
            first_update,
        })
    }
}

impl<T: Scalar, S, U, const N: usize> History<T, S, U, N> {
    /// Number of accepted updates recorded (the end of a window's updates, taken
    /// before the update that reads the window is recorded).
    pub(crate) fn recorded_updates(&self) -> usize {
        self.updates.len()
    }

    /// The last `steps` steps with their D_j (`cross`, `steps` blocks of N x
    /// `measurement_size`, column-major) and the updates among them before index
    /// `end_update`, as a [`RecordedWindow`].
    pub(crate) fn recorded_window<'a>(
        &'a self,
        steps: usize,
        end_update: usize,
        cross: &'a [T],
        measurement_size: usize,
    ) -> Option<WindowView<'a, T, S, U, N>> {
        let window = self.window(steps).ok()?;
        let end_update = end_update.min(self.updates.len());
        (cross.len() == steps * N * measurement_size && window.first_update <= end_update).then(
            || WindowView {
                window,
                end_update,
                cross,
                block: N * measurement_size,
            },
        )
    }
}

/// An accepted update inside a recorded window ([`RecordedWindow::update`]).
#[derive(Debug, Clone, Copy)]
pub struct RecordedUpdate<'a, T: Scalar, const N: usize> {
    /// Position (0 = oldest) of the window's step the update followed.
    pub after_step: usize,
    /// J (I - K H), J the error-state reset (identity for the other runners).
    pub transform: &'a SMatrix<T, N, N>,
    /// H' S^-1 H.
    pub information: &'a SMatrix<T, N, N>,
    /// H' S^-1 nu.
    pub weighted_innovation: &'a SVector<T, N>,
}

/// A windowed update's window as the runner recorded it: each step's Phi_j, Q_j and
/// D_j = Cov(G_j w_j, v), and the other accepted updates inside the window (whose
/// noise is uncorrelated with the process noise: the runner refuses the others).
/// What a smoother needs to smooth a window that spans several of its epochs
/// ([`crate::smoother`]); observers receive it in [`crate::UpdateEvent::window`]
/// when they ask ([`crate::Observer::wants_window`]).
pub trait RecordedWindow<T: Scalar, const N: usize>: std::fmt::Debug {
    /// Number of steps L.
    fn steps(&self) -> usize;
    /// Phi_j of step `position` (0 = oldest).
    fn transition(&self, position: usize) -> Option<&SMatrix<T, N, N>>;
    /// Q_j = Cov(G_j w_j) of step `position`.
    fn process_noise(&self, position: usize) -> Option<&SMatrix<T, N, N>>;
    /// D_j of step `position`: N x M, column-major (M the update's measurement size).
    fn step_cross_covariance(&self, position: usize) -> Option<&[T]>;
    /// Number of other accepted updates inside the window.
    fn updates(&self) -> usize;
    /// Other update `index` (0 = oldest).
    fn update(&self, index: usize) -> Option<RecordedUpdate<'_, T, N>>;
}

/// [`RecordedWindow`] over a runner's [`History`].
pub(crate) struct WindowView<'a, T: Scalar, S, U, const N: usize> {
    window: StepWindow<'a, T, S, U, N>,
    end_update: usize,
    cross: &'a [T],
    block: usize,
}

impl<T: Scalar, S, U, const N: usize> std::fmt::Debug for WindowView<'_, T, S, U, N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordedWindow")
            .field("steps", &self.window.len())
            .field("updates", &(self.end_update - self.window.first_update))
            .finish()
    }
}

impl<T: Scalar, S, U, const N: usize> RecordedWindow<T, N> for WindowView<'_, T, S, U, N> {
    fn steps(&self) -> usize {
        self.window.len()
    }
    fn transition(&self, position: usize) -> Option<&SMatrix<T, N, N>> {
        (position < self.window.len())
            .then(|| self.window.steps.get(self.window.start + position))
            .flatten()
            .map(|r| &r.transition)
    }
    fn process_noise(&self, position: usize) -> Option<&SMatrix<T, N, N>> {
        (position < self.window.len())
            .then(|| self.window.steps.get(self.window.start + position))
            .flatten()
            .map(|r| &r.process_noise)
    }
    fn step_cross_covariance(&self, position: usize) -> Option<&[T]> {
        (position < self.window.len())
            .then(|| {
                self.cross
                    .get(position * self.block..(position + 1) * self.block)
            })
            .flatten()
    }
    fn updates(&self) -> usize {
        self.end_update - self.window.first_update
    }
    fn update(&self, index: usize) -> Option<RecordedUpdate<'_, T, N>> {
        if index >= self.updates() {
            return None;
        }
        let u = self.window.updates.get(self.window.first_update + index)?;
        let first = self.window.steps.get(self.window.start)?.index;
        Some(RecordedUpdate {
            after_step: usize::try_from(u.after_step.checked_sub(first)?).ok()?,
            transform: &u.transform,
            information: &u.information,
            weighted_innovation: &u.weighted_innovation,
        })
    }
}

/// The last L recorded process steps before an update, and the other updates among
/// them, as handed to a [`WindowedCrossCovariance`].
#[derive(Debug)]
pub struct StepWindow<'a, T: Scalar, S, U, const N: usize> {
    steps: &'a VecDeque<StepRecord<T, S, U, N>>,
    start: usize,
    updates: &'a VecDeque<UpdateRecord<T, N>>,
    first_update: usize,
}

impl<'a, T: Scalar, S, U, const N: usize> StepWindow<'a, T, S, U, N> {
    /// Number of steps L.
    pub fn len(&self) -> usize {
        self.steps.len() - self.start
    }

    /// Whether the window is empty (never, for a window handed to a model).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Step `position` (0 = oldest), or `None` past the end.
    pub fn step(&self, position: usize) -> Option<ProcessStep<'a, T, S, U, N>> {
        let r = self.steps.get(self.start + position)?;
        Some(ProcessStep {
            position,
            state: &r.state,
            input: &r.input,
            dt: r.dt,
            transition: &r.transition,
            process_noise: &r.process_noise,
        })
    }

    /// The steps, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = ProcessStep<'a, T, S, U, N>> + '_ {
        (0..self.len()).filter_map(move |i| self.step(i))
    }

    /// Number of other accepted updates inside the window (after its first step).
    pub fn other_updates(&self) -> usize {
        self.updates.len() - self.first_update
    }

    /// For each step, newest first, the transport Phi(k, j+1) = Phi_k ... Phi_{j+1}
    /// from the step's noise to the update time (identity for the newest step),
    /// *ignoring* other updates (valid for
    /// [`WindowedCrossCovariance::transported_cross_covariance`], which the runner
    /// calls only when [`StepWindow::other_updates`] is 0). Cost L N^3.
    pub fn for_each_transport(
        &self,
        mut f: impl FnMut(ProcessStep<'a, T, S, U, N>, &SMatrix<T, N, N>) -> Result<()>,
    ) -> Result<()> {
        let mut transport = SMatrix::<T, N, N>::identity();
        for position in (0..self.len()).rev() {
            let Some(step) = self.step(position) else {
                break;
            };
            let phi = *step.transition;
            f(step, &transport)?;
            transport = mul_static(&transport, &phi);
        }
        Ok(())
    }
}

/// What the exact bookkeeping gives an update: M = Cov(e_k, v), and the conditional
/// Var(v | ...) and E[v | ...] after the other updates of the window.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ExactTerms<T: Scalar, const N: usize, const M: usize> {
    pub(crate) cross: SMatrix<T, N, M>,
    pub(crate) noise_covariance: SMatrix<T, M, M>,
    pub(crate) noise_mean: SVector<T, M>,
}

/// One pass over the window (see the module docs).
pub(crate) fn exact_terms<T, S, U, C, const N: usize, const M: usize>(
    history: &History<T, S, U, N>,
    model: &C,
    measurement_noise: &SMatrix<T, M, M>,
) -> Result<ExactTerms<T, N, M>>
where
    T: Scalar,
    C: WindowedCrossCovariance<T, S, U, N, M> + ?Sized,
{
    if !history.is_enabled() {
        return Err(Error::NotTracked {
            what: "process-step window",
            hint: "FilterConfig::builder().window_capacity(steps)",
        });
    }
    let length = model.window_steps();
    let window = history.window(length)?;
    let last_index = history.steps_done;
    if let Some(u) = window
        .updates
        .iter()
        .skip(window.first_update)
        .find(|u| u.correlated)
    {
        return Err(Error::ColouredMeasurementNoise {
            window: length,
            steps_before_end: usize::try_from(last_index - u.after_step).unwrap_or(usize::MAX),
        });
    }
    if window.other_updates() == 0 {
        if let Some(cross) = model.transported_cross_covariance(&window)? {
            check_finite(cross.as_slice(), "windowed cross-covariance")?;
            return Ok(ExactTerms {
                cross,
                noise_covariance: *measurement_noise,
                noise_mean: SVector::zeros(),
            });
        }
    }
    let mut cross = SMatrix::<T, N, M>::zeros();
    let mut reduction = SMatrix::<T, M, M>::zeros();
    let mut mean = SVector::<T, M>::zeros();
    let mut position = 0usize;
    let mut next_update = window.first_update;
    let steps = window.steps;
    let updates = window.updates;
    let start = window.start;
    model.step_cross_covariances(&window, &mut |d: &SMatrix<T, N, M>| {
        let Some(record) = steps.get(start + position) else {
            return Err(Error::Dimension {
                what: "windowed cross-covariance steps",
                expected: length,
                got: position + 1,
            });
        };
        cross = mul_static(&record.transition, &cross) + d;
        while let Some(u) = updates.get(next_update) {
            if u.after_step != record.index {
                break;
            }
            // Conditioning of [e; v] on the other sensor's measurement.
            let cross_t = cross.transpose();
            mean += mul_static(&cross_t, &u.weighted_innovation);
            reduction += mul_static(&cross_t, &mul_static(&u.information, &cross));
            cross = mul_static(&u.transform, &cross);
            next_update += 1;
        }
        position += 1;
        Ok(())
    })?;
    if position != length {
        return Err(Error::Dimension {
            what: "windowed cross-covariance steps",
            expected: length,
            got: position,
        });
    }
    check_finite(cross.as_slice(), "windowed cross-covariance")?;
    let conditional = measurement_noise - reduction;
    let noise_covariance = crate::gaussian::symmetrize(&conditional);
    check_finite(noise_covariance.as_slice(), "conditional measurement noise")?;
    check_finite(mean.as_slice(), "conditional measurement-noise mean")?;
    Ok(ExactTerms {
        cross,
        noise_covariance,
        noise_mean: mean,
    })
}
