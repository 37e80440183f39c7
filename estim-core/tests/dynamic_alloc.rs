//! `DynKalmanFilter`, `DynUnscentedKalmanFilter` and `DynExtendedKalmanFilter` allocate
//! at construction only: their
//! predict, plain update and correlated update (valid M, certified without the eigen fallback) allocate
//! nothing, at (4, 2), (6, 3) and (50, 10). Counted as in `tests/no_allocation.rs` (the
//! `estim` package): a global allocator that counts the allocations of the calling
//! thread inside `allocations_during`, one test at a time.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use estim_core::dynamic::{DynExtendedKalmanFilter, DynKalmanFilter, DynUnscentedKalmanFilter};
use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::sigma_point::UnscentedTransform;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

thread_local! {
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

fn allocations_during(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    COUNTED.with(|c| c.set(true));
    f();
    COUNTED.with(|c| c.set(false));
    ALLOCATIONS.load(Ordering::SeqCst) - before
}

fn filter(n: usize, m: usize) -> DynKalmanFilter {
    let f = DMatrix::from_fn(n, n, |i, j| match j as isize - i as isize {
        0 => 0.98,
        1 => 0.1,
        _ => 0.0,
    });
    let q = DMatrix::identity(n, n) * 0.04;
    let h = DMatrix::from_fn(m, n, |i, j| if j % m == i { 1.0 } else { 0.0 });
    let r = DMatrix::identity(m, m) * 0.5;
    DynKalmanFilter::new(f, q, h, r, DVector::zeros(n), DMatrix::identity(n, n)).unwrap()
}

#[test]
fn predict_and_updates_allocate_nothing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // The counter sees an allocation (so a zero below means something).
    assert_eq!(
        allocations_during(|| {
            std::hint::black_box(Vec::<u8>::with_capacity(8));
        }),
        1
    );
    for (n, m) in [(4, 2), (6, 3), (50, 10)] {
        let mut kf = filter(n, m);
        // Valid: |corr| = 0.2 between state i's noise and measurement i's.
        let cross = DMatrix::from_fn(n, m, |i, j| {
            if i == j {
                0.2 * (0.04f64 * 0.5).sqrt()
            } else {
                0.0
            }
        });
        let ys: Vec<DVector<f64>> = (0..30)
            .map(|k| DVector::from_fn(m, |i, _| ((k * m + i) as f64 * 0.7).sin()))
            .collect();
        // Warm up outside the count: the CPU dispatch reads ESTIM_FORCE_PORTABLE once
        // per process (an allocation of the environment lookup, not of a step).
        kf.predict().unwrap();
        kf.update(&ys[0]).unwrap();
        let mut reports = 0;
        let count = allocations_during(|| {
            for (k, y) in ys.iter().enumerate() {
                kf.predict().unwrap();
                if k % 5 == 4 {
                    continue; // an unmeasured step: Q_acc accumulates two predicts
                }
                let report = if k % 2 == 0 {
                    kf.update(y).unwrap()
                } else {
                    kf.update_correlated(y, &cross).unwrap()
                };
                reports += usize::from(report.accepted);
            }
        });
        assert_eq!(count, 0, "({n}, {m}): {count} allocations");
        assert_eq!(reports, 24);
    }
}

/// The unscented filter with closures that allocate nothing: predict, update and the
/// correlated update allocate nothing either (every sigma point, image, deviation and
/// sum lives in its workspace).
#[test]
fn unscented_predict_and_updates_allocate_nothing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (n, m) in [(4, 2), (6, 3), (50, 10)] {
        let f = |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| {
            for i in 0..x.len() {
                out[i] = 0.98 * x[i] + dt * (x[(i + 1) % x.len()]).sin();
            }
            Ok(())
        };
        let h = move |x: &DVector<f64>, out: &mut DVector<f64>| {
            for i in 0..m {
                out[i] = x[i].hypot(x[(i + 1) % x.len()] + 2.0);
            }
            Ok(())
        };
        let mut ukf = DynUnscentedKalmanFilter::new(
            UnscentedTransform::new(0.5, 2.0, 0.0).unwrap(),
            DMatrix::identity(n, n) * 0.04,
            DMatrix::identity(m, m) * 0.5,
            DVector::from_element(n, 0.1),
            DMatrix::identity(n, n),
        )
        .unwrap();
        let cross = DMatrix::from_fn(n, m, |i, j| {
            if i == j {
                0.2 * (0.04f64 * 0.5).sqrt()
            } else {
                0.0
            }
        });
        let ys: Vec<DVector<f64>> = (0..30)
            .map(|k| DVector::from_fn(m, |i, _| 2.0 + ((k * m + i) as f64 * 0.7).sin()))
            .collect();
        ukf.predict(&f, 0.1).unwrap();
        ukf.update(&h, &ys[0]).unwrap();
        let mut reports = 0;
        let count = allocations_during(|| {
            for (k, y) in ys.iter().enumerate() {
                ukf.predict(&f, 0.1).unwrap();
                if k % 5 == 4 {
                    continue;
                }
                let report = if k % 2 == 0 {
                    ukf.update(&h, y).unwrap()
                } else {
                    ukf.update_correlated(&h, y, &cross).unwrap()
                };
                reports += usize::from(report.accepted);
            }
        });
        assert_eq!(count, 0, "({n}, {m}): {count} allocations");
        assert_eq!(reports, 24);
    }
}

/// The extended filter with closures that allocate nothing: f, F(x), h and H(x) write
/// into the filter's buffers, so predict, update and the correlated update allocate
/// nothing.
#[test]
fn extended_predict_and_updates_allocate_nothing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (n, m) in [(4, 2), (6, 3), (50, 10)] {
        let f = |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| {
            for i in 0..x.len() {
                out[i] = 0.98 * x[i] + dt * (x[(i + 1) % x.len()]).sin();
            }
            Ok(())
        };
        let jf = |x: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>| {
            out.fill(0.0);
            for i in 0..x.len() {
                out[(i, i)] = 0.98;
                out[(i, (i + 1) % x.len())] += dt * (x[(i + 1) % x.len()]).cos();
            }
            Ok(())
        };
        let h = move |x: &DVector<f64>, out: &mut DVector<f64>| {
            for i in 0..m {
                out[i] = x[i].hypot(x[(i + 1) % x.len()] + 2.0);
            }
            Ok(())
        };
        let jh = move |x: &DVector<f64>, out: &mut DMatrix<f64>| {
            out.fill(0.0);
            for i in 0..m {
                let (a, b) = (x[i], x[(i + 1) % x.len()] + 2.0);
                let r = a.hypot(b);
                out[(i, i)] += a / r;
                out[(i, (i + 1) % x.len())] += b / r;
            }
            Ok(())
        };
        let mut ekf = DynExtendedKalmanFilter::new(
            DMatrix::identity(n, n) * 0.04,
            DMatrix::identity(m, m) * 0.5,
            DVector::from_element(n, 0.1),
            DMatrix::identity(n, n),
        )
        .unwrap();
        let cross = DMatrix::from_fn(n, m, |i, j| {
            if i == j {
                0.2 * (0.04f64 * 0.5).sqrt()
            } else {
                0.0
            }
        });
        let ys: Vec<DVector<f64>> = (0..30)
            .map(|k| DVector::from_fn(m, |i, _| 2.0 + ((k * m + i) as f64 * 0.7).sin()))
            .collect();
        let (process, model) = ((f, jf), (h, jh));
        ekf.predict(&process, 0.1).unwrap();
        ekf.update(&model, &ys[0]).unwrap();
        let mut reports = 0;
        let count = allocations_during(|| {
            for (k, y) in ys.iter().enumerate() {
                ekf.predict(&process, 0.1).unwrap();
                if k % 5 == 4 {
                    continue;
                }
                let report = if k % 2 == 0 {
                    ekf.update(&model, y).unwrap()
                } else {
                    ekf.update_correlated(&model, y, &cross).unwrap()
                };
                reports += usize::from(report.accepted);
            }
        });
        assert_eq!(count, 0, "({n}, {m}): {count} allocations");
        assert_eq!(reports, 24);
    }
}
