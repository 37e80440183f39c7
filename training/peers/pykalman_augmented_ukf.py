"""Expected values for estim-core's augmented-UKF test (estim-core/tests/unscented_pykalman.rs),
computed by pykalman's (augmented) `UnscentedKalmanFilter`.

pykalman's UnscentedKalmanFilter draws its sigma points over [x; w; v] (L = 2N + M, its
defaults alpha = 1, beta = 0, kappa = 3 - L) and has non-additive noise: here
f(x, w) = f(x) + w and g(x, v) = h(x) + v. Two cases, each for several seeds:

- `update`: `filter` on one observation z. pykalman corrects the initial state with no
  prediction (t = 0), so the result is one sigma-point update of (mu0, P0) with R.
- `predict_update`: `filter` on two observations, the first masked (pykalman skips the
  correction of a masked observation), so the result is one prediction through f with
  Q, then one update with the second observation z.

Models (state dimension N, measurement dimension M = 1):

- `range2`: N = 2, h(p) = |p - (1, -2)| (range to a landmark at (1, -2)),
  f(p) = (p0 + 0.5 cos p1, p1 + 0.5 sin p0).
- `bearing2`: N = 2, h(p) = atan2(p1 + 2, p0 - 1) (bearing to the same landmark), same f.
- `linear2`: N = 2, h(p) = p0 + 2 p1 (linear), same f.
- `range1`: N = 1, h(x) = sqrt(x^2 + 4), f(x) = x + 0.5 sin x.

Inputs per seed (numpy.random.default_rng(seed)): mu0 uniform in [2, 5]^N, P0 = A A' / N
+ 0.05 I with A uniform in [-1, 1], Q the same with 0.1 scale and 0.01 I, R uniform in
[0.01, 0.5], and z = h(mu0) + sqrt(R) * standard normal (for `predict_update`: h(f(mu0))
+ noise).

Writes estim-core/tests/data/pykalman_augmented_ukf.csv, one row per (case, model, seed):
case, model, n, m, seed, then mu0 (n), P0 (n*n, row-major), Q (n*n), R (m*m), z (m), the
filtered mean (n) and covariance (n*n, row-major) of the last step; every float as Python's
repr (shortest string that round-trips the f64). The Rust test reads only this file.

Run (once, outside CI; pykalman is never a test dependency):
    pip install --no-cache-dir pykalman==0.11.2 numpy scipy
    python3 training/peers/pykalman_augmented_ukf.py
"""

import os

import numpy as np
import pykalman
import scipy
from numpy import ma
from pykalman import UnscentedKalmanFilter

LANDMARK = np.array([1.0, -2.0])
SEEDS = range(6)


def f2(p):
    return np.array([p[0] + 0.5 * np.cos(p[1]), p[1] + 0.5 * np.sin(p[0])])


def f1(x):
    return np.array([x[0] + 0.5 * np.sin(x[0])])


MODELS = {
    "range2": (2, f2, lambda p: np.array([np.hypot(p[0] - LANDMARK[0], p[1] - LANDMARK[1])])),
    "bearing2": (2, f2, lambda p: np.array([np.arctan2(p[1] - LANDMARK[1], p[0] - LANDMARK[0])])),
    "linear2": (2, f2, lambda p: np.array([p[0] + 2.0 * p[1]])),
    "range1": (1, f1, lambda x: np.array([np.sqrt(x[0] ** 2 + 4.0)])),
}


def spd(rng, n, scale, floor):
    a = rng.uniform(-1.0, 1.0, (n, n))
    return scale * a @ a.T / n + floor * np.eye(n)


def run(case, model, seed):
    n, f, h = MODELS[model]
    rng = np.random.default_rng(seed)
    mu0 = rng.uniform(2.0, 5.0, n)
    p0 = spd(rng, n, 1.0, 0.05)
    q = spd(rng, n, 0.1, 0.01)
    r = np.array([[rng.uniform(0.01, 0.5)]])
    centre = h(mu0) if case == "update" else h(f(mu0))
    z = centre + np.sqrt(r[0, 0]) * rng.standard_normal(1)
    ukf = UnscentedKalmanFilter(
        transition_functions=lambda x, w: f(x) + w,
        observation_functions=lambda x, v: h(x) + v,
        transition_covariance=q,
        observation_covariance=r,
        initial_state_mean=mu0,
        initial_state_covariance=p0,
    )
    if case == "update":
        zs = np.array([z])
    else:
        zs = ma.array([[0.0], z], mask=[[True], [False]])
    means, covariances = ukf.filter(zs)
    inputs = [mu0, p0.reshape(-1), q.reshape(-1), r.reshape(-1), z]
    outputs = [means[-1], covariances[-1].reshape(-1)]
    return n, np.concatenate(inputs + outputs)


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = os.path.join(root, "estim-core", "tests", "data", "pykalman_augmented_ukf.csv")
    rows = 0
    with open(out, "w") as file:
        file.write(f"# pykalman {pykalman.__version__}, numpy {np.__version__}, "
                   f"scipy {scipy.__version__}: python3 training/peers/pykalman_augmented_ukf.py\n")
        file.write("# case,model,n,m,seed,mu0[n],P0[n*n],Q[n*n],R[1],z[1],mean[n],P[n*n]\n")
        for case in ("update", "predict_update"):
            for model in MODELS:
                for seed in SEEDS:
                    n, values = run(case, model, seed)
                    file.write(f"{case},{model},{n},1,{seed},"
                               + ",".join(repr(float(v)) for v in values) + "\n")
                    rows += 1
    print(f"wrote {out}: {rows} rows")


if __name__ == "__main__":
    main()
