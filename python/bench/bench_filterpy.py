"""Speed of estim against filterpy, measured in one run (set OPENBLAS_NUM_THREADS=1
for single-threaded BLAS, as the figures in docs/python.md were):

1. per predict + update on a 6-state, 3-measurement filter: filterpy's KalmanFilter
   against estim.filterpy.KalmanFilter (the same script, one import changed);
2. a whole series at N = 50 states, M = 10 measurements and at N = 200, M = 20:
   filterpy's batch_filter against estim.kalman_filter (same outputs: filtered means
   and covariances), and filter + RTS (filterpy batch_filter + rts_smoother against
   estim.kalman_smoother);
3. per predict + update of an unscented filter (4-state constant velocity, range and
   bearing from the origin, Merwe points, Python fx and hx): filterpy's
   UnscentedKalmanFilter against estim.filterpy.UnscentedKalmanFilter.

Usage: OPENBLAS_NUM_THREADS=1 python python/bench/bench_filterpy.py [--steps 10000]
[--only per-step|ukf|batch]
(--steps is the length of the filtered series, --smooth-steps of the smoothed ones; filterpy's batch_filter keeps two
(steps, N, N) arrays: 10,000 steps take 6.4 GB, the smoother run twice that.)
"""

import argparse
import os
import time

import numpy as np
from filterpy import kalman as fp_kalman
from filterpy.kalman import KalmanFilter as FilterpyKF

import estim
from estim import filterpy as es_kalman
from estim.filterpy import KalmanFilter as EstimKF


def best_of(repeats, run):
    """Best wall time and best CPU time (process_time: robust on a shared, loaded
    machine, where the wall time also counts waiting for a core) of `repeats` runs."""
    walls, cpus = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        run()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus)


def model(n, m, seed=0):
    rng = np.random.default_rng(seed)
    F = np.eye(n) * 0.97 + rng.uniform(-0.01, 0.01, (n, n))
    G = rng.uniform(-0.1, 0.1, (n, n))
    Q = G @ G.T + 1e-3 * np.eye(n)
    H = rng.uniform(-1, 1, (m, n))
    R = np.eye(m) * 0.5
    return F, Q, H, R


def per_step(steps=20000):
    F, Q, H, R = model(6, 3)
    zs = [np.random.default_rng(1).normal(size=(3, 1)) for _ in range(steps)]

    def make(cls):
        kf = cls(6, 3)
        kf.F, kf.Q, kf.H, kf.R = F.copy(), Q.copy(), H.copy(), R.copy()
        return kf

    def run(cls):
        kf = make(cls)

        def loop():
            for z in zs:
                kf.predict()
                kf.update(z)

        return loop

    (w_fp, c_fp), (w_es, c_es) = best_of(3, run(FilterpyKF)), best_of(3, run(EstimKF))
    print(f"per predict+update, 6 states / 3 measurements: filterpy {w_fp / steps * 1e6:.1f} us, "
          f"estim.filterpy {w_es / steps * 1e6:.1f} us, ratio {w_fp / w_es:.1f}x "
          f"(CPU time: {c_fp / steps * 1e6:.1f} / {c_es / steps * 1e6:.1f} us, {c_fp / c_es:.1f}x)")
    return c_fp / c_es


def ukf_per_step(steps=5000):
    dt = 0.1

    def fx(x, dt):
        return np.array([x[0] + dt * x[1], x[1], x[2] + dt * x[3], x[3]])

    def hx(x):
        return np.array([np.hypot(x[0], x[2]), np.arctan2(x[2], x[0])])

    rng = np.random.default_rng(4)
    truth = np.array([50.0, 1.0, 20.0, -0.5])
    zs = []
    for _ in range(steps):
        truth = fx(truth, dt)
        zs.append(hx(truth) + rng.normal(0, [0.5, 0.01]))

    def run(module):
        points = module.MerweScaledSigmaPoints(4, alpha=0.1, beta=2.0, kappa=-1.0)
        ukf = module.UnscentedKalmanFilter(dim_x=4, dim_z=2, dt=dt, hx=hx, fx=fx, points=points)
        ukf.x = np.array([49.0, 1.0, 21.0, -0.5])
        ukf.P = np.diag([4.0, 1.0, 4.0, 1.0])
        ukf.Q = np.eye(4) * 1e-3
        ukf.R = np.diag([0.25, 1e-4])

        def loop():
            for z in zs:
                ukf.predict()
                ukf.update(z)

        return loop

    (w_fp, c_fp), (w_es, c_es) = best_of(3, run(fp_kalman)), best_of(3, run(es_kalman))
    print(f"UKF per predict+update, 4 states / 2 measurements (Python fx, hx): filterpy "
          f"{w_fp / steps * 1e6:.1f} us, estim.filterpy {w_es / steps * 1e6:.1f} us, ratio "
          f"{w_fp / w_es:.1f}x (CPU time: {c_fp / steps * 1e6:.1f} / {c_es / steps * 1e6:.1f} us, "
          f"{c_fp / c_es:.1f}x)")
    return c_fp / c_es


def batch(steps, smooth, n=200, m=20):
    F, Q, H, R = model(n, m, 2)
    rng = np.random.default_rng(3)
    zs = rng.normal(size=(steps, m))
    x0, P0 = np.zeros(n), np.eye(n)

    def run_filterpy():
        kf = FilterpyKF(n, m)
        kf.F, kf.Q, kf.H, kf.R, kf.x, kf.P = F, Q, H, R, x0.copy(), P0.copy()
        means, covs, _, _ = kf.batch_filter(list(zs))
        if smooth:
            kf.rts_smoother(means, covs)

    def run_estim():
        if smooth:
            estim.kalman_smoother(F, Q, H, R, x0, P0, zs)
        else:
            estim.kalman_filter(F, Q, H, R, x0, P0, zs)

    (w_fp, c_fp), (w_es, c_es) = best_of(1, run_filterpy), best_of(1, run_estim)
    what = "filter + RTS" if smooth else "filter"
    print(f"{what}, N = {n}, M = {m}, {steps} steps: filterpy {w_fp:.2f} s, "
          f"estim {w_es:.2f} s, ratio {w_fp / w_es:.2f}x "
          f"(CPU time: {c_fp:.2f} / {c_es:.2f} s, {c_fp / c_es:.2f}x)")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=10000)
    parser.add_argument("--smooth-steps", type=int, default=2000)
    parser.add_argument("--only", choices=["per-step", "ukf", "batch"])
    args = parser.parse_args()
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(unset)')}, "
          f"numpy {np.__version__}")
    if args.only in (None, "per-step"):
        per_step()
    if args.only in (None, "ukf"):
        ukf_per_step()
    if args.only not in (None, "batch"):
        return
    batch(args.steps, smooth=False, n=50, m=10)
    batch(args.smooth_steps, smooth=True, n=50, m=10)
    batch(args.steps, smooth=False)
    batch(args.smooth_steps, smooth=True)


if __name__ == "__main__":
    main()
