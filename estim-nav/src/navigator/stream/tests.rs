use estim_core::{KalmanFilter, StateAndCovariance, Zero};
use estim_ins::ImuSample;
use nalgebra::{DMatrix, DVector, Matrix1, Matrix2, RowVector2, Vector1, Vector2, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use super::*;
use crate::navigator::{
    navigate, DvlStatesConfig, NavigationObserver, NavigatorConfig, PositionFix, SolutionKind,
    SurveyInputs,
};

// ---------------------------------------------------------------------------------
// The history on a small linear model, against joint-Gaussian conditioning.

/// A constant-velocity model (position, velocity; dt = 1) fed through the history:
/// predicts and position measurements.
#[derive(Clone)]
struct Linear(KalmanFilter<f64, 2, 1>);

#[derive(Clone, Copy, Debug)]
enum LinearEvent {
    Predict,
    Measure(f64),
}

impl Replay for Linear {
    type Event = LinearEvent;
    type Output = ();
    type Error = estim_core::Error;

    fn apply(
        &mut self,
        _: &EventKey,
        e: &LinearEvent,
        _: &mut Vec<()>,
    ) -> std::result::Result<(), Self::Error> {
        match e {
            LinearEvent::Predict => self.0.predict(),
            LinearEvent::Measure(y) => self.0.update(&Vector1::new(*y), &Zero).map(|_| ()),
        }
    }
}

const F: [f64; 4] = [1.0, 0.0, 1.0, 1.0]; // column-major [[1, 1], [0, 1]]
const Q_DIAG: [f64; 2] = [0.01, 0.04];
const R: f64 = 0.25;

fn linear_filter() -> Linear {
    let f = Matrix2::from_column_slice(&F);
    let q = Matrix2::from_diagonal(&Vector2::from(Q_DIAG));
    let h = RowVector2::new(1.0, 0.0);
    let p0 = Matrix2::new(1.0, 0.2, 0.2, 0.5);
    let initial = StateAndCovariance::new(Vector2::new(0.5, 1.0), p0).unwrap();
    Linear(KalmanFilter::new(f, q, h, Matrix1::new(R), initial).unwrap())
}

/// The posterior of x_K given the measurements (step, y) by conditioning the joint
/// Gaussian of z = [x_0; w_1..w_K; v_1..v_m]: x_k = F x_{k-1} + w_k, y = H x_j + v.
fn stacked_posterior(steps: usize, measurements: &[(usize, f64)]) -> (DVector<f64>, DMatrix<f64>) {
    let m = measurements.len();
    let n = 2 + 2 * steps + m;
    let mut mean = DVector::zeros(n);
    mean[0] = 0.5;
    mean[1] = 1.0;
    let mut cov = DMatrix::zeros(n, n);
    cov[(0, 0)] = 1.0;
    cov[(0, 1)] = 0.2;
    cov[(1, 0)] = 0.2;
    cov[(1, 1)] = 0.5;
    for k in 0..steps {
        cov[(2 + 2 * k, 2 + 2 * k)] = Q_DIAG[0];
        cov[(3 + 2 * k, 3 + 2 * k)] = Q_DIAG[1];
    }
    for i in 0..m {
        cov[(2 + 2 * steps + i, 2 + 2 * steps + i)] = R;
    }
    let f = DMatrix::from_column_slice(2, 2, &F);
    // A_k: x_k = A_k z.
    let mut a = vec![DMatrix::zeros(2, n)];
    a[0][(0, 0)] = 1.0;
    a[0][(1, 1)] = 1.0;
    for k in 1..=steps {
        let mut next = &f * &a[k - 1];
        next[(0, 2 * k)] += 1.0;
        next[(1, 2 * k + 1)] += 1.0;
        a.push(next);
    }
    // Rows: x_K (2), then each y.
    let mut map = DMatrix::zeros(2 + m, n);
    map.rows_mut(0, 2).copy_from(&a[steps]);
    for (i, (j, _)) in measurements.iter().enumerate() {
        map.row_mut(2 + i).copy_from(&a[*j].row(0));
        map[(2 + i, 2 + 2 * steps + i)] = 1.0;
    }
    let joint_mean = &map * &mean;
    let joint = &map * &cov * map.transpose();
    let sxx = joint.view((0, 0), (2, 2)).into_owned();
    let sxy = joint.view((0, 2), (2, m)).into_owned();
    let syy = joint.view((2, 2), (m, m)).into_owned();
    let y = DVector::from_iterator(m, measurements.iter().map(|(_, y)| *y));
    let innovation = y - joint_mean.rows(2, m);
    let inv = syy.try_inverse().unwrap();
    let posterior_mean = joint_mean.rows(0, 2) + &sxy * &inv * innovation;
    let posterior = sxx - &sxy * inv * sxy.transpose();
    (posterior_mean, posterior)
}

/// A measurement delayed by k steps and applied by rewind equals the in-order filter
/// (bit for bit) and joint-Gaussian conditioning of the stacked problem (1e-9).
#[test]
fn delayed_linear_measurement_equals_stacked_conditioning() {
    let steps = 12;
    let measurements = [(3, 3.9), (6, 6.2), (7, 8.4), (10, 11.1)];
    for delay in [0, 1, 3, 5] {
        for checkpoint_every in [1, 2, 4] {
            let limits = HistoryLimits::new(checkpoint_every, 1000);
            let mut late = History::new(linear_filter(), limits);
            let mut on_time = History::new(linear_filter(), limits);
            let mut sequence = 0;
            let mut key = |time: f64, class: u8| {
                sequence += 1;
                EventKey {
                    time,
                    class,
                    sequence,
                }
            };
            let mut queue: Vec<(usize, f64, usize)> = Vec::new();
            for k in 1..=steps {
                late.insert(key(k as f64, 0), LinearEvent::Predict)
                    .unwrap()
                    .unwrap();
                on_time
                    .insert(key(k as f64, 0), LinearEvent::Predict)
                    .unwrap()
                    .unwrap();
                for &(j, y) in &measurements {
                    if j == k {
                        on_time
                            .insert(key(k as f64, 1), LinearEvent::Measure(y))
                            .unwrap()
                            .unwrap();
                        queue.push((j, y, k + delay));
                    }
                }
                // The second measurement is late by `delay` steps, the others on time.
                for &(j, y, arrives) in &queue {
                    let due = if j == 6 { arrives } else { j };
                    if due == k {
                        late.insert(key(j as f64, 1), LinearEvent::Measure(y))
                            .unwrap()
                            .unwrap();
                    }
                }
            }
            for &(j, y, arrives) in &queue {
                if j == 6 && arrives > steps {
                    late.insert(key(j as f64, 1), LinearEvent::Measure(y))
                        .unwrap()
                        .unwrap();
                }
            }
            let (a, b) = (late.current().0.estimate(), on_time.current().0.estimate());
            assert_eq!(a.state(), b.state(), "delay {delay}");
            assert_eq!(a.covariance(), b.covariance(), "delay {delay}");
            let (mean, cov) = stacked_posterior(steps, &measurements);
            for i in 0..2 {
                let scale = mean[i].abs().max(1.0);
                assert!(
                    (a.state()[i] - mean[i]).abs() <= 1e-9 * scale,
                    "mean {i}: {} vs {}",
                    a.state()[i],
                    mean[i]
                );
                for j in 0..2 {
                    let c = cov[(i, j)];
                    assert!((a.covariance()[(i, j)] - c).abs() <= 1e-9 * c.abs().max(1e-3));
                }
            }
            if delay > 0 {
                assert!(late.stats().rewinds >= 1);
            }
        }
    }
}

// ---------------------------------------------------------------------------------
// The streaming navigator against the batch run.

/// Solutions a batch run emits.
#[derive(Default)]
struct Collect(Vec<(SolutionKind, NavSolution)>);

impl NavigationObserver for Collect {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        s: &NavSolution,
        _: &estim_ins::InsState,
        _: &estim_ins::ErrorMatrix,
    ) -> std::result::Result<(), Box<dyn std::error::Error + Send + Sync>> {
        self.0.push((kind, *s));
        Ok(())
    }
}

/// A simulated survey of `duration` s: the mission's IMU at 100 Hz, DVL velocity
/// rows at 1 Hz from the truth with 0.02 m/s noise, position fixes every 30 s with a
/// 2 m sigma, the initial state configured at the truth.
fn survey(duration: f64, seed: u64) -> (SurveyInputs, NavigatorConfig) {
    let mission = estim_ins::Mission::generate(
        &estim_ins::MissionConfig::builder()
            .duration(duration)
            .build()
            .unwrap(),
        seed,
    )
    .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
    let mut dvl = Vec::new();
    let mut fixes = Vec::new();
    for (j, truth) in mission.truth.iter().enumerate().skip(1) {
        if j % 100 == 37 {
            let v = truth.attitude.inverse() * truth.velocity_ned;
            let noise = Vector3::new(normal(), normal(), normal()) * 0.02;
            dvl.push(DvlRecord {
                time: truth.time,
                input: DvlInput::Velocity(v + noise),
            });
        }
        if j % 3000 == 1550 {
            fixes.push(PositionFix {
                time: truth.time,
                latitude_deg: truth.latitude.to_degrees() + normal() * 1e-5,
                longitude_deg: truth.longitude.to_degrees() + normal() * 1e-5,
                sigma_m: 2.0,
            });
        }
    }
    let x0 = mission.truth[0];
    let mut config = NavigatorConfig::default();
    let (r, p, y) = x0.attitude.euler_angles();
    config.initial.latitude_deg = Some(x0.latitude.to_degrees());
    config.initial.longitude_deg = Some(x0.longitude.to_degrees());
    config.initial.depth_m = Some(-x0.height);
    config.initial.velocity_ned_mps = x0.velocity_ned.into();
    config.initial.attitude_deg = Some([r.to_degrees(), p.to_degrees(), y.to_degrees()]);
    config.imu.rate_hz = Some(1.0 / mission.imu_dt);
    config.dvl.noise_std_mps = 0.02;
    let inputs = SurveyInputs {
        imu: mission.imu,
        dvl,
        fixes,
        ..SurveyInputs::default()
    };
    (inputs, config)
}

/// Feed `inputs` in arrival order: IMU samples at their time, each measurement at
/// its time plus `delay(sensor, index)`; every final solution, and the navigator.
fn stream(
    inputs: &SurveyInputs,
    settings: &NavigatorSettings,
    config: StreamConfig,
    delay: impl Fn(Sensor, usize) -> f64,
) -> (Vec<FinalSolution>, StreamNavigator, Vec<Admission>) {
    enum Record {
        Imu(ImuSample),
        Dvl(DvlRecord),
        Fix(PositionFix),
    }
    let mut arrivals: Vec<(f64, Record)> = Vec::new();
    arrivals.extend(inputs.imu.iter().map(|s| (s.time, Record::Imu(*s))));
    for (i, d) in inputs.dvl.iter().enumerate() {
        arrivals.push((d.time + delay(Sensor::Dvl, i), Record::Dvl(*d)));
    }
    for (i, f) in inputs.fixes.iter().enumerate() {
        arrivals.push((f.time + delay(Sensor::Fix, i), Record::Fix(*f)));
    }
    arrivals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut nav = StreamNavigator::new(settings.clone(), config);
    let mut out = Vec::new();
    let mut admissions = Vec::new();
    for (_, record) in arrivals {
        let admission = match record {
            Record::Imu(s) => nav.push_imu(s).unwrap(),
            Record::Dvl(d) => nav.push_dvl(d).unwrap(),
            Record::Fix(f) => nav.push_fix(f).unwrap(),
        };
        if !matches!(admission, Admission::Taken) {
            admissions.push(admission);
        }
        out.extend(nav.take_final());
    }
    nav.finish().unwrap();
    out.extend(nav.take_final());
    (out, nav, admissions)
}

fn assert_same(stream: &[FinalSolution], batch: &[(SolutionKind, NavSolution)]) -> f64 {
    assert_eq!(stream.len(), batch.len());
    let mut worst: f64 = 0.0;
    for (s, (kind, b)) in stream.iter().zip(batch) {
        assert_eq!(s.kind, *kind);
        assert!(
            solutions_agree(&s.solution, b, 1e-9),
            "at t = {}: {:?} vs {:?}",
            b.time,
            s.solution,
            b
        );
        worst = worst.max((s.solution.latitude_deg - b.latitude_deg).abs());
    }
    worst
}

/// A position fix delayed by k IMU samples (and every DVL row late by up to 2 s),
/// applied by rewind, gives the batch run that had them on time, at every DVL epoch
/// (1e-9 relative; in fact bit for bit).
#[test]
fn delayed_fix_equals_the_batch_run_on_time() {
    let (inputs, config) = survey(200.0, 7);
    let settings = config.check().unwrap();
    let mut batch = Collect::default();
    let run = navigate(&inputs, &settings, None, &mut batch).unwrap();
    assert!(run.fixes.accepted >= 5);
    for k in [1usize, 7, 50, 230] {
        let stream_config = StreamConfig::builder().history_s(4.0).build().unwrap();
        let (solutions, nav, refused) =
            stream(
                &inputs,
                &settings,
                stream_config,
                |sensor, i| match sensor {
                    Sensor::Fix => k as f64 * 0.01,
                    _ => ((i * 7919) % 200) as f64 / 100.0,
                },
            );
        assert!(refused.is_empty(), "{refused:?}");
        let worst = assert_same(&solutions, &batch.0);
        assert_eq!(worst, 0.0, "delay {k}: bit for bit");
        let counts = nav.counts();
        assert!(counts.rewinds >= inputs.fixes.len(), "{counts:?}");
        assert_eq!(counts.fix_nis.count, run.fix_nis.len());
        assert_eq!(nav.update_counts().unwrap()[2], run.fixes);
    }
}

/// The 26-state navigator (DVL error states) through the stream with late DVL rows
/// equals its batch run, and so does a rate output.
#[test]
fn augmented_navigator_and_rate_output_equal_the_batch_run() {
    let (inputs, mut config) = survey(120.0, 11);
    config.dvl_states = Some(DvlStatesConfig::default());
    config.dvl.adaptive_noise_window = Some(20);
    let settings = config.check().unwrap();
    let mut batch = Collect::default();
    navigate(&inputs, &settings, Some(2.0), &mut batch).unwrap();
    let stream_config = StreamConfig::builder()
        .history_s(3.0)
        .output_rate_hz(Some(2.0))
        .build()
        .unwrap();
    let (solutions, nav, refused) = stream(&inputs, &settings, stream_config, |_, i| {
        ((i * 104_729) % 250) as f64 / 100.0
    });
    assert!(refused.is_empty());
    assert_same(&solutions, &batch.0);
    assert!(nav.dvl_states().is_some());
    assert!(nav.counts().rewinds > 50);
}

/// A fix older than the history is refused with its time and the boundary, counted,
/// and never applied: the run equals the batch run without it.
#[test]
fn a_record_older_than_the_history_is_refused_and_counted() {
    let (mut inputs, config) = survey(100.0, 3);
    let settings = config.check().unwrap();
    let stream_config = StreamConfig::builder().history_s(1.0).build().unwrap();
    let (solutions, nav, refused) = stream(&inputs, &settings, stream_config, |sensor, i| {
        if sensor == Sensor::Fix && i == 1 {
            1.5
        } else {
            0.0
        }
    });
    let fix_time = inputs.fixes[1].time;
    assert!(
        matches!(
            refused.as_slice(),
            [Admission::Refused(Refusal::TooOld { sensor: Sensor::Fix, time, boundary })]
                if (*time - fix_time).abs() < 0.006 && (*boundary - (fix_time + 0.5)).abs() < 0.02
        ),
        "{refused:?}"
    );
    assert_eq!(nav.counts().refused_too_old, 1);
    inputs.fixes.remove(1);
    let mut batch = Collect::default();
    navigate(&inputs, &settings, None, &mut batch).unwrap();
    assert_same(&solutions, &batch.0);
}

/// Exact timing: a measurement between IMU samples is applied at its own time, the
/// held sample's interval split there, as the navigator fed in time order does.
#[test]
fn exact_timing_splits_the_imu_interval() {
    let (mut inputs, config) = survey(30.0, 5);
    inputs.fixes.clear();
    for d in &mut inputs.dvl {
        d.time += 0.0037;
    }
    let settings = config.check().unwrap();
    let stream_config = StreamConfig::builder()
        .timing(MeasurementTiming::Exact)
        .build()
        .unwrap();
    let (solutions, _, _) = stream(&inputs, &settings, stream_config, |_, _| 0.8);
    // The reference: the navigator itself, fed in time order by hand.
    let (state, covariance, _) =
        crate::navigator::initial::initial_state(&inputs, &settings).unwrap();
    let period = crate::navigator::initial::imu_period(&inputs.imu, &settings).unwrap();
    let mut nav = Navigator::new(&settings, state, covariance, period).unwrap();
    let mut dvl = inputs.dvl.iter().peekable();
    let mut expected = Vec::new();
    for s in &inputs.imu {
        while let Some(d) = dvl.next_if(|d| d.time < s.time) {
            let DvlInput::Velocity(v) = d.input else {
                unreachable!()
            };
            nav.dvl_velocity(d.time, &v, &Zero).unwrap();
            expected.push(nav.solution());
        }
        nav.imu(s).unwrap();
    }
    assert_eq!(solutions.len(), expected.len());
    for (s, e) in solutions.iter().zip(&expected) {
        assert_eq!(s.solution.time, e.time);
        assert!(
            solutions_agree(&s.solution, e, 1e-12),
            "{:?} vs {e:?}",
            s.solution
        );
    }
    assert!((solutions[0].solution.time * 100.0).fract().abs() > 0.3);
}

/// Memory: over a long stream (1 hour at 100 Hz, DVL late by up to 2 s) the
/// history holds at most its length's worth of events and checkpoints.
#[test]
fn the_history_stays_bounded_over_a_long_stream() {
    let mut config = NavigatorConfig::default();
    config.initial.latitude_deg = Some(32.0);
    config.initial.longitude_deg = Some(34.0);
    config.initial.depth_m = Some(20.0);
    config.initial.attitude_deg = Some([0.0, 0.0, 0.0]);
    config.imu.rate_hz = Some(100.0);
    config.gate.probability = 0.0;
    config.health.nis_window = 0;
    let settings = config.check().unwrap();
    let history_s = 3.0;
    let every = 10;
    let stream_config = StreamConfig::builder()
        .history_s(history_s)
        .checkpoint_every(every)
        .build()
        .unwrap();
    let mut nav = StreamNavigator::new(settings, stream_config);
    let g = estim_ins::earth::normal_gravity(32f64.to_radians(), -20.0);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
    let samples = 360_000;
    let mut late: Vec<(f64, DvlRecord)> = Vec::new();
    let mut solutions = 0;
    let mut largest = (0, 0);
    for k in 0..samples {
        let t = k as f64 * 0.01;
        let f = Vector3::new(normal() * 0.01, normal() * 0.01, -g + normal() * 0.01);
        let w = Vector3::new(normal(), normal(), normal()) * 1e-4;
        nav.push_imu(ImuSample::new(t, f, w)).unwrap();
        if k % 100 == 50 {
            let arrival = t + (normal().abs() * 0.7).min(2.0);
            let v = Vector3::new(normal(), normal(), normal()) * 0.01;
            late.push((
                arrival,
                DvlRecord {
                    time: t,
                    input: DvlInput::Velocity(v),
                },
            ));
        }
        while let Some(i) = late.iter().position(|(a, _)| *a <= t) {
            let (_, record) = late.swap_remove(i);
            assert_eq!(nav.push_dvl(record).unwrap(), Admission::Taken);
        }
        solutions += nav.take_final().len();
        largest.0 = largest.0.max(nav.history_events());
        largest.1 = largest.1.max(nav.history_checkpoints());
    }
    for (_, record) in late {
        assert_eq!(nav.push_dvl(record).unwrap(), Admission::Taken);
    }
    nav.finish().unwrap();
    solutions += nav.take_final().len();
    assert_eq!(solutions, samples / 100);
    // (history + one checkpoint interval) of IMU samples, and the DVL rows in them.
    let bound = (history_s * 100.0) as usize + every + 2 * (history_s as usize + 1);
    assert!(largest.0 <= bound, "{} events > {bound}", largest.0);
    assert!(largest.1 <= bound / every + 2, "{} checkpoints", largest.1);
    let counts = nav.counts();
    assert!(counts.max_history_events <= bound);
    assert_eq!(counts.refused_too_old, 0);
    println!("{counts:?}");
}

/// A bad record is a typed error, never a panic; the IMU may not go back in time.
#[test]
fn bad_records_are_typed_errors() {
    let mut config = NavigatorConfig::default();
    config.initial.latitude_deg = Some(32.0);
    config.initial.longitude_deg = Some(34.0);
    config.initial.depth_m = Some(0.0);
    config.initial.attitude_deg = Some([0.0, 0.0, 0.0]);
    let mut nav = StreamNavigator::new(config.check().unwrap(), StreamConfig::default());
    let s = |t: f64| ImuSample::new(t, Vector3::new(0.0, 0.0, -9.8), Vector3::zeros());
    nav.push_imu(s(0.0)).unwrap();
    nav.push_imu(s(0.01)).unwrap();
    assert!(matches!(
        nav.push_imu(s(0.005)),
        Err(StreamError::ImuTimeOrder { .. })
    ));
    assert!(matches!(
        nav.push_imu(s(f64::NAN)),
        Err(StreamError::NonFinite { .. })
    ));
    let fix = PositionFix {
        time: 0.01,
        latitude_deg: f64::INFINITY,
        longitude_deg: 34.0,
        sigma_m: 1.0,
    };
    assert!(matches!(
        nav.push_fix(fix),
        Err(StreamError::NonFinite {
            sensor: Sensor::Fix,
            ..
        })
    ));
    assert!(StreamConfig::builder().history_s(f64::NAN).build().is_err());
    assert!(StreamConfig::builder().max_events(3).build().is_err());
}

/// Without a configured position the stream buffers until the first fix, and starts
/// from it as the batch run does; a flood of records before it is refused, bounded.
#[test]
fn the_start_waits_for_the_first_fix_with_bounded_memory() {
    let (inputs, mut config) = survey(60.0, 9);
    config.initial.latitude_deg = None;
    config.initial.longitude_deg = None;
    let settings = config.check().unwrap();
    let mut batch = Collect::default();
    navigate(&inputs, &settings, None, &mut batch).unwrap();
    let stream_config = StreamConfig::builder().history_s(20.0).build().unwrap();
    let (solutions, nav, _) = stream(&inputs, &settings, stream_config, |_, _| 0.0);
    assert_eq!(nav.alignment().unwrap().position, "first_fix");
    assert_same(&solutions, &batch.0);
    // No fix ever: the buffer fills and the stream says why.
    let small = StreamConfig::builder().max_events(500).build().unwrap();
    let mut nav = StreamNavigator::new(settings, small);
    let error = inputs
        .imu
        .iter()
        .find_map(|s| nav.push_imu(*s).err())
        .expect("refused");
    assert!(
        matches!(&error, StreamError::NotInitialized { records: 500, reason } if reason.contains("fix")),
        "{error}"
    );
}

/// `lag_s`: each DVL epoch's fixed-lag smoothed solution, emitted once the stream has
/// its lag of data after it (DVL rows late by up to 2 s), equals estim-core's
/// fixed-lag smoother over the batch run's recording (epochs 1 s apart: a 3 s lag is
/// 3 epochs; the last ones given everything), to 1e-9 relative.
#[test]
fn lagged_solutions_equal_the_fixed_lag_smoother_of_the_batch_run() {
    use estim_core::smoother::{ForwardRecorder, RecordAt};
    let (mut inputs, mut config) = survey(60.0, 13);
    inputs.fixes.clear();
    config.gate.probability = 0.0;
    let settings = config.check().unwrap();
    let recorder = ForwardRecorder::new(RecordAt::Updates);
    let (_, recorder) =
        crate::navigator::navigate_with(&inputs, &settings, None, &mut (), recorder).unwrap();
    let process = estim_ins::InsErrorModel::new(settings.filter_spec);
    let reference: Vec<NavSolution> = recorder
        .fixed_lag(3)
        .unwrap()
        .iter()
        .map(|e| {
            let state = e.injected(&process).unwrap();
            NavSolution::from_state(state.time, &state, &e.covariance)
        })
        .collect();
    let stream_config = StreamConfig::builder()
        .history_s(3.0)
        .lag_s(Some(3.0))
        .build()
        .unwrap();
    let (solutions, nav, _) = stream(&inputs, &settings, stream_config, |_, i| {
        ((i * 7919) % 200) as f64 / 100.0
    });
    let lagged: Vec<&FinalSolution> = solutions.iter().filter(|s| s.smoothed).collect();
    assert_eq!(lagged.len(), reference.len());
    assert_eq!(nav.counts().lagged_solutions, reference.len());
    for (s, r) in lagged.iter().zip(&reference) {
        assert!(
            solutions_agree(&s.solution, r, 1e-9),
            "{:?} vs {r:?}",
            s.solution
        );
    }
    // Smoothing lowers the position sigma below the filter's at the same epoch.
    let filtered: Vec<&FinalSolution> = solutions.iter().filter(|s| !s.smoothed).collect();
    let at = |t: f64| {
        filtered
            .iter()
            .find(|f| (f.solution.time - t).abs() < 1e-9)
            .unwrap()
    };
    let middle = lagged[lagged.len() / 2];
    assert!(
        middle.solution.position_sigma_m[0] < at(middle.solution.time).solution.position_sigma_m[0]
    );
}
