//! One filter run over a scenario: the 15-state INS error-state EKF aided by a DVL
//! velocity (least squares or a learned model), with a chosen cross-covariance.

use estim::navigator::{
    run_epochs, DvlConfig, DvlCross, EpochHook, GateConfig, Navigator, NavigatorConfig,
    NavigatorError, NavigatorSettings, Tail,
};
use estim_core::consistency::nees;
use estim_core::nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use estim_core::{
    Fixed, JointCovariance, MeasurementModel, NoObserver, Observer, ProcessModel,
    ScaledCorrelation, Zero,
};
use estim_ins::{ImuSpec, InsErrorModel, InsState, ATT, ERROR_STATES, POS, VEL};
use serde::Serialize;

use super::{
    initial_covariance, initial_nominal, Config, PaperMBasis, PipelineError, Result, Scenario,
};

/// 15 x 3 cross-covariance of the INS/DVL filter.
pub type CrossMatrix = SMatrix<f64, ERROR_STATES, 3>;

/// Where M_k comes from.
#[derive(Debug, Clone)]
pub enum CrossSource {
    /// M = 0 (correlation neglected).
    Zero,
    /// The paper's heuristic M = rho sqrt(diag Q_acc) sqrt(diag R)', Q_acc accumulated
    /// since the previous update.
    Scaled(f64),
    /// The paper's heuristic with the last IMU step's process noise:
    /// M = rho sqrt(diag Q_k) sqrt(diag R)' (the paper's E[w_k v_j'] taken literally).
    ScaledPerStep(f64),
    /// One precomputed M_k per DVL epoch (e.g. from the network's sensitivity).
    PerEpoch(Vec<CrossMatrix>),
}

impl CrossSource {
    /// The paper's heuristic with `rho` on the configured basis (`filter.paper_m_basis`).
    pub fn paper(rho: f64, basis: PaperMBasis) -> Self {
        match basis {
            PaperMBasis::Accumulated => Self::Scaled(rho),
            PaperMBasis::PerStep => Self::ScaledPerStep(rho),
        }
    }
}

/// The velocity measurements of one variant, aligned with `Scenario::dvl`.
#[derive(Debug, Clone)]
pub struct MeasurementSet {
    /// Velocity at the DVL per epoch (`None` = no measurement at that epoch).
    pub velocities: Vec<Option<Vector3<f64>>>,
    /// Measurement noise covariance R.
    pub noise_covariance: Matrix3<f64>,
}

/// Time series of one run, sampled at the DVL epochs (after the update); on a
/// recorded IMU at the reference's epochs instead ([`super::run_recorded`]).
#[derive(Debug, Clone, Serialize)]
pub struct FilterRun {
    /// Stable filter id (e.g. `ls`, `beamsnet_m_rho`; see `pipeline::filter_label`).
    pub id: String,
    /// Human label (serialised as `label`).
    #[serde(rename = "label")]
    pub name: String,
    /// Time since the start \[s\].
    pub time: Vec<f64>,
    /// Diagonal of P.
    pub covariance_diagonal: Vec<[f64; 15]>,
    /// Error against truth per axis (truth minus estimate): position N, E, D \[m\],
    /// velocity N, E, D \[m/s\], misalignment about N, E, D \[rad\]; for the per-axis
    /// error plots with their +-3 sigma bounds from `covariance_diagonal`.
    pub axis_error: Vec<[f64; 9]>,
    /// |position error| \[m\].
    pub position_error: Vec<f64>,
    /// |velocity error| \[m/s\].
    pub velocity_error: Vec<f64>,
    /// |attitude error| \[deg\].
    pub attitude_error_deg: Vec<f64>,
    /// NEES against truth over the first `nees_states` error states (15 on a
    /// synthesized IMU; 9 on a recorded one, whose true biases are unknown).
    pub nees: Vec<f64>,
    /// The states NEES is over.
    pub nees_states: usize,
    /// NIS of each attempted update.
    pub nis: Vec<f64>,
    /// Updates accepted.
    pub accepted: usize,
    /// Updates rejected by the innovation gate.
    pub rejected: usize,
    /// Per DVL epoch: `None` without a measurement, else whether the update was
    /// accepted (the gate's decision; with the recovery rule, accepted after inflation).
    pub update_accepted: Vec<Option<bool>>,
    /// Smallest eigenvalue of [[Q_acc, M], [M', R]] at each update.
    pub joint_min_eigenvalue: Vec<f64>,
    /// Largest valid rho of the paper's heuristic at each update (M built from the
    /// accumulated process noise), against this run's Q_acc and R.
    pub largest_valid_rho: Vec<f64>,
    /// The same with M built from the last IMU step's process noise Q_k (the joint
    /// covariance is still [[Q_acc, M], [M', R]]).
    pub largest_valid_rho_per_step: Vec<f64>,
    /// The largest valid rho of the per-step M against the same per-step Q_k, i.e. of
    /// [[Q_k, M], [M', R]] with M = rho sqrt(diag Q_k) sqrt(diag R)' (the paper's
    /// letter, read against its own Q_k); NaN before the first IMU step.
    pub largest_valid_rho_per_step_own: Vec<f64>,
    /// Per update, the diagonal of the cross term H U + U' H' of S divided by the
    /// diagonal of R, for the paper's M at rho = 1 (U = sqrt(diag Q) sqrt(diag R)'),
    /// on the accumulated basis (`[0]`) and the per-step basis (`[1]`); multiply by rho.
    /// The NED-frame standard deviations of U meet the body-frame H, so it depends on
    /// heading.
    pub paper_cross_term_over_r: Vec<[[f64; 3]; 2]>,
    /// North/east position of the estimate relative to the start \[m\].
    pub north_east: Vec<[f64; 2]>,
    /// Epochs at which P was not positive definite (NEES recorded as NaN).
    pub covariance_not_positive_definite: usize,
    /// The navigator's final DVL error states with their 1-sigma (a recorded IMU's
    /// run with `[dvl_states]`; not serialised).
    #[serde(skip)]
    pub final_dvl_states: Option<estim::navigator::DvlStateSolution>,
    /// The navigator's final adapted DVL noise level (a recorded IMU's run with
    /// `dvl.adaptive_noise_window`; not serialised).
    #[serde(skip)]
    pub final_noise_scale: Option<f64>,
}

/// The error state of `nominal` against `truth` (the library's
/// [`estim::navigator::error_state`]).
pub fn error_state(truth: &InsState, nominal: &InsState) -> SVector<f64, ERROR_STATES> {
    estim::navigator::error_state(truth, nominal)
}

/// The IMU model the filter uses ([`estim::navigator::filter_imu_spec`]: each bias a
/// Gauss-Markov process of correlation time
/// [`estim::navigator::FILTER_BIAS_TIME_CONSTANT`] with the
/// sensor drift's driving-noise PSD).
pub fn filter_imu_spec(spec: &ImuSpec) -> Result<ImuSpec> {
    Ok(estim::navigator::filter_imu_spec(spec)?)
}

/// Run the error-state EKF over `scenario` with `measurements` and `cross`.
///
/// IMU timing: see [`run_filter_with_observer`].
pub fn run_filter(
    name: &str,
    scenario: &Scenario,
    config: &Config,
    measurements: &MeasurementSet,
    cross: &CrossSource,
    seed: u64,
) -> Result<FilterRun> {
    run_filter_with_observer(
        name,
        scenario,
        config,
        measurements,
        cross,
        seed,
        &mut NoObserver,
    )
}

use estim::navigator::IMU_PERIOD_SNAP;

/// [`run_filter`] reporting every predict and update to `observer`.
///
/// IMU timing: the filter's clock starts at the first truth sample; sample k is
/// integrated from its own time `ImuSample::time` to the next sample's time (the last
/// sample over one nominal period), cut at each DVL epoch, so dt comes from the
/// timestamps (the nominal period when they differ from it by less than
/// `IMU_PERIOD_SNAP` relative).
/// - A gap (missing samples) is bridged by holding the last sample over the longer
///   interval (zero-order hold); the process noise grows with that dt.
/// - A duplicate, backward or non-finite IMU timestamp is a typed error
///   ([`PipelineError::ImuSample`] naming the sample index), never a zero or negative dt.
/// - A DVL epoch beyond the end of the IMU (more than one period after the last
///   sample) is an error too: the filter does not extrapolate.
///
/// # Errors
/// As above; the filter core's errors; the observer's errors.
pub fn run_filter_with_observer<O: Observer<f64, InsState, ERROR_STATES>>(
    name: &str,
    scenario: &Scenario,
    config: &Config,
    measurements: &MeasurementSet,
    cross: &CrossSource,
    seed: u64,
    observer: &mut O,
) -> Result<FilterRun> {
    run_filter_inner(
        name,
        scenario,
        config,
        measurements,
        None,
        cross,
        seed,
        observer,
    )
}

/// [`run_filter`] with R chosen per DVL epoch: `noise_per_epoch[k]` (when `Some`)
/// replaces `measurements.noise_covariance` at epoch k (e.g. two learned sensors of
/// different accuracy sharing one run). A scenario of a recorded IMU runs through
/// [`super::recorded::run_recorded_with_noise`] (the vehicle's R where `noise_per_epoch` has none).
///
/// # Errors
/// As [`run_filter_with_observer`]; a non-finite or invalid R.
pub fn run_filter_per_epoch_noise(
    name: &str,
    scenario: &Scenario,
    config: &Config,
    measurements: &MeasurementSet,
    noise_per_epoch: &[Option<Matrix3<f64>>],
    cross: &CrossSource,
    seed: u64,
) -> Result<FilterRun> {
    if let Some(recorded) = &scenario.recorded {
        return super::recorded::run_recorded_with_noise(
            name,
            scenario,
            recorded,
            measurements,
            Some(noise_per_epoch),
            cross,
        );
    }
    run_filter_inner(
        name,
        scenario,
        config,
        measurements,
        Some(noise_per_epoch),
        cross,
        seed,
        &mut NoObserver,
    )
}

/// The navigator settings of a study run: the scenario's IMU spec, the configured
/// gate, the configured DVL lever arm and R.
fn navigator_settings(
    config: &Config,
    scenario: &Scenario,
    noise_covariance: Matrix3<f64>,
) -> Result<NavigatorSettings> {
    let nav = NavigatorConfig {
        dvl: DvlConfig {
            lever_arm_m: config.dvl.lever_arm_m,
            ..DvlConfig::default()
        },
        gate: GateConfig {
            probability: config.filter.gate_probability,
            recovery_after: config.filter.gate_recovery_after,
        },
        ..NavigatorConfig::default()
    };
    Ok(nav
        .check()?
        .with_sensor_spec(scenario.imu_spec)?
        .with_dvl_noise_covariance(noise_covariance)?)
}

#[allow(clippy::too_many_arguments)]
fn run_filter_inner<O: Observer<f64, InsState, ERROR_STATES>>(
    name: &str,
    scenario: &Scenario,
    config: &Config,
    measurements: &MeasurementSet,
    noise_per_epoch: Option<&[Option<Matrix3<f64>>]>,
    cross: &CrossSource,
    seed: u64,
    observer: &mut O,
) -> Result<FilterRun> {
    if scenario.recorded.is_some() {
        return Err(PipelineError::RecordedImu {
            scenario: scenario.name.clone(),
        });
    }
    check_imu_timestamps(scenario)?;
    let truth0 = scenario
        .truth
        .first()
        .ok_or_else(|| PipelineError::NoData {
            what: format!("truth samples in {}", scenario.name),
        })?;
    let p0 = initial_covariance(config, &scenario.imu_spec);
    let nominal0 = initial_nominal(truth0, &p0, seed);
    let settings = navigator_settings(config, scenario, measurements.noise_covariance)?;
    let imu = &scenario.imu;
    let period = scenario.imu_dt;
    let mut nav = Navigator::new(&settings, nominal0, p0, period)?.with_observer(observer);
    let first_imu = imu.first().ok_or_else(|| PipelineError::NoData {
        what: format!("IMU samples in {}", scenario.name),
    })?;
    let mut hook = StudyHook {
        scenario,
        settings: &settings,
        measurements,
        noise_per_epoch,
        cross,
        truth0,
        // The IMU in effect covers up to the next sample, the last one over one period.
        imu_end: imu.last().map_or(first_imu.time, |s| s.time) + period,
        tolerance: IMU_PERIOD_SNAP * period,
        epoch: 0,
        run: FilterRun::new(name, scenario.dvl.len()),
    };
    // An epoch whose truth index is beyond the scenario is refused by the hook before
    // its time (NaN here) is used.
    let epochs = scenario.dvl.iter().map(|dvl| {
        let time = scenario
            .truth
            .get(dvl.imu_index)
            .map_or(f64::NAN, |t| t.time);
        (time, ())
    });
    run_epochs(&mut nav, imu, epochs, &mut hook, Tail::StopAtLastEpoch)?;
    Ok(hook.run)
}

impl FilterRun {
    /// An empty run with room for `n` epochs.
    pub(super) fn new(name: &str, n: usize) -> Self {
        Self {
            id: name.to_string(),
            name: name.to_string(),
            time: Vec::with_capacity(n),
            covariance_diagonal: Vec::with_capacity(n),
            axis_error: Vec::with_capacity(n),
            position_error: Vec::with_capacity(n),
            velocity_error: Vec::with_capacity(n),
            attitude_error_deg: Vec::with_capacity(n),
            nees: Vec::with_capacity(n),
            nees_states: ERROR_STATES,
            nis: Vec::with_capacity(n),
            accepted: 0,
            rejected: 0,
            update_accepted: Vec::with_capacity(n),
            joint_min_eigenvalue: Vec::with_capacity(n),
            largest_valid_rho: Vec::with_capacity(n),
            largest_valid_rho_per_step: Vec::with_capacity(n),
            largest_valid_rho_per_step_own: Vec::with_capacity(n),
            paper_cross_term_over_r: Vec::with_capacity(n),
            north_east: Vec::with_capacity(n),
            covariance_not_positive_definite: 0,
            final_dvl_states: None,
            final_noise_scale: None,
        }
    }
}

/// The navigator of a study run (its estim-core observer borrowed).
type StudyNavigator<'o, O> = Navigator<InsErrorModel, &'o mut O, ERROR_STATES>;

/// The per-epoch hook of a study run: checks each DVL epoch, updates with the
/// variant's R and M, and records the errors against truth.
struct StudyHook<'a> {
    scenario: &'a Scenario,
    settings: &'a NavigatorSettings,
    measurements: &'a MeasurementSet,
    noise_per_epoch: Option<&'a [Option<Matrix3<f64>>]>,
    cross: &'a CrossSource,
    truth0: &'a InsState,
    imu_end: f64,
    tolerance: f64,
    /// The epoch under way.
    epoch: usize,
    run: FilterRun,
}

impl<'o, O: Observer<f64, InsState, ERROR_STATES>> EpochHook<InsErrorModel, &'o mut O, ERROR_STATES>
    for StudyHook<'_>
{
    type Measurement = ();
    type Error = PipelineError;

    fn before_epoch(&mut self, nav: &StudyNavigator<'o, O>, target: f64) -> Result<()> {
        let epoch = self.epoch;
        let dvl = &self.scenario.dvl[epoch];
        let bad = |reason: String| PipelineError::DvlEpoch {
            scenario: self.scenario.name.clone(),
            epoch,
            reason,
        };
        if self.scenario.truth.get(dvl.imu_index).is_none() {
            return Err(bad(format!(
                "truth index {} beyond the scenario ({} samples)",
                dvl.imu_index,
                self.scenario.truth.len()
            )));
        }
        if target < nav.clock() - self.tolerance {
            return Err(bad(format!(
                "at t = {target} s, before the previous one ({} s)",
                nav.clock()
            )));
        }
        if target - self.imu_end > self.tolerance {
            return Err(bad(format!(
                "at t = {target} s, after the end of the IMU ({} s)",
                self.imu_end
            )));
        }
        Ok(())
    }

    fn on_epoch(&mut self, nav: &mut StudyNavigator<'o, O>, target: f64, _: ()) -> Result<()> {
        let epoch = self.epoch;
        match self.measurements.velocities.get(epoch).copied().flatten() {
            Some(y) => self.update(nav, target, &y)?,
            None => self.run.update_accepted.push(None),
        }
        let truth = &self.scenario.truth[self.scenario.dvl[epoch].imu_index];
        self.record(nav, truth);
        self.epoch += 1;
        Ok(())
    }

    fn stopped(&mut self, error: NavigatorError) -> PipelineError {
        nav_error(self.epoch, self.truth0.time, error)
    }
}

impl StudyHook<'_> {
    /// The DVL update of the epoch under way, with its diagnostics.
    fn update<O: Observer<f64, InsState, ERROR_STATES>>(
        &mut self,
        nav: &mut StudyNavigator<'_, O>,
        target: f64,
        y: &Vector3<f64>,
    ) -> Result<()> {
        let epoch = self.epoch;
        let run = &mut self.run;
        let epoch_model;
        let per_epoch = self
            .noise_per_epoch
            .and_then(|v| v.get(epoch).copied().flatten());
        let (model, r) = match per_epoch {
            Some(r_k) => {
                epoch_model = self.settings.dvl_model_with_noise(r_k)?;
                (&epoch_model, r_k)
            }
            None => (
                self.settings.dvl_model(),
                self.measurements.noise_covariance,
            ),
        };
        let filter = nav.filter();
        run.largest_valid_rho
            .push(ScaledCorrelation::largest_valid_rho(
                filter.accumulated_process_noise(),
                &r,
            )?);
        // Q_k of the last step, at the nominal state after it (the attitude moves
        // by one IMU period in between: negligible at the rounding of a heuristic).
        let step_noise = match nav.last_step() {
            Some((sample, dt)) => filter
                .process()
                .process_noise(filter.nominal(), sample, dt)?,
            None => SMatrix::zeros(),
        };
        let step_unit = ScaledCorrelation::unit(&step_noise, &r);
        run.largest_valid_rho_per_step.push(
            JointCovariance::new(*filter.accumulated_process_noise(), step_unit, r)
                .largest_valid_scale()?,
        );
        run.largest_valid_rho_per_step_own
            .push(if nav.last_step().is_some() {
                // A diagnostic: a failure here is a NaN, never a stopped run.
                JointCovariance::new(step_noise, step_unit, r)
                    .largest_valid_scale()
                    .unwrap_or(f64::NAN)
            } else {
                f64::NAN
            });
        let h = model.jacobian(filter.nominal())?;
        let over_r = |u: &CrossMatrix| -> [f64; 3] {
            let hu = h * u;
            std::array::from_fn(|j| 2.0 * hu[(j, j)] / r[(j, j)])
        };
        run.paper_cross_term_over_r.push([
            over_r(&ScaledCorrelation::unit(
                filter.accumulated_process_noise(),
                &r,
            )),
            over_r(&step_unit),
        ]);
        let scaled;
        let fixed;
        let source: &DvlCross<'_> = match self.cross {
            CrossSource::Zero => &Zero,
            CrossSource::Scaled(rho) => {
                scaled = ScaledCorrelation { rho: *rho };
                &scaled
            }
            CrossSource::ScaledPerStep(rho) => {
                fixed = Fixed(step_unit * *rho);
                &fixed
            }
            CrossSource::PerEpoch(ms) => {
                fixed = Fixed(ms.get(epoch).copied().unwrap_or_else(CrossMatrix::zeros));
                &fixed
            }
        };
        let report = nav
            .dvl_velocity_with(target, y, model, source)
            .map_err(|e| nav_error(epoch, self.truth0.time, e))?;
        run.nis.push(report.nis);
        if let Some(eig) = report.joint_min_eigenvalue {
            run.joint_min_eigenvalue.push(eig);
        }
        if report.is_accepted() {
            run.accepted += 1;
        } else {
            run.rejected += 1;
        }
        run.update_accepted.push(Some(report.is_accepted()));
        Ok(())
    }

    /// The errors against `truth` after the epoch under way.
    fn record<O>(&mut self, nav: &StudyNavigator<'_, O>, truth: &InsState) {
        let (run, truth0) = (&mut self.run, self.truth0);
        let (rn0, re0) = estim_ins::earth::radii_of_curvature(truth0.latitude);
        let nominal = nav.nominal();
        let p = nav.covariance();
        let e = error_state(truth, nominal);
        run.time.push(truth.time - truth0.time);
        run.covariance_diagonal
            .push(std::array::from_fn(|i| p[(i, i)]));
        run.axis_error.push(std::array::from_fn(|i| e[i]));
        run.position_error.push(e.fixed_rows::<3>(POS).norm());
        run.velocity_error.push(e.fixed_rows::<3>(VEL).norm());
        run.attitude_error_deg
            .push(e.fixed_rows::<3>(ATT).norm().to_degrees());
        // A covariance that lost positive definiteness (possible when M makes the joint
        // covariance invalid) is a finding to report, not a reason to abort the run.
        match nees(&e, p) {
            Ok(v) => run.nees.push(v),
            Err(_) => {
                run.nees.push(f64::NAN);
                run.covariance_not_positive_definite += 1;
            }
        }
        run.north_east.push([
            (nominal.latitude - truth0.latitude) * (rn0 + truth0.height),
            (nominal.longitude - truth0.longitude) * (re0 + truth0.height) * truth0.latitude.cos(),
        ]);
    }
}

/// A navigator error at a DVL epoch: a numerical failure of the filter is a finding
/// about this variant (with the time since the start), anything else invalid input.
fn nav_error(epoch: usize, start: f64, error: NavigatorError) -> PipelineError {
    match error {
        NavigatorError::Filter { time, source } => stopped(epoch, time - start, source),
        error => PipelineError::NavigatorAt { epoch, error },
    }
}

/// A numerical failure of the filter at a DVL epoch: a finding about this filter
/// variant, reported with where it happened (the other variants are unaffected).
fn stopped(epoch: usize, time_s: f64, source: estim_core::Error) -> PipelineError {
    PipelineError::FilterStopped {
        epoch,
        time_s,
        source,
    }
}

/// Reject duplicate, backward and non-finite IMU timestamps, naming the sample.
fn check_imu_timestamps(scenario: &Scenario) -> Result<()> {
    let mut previous: Option<f64> = None;
    for (index, sample) in scenario.imu.iter().enumerate() {
        let t = sample.time;
        let bad = |reason: String| PipelineError::ImuSample {
            scenario: scenario.name.clone(),
            index,
            reason,
        };
        if !t.is_finite() {
            return Err(bad(format!("non-finite timestamp {t}")));
        }
        if let Some(p) = previous {
            if t <= p {
                let what = if t == p { "duplicate" } else { "backward" };
                return Err(bad(format!("{what} timestamp {t} s (previous {p} s)")));
            }
        }
        previous = Some(t);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use estim_core::nalgebra::UnitQuaternion;
    use estim_ins::inject;

    #[test]
    fn error_state_inverts_inject() {
        // inject (estim-ins) and error_state (here) are coded independently.
        let nominal = InsState {
            time: 0.0,
            latitude: 0.57,
            longitude: 0.61,
            height: -20.0,
            velocity_ned: Vector3::new(1.5, -0.3, 0.05),
            attitude: UnitQuaternion::from_euler_angles(0.02, -0.01, 2.5),
            acc_bias: Vector3::new(1e-3, -2e-3, 5e-4),
            gyro_bias: Vector3::new(1e-5, 2e-5, -3e-5),
            angular_rate: Vector3::zeros(),
        };
        let e = SVector::<f64, ERROR_STATES>::from_iterator([
            3.0, -2.0, 0.5, 0.01, -0.02, 0.003, 1e-3, -2e-3, 5e-3, 1e-4, 2e-4, -1e-4, 1e-6, -2e-6,
            3e-6,
        ]);
        let truth = inject(&nominal, &e);
        let back = error_state(&truth, &nominal);
        for i in 0..ERROR_STATES {
            let tol = 1e-9 * e[i].abs().max(1e-6);
            assert!(
                (back[i] - e[i]).abs() <= tol,
                "component {i}: {} vs {}",
                back[i],
                e[i]
            );
        }
    }
}
