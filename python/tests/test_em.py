"""estim.em against independent references:

- pykalman 0.11.2 on its own robot problem (5 states, 2 measurements, 501 epochs with
  epoch 0 missing, per-step transition offsets, an observation offset): the values
  estim-core's Rust tests compare with, committed in estim-core/tests/data (written by
  training/peers/pykalman_robot.py), with the same tolerances and reasons as
  estim-core/tests/em.rs, and the MATLAB log-likelihoods the dataset ships;
- the Rust `noise::em::em` on a problem of its own (python/tests/data/em_rust.json,
  kept equal to the Rust result by estim-core/tests/em_expected.rs);
- a Kalman filter written here in NumPy for the fitted model's log-likelihood;
- typed errors naming the argument at fault.
"""

import json
import pathlib

import numpy as np
import pytest

import estim
from estim import EstimError

ROOT = pathlib.Path(__file__).resolve().parents[2]
DATA = ROOT / "estim-core" / "tests" / "data"


def table(name, keys):
    """`key -> {(i, j): value}` of a committed CSV (NaN for an empty value)."""
    out = {}
    lines = [l for l in (DATA / name).read_text().splitlines() if not l.startswith("#")]
    for line in lines[1:]:
        cells = line.split(",")
        key = ",".join(cells[:keys])
        i, j, v = int(cells[keys]), int(cells[keys + 1]), cells[keys + 2]
        out.setdefault(key, {})[(i, j)] = float(v) if v else np.nan
    return out


def matrix(cells):
    rows = max(i for i, _ in cells) + 1
    cols = max(j for _, j in cells) + 1
    m = np.empty((rows, cols))
    for (i, j), v in cells.items():
        m[i, j] = v
    return m


@pytest.fixture(scope="module")
def robot():
    inputs = {k: matrix(v) for k, v in table("pykalman_robot_inputs.csv", 1).items()}
    expected = {k: matrix(v) for k, v in table("pykalman_robot_expected.csv", 3).items()}
    return inputs, expected


def start(inputs, q="initial_transition_covariance", r="initial_observation_covariance"):
    """The arguments of test_kalman_fit's start (Q_0 = 10 I, R_0 = 10 I)."""
    return dict(
        F=inputs["transition_matrix"],
        H=inputs["observation_matrix"],
        Q=inputs[q],
        R=inputs[r],
        x0=inputs["initial_state_mean"][:, 0],
        P0=inputs["initial_state_covariance"],
        b=inputs["transition_offsets"],
        d=inputs["observation_offset"][:, 0],
    )


def rel_err(a, b):
    """max |a - b| / max |b| (estim-core/tests/common's rel_err)."""
    a, b = np.atleast_2d(np.asarray(a, float)), np.atleast_2d(np.asarray(b, float))
    assert a.shape == b.shape, (a.shape, b.shape)
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def relative(a, b):
    return abs(a - b) / abs(b)


ATTRIBUTES = {
    "transition_covariance": "Q",
    "observation_covariance": "R",
    "initial_state_mean": "x0",
    "initial_state_covariance": "P0",
    "transition_matrix": "F",
    "observation_matrix": "H",
    "transition_offsets": "b",
    "observation_offset": "d",
}


def ours(fit, name):
    value = np.asarray(getattr(fit, ATTRIBUTES[name]))
    # pykalman's vectors are columns in the committed file.
    return value.reshape(-1, 1) if value.ndim == 1 else value


def fits(robot, em_vars, iterations):
    """EM from the start for k = 0 .. iterations iterations (the k-th fit)."""
    inputs, _ = robot
    zs = inputs["observations"]
    runs = [estim.em(zs, **start(inputs), em_vars=em_vars, n_iter=k) for k in range(iterations + 1)]
    # One call of `iterations` gives every intermediate log-likelihood.
    np.testing.assert_array_equal(runs[-1].log_likelihoods, [r.log_likelihoods[-1] for r in runs])
    for r in runs:
        assert r.stopped is None
    return runs


def against_pykalman(robot, case, runs, names):
    """Largest relative differences over the iterations: of the log-likelihood, of the
    matrices, and pykalman's own round-off asymmetry of its fitted covariances."""
    _, expected = robot
    trace = matrices = asymmetry = 0.0
    for k, fit in enumerate(runs):
        trace = max(trace, relative(fit.log_likelihoods[-1], expected[f"{case},{k},loglikelihood"][0, 0]))
        for name in names:
            theirs = expected[f"{case},{k},{name}"]
            if np.max(np.abs(theirs)) == 0.0:
                # The zero initial mean of the start stays exactly zero.
                assert np.max(np.abs(ours(fit, name))) == 0.0
                continue
            matrices = max(matrices, rel_err(ours(fit, name), theirs))
            if theirs.shape[0] == theirs.shape[1] and theirs.shape[0] > 1:
                asymmetry = max(asymmetry, np.max(np.abs(theirs - theirs.T)) / np.max(np.abs(theirs)))
    return trace, matrices, asymmetry


NOISE_AND_INITIAL = ["transition_covariance", "observation_covariance", "initial_state_mean", "initial_state_covariance"]


def test_log_likelihood_of_the_given_model_equals_pykalman(robot):
    inputs, expected = robot
    zs = inputs["observations"]
    assert zs.shape == (501, 2) and np.isnan(zs[0]).all() and not np.isnan(zs[1:]).any()
    fit = estim.em(zs, **start(inputs, "transition_covariance", "observation_covariance"), n_iter=0)
    assert fit.iterations == 0 and fit.log_likelihoods.shape == (1,)
    # Rust measured 8.6e-16.
    assert relative(fit.log_likelihoods[0], expected["given,0,loglikelihood"][0, 0]) < 1e-10


def test_em_of_q_and_r_equals_pykalman_test_kalman_fit(robot):
    inputs, _ = robot
    runs = fits(robot, ["transition_covariance", "observation_covariance"], 5)
    trace, matrices, asymmetry = against_pykalman(robot, "fit_qr", runs, NOISE_AND_INITIAL)
    # Rust measured: trace 1.4e-15, matrices 4.1e-13, pykalman's own asymmetry 6.0e-13.
    assert trace < 1e-10, trace
    assert matrices < 1e-10, matrices
    # A difference of the size of pykalman's own round-off is agreement
    # (estim-core/tests/em.rs, round_off_floor).
    assert matrices <= 2.0 * asymmetry, (matrices, asymmetry)
    # The first five equal the MATLAB values the dataset ships (measured 5.6e-16 in Rust).
    matlab = inputs["matlab_loglikelihoods"][:, 0]
    assert max(relative(runs[-1].log_likelihoods[k], matlab[k]) for k in range(5)) < 1e-12
    assert np.all(np.diff(runs[-1].log_likelihoods) > 0)
    # Only Q and R moved.
    np.testing.assert_array_equal(runs[-1].x0, inputs["initial_state_mean"][:, 0])
    np.testing.assert_array_equal(runs[-1].P0, inputs["initial_state_covariance"])
    np.testing.assert_array_equal(runs[-1].b, inputs["transition_offsets"])


def test_em_default_variables_equal_pykalman(robot):
    """em_vars=None is pykalman's default: Q, R, x0, P0."""
    runs = fits(robot, None, 10)
    trace, matrices, asymmetry = against_pykalman(robot, "fit_all", runs, NOISE_AND_INITIAL)
    # Rust measured: trace 2.1e-13, matrices 1.1e-9 (Q at iteration 10), pykalman's own
    # asymmetry 2.2e-9: the EM map amplifies round-off, in pykalman as here
    # (estim-core/tests/em.rs, round_off_floor).
    assert trace < 1e-10, trace
    assert matrices < 1e-8, matrices
    assert matrices <= 2.0 * asymmetry, (matrices, asymmetry)
    assert np.all(np.diff(runs[-1].log_likelihoods) > 0)


def test_em_of_every_parameter_equals_pykalman_em_vars_all(robot):
    """em_vars='all': every parameter after every iteration within 10 times pykalman's own
    movement under a 1e-15 perturbation of Q_0, plus 1e-12 (estim-core/tests/em.rs,
    em_of_every_parameter_equals_pykalman_em_vars_all, explains the bound)."""
    _, expected = robot
    runs = fits(robot, "all", 10)
    trace = matrices = 0.0
    for k, fit in enumerate(runs):
        trace = max(trace, relative(fit.log_likelihoods[-1], expected[f"em_all,{k},loglikelihood"][0, 0]))
        for name in ATTRIBUTES:
            key = f"em_all,{k},{name}"
            if key not in expected:
                # At the start F, H, b, d are the inputs' own (not written again).
                assert k == 0
                continue
            theirs = expected[key]
            if np.max(np.abs(theirs)) == 0.0:
                assert np.max(np.abs(ours(fit, name))) == 0.0
                continue
            d = rel_err(ours(fit, name), theirs)
            matrices = max(matrices, d)
            if k > 0:
                moves = expected[f"em_all_sensitivity,{k},{name}"][0, 0]
                assert d <= 10.0 * moves + 1e-12, (k, name, d, moves)
    # Rust measured: trace 1.5e-12, matrices 8.3e-8 (Q at iteration 10).
    assert trace < 1e-10, trace
    assert matrices < 1e-6, matrices
    # Learned, the per-step offsets become one constant.
    assert runs[0].b.shape == (500, 5) and runs[1].b.shape == (5,)


def numpy_log_likelihood(zs, F, H, Q, R, x0, P0, b, d):
    """ln p(z_0..z_{T-1}) by a Kalman filter written here (pykalman's indexing: epoch 0
    measured at x_0; NaN rows skipped), each term ln N(nu; 0, S)."""
    x, P, total = np.asarray(x0, float), np.asarray(P0, float), 0.0
    for t, z in enumerate(zs):
        if t > 0:
            x, P = F @ x + b, F @ P @ F.T + Q
        if np.isnan(z).any():
            continue
        nu = z - H @ x - d
        S = H @ P @ H.T + R
        _, logdet = np.linalg.slogdet(S)
        total -= 0.5 * (len(z) * np.log(2 * np.pi) + logdet + nu @ np.linalg.solve(S, nu))
        K = P @ H.T @ np.linalg.inv(S)
        x, P = x + K @ nu, P - K @ H @ P
    return total


@pytest.fixture(scope="module")
def rust_case():
    return json.loads((pathlib.Path(__file__).parent / "data" / "em_rust.json").read_text())


def rust_zs(case):
    zs = case["zs"]
    m = len(next(z for z in zs if z is not None))
    return np.array([z if z is not None else [np.nan] * m for z in zs], float)


def test_em_equals_the_rust_result_on_another_problem(rust_case):
    zs = rust_case["zs"]
    assert sum(z is None for z in zs) == 12 and zs[0] is None
    fit = estim.em(rust_zs(rust_case), **rust_case["start"], em_vars=rust_case["em_vars"], n_iter=rust_case["n_iter"])
    assert fit.stopped is None and fit.iterations == rust_case["n_iter"]
    for name, value in rust_case["fitted"].items():
        got, value = np.asarray(getattr(fit, name)), np.asarray(value)
        assert got.shape == value.shape, name
        assert np.max(np.abs(got - value)) <= 1e-12 * max(np.max(np.abs(value)), 1e-300), name
    np.testing.assert_allclose(fit.log_likelihoods, rust_case["log_likelihoods"], rtol=1e-12, atol=0)
    # H, x0, P0 were not learned: as given.
    for name in ["H", "x0", "P0"]:
        np.testing.assert_array_equal(getattr(fit, name), rust_case["start"][name])


def test_fitted_log_likelihood_equals_a_numpy_kalman_filter(rust_case):
    zs = rust_zs(rust_case)
    fit = estim.em(zs, **rust_case["start"], em_vars=rust_case["em_vars"], n_iter=rust_case["n_iter"])
    theirs = numpy_log_likelihood(zs, fit.F, fit.H, fit.Q, fit.R, fit.x0, fit.P0, fit.b, fit.d)
    # The same operations in another order: measured 0 (bit-equal); 1e-12 allows
    # round-off only.
    assert relative(fit.log_likelihoods[-1], theirs) < 1e-12, (fit.log_likelihoods[-1], theirs)
    start = rust_case["start"]
    given = numpy_log_likelihood(zs, *(np.asarray(start[k], float) for k in ["F", "H", "Q", "R", "x0", "P0", "b", "d"]))
    assert relative(fit.log_likelihoods[0], given) < 1e-12


def test_defaults_are_pykalmans(rust_case):
    """F, H, Q, R, P0 identity, x0, b, d zero, n = m unless dim_x or an array says."""
    zs = rust_zs(rust_case)
    implicit = estim.em(zs, n_iter=3)
    explicit = estim.em(zs, F=np.eye(2), H=np.eye(2), Q=np.eye(2), R=np.eye(2), x0=np.zeros(2), P0=np.eye(2),
                        b=np.zeros(2), d=np.zeros(2), em_vars=["Q", "R", "x0", "P0"], n_iter=3)
    np.testing.assert_array_equal(implicit.log_likelihoods, explicit.log_likelihoods)
    np.testing.assert_array_equal(implicit.Q, explicit.Q)
    wide = estim.em(zs, dim_x=3, n_iter=1)
    assert wide.F.shape == (3, 3) and wide.H.shape == (2, 3)
    np.testing.assert_array_equal(wide.H, np.eye(2, 3))
    from_h = estim.em(zs, H=np.ones((2, 4)), n_iter=1)
    assert from_h.Q.shape == (4, 4)


def test_errors_name_the_argument():
    zs = np.array([[0.1, 0.2], [np.nan, np.nan], [0.3, 0.1], [0.2, 0.0]])
    with pytest.raises(EstimError, match='em_vars: unknown variable "S"'):
        estim.em(zs, em_vars=["Q", "S"])
    with pytest.raises(EstimError, match="n_iter"):
        estim.em(zs, n_iter=-1)
    with pytest.raises(EstimError, match="observation matrix"):
        estim.em(zs, F=np.eye(3), H=np.eye(2))
    with pytest.raises(EstimError, match="transition covariance"):
        estim.em(zs, Q=np.diag([1.0, -1.0]))
    with pytest.raises(EstimError, match="zs: expected shape"):
        estim.em(np.zeros((3, 2, 2)))
    with pytest.raises(EstimError, match="transition offsets"):
        estim.em(zs, b=np.zeros((2, 2)))
    with pytest.raises(EstimError, match="zs: row 2 is partly NaN"):
        estim.em(np.array([[0.0, 0.0], [0.1, 0.2], [np.nan, 0.3]]))
    with pytest.raises(EstimError, match="measurement"):
        estim.em(np.array([[np.inf, 0.0], [0.0, 0.0]]))
