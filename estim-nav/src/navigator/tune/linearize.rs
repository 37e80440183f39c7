//! The filter of one trajectory run once at theta_0 and recorded between and at its
//! DVL epochs ([`linearize`]; the parent module's docs derive the model).

use super::*;
use crate::navigator::{run_epochs, EpochHook, Navigator, NavigatorConfig, Tail};
use estim_core::NoObserver;

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

/// Run the navigator over `trajectory` at `theta` (no gate; the one IMU loop,
/// [`run_epochs`]) and record its linearization (module docs).
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
    let imu = trajectory.imu;
    let (Some(first), Some(last)) = (imu.first(), imu.last()) else {
        return Err(NavigatorError::invalid("tune", "no IMU samples"));
    };
    check_imu_times(imu, period)?;
    let spec = model.filter_spec(theta)?;
    let r = model.measurement_noise(theta);
    let dvl = model.dvl_with_noise(r)?;
    let settings = NavigatorSettings {
        config: NavigatorConfig::default(),
        sensor_spec: model.sensor_spec,
        filter_spec: spec,
        // No gate. The joint check is reported, not refused (estim-core's default
        // refuses an invalid M): the pass records the joint margin of each update.
        filter_config: FilterConfig::builder()
            .joint_check(JointCheck::Report)
            .build()?,
        dvl: dvl.clone(),
        geometry: model.geometry.clone(),
        dvl_noise_scale: None,
    };
    // The clock starts at the first sample, which is held from there.
    let initial = InsState {
        time: first.time,
        ..trajectory.initial
    };
    let mut nav = Navigator::new(&settings, initial, trajectory.covariance, period)?;
    let mut recorder = Recorder {
        parts: noise_parts(&spec)?,
        dvl,
        r,
        cross: ScaledCorrelation {
            rho: theta[M_SCALE],
        },
        imu_end: last.time + period,
        tolerance: IMU_PERIOD_SNAP * period,
        clock: nav.clock(),
        before: initial,
        phi_acc: ErrorMatrix::identity(),
        q_acc: [ErrorMatrix::zeros(); 3],
        reset: ErrorMatrix::identity(),
        correction: SVector::zeros(),
        epochs: Vec::with_capacity(trajectory.dvl.len()),
        largest_valid_rho: f64::INFINITY,
    };
    run_epochs(
        &mut nav,
        imu,
        trajectory.dvl.iter().copied(),
        &mut recorder,
        Tail::StopAtLastEpoch,
    )?;
    Ok(Linearization {
        epochs: recorder.epochs,
        covariance: trajectory.covariance,
        theta: *theta,
        filter_log_likelihood: nav.filter().log_likelihood(),
        largest_valid_rho: recorder.largest_valid_rho,
    })
}

/// IMU times finite and increasing.
fn check_imu_times(imu: &[ImuSample], period: f64) -> Result<()> {
    for (j, pair) in imu.windows(2).enumerate() {
        let (sample, end) = (pair[0].time, pair[1].time);
        if !(sample.is_finite() && end.is_finite() && end > sample) {
            return Err(NavigatorError::invalid(
                "tune",
                format!(
                    "IMU sample {} at t = {end} s does not follow sample {j} at t = {sample} s",
                    j + 1
                ),
            ));
        }
    }
    if let Some(last) = imu.last().filter(|s| !(s.time + period).is_finite()) {
        return Err(NavigatorError::invalid(
            "tune",
            format!("IMU sample at t = {} s is not finite", last.time),
        ));
    }
    Ok(())
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

/// The hook of [`linearize`]'s run: records, between and at DVL epochs, Phi and the
/// parts of Q_d accumulated since the last epoch (from each step the navigator takes,
/// [`Navigator::last_step`]), the last correction and its reset Jacobian, and applies
/// the DVL updates.
struct Recorder {
    parts: [InsErrorModel; 3],
    dvl: DvlVelocityModel,
    r: Matrix3<f64>,
    cross: ScaledCorrelation<f64>,
    /// The last sample's time plus a period: no DVL epoch after it (within tolerance).
    imu_end: f64,
    tolerance: f64,
    /// The navigator's clock and nominal when the recorder last saw it.
    clock: f64,
    before: InsState,
    phi_acc: ErrorMatrix,
    q_acc: [ErrorMatrix; 3],
    reset: ErrorMatrix,
    correction: SVector<f64, ERROR_STATES>,
    epochs: Vec<Epoch>,
    largest_valid_rho: f64,
}

impl Recorder {
    /// Record the step the navigator took since the recorder last saw it (if any):
    /// Phi and the parts of Q_d at the nominal before it, with its sample and dt.
    fn record_step(&mut self, nav: &Navigator) {
        if nav.clock() != self.clock {
            if let Some((sample, dt)) = nav.last_step() {
                let mut phi = ErrorMatrix::identity();
                for (q, model) in self.q_acc.iter_mut().zip(&self.parts) {
                    let (p, qd) = model.transition_and_noise(&self.before, sample, dt);
                    *q = model.propagate_covariance(q, &p, &qd);
                    phi = p;
                }
                self.phi_acc = self.parts[0].compose_transitions(&phi, &self.phi_acc);
            }
        }
        self.clock = nav.clock();
        self.before = *nav.ins();
    }
}

impl EpochHook<InsErrorModel, NoObserver, ERROR_STATES> for Recorder {
    type Measurement = Vector3<f64>;
    type Error = NavigatorError;

    fn before_epoch(&mut self, nav: &Navigator, time: f64) -> Result<()> {
        let index = self.epochs.len();
        if !(time.is_finite() && time >= nav.clock() - self.tolerance) {
            return Err(NavigatorError::invalid(
                "tune",
                format!(
                    "DVL measurement {index} at t = {time} s is before t = {} s \
                     (out of order, or before the first IMU sample)",
                    nav.clock()
                ),
            ));
        }
        if time > self.imu_end + self.tolerance {
            return Err(NavigatorError::invalid(
                "tune",
                format!(
                    "DVL measurement {index} at t = {time} s is beyond the IMU's end (t = {} s)",
                    self.imu_end
                ),
            ));
        }
        Ok(())
    }

    fn on_sample(&mut self, nav: &Navigator, _sample: &ImuSample) -> Result<()> {
        self.record_step(nav);
        Ok(())
    }

    /// The DVL update `y` and its epoch of the linearized model; the accumulation
    /// starts again.
    fn on_epoch(&mut self, nav: &mut Navigator, time: f64, y: Vector3<f64>) -> Result<()> {
        self.record_step(nav);
        let fail = |source| NavigatorError::Filter { time, source };
        self.largest_valid_rho = self.largest_valid_rho.min(
            ScaledCorrelation::largest_valid_rho(nav.filter().accumulated_process_noise(), &self.r)
                .map_err(fail)?,
        );
        let before = *nav.ins();
        let jacobian = self.dvl.jacobian(&before).map_err(fail)?;
        let report = nav.dvl_velocity_with(time, &y, &self.dvl, &self.cross)?;
        let transition = self.phi_acc * self.reset;
        self.epochs.push(Epoch {
            control: -(transition * self.correction),
            transition,
            noise: self.q_acc,
            jacobian,
            innovation: report.innovation,
        });
        self.correction = report.correction.unwrap_or_else(SVector::zeros);
        self.reset = nav
            .filter()
            .process()
            .reset_jacobian(&before, &self.correction);
        self.phi_acc = ErrorMatrix::identity();
        self.q_acc = [ErrorMatrix::zeros(); 3];
        self.clock = nav.clock();
        self.before = *nav.ins();
        Ok(())
    }
}
