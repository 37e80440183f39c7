//! The INS hot loop allocates nothing per step: the in-place covariance step, the
//! error-state filter's predict (default configuration: Q_acc and Phi_acc accumulated;
//! and with a 100-step window recorded), and its 1 Hz DVL update (one-step M = 0 and
//! the exact windowed M), and a pure-Rust learned sensor's updates through the generic
//! `LearnedCrossCovariance` (its measure, the adjoint and the per-step M, over several
//! windows and output sizes). Counted with a global allocator that counts the allocations
//! of the thread inside `allocations_during` (the steps under test run on the calling
//! thread and start none): the test harness reports a finished test from another thread
//! while the next one runs, and counting every thread let those allocations in (5 in one
//! CI run, none in the next). Each test still holds a lock, so the tests run one at a time.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::window::StepWindow;
use estim_core::{
    ErrorStateKalmanFilter, FilterConfig, MeasurementModel, WindowedCrossCovariance, Zero,
};
use estim_dvl::DvlVelocityModel;
use estim_ins::{
    ErrorMatrix, ImuSample, ImuSpec, InsErrorModel, InsState, Mechanization, Mission,
    MissionConfig, ERROR_STATES,
};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

thread_local! {
    /// Whether this thread's allocations are counted (const-initialised: reading it
    /// allocates nothing).
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

fn count_one() {
    if COUNTED.try_with(Cell::get).unwrap_or(false) {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
    }
}

// SAFETY: every call is forwarded unchanged to the system allocator; the counter is
// only incremented.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by this thread while `f` runs.
fn allocations_during(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    COUNTED.with(|c| c.set(true));
    f();
    COUNTED.with(|c| c.set(false));
    ALLOCATIONS.load(Ordering::SeqCst) - before
}

const WINDOW: usize = 100;

/// A learned-style velocity noise sharing the window's accelerometer noise (as in
/// benches/ins.rs).
struct SharedAccelerometerNoise(f64);

impl WindowedCrossCovariance<f64, InsState, ImuSample, ERROR_STATES, 3>
    for SharedAccelerometerNoise
{
    fn window_steps(&self) -> usize {
        WINDOW
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, InsState, ImuSample, ERROR_STATES>,
        sink: &mut dyn FnMut(&SMatrix<f64, ERROR_STATES, 3>) -> estim_core::Result<()>,
    ) -> estim_core::Result<()> {
        for step in window.iter() {
            let c_bn = step.state.attitude.to_rotation_matrix().into_inner();
            let mut d = SMatrix::<f64, ERROR_STATES, 3>::zeros();
            d.fixed_view_mut::<3, 3>(3, 0).copy_from(&(c_bn * -self.0));
            sink(&d)?;
        }
        Ok(())
    }
}

fn initial_covariance() -> ErrorMatrix {
    ErrorMatrix::from_diagonal(&SVector::<f64, 15>::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }))
}

#[test]
fn in_place_covariance_step_allocates_nothing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // The counter sees an allocation (so a zero below means something).
    let seen = allocations_during(|| {
        std::hint::black_box(Vec::<u8>::with_capacity(8));
    });
    assert_eq!(seen, 1);
    let mission = Mission::generate(&MissionConfig::default(), 7).unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mech = Mechanization::new();
    let (mut s, mut p) = (mission.truth[0], initial_covariance());
    let count = allocations_during(|| {
        for imu in &mission.imu[..2000] {
            model.predict_covariance(&s, imu, mission.imu_dt, &mut p);
            s = mech.step_unchecked(&s, imu, mission.imu_dt);
        }
    });
    assert_eq!(count, 0);
    assert!(p.iter().all(|v| v.is_finite()));
}

#[test]
fn error_state_filter_predict_and_update_allocate_nothing_per_step() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mission = Mission::generate(&MissionConfig::default(), 7).unwrap();
    let spec = ImuSpec::akit_observed();
    let dvl = DvlVelocityModel::builder().noise_std(0.02).build().unwrap();
    let cross = SharedAccelerometerNoise(spec.continuous_noise_psd()[0] / WINDOW as f64);
    let windowed = FilterConfig::builder()
        .track_accumulated_noise(false)
        .window_capacity(WINDOW)
        .build()
        .unwrap();
    for (config, use_window) in [(FilterConfig::default(), false), (windowed, true)] {
        let mut filter = ErrorStateKalmanFilter::new(
            InsErrorModel::new(spec),
            mission.truth[0],
            initial_covariance(),
        )
        .unwrap()
        .with_config(config);
        let mut run = |steps: std::ops::Range<usize>| {
            for k in steps {
                filter.predict(&mission.imu[k], mission.imu_dt).unwrap();
                if (k + 1) % WINDOW == 0 {
                    let y = dvl.predict(&mission.truth[k + 1]).unwrap();
                    let report = if use_window {
                        filter.update_windowed(&dvl, &y, &cross)
                    } else {
                        filter.update(&dvl, &y, &Zero)
                    };
                    assert!(report.unwrap().is_accepted());
                }
            }
        };
        // The first window fills the recorded history (allocated once, at its capacity).
        run(0..2 * WINDOW);
        let count = allocations_during(|| run(2 * WINDOW..10 * WINDOW));
        assert_eq!(count, 0, "window recorded: {use_window}");
    }
}

// ---------------------------------------------------------------------------------
// A learned sensor (pure Rust, any window L and output size M) through the generic
// LearnedCrossCovariance: measure, the adjoint M (no other update in the window) and
// the per-step D_j (a plain update inside the window), on an extended Kalman filter.
// ---------------------------------------------------------------------------------

use estim_core::nalgebra::{DMatrix, Matrix3, Matrix3x2, Vector2, Vector3};
use estim_core::{ExtendedKalmanFilter, InputSpec, LearnedMeasurement, ProcessModel};
use estim_learned::{InputNoise, LearnedCrossCovariance, LearnedSensor, Observation};

/// x = [position, velocity, heading]: velocity and heading integrate the measured
/// acceleration and turn rate u (2 channels, read by the model as two 1-channel
/// streams).
struct Cart;

const INPUT_VARIANCE: f64 = 1e-4;

fn cart_input_gain() -> Matrix3x2<f64> {
    Matrix3x2::new(0.0, 0.0, 1.0, 0.0, 0.0, 1.0)
}

impl ProcessModel<f64, 3> for Cart {
    type State = Vector3<f64>;
    type Input = Vector2<f64>;
    fn propagate(
        &self,
        x: &Vector3<f64>,
        u: &Vector2<f64>,
        dt: f64,
    ) -> estim_core::Result<Vector3<f64>> {
        Ok(self.transition(x, u, dt)? * x + cart_input_gain() * u * dt)
    }
    fn transition(
        &self,
        _: &Vector3<f64>,
        _: &Vector2<f64>,
        dt: f64,
    ) -> estim_core::Result<Matrix3<f64>> {
        Ok(Matrix3::new(1.0, dt, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.99))
    }
    fn process_noise(
        &self,
        _: &Vector3<f64>,
        _: &Vector2<f64>,
        dt: f64,
    ) -> estim_core::Result<Matrix3<f64>> {
        let g = cart_input_gain() * dt;
        Ok(g * g.transpose() * INPUT_VARIANCE + Matrix3::identity() * 1e-9)
    }
}

impl InputNoise<f64, 3, 2> for Cart {
    fn input_channels(&self, u: &Vector2<f64>) -> Vector2<f64> {
        *u
    }
    fn input_noise_jacobian(&self, _: &Vector3<f64>, _: &Vector2<f64>, dt: f64) -> Matrix3x2<f64> {
        -cart_input_gain() * dt
    }
    fn input_noise_covariance(&self, _: f64) -> estim_core::nalgebra::Matrix2<f64> {
        estim_core::nalgebra::Matrix2::identity() * INPUT_VARIANCE
    }
}

/// y_m = tanh(w_m . [acc; turn] / L) + bias_m: a nonlinear model of the two process
/// streams (1 x L each) and a per-update bias stream (M x 1). Computes in place.
struct WindowNet<const M: usize> {
    specs: Vec<InputSpec>,
    /// M x 2L weights.
    weights: DMatrix<f64>,
    /// Directions of the last sensitivity call (which form of M the filter used).
    last_directions: std::cell::Cell<usize>,
}

impl<const M: usize> WindowNet<M> {
    fn new(window: usize) -> Self {
        let spec = |name: &str, channels, window| InputSpec {
            name: name.into(),
            channels,
            window,
            sample_rate_hz: 10.0,
        };
        Self {
            specs: vec![
                spec("acc", 1, window),
                spec("turn", 1, window),
                spec("bias", M, 1),
            ],
            weights: DMatrix::from_fn(M, 2 * window, |m, j| ((m + 2 * j) % 5) as f64 * 0.1 - 0.2),
            last_directions: std::cell::Cell::new(0),
        }
    }

    /// (w_m . [a; b] / L) for every m, for inputs or directions alike.
    fn linear(&self, a: &DMatrix<f64>, b: &DMatrix<f64>, m: usize) -> f64 {
        let l = a.ncols();
        let w = self.weights.row(m);
        (0..l).map(|j| w[j] * a[j] + w[l + j] * b[j]).sum::<f64>() / l as f64
    }
}

impl<const M: usize> LearnedMeasurement<f64, M> for WindowNet<M> {
    fn input_specs(&self) -> &[InputSpec] {
        &self.specs
    }
    fn measure(&self, inputs: &[DMatrix<f64>]) -> estim_core::Result<SVector<f64, M>> {
        Ok(SVector::from_fn(|m, _| {
            self.linear(&inputs[0], &inputs[1], m).tanh() + inputs[2][m]
        }))
    }
    fn noise_covariance(&self) -> SMatrix<f64, M, M> {
        SMatrix::identity() * 0.1
    }
    fn sensitivity(
        &self,
        inputs: &[DMatrix<f64>],
        directions: &[DMatrix<f64>],
        products: &mut [SVector<f64, M>],
    ) -> estim_core::Result<bool> {
        self.last_directions.set(products.len());
        for (d, product) in directions.chunks_exact(3).zip(products) {
            *product = SVector::from_fn(|m, _| {
                let t = self.linear(&inputs[0], &inputs[1], m).tanh();
                (1.0 - t * t) * self.linear(&d[0], &d[1], m) + d[2][m]
            });
        }
        Ok(true)
    }
}

/// h(x) = the first M states.
struct LeadingStates;

impl<const M: usize> Observation<f64, 3, M> for LeadingStates {
    type State = Vector3<f64>;
    fn predict(&self, x: &Vector3<f64>) -> estim_core::Result<SVector<f64, M>> {
        Ok(SVector::from_fn(|m, _| x[m]))
    }
    fn jacobian(&self, _: &Vector3<f64>) -> estim_core::Result<SMatrix<f64, M, 3>> {
        Ok(SMatrix::identity())
    }
}

/// Updates of a learned sensor with output size M over `window` steps allocate nothing
/// after the first cycles, with M from the adjoint form (`plain_update_inside` false)
/// or from the per-step form (a plain update in the middle of the window). Returns the
/// last M (finite, non-zero: the count covers real work).
fn learned_updates_allocate_nothing<const M: usize>(
    window: usize,
    plain_update_inside: bool,
) -> SMatrix<f64, 3, M> {
    let model = WindowNet::<M>::new(window);
    let mut cross = LearnedCrossCovariance::new(&model, &Cart, &[DMatrix::zeros(M, 1)]).unwrap();
    let config = FilterConfig::builder()
        .window_capacity(window)
        .build()
        .unwrap();
    let initial =
        estim_core::StateAndCovariance::new(Vector3::zeros(), Matrix3::identity() * 0.1).unwrap();
    let mut filter = ExtendedKalmanFilter::new(Cart, initial).with_config(config);
    let mut last = SMatrix::<f64, 3, M>::zeros();
    let mut cycle = |k: usize, filter: &mut ExtendedKalmanFilter<f64, Cart, 3>| {
        for j in 0..window {
            let t = (k * window + j) as f64 * 0.1;
            filter
                .predict(&Vector2::new((0.3 * t).sin(), 0.1 * (0.2 * t).cos()), 0.1)
                .unwrap();
            if plain_update_inside && j == window / 2 {
                // Plain (uncorrelated) update inside the next learned window.
                let y = SVector::<f64, M>::from_fn(|m, _| filter.estimate().state()[m] + 0.01);
                let sensor = LearnedSensor::new(cross.model(), LeadingStates);
                filter.update(&sensor, &y, &Zero).unwrap();
            }
        }
        let bias = SVector::<f64, M>::from_fn(|m, _| 0.05 * (k + m) as f64);
        cross.set_update_input(0, bias.as_slice()).unwrap();
        let y = cross.measure(&filter.step_window(window).unwrap()).unwrap();
        let sensor = LearnedSensor::new(cross.model(), LeadingStates);
        let report = filter.update_windowed(&sensor, &y, &cross).unwrap();
        assert!(report.is_accepted());
        // The per-step form asks for K L = 2 L directions, the adjoint form for at
        // most N = 3 (the non-zero rows).
        let asked = model.last_directions.get();
        assert!(
            if plain_update_inside {
                asked == 2 * window
            } else {
                asked <= 3
            },
            "{asked} directions"
        );
        last = report.cross_covariance;
    };
    // Warm-up: the first cycles size the workspace and the recorded history.
    for k in 0..3 {
        cycle(k, &mut filter);
    }
    let count = allocations_during(|| {
        for k in 3..13 {
            cycle(k, &mut filter);
        }
    });
    assert_eq!(
        count, 0,
        "window {window}, M = {M}, plain update inside: {plain_update_inside}"
    );
    last
}

#[test]
fn learned_sensor_updates_allocate_nothing_across_windows_and_output_sizes() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let ms = [
        learned_updates_allocate_nothing::<1>(1, false).abs().max(),
        learned_updates_allocate_nothing::<2>(6, false).abs().max(),
        learned_updates_allocate_nothing::<3>(40, false).abs().max(),
        learned_updates_allocate_nothing::<1>(7, true).abs().max(),
        learned_updates_allocate_nothing::<2>(2, true).abs().max(),
        learned_updates_allocate_nothing::<3>(25, true).abs().max(),
    ];
    assert!(ms.iter().all(|m| m.is_finite() && *m > 0.0), "{ms:?}");
}
