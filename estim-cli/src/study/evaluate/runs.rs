//! One evaluation run: the augmented navigator on one trajectory and seed, fed by
//! the navigator's loop, and the 15-state comparison.

use super::*;

/// One run's fixed inputs.
pub(super) struct Run<'a> {
    pub(super) scenario: &'a Scenario,
    pub(super) config: &'a Config,
    pub(super) fit: &'a TrainingFit,
    pub(super) states: &'a DvlStatesConfig,
    pub(super) adaptive_noise: Option<usize>,
}

impl Run<'_> {
    /// One run of the augmented filter; `Ok(Err(..))` for a numerical failure of the
    /// filter (a finding), `Err` for invalid input.
    pub(super) fn run(
        self,
        velocities: &[Option<Vector3<f64>>],
        r: Matrix3<f64>,
        seed: u64,
    ) -> Result<std::result::Result<EvaluationRun, String>> {
        let Run {
            scenario,
            config,
            fit,
            states,
            adaptive_noise,
        } = self;
        let truth0 = scenario
            .truth
            .first()
            .ok_or_else(|| PipelineError::NoData {
                what: format!("truth samples in {}", scenario.name),
            })?;
        let p0 = initial_covariance(config, &scenario.imu_spec);
        let nominal0 = initial_nominal(truth0, &p0, seed);
        let nav_config = NavigatorConfig {
            dvl: DvlConfig {
                adaptive_noise_window: adaptive_noise,
                ..fit.dvl_config()
            },
            gate: GateConfig {
                probability: config.filter.gate_probability,
                recovery_after: config.filter.gate_recovery_after,
            },
            ..NavigatorConfig::default()
        };
        let settings = nav_config
            .check()?
            .with_sensor_spec(scenario.imu_spec)?
            .with_dvl_noise_covariance(r)?;
        let dvl0 = DvlParameters {
            scale_factor_error: fit.scale_factor_error,
            dvl_to_body: Rotation3::new(Vector3::from(fit.misalignment_rad)),
            bias: Vector3::zeros(),
            lever_arm: Vector3::from(fit.lever_arm_m),
            time_offset: 0.0,
        };
        let model = AugmentedDvlModel::new(r)?.with_rate_noise(fit.rate_noise_mps_per_radps)?;
        let mut nav =
            AugmentedNavigator::with_dvl(&settings, states, nominal0, dvl0, p0, scenario.imu_dt)?
                .with_dvl_model(model);
        let mut hook = EvaluateHook {
            scenario,
            velocities,
            truth0,
            epoch: 0,
            nees: Vec::new(),
            nis: Vec::new(),
            position: Vec::new(),
        };
        // An epoch whose truth index is beyond the scenario is refused by the hook
        // before its time (NaN here) is used.
        let epochs = scenario.dvl.iter().map(|dvl| {
            let time = scenario
                .truth
                .get(dvl.imu_index)
                .map_or(f64::NAN, |t| t.time);
            (time, ())
        });
        match run_epochs(
            &mut nav,
            &scenario.imu,
            epochs,
            &mut hook,
            Tail::StopAtLastEpoch,
        ) {
            Ok(_) => {}
            Err(Stop::Finding(finding)) => return Ok(Err(finding)),
            Err(Stop::Invalid(e)) => return Err(e),
        }
        let EvaluateHook {
            nees: nees_values,
            nis,
            position,
            ..
        } = hook;
        let Some(s) = nav.dvl_states() else {
            return Err(PipelineError::Missing {
                within: "the augmented navigator".into(),
                what: "DVL states".into(),
            });
        };
        Ok(Ok(EvaluationRun {
            trajectory: 0,
            seed,
            id: String::new(),
            imu_source: ImuSource::Synthesized,
            nees_states: ERROR_STATES,
            nees: finite_mean(&nees_values),
            nis: finite_mean(&nis),
            position_rmse_m: error_summary(&position).rmse,
            accepted: nav.dvl_counts.accepted,
            rejected: nav.dvl_counts.gated,
            applied_time_offset_s: fit.time_offset_s,
            time_offset_s: [s.time_offset_s, s.time_offset_sigma_s],
            scale_factor_error: [s.scale_factor_error, s.scale_factor_sigma],
            noise_scale: nav.dvl_noise_scale().unwrap_or(1.0),
            fifteen_state_position_rmse_m: f64::NAN,
        }))
    }
}

/// Why an evaluation run stopped: a numerical failure of the filter (a finding, with
/// its time since the start) or invalid input.
enum Stop {
    Finding(String),
    Invalid(PipelineError),
}

impl From<NavigatorError> for Stop {
    fn from(e: NavigatorError) -> Self {
        Self::Invalid(PipelineError::from(e))
    }
}

/// The per-epoch hook of an evaluation run: the DVL update at each epoch, then the
/// position error and the NEES of the INS states against truth.
struct EvaluateHook<'a> {
    scenario: &'a Scenario,
    velocities: &'a [Option<Vector3<f64>>],
    truth0: &'a InsState,
    /// The epoch under way.
    epoch: usize,
    nees: Vec<f64>,
    nis: Vec<f64>,
    position: Vec<f64>,
}

impl EvaluateHook<'_> {
    /// DVL epoch `epoch` has no truth sample (its IMU index is beyond the scenario).
    fn beyond_truth(&self, epoch: usize) -> PipelineError {
        PipelineError::DvlEpoch {
            scenario: self.scenario.name.clone(),
            epoch,
            reason: "truth index beyond the scenario".into(),
        }
    }
}

impl EpochHook<AugmentedErrorModel, NoObserver, AUGMENTED_STATES> for EvaluateHook<'_> {
    type Measurement = ();
    type Error = Stop;

    fn before_epoch(&mut self, _: &AugmentedNavigator, _: f64) -> std::result::Result<(), Stop> {
        let epoch = self.epoch;
        let inside = self
            .scenario
            .dvl
            .get(epoch)
            .is_some_and(|dvl| dvl.imu_index < self.scenario.truth.len());
        if inside {
            Ok(())
        } else {
            Err(Stop::Invalid(self.beyond_truth(epoch)))
        }
    }

    fn on_epoch(
        &mut self,
        nav: &mut AugmentedNavigator,
        target: f64,
        _: (),
    ) -> std::result::Result<(), Stop> {
        if let Some(y) = self.velocities.get(self.epoch).copied().flatten() {
            match nav.dvl_velocity(target, &y, &Zero) {
                Ok(report) => self.nis.push(report.nis),
                Err(e) => return Err(self.stopped(e)),
            }
        }
        let truth = self
            .scenario
            .dvl
            .get(self.epoch)
            .and_then(|dvl| self.scenario.truth.get(dvl.imu_index))
            .ok_or_else(|| Stop::Invalid(self.beyond_truth(self.epoch)))?;
        let e = error_state(truth, nav.ins());
        self.position.push(e.fixed_rows::<3>(POS).norm());
        self.nees
            .push(nees(&e, &nav.ins_covariance()).unwrap_or(f64::NAN));
        self.epoch += 1;
        Ok(())
    }

    fn stopped(&mut self, error: NavigatorError) -> Stop {
        match error {
            NavigatorError::Filter { time, source } => Stop::Finding(format!(
                "stopped at t = {:.2} s: {source}",
                time - self.truth0.time
            )),
            other => Stop::Invalid(PipelineError::from(other)),
        }
    }
}

/// Position RMSE of the 15-state filter of `estim reproduce --data` on trajectory
/// `n` with `seed` (the configuration as given: its time offset, R with the reference
/// mismatch, its gate), for [`EVALUATED_VARIANTS`] in order; NaN for a run that
/// stopped on a numerical failure.
pub(super) fn fifteen_state_rmse(
    dir: &Path,
    n: u32,
    config: &Config,
    seed: u64,
    learned: &LearnedSource,
) -> Result<[f64; 2]> {
    let config = Config {
        seed,
        ..config.clone()
    };
    let scenario = Scenario::akit(dir, n, &config, seed)?;
    let [ls, net] = recorded_sets(&scenario, &config, learned)?;
    let mut out = [f64::NAN; 2];
    for (slot, (id, set)) in out.iter_mut().zip([(LS, ls), (BEAMSNET_NEGLECTED, net)]) {
        if let Ok(run) = run_variant(id, &scenario, &config, &set, &CrossSource::Zero, seed)? {
            *slot = summarise(&run)?.position_error_m.rmse;
        }
    }
    Ok(out)
}
