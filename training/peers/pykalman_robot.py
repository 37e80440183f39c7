"""Expected values for estim-core's EM test (estim-core/tests/em.rs), computed by pykalman.

The problem is pykalman's own robot test (pykalman/tests/test_standard.py, `test_kalman_fit`,
data from `pykalman.datasets.load_robot()`): a 5-state, 2-observation linear-Gaussian model

    x_0 ~ N(mu_0, Sigma_0),  x_{t+1} = A x_t + b_t + w_t,  z_t = C x_t + d + v_t,
    Cov(w_t) = Q,  Cov(v_t) = R,  t = 0 .. 500 (501 epochs, z_0 masked),

with time-varying transition offsets b_t (500 of them) and a constant observation offset d.

Cases (all on the full 501 epochs):
- `given`: the log-likelihood `KalmanFilter.loglikelihood` under the dataset's parameters
  (Q, R = `transition_covariance`, `observation_covariance`, the MATLAB fit the data ships).
- `fit_qr`: test_kalman_fit's EM, from Q_0 = 10 I, R_0 = 10 I with
  em_vars = ['transition_covariance', 'observation_covariance'], 5 iterations.
- `fit_all`: from the same start, em_vars = ['transition_covariance',
  'observation_covariance', 'initial_state_mean', 'initial_state_covariance'] (pykalman's
  default em_vars), 10 iterations.
The script also prints how far pykalman's own `fit_all` Q moves when Q_0 is scaled by
1 + 1e-15 (the round-off the EM map amplifies on this problem). For the two fits, iteration k = 0 .. n is the model after k calls of `em(n_iter=1)` (k = 0:
the start), with its log-likelihood and its Q, R, mu_0, Sigma_0. The script checks that
one call of `em(n_iter=n)` ends at the same matrices, bit for bit.

Writes
- estim-core/tests/data/pykalman_robot_inputs.csv: `name,i,j,value` rows for the robot
  problem: observations (i = epoch, j = component; value empty where masked),
  transition_matrix, transition_offsets (i = step t of b_t), observation_matrix,
  observation_offset, initial_state_mean, initial_state_covariance,
  transition_covariance, observation_covariance (the given Q, R) and
  initial_transition_covariance, initial_observation_covariance (Q_0, R_0), and
  matlab_loglikelihoods (the 50 values the dataset ships, i = iteration);
- estim-core/tests/data/pykalman_robot_expected.csv: `case,iteration,name,i,j,value` rows.
Every float is Python's repr (the shortest string that round-trips the f64). The first line
of each file is a comment with the versions. The Rust test reads only these files.

License: the robot data are pykalman's test data set (`pykalman/datasets/data/robot.mat`,
from Pieter Abbeel's CS 287 course, Fall 2011), distributed with pykalman under its BSD
license; they are committed here as CSV for the test only and are not project data.

Run (once, outside CI; pykalman is never a test dependency):
    pip install --no-cache-dir pykalman==0.11.2 numpy scipy
    python3 training/peers/pykalman_robot.py
pykalman 0.11.2 rather than 0.10.x: 0.10.2's `_loglikelihoods` fails under numpy 2 (it
assigns a (1, 1) array to a float slot; 0.11 takes its [0, 0] entry). Their filter,
smoother and EM functions (`_filter`, `_smooth`, `_smooth_pair`, `_em*`) are the same code
apart from 0.11's guard of Q's 1 / (T - 1) for a single epoch.
"""

import os

import numpy as np
import pykalman
import scipy
from pykalman import KalmanFilter
from pykalman.datasets import load_robot

QR = ["transition_covariance", "observation_covariance"]
ALL4 = QR + ["initial_state_mean", "initial_state_covariance"]


def header():
    return (f"# pykalman {pykalman.__version__}, numpy {np.__version__}, scipy {scipy.__version__}: "
            "training/peers/pykalman_robot.py; robot data: pykalman's BSD-licensed test data\n")


def filter_for(data, q, r, em_vars):
    return KalmanFilter(
        data.transition_matrix, data.observation_matrix, q, r,
        data.transition_offsets, data.observation_offset,
        data.initial_state_mean, data.initial_state_covariance, em_vars=em_vars)


def parameters(kf):
    return [
        ("transition_covariance", np.asarray(kf.transition_covariance, dtype=float)),
        ("observation_covariance", np.asarray(kf.observation_covariance, dtype=float)),
        ("initial_state_mean", np.asarray(kf.initial_state_mean, dtype=float)),
        ("initial_state_covariance", np.asarray(kf.initial_state_covariance, dtype=float)),
    ]


def rows_of(name, values):
    values = np.asarray(values, dtype=float)
    if values.ndim == 0:
        yield (name, 0, 0, repr(float(values)))
    elif values.ndim == 1:
        for i, v in enumerate(values):
            yield (name, i, 0, repr(float(v)))
    else:
        for i in range(values.shape[0]):
            for j in range(values.shape[1]):
                yield (name, i, j, repr(float(values[i, j])))


def fit(data, em_vars, n_iter):
    """Rows of (iteration, name, i, j, value) for k = 0 .. n_iter."""
    z = data.observations
    kf = filter_for(data, data.initial_transition_covariance,
                    data.initial_observation_covariance, em_vars)
    rows = []
    for k in range(n_iter + 1):
        rows.extend((k,) + row for row in rows_of("loglikelihood", kf.loglikelihood(z)))
        for name, values in parameters(kf):
            rows.extend((k,) + row for row in rows_of(name, values))
        if k < n_iter:
            kf.em(X=z, n_iter=1)
    # One call with n_iter iterations ends at the same model.
    once = filter_for(data, data.initial_transition_covariance,
                      data.initial_observation_covariance, em_vars).em(X=z, n_iter=n_iter)
    for (_, a), (_, b) in zip(parameters(kf), parameters(once)):
        assert np.array_equal(a, b)
    return rows


def sensitivity(data, n_iter=10):
    """pykalman against itself from Q_0 (1 + 1e-15): the round-off the EM map amplifies.

    Printed only (the Rust test's docs cite it): max |Q - Q'| / max |Q| per iteration.
    """
    z = data.observations
    runs = []
    for scale in (1.0, 1.0 + 1e-15):
        kf = filter_for(data, data.initial_transition_covariance * scale,
                        data.initial_observation_covariance, ALL4)
        qs = []
        for _ in range(n_iter):
            kf.em(X=z, n_iter=1)
            qs.append(np.array(kf.transition_covariance, dtype=float))
        runs.append(qs)
    for k, (a, b) in enumerate(zip(*runs)):
        print(f"fit_all iteration {k + 1}: pykalman's Q moves {np.abs(a - b).max() / np.abs(a).max():.1e} "
              "relative under Q_0 (1 + 1e-15)")


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out_dir = os.path.join(root, "estim-core", "tests", "data")
    data = load_robot()
    z = data.observations
    mask = np.ma.getmaskarray(z)

    inputs = os.path.join(out_dir, "pykalman_robot_inputs.csv")
    with open(inputs, "w") as f:
        f.write(header())
        f.write("name,i,j,value\n")
        for t in range(z.shape[0]):
            for j in range(z.shape[1]):
                value = "" if mask[t, j] else repr(float(z.data[t, j]))
                f.write(f"observations,{t},{j},{value}\n")
        for name in ["transition_matrix", "transition_offsets", "observation_matrix",
                     "observation_offset", "initial_state_mean", "initial_state_covariance",
                     "transition_covariance", "observation_covariance",
                     "initial_transition_covariance", "initial_observation_covariance"]:
            for row in rows_of(name, data[name]):
                f.write(",".join(str(v) for v in row) + "\n")
        for row in rows_of("matlab_loglikelihoods", data.loglikelihoods):
            f.write(",".join(str(v) for v in row) + "\n")

    expected = os.path.join(out_dir, "pykalman_robot_expected.csv")
    given = filter_for(data, data.transition_covariance, data.observation_covariance, QR)
    with open(expected, "w") as f:
        f.write(header())
        f.write("case,iteration,name,i,j,value\n")
        for row in rows_of("loglikelihood", given.loglikelihood(z)):
            f.write("given,0," + ",".join(str(v) for v in row) + "\n")
        for case, em_vars, n_iter in [("fit_qr", QR, 5), ("fit_all", ALL4, 10)]:
            for row in fit(data, em_vars, n_iter):
                f.write(f"{case}," + ",".join(str(v) for v in row) + "\n")
    print(f"wrote {inputs} and {expected}")
    sensitivity(data)


if __name__ == "__main__":
    main()
