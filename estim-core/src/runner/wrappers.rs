//! The code every runner has, written once: the accessors over the shared core, the
//! `update` / `update_windowed` / `step` wrappers around each runner's
//! `update_from`, the `filter_batch` / `smooth_batch` wrappers around the batch loop,
//! the linear model's accessors of the two linear runners, and the AVX2 dispatch of
//! the linear runner.

/// `$this.$body`, run through its copy `$avx2` compiled for AVX2 when the CPU has it
/// and the dispatch allows it ([`crate::linalg::dispatch`])
/// (4 lanes instead of SSE2's 2). No FMA in this build itself: its loops do the same
/// separately rounded multiply and add as the portable build. The large dense
/// products (N >= 8) go through [`crate::linalg::fused_product`], which fuses them on AVX-512 CPUs:
/// there the results differ from the portable build's by round-off. (An AVX-512 copy
/// of the whole runner measured no faster at (15,3) and 10 % slower at (4,2).)
macro_rules! simd_dispatch {
    ($this:ident . $body:ident ( $($arg:expr),* ) via $avx2:ident) => {{
        #[cfg(target_arch = "x86_64")]
        {
            if crate::linalg::dispatch::avx2() {
                // SAFETY: a `target_feature(enable = "avx2")` function only requires
                // that the CPU has AVX2, which the dispatch checked on the line above.
                return unsafe { $this.$avx2($($arg),*) };
            }
        }
        $this.$body($($arg),*)
    }};
}

/// The accessors every runner has, over its `shared` field (one definition); with
/// `step_window: State, Input`, also `step_window` (the runners over a
/// [`crate::ProcessModel`]).
macro_rules! shared_accessors {
    (step_window: $S:ty, $U:ty) => {
        shared_accessors!();

        /// The last `steps` recorded process steps (states before propagation, inputs,
        /// dt, transitions), e.g. to build a learned measurement's input window from the
        /// samples the filter itself consumed (the runner is the ring buffer of its
        /// input stream).
        ///
        /// # Errors
        /// [`crate::Error::WindowUnavailable`] if fewer steps are recorded (or `steps` is 0).
        pub fn step_window(
            &self,
            steps: usize,
        ) -> Result<crate::window::StepWindow<'_, T, $S, $U, N>> {
            self.shared.history.window(steps)
        }
    };
    () => {
        /// The configuration.
        pub fn config(&self) -> &FilterConfig {
            &self.shared.config
        }

        /// Q_acc since the last measurement (zero when not tracked, see
        /// [`FilterConfig::track_accumulated_noise`]).
        pub fn accumulated_process_noise(&self) -> &SMatrix<T, N, N> {
            self.shared.accumulated.noise()
        }

        /// Phi_acc since the last measurement (identity when not tracked).
        pub fn accumulated_transition(&self) -> &SMatrix<T, N, N> {
            self.shared.accumulated.transition()
        }

        /// The log-likelihood of the accepted measurements so far, ln p(y_1, ..., y_K)
        /// under the model: the sum of the accepted updates'
        /// [`UpdateReport::log_likelihood`](crate::UpdateReport::log_likelihood), each
        /// ln p(y_k | y_1, ..., y_{k-1}) (the prediction-error decomposition, Harvey
        /// 1989, sec. 3.4, eq. 3.4.7). Exact for a linear-Gaussian model (the
        /// innovations are then independent Gaussians, with correlated or windowed M
        /// as well); for a nonlinear model the sum of the linearised (or sigma-point)
        /// Gaussian terms, an approximation. Rejected updates add nothing; an update
        /// accepted after gate-recovery inflation adds its term before the inflation
        /// (as reported). Zero at construction and reset by nothing else (not by
        /// [`Self::with_config`] nor by replacing the observer): to score a segment,
        /// take the difference of two readings.
        pub fn log_likelihood(&self) -> T {
            self.shared.log_likelihood
        }

        /// Propagations since the last measurement.
        pub fn propagations_since_update(&self) -> usize {
            self.shared.accumulated.steps
        }

        /// Process steps currently recorded for windowed cross-covariances (at most
        /// [`FilterConfig::window_capacity`]).
        pub fn recorded_steps(&self) -> usize {
            self.shared.history.len()
        }

        /// The observer.
        pub fn observer(&self) -> &O {
            &self.shared.observer
        }

        /// The observer, mutably.
        pub fn observer_mut(&mut self) -> &mut O {
            &mut self.shared.observer
        }

        /// Consume the filter, keeping the observer (e.g. to read what it recorded).
        pub fn into_observer(self) -> O {
            self.shared.observer
        }

        /// Replace the configuration. The recorded window (if any) restarts empty
        /// with the new capacity; Q_acc is kept.
        #[must_use]
        pub fn with_config(mut self, config: FilterConfig) -> Self {
            self.shared.set_config(config);
            self
        }
    };
}

/// `update`, `update_windowed` and `step` of a runner, around its
/// `update_from(model?, measurement, CrossSource)` and `predict(args)`.
///
/// `state` / `input`: the state models see and the process input; `model`: the
/// measurement-model argument and its bound (`model: Mm: Bound<..>`) of the
/// EKF-shaped runners, empty for the linear one (whose H is fixed); `size`: `M` when
/// the measurement size is a generic of the methods (EKF-shaped runners), empty when
/// it is the runner's; `predict`: the arguments `step` passes to `predict`. The four
/// docs follow, each before its method's name (`update_uncorrelated`'s also serves
/// `step_uncorrelated`, with a line of its own).
macro_rules! update_methods {
    (
        state: $S:ty,
        input: $U:ty,
        model: [$($model:ident: $Mm:ident: $($bound:tt)+)?],
        size: [$($size:ident)?],
        predict: [$($arg:ident: $arg_ty:ty),*],
        $(#[$update_doc:meta])* update;
        $(#[$windowed_doc:meta])* update_windowed;
        $(#[$step_doc:meta])* step;
        $(#[$uncorrelated_doc:meta])* update_uncorrelated;
    ) => {
        $(#[$update_doc])*
        pub fn update<$($Mm,)? C $(, const $size: usize)?>(
            &mut self,
            $($model: &$Mm,)?
            measurement: &SVector<T, M>,
            cross: &C,
        ) -> Result<UpdateReport<T, N, M>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
            C: CrossCovariance<T, $S, N, M> + ?Sized,
        {
            self.update_from(
                $($model,)?
                measurement,
                CrossSource::<C, dyn WindowedCrossCovariance<T, $S, $U, N, M>>::OneStep(cross),
            )
        }

        $(#[$windowed_doc])*
        pub fn update_windowed<$($Mm,)? W $(, const $size: usize)?>(
            &mut self,
            $($model: &$Mm,)?
            measurement: &SVector<T, M>,
            cross: &W,
        ) -> Result<UpdateReport<T, N, M>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
            W: WindowedCrossCovariance<T, $S, $U, N, M> + ?Sized,
        {
            self.update_from(
                $($model,)?
                measurement,
                CrossSource::<crate::Zero, W>::Windowed(cross),
            )
        }

        $(#[$step_doc])*
        pub fn step<$($Mm,)? C $(, const $size: usize)?>(
            &mut self,
            $($arg: $arg_ty,)*
            $($model: &$Mm,)?
            measurement: Option<&SVector<T, M>>,
            cross: &C,
        ) -> Result<Option<UpdateReport<T, N, M>>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
            C: CrossCovariance<T, $S, N, M> + ?Sized,
        {
            self.predict($($arg),*)?;
            measurement
                .map(|y| self.update($($model,)? y, cross))
                .transpose()
        }

        $(#[$uncorrelated_doc])*
        pub fn update_uncorrelated<$($Mm,)? $(const $size: usize)?>(
            &mut self,
            $($model: &$Mm,)?
            measurement: &SVector<T, M>,
        ) -> Result<UpdateReport<T, N, M>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
        {
            self.update($($model,)? measurement, &crate::Zero)
        }

        /// One time step with a measurement whose noise is uncorrelated with the
        /// process noise: `step` with the cross-covariance [`crate::Zero`] (as
        /// `update_uncorrelated` is `update` with it).
        ///
        /// # Errors
        /// Those of `step`.
        pub fn step_uncorrelated<$($Mm,)? $(const $size: usize)?>(
            &mut self,
            $($arg: $arg_ty,)*
            $($model: &$Mm,)?
            measurement: Option<&SVector<T, M>>,
        ) -> Result<Option<UpdateReport<T, N, M>>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
        {
            self.step($($arg,)* $($model,)? measurement, &crate::Zero)
        }
    };
}

/// `filter_batch` and `smooth_batch` of a runner, around [`super::batch::filter_steps`],
/// [`super::batch::smooth_steps`] and the runner's private `fork` (a copy of it with
/// another observer).
///
/// `steps`: the slice's parameter name and the type of one step; `step`: a pattern
/// for one step, then the arguments it gives `step` before the model and the
/// measurement after it; `model` and `size` as in [`update_methods`]; `state`: the
/// state models see; `estimate`: the batch's estimate type (empty for
/// [`crate::StateAndCovariance`], the batches' default) and how to read it from the
/// runner, named by `|filter|`; `initial`: x_0 for the smoother, (state as models see
/// it, covariance), from the same `filter`; `smoothed`: a smoothed epoch as the
/// estimate; `smooth_where`: what smoothing needs beyond filtering (a `Clone` process
/// model for the copy). The two docs follow, each before its method's name.
macro_rules! batch_methods {
    (
        steps: $steps:ident: $Step:ty,
        step: |$step:pat_param| [$($arg:expr),*] $measurement:expr,
        model: [$($model:ident: $Mm:ident: $($bound:tt)+)?],
        size: [$($size:ident)?],
        state: $S:ty,
        estimate: [$($E:ty)?] |$filter:ident| $estimate:expr,
        initial: $initial:expr,
        smoothed: |$epoch:ident| $smoothed:expr,
        smooth_where: [$($where:tt)*],
        $(#[$filter_doc:meta])* filter_batch;
        $(#[$smooth_doc:meta])* smooth_batch;
    ) => {
        $(#[$filter_doc])*
        pub fn filter_batch<$($Mm,)? C $(, const $size: usize)?>(
            &mut self,
            $steps: &[$Step],
            $($model: &$Mm,)?
            cross: &C,
        ) -> Result<FilteredBatch<T, N, M $(, $E)?>>
        where
            $($Mm: $($bound)+ + ?Sized,)?
            C: CrossCovariance<T, $S, N, M> + ?Sized,
        {
            super::batch::filter_steps($steps, |$step| {
                let report = self.step($($arg,)* $($model,)? $measurement, cross)?;
                let $filter = &*self;
                Ok((report, $estimate))
            })
        }

        $(#[$smooth_doc])*
        pub fn smooth_batch<$($Mm,)? C $(, const $size: usize)?>(
            &self,
            $steps: &[$Step],
            $($model: &$Mm,)?
            cross: &C,
        ) -> Result<SmoothedBatch<T, N $(, $E)?>>
        where
            $($where)*
            $($Mm: $($bound)+ + ?Sized,)?
            C: CrossCovariance<T, $S, N, M> + ?Sized,
        {
            let $filter = self;
            super::batch::smooth_steps(
                $initial,
                self.propagations_since_update() > 0,
                |recorder| {
                    let mut forward = self.fork(recorder);
                    let filtered = forward.filter_batch($steps, $($model,)? cross)?;
                    Ok((filtered, forward.into_observer()))
                },
                |$epoch| $smoothed,
            )
        }
    };
}

/// The accessors of the linear model that [`crate::KalmanFilter`] and
/// [`crate::SquareRootKalmanFilter`] share (fields `transition`, `process_noise`,
/// `observation`, `measurement_noise`, `model_unchanged`): F, Q, H and R, and the
/// setters of F and H (those of Q and R check and factor in each runner's own way).
macro_rules! linear_model_accessors {
    () => {
        /// The transition F used by the next predict.
        pub fn transition(&self) -> &SMatrix<T, N, N> {
            &self.transition
        }

        /// The process-noise covariance Q = Cov(G w) used by the next predict.
        pub fn process_noise(&self) -> &SMatrix<T, N, N> {
            &self.process_noise
        }

        /// The observation matrix H used by the next update.
        pub fn observation(&self) -> &SMatrix<T, M, N> {
            &self.observation
        }

        /// The measurement-noise covariance R used by the next update.
        pub fn measurement_noise(&self) -> &SMatrix<T, M, M> {
            &self.measurement_noise
        }

        /// Replace F for the following predicts (a time-varying model; time index:
        /// module docs of [`crate::KalmanFilter`]). Q_acc and Phi_acc keep what earlier
        /// steps accumulated.
        ///
        /// # Errors
        /// [`crate::Error::NonFinite`]; the filter is then unchanged.
        pub fn set_transition(&mut self, transition: SMatrix<T, N, N>) -> Result<()> {
            check_finite(transition.as_slice(), "transition matrix")?;
            self.transition = transition;
            self.model_unchanged = false;
            Ok(())
        }

        /// Replace H for the following updates.
        ///
        /// # Errors
        /// [`crate::Error::NonFinite`]; the filter is then unchanged.
        pub fn set_observation(&mut self, observation: SMatrix<T, M, N>) -> Result<()> {
            check_finite(observation.as_slice(), "observation matrix")?;
            self.observation = observation;
            Ok(())
        }
    };
}
