//! The batch run: IMU, DVL, depth and fixes merged by time through one [`Navigator`].

use estim_core::{NoObserver, Observer, Zero};
use estim_ins::{ErrorMatrix, ImuSample, InsState, ERROR_STATES};
use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector3};
use serde::Serialize;

use super::filter::UpdateCounts;
use super::{NavSolution, Navigator, NavigatorError, NavigatorSettings, Result};

/// One DVL row: a velocity, beams, or a row without bottom lock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DvlInput {
    /// Velocity in the DVL frame \[m/s\].
    Velocity(Vector3<f64>),
    /// Beam velocities \[m/s\] (`None` = missing beam).
    Beams([Option<f64>; 4]),
    /// The vehicle's velocity N, E, D \[m/s\] (a DVL in earth coordinates): rotated
    /// into the body frame with the filter's attitude at the update time and used as
    /// a DVL-frame velocity (the attitude error it carries is not modelled).
    EarthVelocity(Vector3<f64>),
    /// No bottom lock (NaN, empty, the -32.768 marker or a validity flag): skipped
    /// and counted, never used.
    NoLock,
}

/// A DVL row at its stamped time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlRecord {
    /// Time stamp \[s\] (before the configured time offset).
    pub time: f64,
    /// What the row holds.
    pub input: DvlInput,
}

/// A depth sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthSample {
    /// Time stamp \[s\].
    pub time: f64,
    /// Depth \[m\], positive down.
    pub depth_m: f64,
}

/// A position fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionFix {
    /// Time stamp \[s\].
    pub time: f64,
    /// Latitude \[deg\].
    pub latitude_deg: f64,
    /// Longitude \[deg\].
    pub longitude_deg: f64,
    /// Horizontal 1-sigma \[m\].
    pub sigma_m: f64,
}

/// Everything a survey provides, each series in time order on one clock.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurveyInputs {
    /// IMU samples (sample k covers [t_k, t_k+1]).
    pub imu: Vec<ImuSample>,
    /// DVL rows.
    pub dvl: Vec<DvlRecord>,
    /// Depth samples.
    pub depth: Vec<DepthSample>,
    /// Position fixes.
    pub fixes: Vec<PositionFix>,
}

/// Why a solution was emitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolutionKind {
    /// After a DVL epoch (used or not); for the smoother, an accepted DVL update.
    Dvl,
    /// At the output rate.
    Rate,
    /// A smoothed epoch whose updates are depth or fixes only.
    Aiding,
    /// The smoother's last epoch: the propagation after the last update.
    End,
}

impl SolutionKind {
    /// The name written in `solution.csv` (`dvl`, `rate`, `aiding`, `end`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Dvl => "dvl",
            Self::Rate => "rate",
            Self::Aiding => "aiding",
            Self::End => "end",
        }
    }
}

/// Receives every solution of [`navigate`] (writers and evaluators are observers).
pub trait NavigationObserver {
    /// One solution; `state` and `covariance` are the filter's at that time.
    ///
    /// # Errors
    /// Whatever the observer reports; the run stops with [`NavigatorError::Observer`].
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        solution: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>>;
}

impl NavigationObserver for () {
    fn on_solution(
        &mut self,
        _: SolutionKind,
        _: &NavSolution,
        _: &InsState,
        _: &ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        Ok(())
    }
}

/// Which initial attitude was used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum InitialAttitude {
    /// From the configuration (`initial.attitude_deg`).
    Configured,
    /// Coarse alignment: roll and pitch from the mean specific force over the first
    /// `window_s` seconds (`samples` IMU samples), heading as configured.
    CoarseAlignment {
        /// Length of the window \[s\].
        window_s: f64,
        /// IMU samples averaged.
        samples: usize,
    },
}

/// The initial state [`navigate`] started from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Alignment {
    /// The attitude's source.
    pub attitude: InitialAttitude,
    /// `configured` or `first_fix`.
    pub position: &'static str,
    /// Roll, pitch, heading \[deg\].
    pub attitude_deg: [f64; 3],
}

/// Roll and pitch \[rad\] from a mean specific force in the body frame (levelling:
/// f = -C_n^b g, so roll = atan2(-f_y, -f_z), pitch = atan2(f_x, sqrt(f_y^2 + f_z^2))).
pub fn coarse_alignment(mean_specific_force: &Vector3<f64>) -> (f64, f64) {
    let f = mean_specific_force;
    let roll = (-f.y).atan2(-f.z);
    let pitch = f.x.atan2((f.y * f.y + f.z * f.z).sqrt());
    (roll, pitch)
}

/// What [`navigate`] did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NavigationRun {
    /// The initial state's sources.
    pub alignment: Alignment,
    /// The nominal IMU period used \[s\].
    pub imu_period_s: f64,
    /// First and last IMU times \[s\].
    pub span_s: [f64; 2],
    /// IMU samples integrated.
    pub imu_samples: usize,
    /// DVL velocity (or beam) updates.
    pub dvl: UpdateCounts,
    /// Depth updates.
    pub depth: UpdateCounts,
    /// Position-fix updates.
    pub fixes: UpdateCounts,
    /// DVL rows without bottom lock, skipped.
    pub dvl_no_lock: usize,
    /// DVL beam rows with fewer than 3 beams, skipped.
    pub dvl_insufficient_beams: usize,
    /// Measurements outside the IMU's span (before its first interval or after its
    /// end), skipped.
    pub outside_imu_span: usize,
    /// Gaps between consecutive DVL updates longer than twice the median DVL
    /// interval, coasted on the INS alone.
    pub dvl_gaps_coasted: usize,
    /// The longest interval between consecutive DVL updates \[s\].
    pub longest_dvl_gap_s: f64,
    /// The final DVL noise scale λ when the noise level is adapted
    /// (`dvl.adaptive_noise_window`), else `None`.
    pub dvl_noise_scale: Option<f64>,
    /// NIS of every DVL update attempt.
    pub dvl_nis: Vec<f64>,
    /// Time of each entry of `dvl_nis` \[s\].
    pub dvl_nis_times: Vec<f64>,
    /// Times of the accepted DVL updates \[s\], increasing.
    pub dvl_update_times: Vec<f64>,
    /// What the BeamsNet sensor did ([`navigate_learned`] only).
    pub learned: Option<LearnedCounts>,
    /// NIS of every depth update attempt.
    pub depth_nis: Vec<f64>,
    /// NIS of every fix update attempt.
    pub fix_nis: Vec<f64>,
    /// Solutions emitted.
    pub solutions: usize,
    /// The last solution.
    pub final_solution: NavSolution,
}

/// What [`navigate_learned`] did with the beam rows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct LearnedCounts {
    /// Updates with BeamsNet's velocity (and M from its sensitivity).
    pub beamsnet_updates: usize,
    /// Rows with 3 beams: least squares on them (M = 0, the vehicle's DVL noise);
    /// BeamsNet takes 4 beams and no beam is filled in.
    pub least_squares_three_beams: usize,
    /// Rows before a full IMU window (the first second): least squares.
    pub least_squares_window_not_full: usize,
    /// Time \[s\] and network velocity \[m/s\] of the first BeamsNet update.
    pub first_update: Option<(f64, [f64; 3])>,
}

/// The DVL sensor of a batch run.
// Built once per run and passed by reference: the size of a variant costs nothing.
#[allow(clippy::large_enum_variant)]
enum Sensor<'a> {
    /// Least squares on beams, or the velocity as given.
    LeastSquares,
    /// BeamsNet on 4-beam rows, least squares on the others.
    BeamsNet {
        network: &'a estim_learned::BeamsNet,
        error_model: estim_ins::InsErrorModel,
        model: estim_dvl::DvlVelocityModel,
    },
}

/// The nominal IMU period: 1 / `imu.rate_hz`, else the median sample interval.
pub(super) fn imu_period(imu: &[ImuSample], settings: &NavigatorSettings) -> Result<f64> {
    if let Some(rate) = settings.config.imu.rate_hz {
        return Ok(1.0 / rate);
    }
    let mut dts: Vec<f64> = imu.windows(2).map(|w| w[1].time - w[0].time).collect();
    dts.sort_by(f64::total_cmp);
    match dts.get(dts.len() / 2) {
        Some(&dt) if dt.is_finite() && dt > 0.0 => Ok(dt),
        _ => Err(NavigatorError::Inputs(
            "the IMU needs at least 2 samples with increasing times".into(),
        )),
    }
}

/// The initial nominal state and covariance from the configuration and the data.
pub(super) fn initial_state(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
) -> Result<(InsState, ErrorMatrix, Alignment)> {
    let c = &settings.config.initial;
    let first = inputs
        .imu
        .first()
        .ok_or_else(|| NavigatorError::Inputs("no IMU samples".into()))?;
    let (latitude, longitude, position) = match (c.latitude_deg, c.longitude_deg) {
        (Some(lat), Some(lon)) => (lat.to_radians(), lon.to_radians(), "configured"),
        _ => match inputs.fixes.first() {
            Some(f) => (
                f.latitude_deg.to_radians(),
                f.longitude_deg.to_radians(),
                "first_fix",
            ),
            None => {
                return Err(NavigatorError::Inputs(
                    "no initial position: set initial.latitude_deg / longitude_deg in the \
                     vehicle configuration or give position fixes"
                        .into(),
                ))
            }
        },
    };
    let depth = c
        .depth_m
        .or_else(|| inputs.depth.first().map(|d| d.depth_m))
        .unwrap_or(0.0);
    let (attitude, source) = match c.attitude_deg {
        Some([r, p, y]) => (
            UnitQuaternion::from_euler_angles(r.to_radians(), p.to_radians(), y.to_radians()),
            InitialAttitude::Configured,
        ),
        None => {
            let end = first.time + c.alignment_s;
            let window: Vec<&ImuSample> = inputs.imu.iter().take_while(|s| s.time < end).collect();
            let n = window.len().max(1);
            let mean = window
                .iter()
                .fold(Vector3::zeros(), |a, s| a + s.specific_force)
                / n as f64;
            let (roll, pitch) = coarse_alignment(&mean);
            (
                UnitQuaternion::from_euler_angles(roll, pitch, c.heading_deg.to_radians()),
                InitialAttitude::CoarseAlignment {
                    window_s: c.alignment_s,
                    samples: window.len(),
                },
            )
        }
    };
    let state = InsState::new(
        first.time,
        latitude,
        longitude,
        -depth,
        Vector3::from(c.velocity_ned_mps),
        attitude,
    );
    let (a, g) = (
        settings.sensor_spec.accelerometer(),
        settings.sensor_spec.gyroscope(),
    );
    let acc = c
        .acc_bias_std_mps2
        .unwrap_or_else(|| (a.turn_on_bias.powi(2) + a.bias_instability.powi(2)).sqrt());
    let gyro = c
        .gyro_bias_std_radps
        .unwrap_or_else(|| (g.turn_on_bias.powi(2) + g.bias_instability.powi(2)).sqrt());
    let covariance = initial_covariance(
        c.position_std_m,
        c.velocity_std_mps,
        c.level_std_deg,
        c.heading_std_deg,
        acc,
        gyro,
    );
    let (r, p, y) = attitude.euler_angles();
    let alignment = Alignment {
        attitude: source,
        position,
        attitude_deg: [
            r.to_degrees(),
            p.to_degrees(),
            super::wrap_heading_deg(y.to_degrees()),
        ],
    };
    Ok((state, covariance, alignment))
}

/// The diagonal initial covariance of 1-sigmas per group (angles in degrees; bias
/// sigmas floored at 1e-9 m/s^2 and 1e-12 rad/s so that P stays positive definite).
pub(crate) fn initial_covariance(
    position_m: f64,
    velocity_mps: f64,
    level_deg: f64,
    heading_deg: f64,
    acc_bias: f64,
    gyro_bias: f64,
) -> ErrorMatrix {
    let level = level_deg.to_radians();
    let heading = heading_deg.to_radians();
    let std = [
        position_m,
        position_m,
        position_m,
        velocity_mps,
        velocity_mps,
        velocity_mps,
        level,
        level,
        heading,
        acc_bias.max(1e-9),
        acc_bias.max(1e-9),
        acc_bias.max(1e-9),
        gyro_bias.max(1e-12),
        gyro_bias.max(1e-12),
        gyro_bias.max(1e-12),
    ];
    SMatrix::from_diagonal(&SVector::<f64, ERROR_STATES>::from_iterator(
        std.iter().map(|s| s * s),
    ))
}

#[derive(Debug, Clone, Copy)]
enum Event {
    Dvl(DvlInput),
    Depth(f64),
    Fix(PositionFix),
}

/// The time a measurement is applied at: the IMU sample time nearest to `t` (the
/// end of the last sample's interval counts as one), when within half a period; `t`
/// itself inside an IMU gap; `None` before the first sample's end or after the
/// IMU's end.
pub(super) fn snap(imu: &[ImuSample], period: f64, t: f64) -> Option<f64> {
    let last = imu.last()?;
    let end = last.time + period;
    let time_at = |j: usize| imu.get(j).map_or(end, |s| s.time);
    let j = imu.partition_point(|s| s.time < t);
    let candidates = [j.checked_sub(1), Some(j)];
    let (best, distance) = candidates
        .into_iter()
        .flatten()
        .filter(|&k| k <= imu.len())
        .map(|k| (k, (time_at(k) - t).abs()))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))?;
    let half = 0.5 * period * (1.0 + 1e-9);
    if best == 0 || t > end + half {
        return None;
    }
    if distance <= half {
        Some(time_at(best))
    } else {
        Some(t)
    }
}

/// The IMU stream of a batch run and the solutions emitted at the output rate.
struct Feeder<'a> {
    imu: &'a [ImuSample],
    start: f64,
    step: Option<f64>,
    fed: usize,
    next_output: usize,
    solutions: usize,
}

impl Feeder<'_> {
    fn emit<F>(
        &mut self,
        nav: &Navigator<F>,
        kind: SolutionKind,
        observer: &mut dyn NavigationObserver,
    ) -> Result<()> {
        self.solutions += 1;
        observer
            .on_solution(kind, &nav.solution(), nav.nominal(), nav.covariance())
            .map_err(NavigatorError::Observer)
    }

    /// Feed the IMU samples stamped up to `limit`.
    fn feed_until<F: Observer<f64, InsState, ERROR_STATES>>(
        &mut self,
        nav: &mut Navigator<F>,
        limit: f64,
        observer: &mut dyn NavigationObserver,
    ) -> Result<()> {
        while let Some(sample) = self.imu.get(self.fed).filter(|s| s.time <= limit) {
            nav.imu(sample)?;
            self.fed += 1;
            if let Some(step) = self.step {
                let since = sample.time - self.start;
                if since >= self.next_output as f64 * step {
                    self.emit(nav, SolutionKind::Rate, observer)?;
                    self.next_output = (since / step).floor() as usize + 1;
                }
            }
        }
        Ok(())
    }
}

/// Navigate a survey: initial state from the configuration (else the first fix and a
/// coarse alignment), then the IMU and the measurements merged by time, each
/// measurement at its stamp minus its sensor's time offset, applied at the nearest
/// IMU sample time (see [`Navigator`] for the integration). Emits a solution to
/// `observer` after every DVL row and, with `output_rate_hz`, at that rate (at the
/// first IMU sample at or after each multiple of 1 / rate from the start).
///
/// DVL rows without lock and beam rows with fewer than 3 beams are skipped and
/// counted; measurements outside the IMU's span are skipped and counted.
///
/// # Errors
/// [`NavigatorError::Inputs`] for unusable inputs (no IMU, no initial position);
/// the navigator's errors; [`NavigatorError::Observer`].
pub fn navigate(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
) -> Result<NavigationRun> {
    navigate_with(inputs, settings, output_rate_hz, observer, NoObserver).map(|(run, _)| run)
}

/// [`navigate`] with an estim-core observer on the filter (e.g. a `ForwardRecorder`
/// for the smoother), returned with the run.
///
/// # Errors
/// As [`navigate`].
pub fn navigate_with<F: Observer<f64, InsState, ERROR_STATES>>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    filter_observer: F,
) -> Result<(NavigationRun, F)> {
    run_batch(
        inputs,
        settings,
        output_rate_hz,
        observer,
        filter_observer,
        &Sensor::LeastSquares,
    )
}

/// [`navigate`] with the embedded BeamsNet (`estim::models::beamsnet`) as the DVL
/// sensor: each row with 4 beams is an update with the network's velocity on the
/// [`estim_learned::BEAMSNET_WINDOW`] IMU samples the filter integrated before it and
/// those beams, with the network's R and M from its own sensitivity
/// ([`Navigator::dvl_beamsnet`]). Rows with 3 beams, and rows before a full window, are
/// least-squares updates (M = 0), counted in [`LearnedCounts`]; no beam is ever
/// synthesized or filled in.
///
/// # Errors
/// [`NavigatorError::Inputs`] for DVL rows that are not beams, or beams whose geometry
/// (`dvl.beam_angle_deg`, `dvl.beam1_azimuth_deg`) is not the one the network was
/// trained on; [`NavigatorError::Config`] for an IMU period other than the network's
/// 0.01 s; as [`navigate`].
pub fn navigate_learned(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    network: &estim_learned::BeamsNet,
) -> Result<NavigationRun> {
    if inputs
        .dvl
        .iter()
        .any(|d| !matches!(d.input, DvlInput::Beams(_) | DvlInput::NoLock))
    {
        return Err(NavigatorError::Inputs(
            "BeamsNet takes DVL beams (a beams CSV or a beam-coordinate PD0 file), not \
             velocities"
                .into(),
        ));
    }
    let metadata = network.measurement().metadata();
    if let Some(g) = &metadata.beam_geometry {
        let theta = g.theta_deg.to_radians();
        let trained: Vec<Vector3<f64>> = g
            .psi_deg
            .iter()
            .map(|psi| {
                let psi = psi.to_radians();
                Vector3::new(
                    psi.cos() * theta.sin(),
                    psi.sin() * theta.sin(),
                    theta.cos(),
                )
            })
            .collect();
        let ours = settings.geometry.matrix();
        let same = trained.len() == 4
            && (0..4).all(|i| (0..3).all(|j| (ours[(i, j)] - trained[i][j]).abs() <= 1e-9));
        if !same {
            return Err(NavigatorError::Inputs(format!(
                "BeamsNet was trained on beams {} deg from the z axis at azimuths {:?} deg; \
                 this survey's beam geometry differs (set dvl.beam_angle_deg and \
                 dvl.beam1_azimuth_deg, or use least squares)",
                g.theta_deg, g.psi_deg
            )));
        }
    }
    let period = imu_period(&inputs.imu, settings)?;
    let window_period = 1.0 / 100.0;
    if (period - window_period).abs() > super::IMU_PERIOD_SNAP * window_period {
        return Err(NavigatorError::Config(format!(
            "BeamsNet takes {} IMU samples at 100 Hz; this IMU's period is {period} s",
            estim_learned::BEAMSNET_WINDOW
        )));
    }
    let mut recording = settings.clone();
    recording.filter_config = estim_core::FilterConfigBuilder::from(settings.filter_config.clone())
        .window_capacity(estim_learned::BEAMSNET_WINDOW)
        .build()?;
    let sensor = Sensor::BeamsNet {
        network,
        error_model: estim_ins::InsErrorModel::new(settings.filter_spec),
        model: settings.dvl_model_with_noise(network.noise_covariance())?,
    };
    run_batch(
        inputs,
        &recording,
        output_rate_hz,
        observer,
        NoObserver,
        &sensor,
    )
    .map(|(run, _)| run)
}

fn run_batch<F: Observer<f64, InsState, ERROR_STATES>>(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    output_rate_hz: Option<f64>,
    observer: &mut dyn NavigationObserver,
    filter_observer: F,
    sensor: &Sensor<'_>,
) -> Result<(NavigationRun, F)> {
    if let Some(rate) = output_rate_hz {
        if !(rate.is_finite() && rate > 0.0) {
            return Err(NavigatorError::Config(format!(
                "output rate {rate} Hz is not positive and finite"
            )));
        }
    }
    let imu = &inputs.imu;
    let period = imu_period(imu, settings)?;
    let (state, covariance, alignment) = initial_state(inputs, settings)?;
    let mut nav =
        Navigator::new(settings, state, covariance, period)?.with_observer(filter_observer);
    let config = &settings.config;
    let mut outside = 0;
    let mut no_lock = 0;
    let mut events: Vec<(f64, Event)> = Vec::new();
    let mut push = |t: f64, event: Event, events: &mut Vec<(f64, Event)>| match snap(imu, period, t)
    {
        Some(at) => events.push((at, event)),
        None => outside += 1,
    };
    for d in &inputs.dvl {
        if d.input == DvlInput::NoLock {
            no_lock += 1;
            continue;
        }
        push(
            d.time - config.dvl.time_offset_s,
            Event::Dvl(d.input),
            &mut events,
        );
    }
    for d in &inputs.depth {
        push(
            d.time - config.depth.time_offset_s,
            Event::Depth(d.depth_m),
            &mut events,
        );
    }
    for f in &inputs.fixes {
        push(
            f.time - config.fixes.time_offset_s,
            Event::Fix(*f),
            &mut events,
        );
    }
    // Stable: DVL before depth before fixes at one time, each in file order.
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    let start = imu.first().map_or(0.0, |s| s.time);
    let mut feeder = Feeder {
        imu,
        start,
        step: output_rate_hz.map(|r| 1.0 / r),
        fed: 0,
        next_output: 0,
        solutions: 0,
    };
    let mut dvl_nis = Vec::new();
    let mut dvl_nis_times = Vec::new();
    let mut learned = match sensor {
        Sensor::BeamsNet { .. } => Some(LearnedCounts::default()),
        Sensor::LeastSquares => None,
    };
    let mut depth_nis = Vec::new();
    let mut fix_nis = Vec::new();
    let mut insufficient = 0;
    let mut dvl_times: Vec<f64> = Vec::new();
    for (t, event) in events {
        feeder.feed_until(&mut nav, t, observer)?;
        match event {
            Event::Dvl(input) => {
                let report = match input {
                    DvlInput::Velocity(v) => Some(nav.dvl_velocity(t, &v, &Zero)?),
                    DvlInput::EarthVelocity(v_ned) => {
                        nav.propagate_to(t)?;
                        let body = nav.nominal().attitude.inverse() * v_ned;
                        Some(nav.dvl_velocity(t, &body, &Zero)?)
                    }
                    DvlInput::Beams(b) => {
                        let mut report = None;
                        if let (
                            Sensor::BeamsNet {
                                network,
                                error_model,
                                model,
                            },
                            Some(counts),
                        ) = (sensor, learned.as_mut())
                        {
                            let present = b.iter().flatten().filter(|v| v.is_finite()).count();
                            if present == 4 {
                                let beams =
                                    nalgebra::Vector4::from_fn(|i, _| b[i].unwrap_or(f64::NAN));
                                report =
                                    nav.dvl_beamsnet(t, &beams, network, error_model, model)?;
                                match report {
                                    Some(_) => {
                                        counts.beamsnet_updates += 1;
                                        if counts.first_update.is_none() {
                                            counts.first_update =
                                                nav.last_learned_velocity().map(|v| (t, v.into()));
                                        }
                                    }
                                    None => counts.least_squares_window_not_full += 1,
                                }
                            } else if present == 3 {
                                counts.least_squares_three_beams += 1;
                            }
                        }
                        match report {
                            Some(r) => Some(r),
                            None => {
                                let r = nav.dvl_beams(t, &b, &settings.geometry, &Zero)?;
                                if r.is_none() {
                                    insufficient += 1;
                                }
                                r
                            }
                        }
                    }
                    DvlInput::NoLock => None,
                };
                if let Some(r) = report {
                    dvl_nis.push(r.nis);
                    dvl_nis_times.push(t);
                    if r.is_accepted() {
                        dvl_times.push(t);
                    }
                }
                feeder.emit(&nav, SolutionKind::Dvl, observer)?;
            }
            Event::Depth(d) => depth_nis.push(nav.depth(t, d)?.nis),
            Event::Fix(f) => fix_nis.push(
                nav.position_fix(t, f.latitude_deg, f.longitude_deg, f.sigma_m)?
                    .nis,
            ),
        }
    }
    feeder.feed_until(&mut nav, f64::INFINITY, observer)?;
    let mut gaps: Vec<f64> = dvl_times.windows(2).map(|w| w[1] - w[0]).collect();
    let longest = gaps.iter().copied().fold(0.0, f64::max);
    gaps.sort_by(f64::total_cmp);
    let median = gaps.get(gaps.len() / 2).copied().unwrap_or(f64::INFINITY);
    let coasted = gaps.iter().filter(|&&g| g > 2.0 * median).count();
    let run = NavigationRun {
        alignment,
        imu_period_s: period,
        span_s: [start, imu.last().map_or(start, |s| s.time)],
        imu_samples: feeder.fed,
        dvl: nav.dvl_counts,
        depth: nav.depth_counts,
        fixes: nav.fix_counts,
        dvl_no_lock: no_lock,
        dvl_insufficient_beams: insufficient,
        outside_imu_span: outside,
        dvl_gaps_coasted: coasted,
        longest_dvl_gap_s: longest,
        dvl_noise_scale: nav.dvl_noise_scale(),
        dvl_nis,
        dvl_nis_times,
        dvl_update_times: dvl_times.clone(),
        learned,
        depth_nis,
        fix_nis,
        solutions: feeder.solutions,
        final_solution: nav.solution(),
    };
    Ok((run, nav.into_filter().into_observer()))
}
