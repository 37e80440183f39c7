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
- `em_all`: from the same start, em_vars = 'all' (also the transition matrix A, the
  observation matrix C, the transition offsets b, which become one constant offset after
  the first iteration, and the observation offset d), 10 iterations.
For the fits, iteration k = 0 .. n is the model after k calls of `em(n_iter=1)` (k = 0:
the start), with its log-likelihood and its Q, R, mu_0, Sigma_0; `em_all` also has
transition_matrix, observation_matrix, transition_offsets and observation_offset at every
k >= 1 (at k = 0 they are the inputs' own, the per-step b among them). The script checks
that one call of `em(n_iter=n)` ends at the same matrices, bit for bit.

pykalman's sensitivity (the round-off the EM map amplifies on this problem): the script
reruns `fit_all` and `em_all` from Q_0 (1 + 1e-15) and measures, per iteration k >= 1
and parameter, max |p - p'| / max |p| between the two pykalman runs. It prints both; for
`em_all` it also writes them as the case `em_all_sensitivity` (name = the parameter or
loglikelihood, i = j = 0), which the Rust test reads to judge its own differences.

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
(the committed files: pykalman 0.11.2, numpy 2.4.6, scipy 1.17.1 from those wheels, whose
OpenBLAS picks its kernel by CPU; on an AMD EPYC here, in a venv:
`python3 -m venv /tmp/pyk && /tmp/pyk/bin/pip install --no-cache-dir pykalman==0.11.2
numpy scipy && /tmp/pyk/bin/python training/peers/pykalman_robot.py`). The output is
bit-reproducible on one machine (also with OPENBLAS_NUM_THREADS=1) but not across CPUs:
the previous version of the expected file, from the same versions on another CPU, differs
from this one by up to 8.3e-13 relative in `fit_qr` and 1.2e-9 in `fit_all` (the inputs
file is identical), which is pykalman's round-off as the sensitivity below measures it.
pykalman 0.11.2 rather than 0.10.x: 0.10.2's `_loglikelihoods` fails under numpy 2 (it
assigns a (1, 1) array to a float slot; 0.11 takes its [0, 0] entry). Their filter,
smoother and EM functions (`_filter`, `_smooth`, `_smooth_pair`, `_em*`) are the same code
apart from 0.11's guard of Q's 1 / (T - 1) for a single epoch.
"""

import os
import warnings

import numpy as np
import pykalman
import scipy
from pykalman import KalmanFilter
from pykalman.datasets import load_robot

QR = ["transition_covariance", "observation_covariance"]
ALL4 = QR + ["initial_state_mean", "initial_state_covariance"]
# The four more that em_vars='all' learns: (name in the files, pykalman's attribute).
STRUCTURE = [("transition_matrix", "transition_matrices"),
             ("observation_matrix", "observation_matrices"),
             ("transition_offsets", "transition_offsets"),
             ("observation_offset", "observation_offsets")]


# em_vars='all' turns the per-step b into one offset, and pykalman says so on each call.
warnings.filterwarnings("ignore", message="transition_offsets has 2 dimensions now")


def header():
    return (f"# pykalman {pykalman.__version__}, numpy {np.__version__}, scipy {scipy.__version__}: "
            "training/peers/pykalman_robot.py; robot data: pykalman's BSD-licensed test data\n")


def filter_for(data, q, r, em_vars):
    return KalmanFilter(
        data.transition_matrix, data.observation_matrix, q, r,
        data.transition_offsets, data.observation_offset,
        data.initial_state_mean, data.initial_state_covariance, em_vars=em_vars)


def parameters(kf, structure=False):
    """Q, R, mu_0, Sigma_0, and with `structure` also A, C, b, d."""
    out = [(name, np.asarray(getattr(kf, name), dtype=float)) for name in ALL4]
    if structure:
        out += [(name, np.asarray(getattr(kf, attr), dtype=float)) for name, attr in STRUCTURE]
    return out


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
    structure = em_vars == "all"
    kf = filter_for(data, data.initial_transition_covariance,
                    data.initial_observation_covariance, em_vars)
    rows = []
    for k in range(n_iter + 1):
        rows.extend((k,) + row for row in rows_of("loglikelihood", kf.loglikelihood(z)))
        for name, values in parameters(kf, structure and k > 0):
            rows.extend((k,) + row for row in rows_of(name, values))
        if k < n_iter:
            kf.em(X=z, n_iter=1)
    # One call with n_iter iterations ends at the same model.
    once = filter_for(data, data.initial_transition_covariance,
                      data.initial_observation_covariance, em_vars).em(X=z, n_iter=n_iter)
    for (_, a), (_, b) in zip(parameters(kf, structure), parameters(once, structure)):
        assert np.array_equal(a, b)
    return rows


def sensitivity(data, em_vars, n_iter=10):
    """pykalman against itself from Q_0 (1 + 1e-15): the round-off the EM map amplifies.

    Returns {(k, name): max |p - p'| / max |p|} for k = 1 .. n_iter, over the fitted
    parameters and the log-likelihood (|l - l'| / |l|).
    """
    z = data.observations
    structure = em_vars == "all"
    runs = []
    for scale in (1.0, 1.0 + 1e-15):
        kf = filter_for(data, data.initial_transition_covariance * scale,
                        data.initial_observation_covariance, em_vars)
        fits = []
        for _ in range(n_iter):
            kf.em(X=z, n_iter=1)
            fits.append([("loglikelihood", np.asarray(kf.loglikelihood(z)))]
                        + parameters(kf, structure))
        runs.append(fits)
    out = {}
    for k, (a, b) in enumerate(zip(*runs)):
        for (name, p), (_, q) in zip(a, b):
            out[(k + 1, name)] = float(np.abs(p - q).max() / np.abs(p).max())
    return out


def print_sensitivity(case, moves):
    iterations = sorted({k for k, _ in moves})
    names = [name for k, name in moves if k == iterations[0]]
    for k in iterations:
        print(f"{case} iteration {k}: pykalman moves under Q_0 (1 + 1e-15), relative: "
              + ", ".join(f"{name} {moves[(k, name)]:.1e}" for name in names))


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
        for case, em_vars, n_iter in [("fit_qr", QR, 5), ("fit_all", ALL4, 10),
                                      ("em_all", "all", 10)]:
            for row in fit(data, em_vars, n_iter):
                f.write(f"{case}," + ",".join(str(v) for v in row) + "\n")
        moves = sensitivity(data, "all")
        for (k, name), value in moves.items():
            f.write(f"em_all_sensitivity,{k},{name},0,0,{value!r}\n")
    print(f"wrote {inputs} and {expected}")
    print_sensitivity("fit_all", sensitivity(data, ALL4))
    print_sensitivity("em_all", moves)


if __name__ == "__main__":
    main()
