//! The recorded IMU in the study: an A-KIT trajectory whose folder holds
//! `IMU_trajectoryN.csv` is read as a user's survey (the vehicle file
//! `vehicles/akit.toml`: axes, clocks, offsets, lever arms, the reference's point and
//! clock), and every filter variant runs through the navigator's own batch loop
//! ([`estim::navigator::navigate_beams_with`]) with the variant's velocity and M.
//!
//! What differs from the synthesized IMU, and why:
//! - truth is the reference (GT) track on the navigator's clock, carried to the IMU by
//!   the vehicle's `[truth]` lever arm, its clock offset estimated against the IMU's
//!   angular rate, as `estim navigate --truth` does; the IMU's true biases are unknown,
//!   so NEES is over the 9 states with truth (position, velocity, attitude);
//! - errors, NEES and the state std are scored at the reference's own epochs (1 Hz),
//!   not at the DVL epochs between them;
//! - every variant uses the vehicle's DVL model (its R, adapted online over
//!   `dvl.adaptive_noise_window` updates, and the DVL error states of `[dvl_states]`);
//!   the variants differ in the velocity (least squares on the protocol's beams, or the
//!   network's) and in M;
//! - the run starts at the reference's first epoch in the IMU's span, from the
//!   reference's state (`[truth] initial_state`), with the vehicle's initial
//!   covariance; no initial error is drawn.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use estim::navigator::{
    error_state, navigate_beams_with, nees_of_block, AugmentedNavigator, DvlCross, DvlInput,
    DvlRecord, NavSolution, NavigationModel, NavigationObserver, Navigator, NavigatorConfig,
    NavigatorError, NavigatorSettings, SolutionKind, SurveyInputs,
};
use estim_core::nalgebra::{Matrix3, SMatrix, Vector3, Vector4};
use estim_core::{Fixed, JointCovariance, NoObserver, ScaledCorrelation, Zero};
use estim_dvl::BeamsNetProtocol;
use estim_ins::{ErrorMatrix, ImuSample, InsState, ATT, ERROR_STATES, POS, VEL};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::{
    Config, CrossSource, DvlEpoch, FilterRun, MeasurementSet, PipelineError, Result, Scenario,
};
use estim::datasets::trajectory_files;

/// The A-KIT vehicle file the study reads a recorded IMU with, unless another is given.
pub const AKIT_VEHICLE: &str = include_str!("../../../vehicles/akit.toml");

/// The states with truth on a recorded IMU: position, velocity, attitude.
pub const RECORDED_NEES_STATES: usize = 9;

/// Which IMU a scenario's filter integrates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ImuSource {
    /// The vehicle's IMU as recorded (`IMU_trajectoryN.csv`).
    Recorded,
    /// An IMU synthesized from the reference track with the configured error model.
    Synthesized,
}

impl ImuSource {
    /// `recorded` or `synthesized`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Recorded => "recorded",
            Self::Synthesized => "synthesized",
        }
    }
}

pub use crate::imu_choice::ImuChoice;

/// The IMU a study command uses for the A-KIT trajectories, and the vehicle file a
/// recorded one is read with (`--imu`, `--vehicle`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImuSelection {
    /// Recorded where it exists (default), recorded only, or synthesized.
    pub choice: ImuChoice,
    /// The vehicle file; `None`: the embedded [`AKIT_VEHICLE`].
    pub vehicle: Option<std::path::PathBuf>,
}

/// A recorded survey as the study runs it.
#[derive(Debug, Clone)]
pub struct RecordedSurvey {
    /// The vehicle file (a path, or the embedded `vehicles/akit.toml`).
    pub vehicle: String,
    /// The navigator settings from it (the initial state from the reference).
    pub settings: NavigatorSettings,
    /// The IMU (on the navigator's clock, trimmed to the reference's span) and the
    /// DVL rows' stamps, one per [`Scenario::dvl`] epoch (their inputs are set per
    /// variant by [`run_recorded`]).
    pub inputs: SurveyInputs,
    /// The reference's epochs inside the run with the truth there.
    pub truth_epochs: Vec<(f64, InsState)>,
    /// The reference's clock offset (as `estim navigate --truth` reports it).
    pub truth_time_offset: serde_json::Value,
}

impl Scenario {
    /// A-KIT trajectory `n` with the IMU `choice` selects: the recorded one read
    /// through `vehicle` (default: the embedded [`AKIT_VEHICLE`]) where the folder
    /// holds `IMU_trajectoryN.csv`, else [`Scenario::akit_with`].
    ///
    /// # Errors
    /// As [`Scenario::akit_with`]; a missing IMU file under [`ImuChoice::Recorded`];
    /// the survey's errors (naming the file and line) as [`PipelineError::Survey`] or [`PipelineError::Data`].
    pub fn akit_choosing(
        dir: &Path,
        n: u32,
        config: &Config,
        seed: u64,
        allow_partial: bool,
        choice: ImuChoice,
        vehicle: Option<&Path>,
    ) -> Result<Self> {
        let files = trajectory_files(dir, n)?;
        let imu = files.gt.with_file_name(format!("IMU_trajectory{n}.csv"));
        match choice {
            ImuChoice::Synthesized => return Self::akit_with(dir, n, config, seed, allow_partial),
            ImuChoice::Auto if !imu.is_file() => {
                return Self::akit_with(dir, n, config, seed, allow_partial)
            }
            _ => {}
        }
        let mut scenario = Self::recorded_imu(&imu, &files.dvl, &files.gt, config, seed, vehicle)?;
        scenario.name = format!("A-KIT trajectory {n}");
        scenario.trajectory = Some(n);
        Ok(scenario)
    }

    /// A-KIT trajectory `n` with the IMU of `selection` ([`Scenario::akit_choosing`],
    /// no partial trajectory).
    ///
    /// # Errors
    /// As [`Scenario::akit_choosing`].
    pub fn akit_selected(
        dir: &Path,
        n: u32,
        config: &Config,
        seed: u64,
        selection: &ImuSelection,
    ) -> Result<Self> {
        Self::akit_choosing(
            dir,
            n,
            config,
            seed,
            false,
            selection.choice,
            selection.vehicle.as_deref(),
        )
    }

    /// The same scenario with a recorded survey's innovation gate off (a synthesized
    /// scenario's gate is the configuration's `filter.gate_probability`).
    ///
    /// # Errors
    /// As [`RecordedSurvey::without_gate`].
    pub fn without_recorded_gate(&self) -> Result<Self> {
        let mut open = self.clone();
        if let Some(recorded) = &self.recorded {
            open.recorded = Some(Arc::new(recorded.without_gate()?));
        }
        Ok(open)
    }

    /// A recorded IMU, DVL and reference read through a vehicle file (see the module
    /// documentation); beams from the DVL velocity by the configured protocol.
    ///
    /// # Errors
    /// Every reader's error naming the file and line; a reference with no epoch in the
    /// IMU's span; two DVL rows on one IMU sample; fewer than
    /// [`super::scenario::MIN_DVL_EPOCHS`] DVL rows inside the run.
    pub fn recorded_imu(
        imu_path: &Path,
        dvl_path: &Path,
        gt_path: &Path,
        config: &Config,
        seed: u64,
        vehicle: Option<&Path>,
    ) -> Result<Self> {
        let invalid = PipelineError::Survey;
        let data = |path: &Path, reason: String| PipelineError::Data {
            path: path.to_path_buf(),
            line: None,
            reason,
        };
        let (nav_config, vehicle_name) = vehicle_config(vehicle)?;
        let dvl_offset = nav_config.dvl.time_offset_s;
        // As `estim navigate --imu --dvl --vehicle --truth` reads them.
        let files = crate::navigate::SurveyFiles {
            sensors: estim::SurveyFiles {
                imu: imu_path.to_path_buf(),
                dvl: Some(dvl_path.to_path_buf()),
                vehicle: vehicle.map(Path::to_path_buf),
                ..Default::default()
            },
            truth: Some(gt_path.to_path_buf()),
            init_from_truth: true,
        };
        let survey = crate::navigate::load_survey_from(files, nav_config).map_err(invalid)?;
        let truth = survey
            .truth
            .as_ref()
            .ok_or_else(|| data(gt_path, "no truth read".into()))?;
        let all = &survey.inputs.imu;
        let period = estim::navigator::nominal_imu_period(all, &survey.settings)
            .map_err(|e| data(imu_path, e.to_string()))?;
        let start_time = survey
            .settings
            .config()
            .initial
            .time_s
            .unwrap_or(f64::NEG_INFINITY);
        let epochs = truth.epochs();
        let truth_end = epochs.last().copied().unwrap_or(f64::NEG_INFINITY);
        // The run: from the first sample at the start, to the last sample whose
        // interval ends inside the reference's span.
        let first = all.partition_point(|s| s.time < start_time - 1e-9);
        let last = all.partition_point(|s| s.time + period <= truth_end + 1e-9);
        if last <= first + 1 {
            return Err(data(
                imu_path,
                format!(
                    "no IMU sample inside the reference's span ({})",
                    gt_path.display()
                ),
            ));
        }
        let imu: Vec<ImuSample> = all[first..last].to_vec();
        let end = imu[imu.len() - 1].time + period;
        let reference = |t: f64| -> Result<(InsState, Vector3<f64>)> {
            truth
                .kinematics(t)
                .map_err(|e| data(gt_path, e.to_string()))?
                .ok_or_else(|| {
                    data(
                        gt_path,
                        format!("t = {t:.3} s is outside the reference's span"),
                    )
                })
        };
        let (states, clean) = reference_imu(&imu, end, &reference)?;

        let protocol = if config.dvl.protocol == "v2" {
            BeamsNetProtocol::v2()
        } else {
            BeamsNetProtocol::v1()
        };
        let (dvl, rows) = dvl_epochs(
            &survey.inputs.dvl,
            &imu,
            period,
            dvl_offset,
            &protocol,
            seed,
            [dvl_path, imu_path],
        )?;
        let truth_epochs = epochs
            .iter()
            .filter(|&&t| t >= imu[0].time && t <= end)
            .map(|&t| reference(t).map(|(s, _)| (t, s)))
            .collect::<Result<Vec<_>>>()?;
        let inputs = variant_inputs(&imu, &rows, &truth_epochs);
        let imu_spec = *survey.settings.sensor_spec();
        let recorded = RecordedSurvey {
            vehicle: vehicle_name,
            // A row the variant leaves to least squares (3 beams) is solved on the
            // protocol's geometry, on which its beams were drawn.
            settings: survey
                .settings
                .clone()
                .with_beam_geometry(protocol.geometry().clone()),
            inputs,
            truth_epochs,
            truth_time_offset: crate::navigate::time_offset_json(truth.time_offset()),
        };
        Ok(Self {
            name: gt_path.display().to_string(),
            trajectory: None,
            truth: states,
            imu,
            clean_imu: clean,
            imu_dt: period,
            imu_spec,
            dvl,
            span: None,
            imu_source: ImuSource::Recorded,
            recorded: Some(Arc::new(recorded)),
        })
    }
}

/// The vehicle file a recorded IMU is read with (default the embedded
/// [`AKIT_VEHICLE`]), and its name for reports.
fn vehicle_config(vehicle: Option<&Path>) -> Result<(NavigatorConfig, String)> {
    Ok(match vehicle {
        Some(p) => (
            crate::navigate::vehicle_config(p).map_err(PipelineError::Survey)?,
            p.display().to_string(),
        ),
        None => (
            toml::from_str::<NavigatorConfig>(AKIT_VEHICLE).map_err(|e| PipelineError::Data {
                path: "vehicles/akit.toml (embedded)".into(),
                line: None,
                reason: e.to_string(),
            })?,
            "vehicles/akit.toml (embedded)".to_string(),
        ),
    })
}

/// The navigator's inputs of a variant run: the IMU, a placeholder row at each DVL
/// row's stamp (each variant supplies its velocity there), and a solution at each of
/// the reference's epochs.
fn variant_inputs(
    imu: &[ImuSample],
    rows: &[f64],
    truth_epochs: &[(f64, InsState)],
) -> SurveyInputs {
    SurveyInputs {
        imu: imu.to_vec(),
        dvl: rows
            .iter()
            .map(|&time| DvlRecord {
                time,
                input: DvlInput::NoLock,
            })
            .collect(),
        depth: Vec::new(),
        fixes: Vec::new(),
        output_epochs: truth_epochs.iter().map(|(t, _)| *t).collect(),
    }
}

/// The reference at each IMU sample (and at `end`, the last sample's interval's end),
/// and the error-free IMU: over [t_k, t_k+1] the reference's specific force and rate
/// at the interval's middle.
fn reference_imu(
    imu: &[ImuSample],
    end: f64,
    reference: &dyn Fn(f64) -> Result<(InsState, Vector3<f64>)>,
) -> Result<(Vec<InsState>, Vec<ImuSample>)> {
    let mut states = Vec::with_capacity(imu.len() + 1);
    let mut clean = Vec::with_capacity(imu.len());
    for (k, sample) in imu.iter().enumerate() {
        let (mut state, _) = reference(sample.time)?;
        state.time = sample.time;
        states.push(state);
        // The error-free sample over [t_k, t_k+1]: the reference at its middle.
        let next = imu.get(k + 1).map_or(end, |s| s.time);
        let (middle, force) = reference(0.5 * (sample.time + next))?;
        clean.push(ImuSample {
            time: sample.time,
            specific_force: force,
            angular_rate: middle.angular_rate,
        });
    }
    let (mut last_state, _) = reference(end)?;
    last_state.time = end;
    states.push(last_state);
    Ok((states, clean))
}

/// The survey's DVL velocity rows as the study's epochs: each at the IMU sample
/// nearest its stamp minus `dvl_offset` (within half a period), with the protocol's
/// beams drawn from its velocity (seeded); and the rows' stamps. `[dvl_path,
/// imu_path]` name the files in errors.
fn dvl_epochs(
    records: &[DvlRecord],
    imu: &[ImuSample],
    period: f64,
    dvl_offset: f64,
    protocol: &BeamsNetProtocol,
    seed: u64,
    [dvl_path, imu_path]: [&Path; 2],
) -> Result<(Vec<DvlEpoch>, Vec<f64>)> {
    let data = |path: &Path, reason: String| PipelineError::Data {
        path: path.to_path_buf(),
        line: None,
        reason,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD71);
    let mut dvl = Vec::new();
    let mut rows = Vec::new();
    let half = 0.5 * period * (1.0 + 1e-9);
    for record in records {
        let DvlInput::Velocity(v) = record.input else {
            continue;
        };
        let t = record.time - dvl_offset;
        let j = imu.partition_point(|s| s.time < t);
        let nearest = [j.checked_sub(1), Some(j)]
            .into_iter()
            .flatten()
            .filter(|&i| i < imu.len())
            .min_by(|&a, &b| (imu[a].time - t).abs().total_cmp(&(imu[b].time - t).abs()));
        let Some(i) = nearest.filter(|&i| i >= 1 && (imu[i].time - t).abs() <= half) else {
            continue;
        };
        if dvl.last().is_some_and(|d: &DvlEpoch| d.imu_index >= i) {
            return Err(data(
                dvl_path,
                format!(
                    "two DVL rows on the IMU sample at t = {:.3} s (rows must be at \
                     least one IMU period apart; refused, not merged)",
                    imu[i].time
                ),
            ));
        }
        dvl.push(DvlEpoch {
            imu_index: i,
            reference_velocity: v,
            beams: protocol.beams(&v, &mut rng),
        });
        rows.push(record.time);
    }
    if dvl.len() < super::scenario::MIN_DVL_EPOCHS {
        return Err(data(
            dvl_path,
            format!(
                "{} DVL rows inside the run on {} (after dvl.time_offset_s = \
                 {dvl_offset} s); at least {} are needed",
                dvl.len(),
                imu_path.display(),
                super::scenario::MIN_DVL_EPOCHS
            ),
        ));
    }
    Ok((dvl, rows))
}

impl RecordedSurvey {
    /// The same survey with the innovation gate off (every update accepted): for
    /// paired comparisons whose variants must not differ in the gate's decisions.
    ///
    /// # Errors
    /// The navigator's check of the changed configuration.
    pub fn without_gate(&self) -> Result<Self> {
        self.rechecked(|config| config.gate.probability = 0.0)
    }

    /// The same survey without DVL error states (the 15-state navigator, the vehicle's
    /// DVL mounting fixed).
    ///
    /// # Errors
    /// As [`RecordedSurvey::without_gate`].
    pub fn without_dvl_states(&self) -> Result<Self> {
        self.rechecked(|config| config.dvl_states = None)
    }

    /// The same survey with its configuration changed by `change` and checked again.
    fn rechecked(&self, change: impl FnOnce(&mut NavigatorConfig)) -> Result<Self> {
        let mut config = self.settings.config().clone();
        change(&mut config);
        let settings = config
            .check()
            .map_err(|e| PipelineError::Data {
                path: self.vehicle.clone().into(),
                line: None,
                reason: e.to_string(),
            })?
            .with_beam_geometry(self.settings.beam_geometry().clone());
        Ok(Self {
            settings,
            ..self.clone()
        })
    }
}

/// Run one variant on a recorded survey (see the module documentation).
///
/// # Errors
/// [`PipelineError::FilterStopped`] when the navigator stopped (a numerical failure,
/// or its health checks found the solution diverged); other navigator errors as
/// [`PipelineError::NavigatorAt`].
pub fn run_recorded(
    id: &str,
    scenario: &Scenario,
    recorded: &RecordedSurvey,
    measurements: &MeasurementSet,
    cross: &CrossSource,
) -> Result<FilterRun> {
    run_recorded_with_noise(id, scenario, recorded, measurements, None, cross)
}

/// [`run_recorded`] with an R of its own at the epochs where `noise_per_epoch` has one
/// (a learned sensor's, during a scripted loss): there the update uses that R, not the
/// vehicle's adapted one, and leaves the adapted level alone.
///
/// # Errors
/// As [`run_recorded`].
pub fn run_recorded_with_noise(
    id: &str,
    scenario: &Scenario,
    recorded: &RecordedSurvey,
    measurements: &MeasurementSet,
    noise_per_epoch: Option<&[Option<Matrix3<f64>>]>,
    cross: &CrossSource,
) -> Result<FilterRun> {
    let variant = Variant {
        id,
        measurements,
        noise_per_epoch,
        cross,
    };
    match recorded.settings.dvl_states().copied() {
        Some(states) => run_on(&variant, scenario, recorded, |s, p, dt| {
            AugmentedNavigator::with_states(&recorded.settings, &states, s, p, dt)
        }),
        None => run_on(&variant, scenario, recorded, |s, p, dt| {
            Navigator::new(&recorded.settings, s, p, dt)
        }),
    }
}

/// What one variant feeds the navigator.
struct Variant<'a> {
    id: &'a str,
    measurements: &'a MeasurementSet,
    noise_per_epoch: Option<&'a [Option<Matrix3<f64>>]>,
    cross: &'a CrossSource,
}

/// What the variant's updates did, per DVL epoch.
struct Updates {
    nis: Vec<f64>,
    accepted: Vec<Option<bool>>,
    joint_min_eigenvalue: Vec<f64>,
    largest_valid_rho: Vec<f64>,
    /// The DVL epoch under way (for a stop's report).
    epoch: usize,
}

fn run_on<E: NavigationModel<N>, const N: usize>(
    variant: &Variant<'_>,
    scenario: &Scenario,
    recorded: &RecordedSurvey,
    make: impl FnOnce(
        InsState,
        ErrorMatrix,
        f64,
    ) -> estim::navigator::Result<Navigator<E, NoObserver, N>>,
) -> Result<FilterRun> {
    // The DVL epoch of each update time (the time of its IMU sample).
    let epoch_at: HashMap<u64, usize> = scenario
        .dvl
        .iter()
        .enumerate()
        .filter_map(|(k, d)| scenario.imu.get(d.imu_index).map(|s| (s.time.to_bits(), k)))
        .collect();
    let n = scenario.dvl.len();
    let mut updates = Updates {
        nis: Vec::with_capacity(n),
        accepted: vec![None; n],
        joint_min_eigenvalue: Vec::with_capacity(n),
        largest_valid_rho: Vec::with_capacity(n),
        epoch: 0,
    };
    let &Variant {
        id,
        measurements,
        noise_per_epoch,
        cross,
    } = variant;
    if let CrossSource::ScaledPerStep(_) = cross {
        return Err(PipelineError::Setting {
            key: "filter.paper_m_basis".into(),
            reason: "\"per_step\" is not run on a recorded IMU; use \"accumulated\"".into(),
        });
    }
    let mut update = |nav: &mut Navigator<E, NoObserver, N>,
                      time: f64,
                      _: &Vector4<f64>|
     -> estim::navigator::Result<Option<estim_core::UpdateReport<f64, N, 3>>> {
        let Some(&k) = epoch_at.get(&time.to_bits()) else {
            return Err(NavigatorError::Inputs(format!(
                "a DVL row at t = {time} s is not one of the scenario's DVL epochs"
            )));
        };
        updates.epoch = k;
        // Rows without this variant's measurement are no-lock rows (see below).
        let Some(y) = measurements.velocities.get(k).copied().flatten() else {
            return Ok(None);
        };
        nav.propagate_to(time)?;
        // R of this update: the variant's own at this epoch, else the vehicle's times
        // the adapted noise level.
        let given = noise_per_epoch.and_then(|n| n.get(k).copied().flatten());
        let r = match given {
            Some(r) => r,
            None => {
                estim_core::MeasurementModel::noise_covariance(nav.dvl_model(), nav.nominal())
                    .map_err(|source| NavigatorError::Filter { time, source })?
                    * nav.dvl_noise_scale().unwrap_or(1.0)
            }
        };
        let (unit, largest_valid_rho) = paper_unit(nav.filter().accumulated_process_noise(), &r);
        updates.largest_valid_rho.push(largest_valid_rho);
        let fixed = cross_matrix(cross, k, &unit).map(Fixed);
        let source: &DvlCross<'_, E::State, N> = match &fixed {
            Some(m) => m,
            None => &Zero,
        };
        let report = match given {
            Some(r) => nav.dvl_velocity_with_noise(time, &y, &r, source)?,
            None => nav.dvl_velocity(time, &y, source)?,
        };
        updates.nis.push(report.nis);
        if let Some(eig) = report.joint_min_eigenvalue {
            updates.joint_min_eigenvalue.push(eig);
        }
        updates.accepted[k] = Some(report.is_accepted());
        Ok(Some(report))
    };
    let inputs = variant_rows(recorded, measurements);
    let mut observer = Scorer::new(id, recorded, n);
    let outcome = navigate_beams_with(
        &inputs,
        &recorded.settings,
        None,
        &mut observer,
        &mut update,
        make,
    );
    let t0 = scenario.truth.first().map_or(0.0, |s| s.time);
    let run = match outcome {
        Ok(run) => run,
        Err(e) => return Err(stopped(updates.epoch, t0, e)),
    };
    let mut out = observer.run;
    out.nis = updates.nis;
    out.accepted = run.dvl.accepted;
    out.rejected = run.dvl.gated;
    out.update_accepted = updates.accepted;
    out.joint_min_eigenvalue = updates.joint_min_eigenvalue;
    out.largest_valid_rho = updates.largest_valid_rho;
    out.final_dvl_states = run.dvl_states;
    out.final_noise_scale = run.dvl_noise_scale;
    Ok(out)
}

/// The M of a variant's update at DVL epoch `k` (`unit`: the paper's M at rho = 1),
/// padded to the navigator's `N` states; `None` for M = 0.
fn cross_matrix<const N: usize>(
    cross: &CrossSource,
    k: usize,
    unit: &SMatrix<f64, N, 3>,
) -> Option<SMatrix<f64, N, 3>> {
    match cross {
        CrossSource::Zero | CrossSource::ScaledPerStep(_) => None,
        CrossSource::Scaled(rho) => Some(unit * *rho),
        CrossSource::PerEpoch(ms) => {
            let m = ms.get(k).copied().unwrap_or_else(super::CrossMatrix::zeros);
            let mut padded = SMatrix::<f64, N, 3>::zeros();
            padded.fixed_rows_mut::<ERROR_STATES>(0).copy_from(&m);
            Some(padded)
        }
    }
}

/// The survey's inputs for a variant: every row with the variant's measurement
/// reaches its update, whatever beams a scripted loss removed (the velocity comes from
/// `measurements`: least squares on the beams left, or a network's); a row without
/// one gets no update at all (not least squares on its beams): it is a no-lock row.
fn variant_rows(recorded: &RecordedSurvey, measurements: &MeasurementSet) -> SurveyInputs {
    let mut inputs = recorded.inputs.clone();
    for (row, velocity) in inputs.dvl.iter_mut().zip(&measurements.velocities) {
        row.input = match velocity {
            Some(_) => DvlInput::Beams([Some(0.0); 4]),
            None => DvlInput::NoLock,
        };
    }
    inputs
}

/// The paper's M at rho = 1 on the INS states' accumulated noise `q_acc` (the IMU
/// noise the measurement can share), zero on the DVL states; and the largest rho for
/// which [[Q, rho M], [rho M', R]] is a covariance (NaN where none is found).
fn paper_unit<const N: usize>(
    q_acc: &SMatrix<f64, N, N>,
    r: &Matrix3<f64>,
) -> (SMatrix<f64, N, 3>, f64) {
    let ins_q = q_acc
        .fixed_view::<ERROR_STATES, ERROR_STATES>(0, 0)
        .clone_owned();
    let mut unit = SMatrix::<f64, N, 3>::zeros();
    unit.fixed_rows_mut::<ERROR_STATES>(0)
        .copy_from(&ScaledCorrelation::unit(&ins_q, r));
    let largest = JointCovariance::new(*q_acc, unit, *r)
        .largest_valid_scale()
        .unwrap_or(f64::NAN);
    (unit, largest)
}

/// A navigator's stop on a recorded survey as a variant's failure.
fn stopped(epoch: usize, t0: f64, error: NavigatorError) -> PipelineError {
    match error {
        NavigatorError::Filter { time, source } => PipelineError::FilterStopped {
            epoch,
            time_s: time - t0,
            source,
        },
        NavigatorError::Diverged { time, reason } => PipelineError::FilterStopped {
            epoch,
            time_s: time - t0,
            source: estim_core::Error::Model(format!("the navigator diverged: {reason}")),
        },
        error => PipelineError::NavigatorAt { epoch, error },
    }
}

/// Scores each solution at the reference's epochs against the truth there.
struct Scorer<'a> {
    truth: HashMap<u64, &'a InsState>,
    start: Option<InsState>,
    run: FilterRun,
}

impl<'a> Scorer<'a> {
    fn new(id: &str, recorded: &'a RecordedSurvey, dvl_epochs: usize) -> Self {
        let mut run = FilterRun::new(id, dvl_epochs);
        run.nees_states = RECORDED_NEES_STATES;
        Self {
            truth: recorded
                .truth_epochs
                .iter()
                .map(|(t, s)| (t.to_bits(), s))
                .collect(),
            start: recorded.truth_epochs.first().map(|(_, s)| *s),
            run,
        }
    }
}

impl NavigationObserver for Scorer<'_> {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        solution: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        if kind != SolutionKind::Epoch {
            return Ok(());
        }
        let (Some(truth), Some(start)) = (self.truth.get(&solution.time.to_bits()), self.start)
        else {
            return Ok(());
        };
        // The IMU's true biases are unknown: their errors are not scored.
        let mut truth = **truth;
        truth.acc_bias = state.acc_bias;
        truth.gyro_bias = state.gyro_bias;
        let e = error_state(&truth, state);
        let run = &mut self.run;
        run.time.push(solution.time - start.time);
        run.covariance_diagonal
            .push(std::array::from_fn(|i| covariance[(i, i)]));
        run.axis_error.push(std::array::from_fn(|i| e[i]));
        run.position_error.push(e.fixed_rows::<3>(POS).norm());
        run.velocity_error.push(e.fixed_rows::<3>(VEL).norm());
        run.attitude_error_deg
            .push(e.fixed_rows::<3>(ATT).norm().to_degrees());
        match nees_of_block(&e, covariance, 0, RECORDED_NEES_STATES) {
            Some(v) => run.nees.push(v),
            None => {
                run.nees.push(f64::NAN);
                run.covariance_not_positive_definite += 1;
            }
        }
        let (rn, re) = estim_ins::earth::radii_of_curvature(start.latitude);
        run.north_east.push([
            (state.latitude - start.latitude) * (rn + start.height),
            (state.longitude - start.longitude) * (re + start.height) * start.latitude.cos(),
        ]);
        Ok(())
    }
}
