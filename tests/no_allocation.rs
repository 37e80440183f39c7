//! The INS hot loop allocates nothing per step: the in-place covariance step, the
//! error-state filter's predict (default configuration: Q_acc and Phi_acc accumulated;
//! and with a 100-step window recorded), and its 1 Hz DVL update (one-step M = 0 and
//! the exact windowed M). Counted with a global allocator that counts every allocation
//! of this test binary; each test holds a lock so that the counts of the others (run on
//! other threads) do not mix in.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::{
    ErrorStateKalmanFilter, FilterConfig, MeasurementModel, StepWindow, WindowedCrossCovariance,
    Zero,
};
use estim_dvl::DvlVelocityModel;
use estim_ins::{
    ErrorMatrix, ImuSample, ImuSpec, InsErrorModel, InsState, Mechanization, Mission,
    MissionConfig, ERROR_STATES,
};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

// SAFETY: every call is forwarded unchanged to the system allocator; the counter is
// only incremented.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_during(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    f();
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
