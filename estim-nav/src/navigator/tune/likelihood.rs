//! The exact Gaussian log-likelihood of the linearized filters as a function of theta
//! ([`InsDvlLikelihood`]; the parent module's docs derive it).

use super::*;

/// The log-likelihood of the linearized filters of one or more trajectories (their
/// sum), as a function of theta (module docs).
#[derive(Debug, Clone, Copy)]
pub struct InsDvlLikelihood<'a> {
    /// (A'A)^-1 of the beam geometry ([`TuneModel::beam_covariance`]).
    pub beam_covariance: Matrix3<f64>,
    /// The linearized trajectories.
    pub trajectories: &'a [Linearization],
}

/// sqrt of a nonnegative diagonal entry, 0 where it is 0 (no derivative to carry: the
/// entry's value does not depend on theta there).
fn root<T: Scalar>(d: T) -> T {
    if d > T::zero() {
        d.sqrt()
    } else {
        T::zero()
    }
}

impl LogLikelihood<TUNE_PARAMETERS> for InsDvlLikelihood<'_> {
    fn log_likelihood<T: Scalar>(
        &self,
        theta: &SVector<T, TUNE_PARAMETERS>,
    ) -> estim_core::Result<T> {
        let beam = self.beam_covariance.map(lit::<T>);
        let r = measurement_noise(&beam, theta[2], theta[3]);
        let r_root = r.diagonal().map(root);
        let config = FilterConfig::builder()
            .joint_check(JointCheck::Skip)
            .build()?;
        let input = SMatrix::<T, ERROR_STATES, ERROR_STATES>::identity();
        let mut total = T::zero();
        for linearization in self.trajectories {
            let initial =
                StateAndCovariance::new(SVector::zeros(), linearization.covariance.map(lit::<T>))?;
            let mut kf = KalmanFilter::new(
                SMatrix::identity(),
                SMatrix::zeros(),
                SMatrix::zeros(),
                r,
                initial,
            )?
            .with_config(config.clone());
            for epoch in &linearization.epochs {
                let [qa, qg, qb] = &epoch.noise;
                let q =
                    qa.map(lit::<T>) * theta[0] + qg.map(lit::<T>) * theta[1] + qb.map(lit::<T>);
                let m = q.diagonal().map(root) * r_root.transpose() * theta[M_SCALE];
                kf.predict_with(
                    epoch.transition.map(lit::<T>),
                    q,
                    Some((&input, &epoch.control.map(lit::<T>))),
                )?;
                kf.update_with(
                    epoch.jacobian.map(lit::<T>),
                    r,
                    &epoch.innovation.map(lit::<T>),
                    &Fixed(m),
                )?;
            }
            total += kf.log_likelihood();
        }
        Ok(total)
    }
}
