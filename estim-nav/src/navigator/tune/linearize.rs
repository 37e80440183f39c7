//! The filter of one trajectory run once at theta_0 and recorded between and at its
//! DVL epochs ([`linearize`]; the parent module's docs derive the model).

use super::*;

/// One DVL epoch of the linearized model (module docs).
#[derive(Debug, Clone)]
pub(super) struct Epoch {
    /// Phi_acc,k J_{k-1}.
    pub(super) transition: ErrorMatrix,
    /// -Phi_acc,k J_{k-1} Delta_{k-1}.
    pub(super) control: SVector<f64, ERROR_STATES>,
    /// Q_a, Q_g, Q_bias accumulated since the previous epoch.
    pub(super) noise: [ErrorMatrix; 3],
    pub(super) jacobian: SMatrix<f64, 3, ERROR_STATES>,
    pub(super) innovation: Vector3<f64>,
}

/// The filter of one trajectory linearized at theta_0 ([`linearize`]).
#[derive(Debug, Clone)]
pub struct Linearization {
    pub(super) epochs: Vec<Epoch>,
    pub(super) covariance: ErrorMatrix,
    /// The linearization point theta_0.
    pub theta: TuneParameters,
    /// The error-state filter's own cumulative log-likelihood at theta_0.
    pub filter_log_likelihood: f64,
    /// The largest |rho| for which [[Q_acc, M], [M', R]] is positive semidefinite at
    /// every epoch, at theta_0.
    pub largest_valid_rho: f64,
}

impl Linearization {
    /// DVL epochs (updates).
    pub fn epochs(&self) -> usize {
        self.epochs.len()
    }
}

/// Run the error-state filter over `trajectory` at `theta` (no gate) and record its
/// linearization (module docs).
///
/// # Errors
/// [`NavigatorError::InvalidValue`] for an invalid theta, an IMU period that is not positive,
/// a DVL index beyond the IMU or out of order, or IMU times that do not increase;
/// [`NavigatorError::Filter`] for a numerical failure (with the time).
pub fn linearize(
    trajectory: &TuneTrajectory<'_>,
    model: &TuneModel,
    theta: &TuneParameters,
) -> Result<Linearization> {
    if !theta.iter().all(|v| v.is_finite()) {
        return Err(NavigatorError::invalid(
            "tune",
            format!("parameters {:?} must be finite", theta.as_slice()),
        ));
    }
    let period = trajectory.imu_period;
    if !(period.is_finite() && period > 0.0) {
        return Err(NavigatorError::invalid(
            "tune",
            format!("IMU period {period} s is not positive and finite"),
        ));
    }
    let spec = model.filter_spec(theta)?;
    let r = model.measurement_noise(theta);
    let dvl = model.dvl_with_noise(r)?;
    let cross = ScaledCorrelation {
        rho: theta[M_SCALE],
    };
    let mut filter = ErrorStateKalmanFilter::new(
        InsErrorModel::new(spec),
        trajectory.initial,
        trajectory.covariance,
    )?
    // Reported, not refused (estim-core's default refuses an invalid M): the
    // linearisation pass records the joint margin of each update as before.
    .with_config(
        FilterConfig::builder()
            .joint_check(JointCheck::Report)
            .build()?,
    );
    let imu = trajectory.imu;
    let Some(first) = imu.first() else {
        return Err(NavigatorError::invalid("tune", "no IMU samples"));
    };
    let tolerance = IMU_PERIOD_SNAP * period;
    let mut recorder = Recorder::new(noise_parts(&spec)?, period);
    let mut epochs = Vec::with_capacity(trajectory.dvl.len());
    let mut largest_valid_rho = f64::INFINITY;
    let mut clock = first.time;
    let mut next = 0;
    for (j, sample) in imu.iter().enumerate() {
        let last = j + 1 == imu.len();
        let end = imu.get(j + 1).map_or(sample.time + period, |s| s.time);
        if !(end.is_finite() && end > sample.time) {
            return Err(NavigatorError::invalid(
                "tune",
                format!(
                    "IMU sample {} at t = {end} s does not follow sample {j} at t = {} s",
                    j + 1,
                    sample.time
                ),
            ));
        }
        while let Some(&(time, y)) = trajectory.dvl.get(next) {
            // A measurement at the next sample's time belongs to the next interval.
            let inside = time < end - tolerance || (last && time <= end + tolerance);
            if !inside {
                break;
            }
            if !(time.is_finite() && time >= clock - tolerance) {
                return Err(NavigatorError::invalid(
                    "tune",
                    format!(
                        "DVL measurement {next} at t = {time} s is before t = {clock} s \
                     (out of order, or before the first IMU sample)"
                    ),
                ));
            }
            if time - clock > tolerance {
                recorder.step(&mut filter, sample, time - clock)?;
                clock = time;
            }
            let fail = |source| NavigatorError::Filter { time, source };
            largest_valid_rho = largest_valid_rho.min(
                ScaledCorrelation::largest_valid_rho(filter.accumulated_process_noise(), &r)
                    .map_err(fail)?,
            );
            epochs.push(
                recorder
                    .update(&mut filter, &dvl, &y, &cross)
                    .map_err(fail)?,
            );
            next += 1;
        }
        if last {
            break;
        }
        if end - clock > tolerance {
            recorder.step(&mut filter, sample, end - clock)?;
            clock = end;
        }
    }
    if let Some(&(time, _)) = trajectory.dvl.get(next) {
        return Err(NavigatorError::invalid(
            "tune",
            format!(
                "DVL measurement {next} at t = {time} s is beyond the IMU's end (t = {} s)",
                clock.max(imu.last().map_or(clock, |s| s.time + period))
            ),
        ));
    }
    Ok(Linearization {
        epochs,
        covariance: trajectory.covariance,
        theta: *theta,
        filter_log_likelihood: filter.log_likelihood(),
        largest_valid_rho,
    })
}

/// One error model per part of Q_d (white accelerometer noise, white gyroscope
/// noise, bias drift) of the filter's `spec`: their transitions are the same (same
/// time constants), their noises the parts (PSDs 1 or 0).
fn noise_parts(spec: &ImuSpec) -> Result<[InsErrorModel; 3]> {
    let part = |qa: f64, qg: f64, bias: bool| -> Result<InsErrorModel> {
        let mut acc = *spec.accelerometer();
        let mut gyro = *spec.gyroscope();
        acc.white_noise_density = qa;
        gyro.white_noise_density = qg;
        if !bias {
            acc.bias_instability = 0.0;
            gyro.bias_instability = 0.0;
        }
        Ok(InsErrorModel::new(
            ImuSpec::builder()
                .accelerometer(acc)
                .gyroscope(gyro)
                .build()?,
        ))
    };
    Ok([
        part(1.0, 0.0, false)?,
        part(0.0, 1.0, false)?,
        part(0.0, 0.0, true)?,
    ])
}

/// What [`linearize`] records between and at DVL epochs: Phi and the parts of Q_d
/// accumulated since the last epoch, the last correction and its reset Jacobian.
struct Recorder {
    parts: [InsErrorModel; 3],
    period: f64,
    tolerance: f64,
    phi_acc: ErrorMatrix,
    q_acc: [ErrorMatrix; 3],
    reset: ErrorMatrix,
    correction: SVector<f64, ERROR_STATES>,
}

impl Recorder {
    fn new(parts: [InsErrorModel; 3], period: f64) -> Self {
        Self {
            parts,
            period,
            tolerance: IMU_PERIOD_SNAP * period,
            phi_acc: ErrorMatrix::identity(),
            q_acc: [ErrorMatrix::zeros(); 3],
            reset: ErrorMatrix::identity(),
            correction: SVector::zeros(),
        }
    }

    /// Integrate `sample` over dt (the period when within the snap tolerance of it),
    /// recording Phi and the parts of Q_d.
    fn step(
        &mut self,
        filter: &mut ErrorStateKalmanFilter<f64, InsErrorModel, ERROR_STATES>,
        sample: &ImuSample,
        mut dt: f64,
    ) -> Result<()> {
        if (dt - self.period).abs() <= self.tolerance {
            dt = self.period;
        }
        let before = *filter.nominal();
        filter
            .predict(sample, dt)
            .map_err(|source| NavigatorError::Filter {
                time: before.time,
                source,
            })?;
        let mut phi = ErrorMatrix::identity();
        for (q, model) in self.q_acc.iter_mut().zip(&self.parts) {
            let (p, qd) = model.transition_and_noise(&before, sample, dt);
            *q = model.propagate_covariance(q, &p, &qd);
            phi = p;
        }
        self.phi_acc = self.parts[0].compose_transitions(&phi, &self.phi_acc);
        Ok(())
    }

    /// The DVL update `y` and its epoch of the linearized model; the accumulation
    /// starts again.
    fn update(
        &mut self,
        filter: &mut ErrorStateKalmanFilter<f64, InsErrorModel, ERROR_STATES>,
        dvl: &DvlVelocityModel,
        y: &Vector3<f64>,
        cross: &ScaledCorrelation<f64>,
    ) -> estim_core::Result<Epoch> {
        let before = *filter.nominal();
        let jacobian = dvl.jacobian(&before)?;
        let report = filter.update(dvl, y, cross)?;
        let transition = self.phi_acc * self.reset;
        let epoch = Epoch {
            control: -(transition * self.correction),
            transition,
            noise: self.q_acc,
            jacobian,
            innovation: report.innovation,
        };
        self.correction = report.correction.unwrap_or_else(SVector::zeros);
        self.reset = filter.process().reset_jacobian(&before, &self.correction);
        self.phi_acc = ErrorMatrix::identity();
        self.q_acc = [ErrorMatrix::zeros(); 3];
        Ok(epoch)
    }
}
