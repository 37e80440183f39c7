"""estim.fit_noise against independent references:

- the Rust `noise::ml::maximize_dyn` on the same problem (python/tests/data/
  noise_fit_rust.json, kept equal to the Rust result by estim-core/tests/noise_ml_dyn.rs);
- a Kalman filter log-likelihood written here in NumPy: equal at the optimum, its
  finite-difference gradient zero there (in standard-error units), and its
  finite-difference Hessian the observed information;
- estim.kalman_filter's log-likelihood with the fitted Q and R;
- typed errors naming the argument at fault.
"""

import json
import pathlib

import numpy as np
import pytest

import estim
from estim import EstimError


@pytest.fixture(scope="module")
def case():
    data = json.loads((pathlib.Path(__file__).parent / "data" / "noise_fit_rust.json").read_text())
    m = len(data["R"])
    zs = np.array([z if z is not None else [np.nan] * m for z in data["zs"]], float)
    model = {k: np.asarray(data[k], float) for k in ["F", "Q", "H", "R", "x0", "P0"]}
    return data, model, zs


def numpy_log_likelihood(F, Q, H, R, x0, P0, zs):
    """ln p(z_1..z_T) by a Kalman filter written here: predict, then update when row k
    is not NaN; each term ln N(nu; 0, S)."""
    x, P, total = x0.copy(), P0.copy(), 0.0
    for z in zs:
        x, P = F @ x, F @ P @ F.T + Q
        if np.isnan(z).any():
            continue
        nu = z - H @ x
        S = H @ P @ H.T + R
        _, logdet = np.linalg.slogdet(S)
        total -= 0.5 * (len(z) * np.log(2 * np.pi) + logdet + nu @ np.linalg.solve(S, nu))
        K = P @ H.T @ np.linalg.inv(S)
        A = np.eye(len(x)) - K @ H
        x, P = x + K @ nu, A @ P @ A.T + K @ R @ K.T
    return total


def noise(model, theta, diagonal):
    n = model["F"].shape[0]
    if diagonal:
        return np.diag(theta[:n]), np.diag(theta[n:])
    return theta[0] * model["Q"], theta[1] * model["R"]


def numpy_at(model, zs, theta, diagonal):
    Q, R = noise(model, theta, diagonal)
    return numpy_log_likelihood(model["F"], Q, model["H"], R, model["x0"], model["P0"], zs)


@pytest.mark.parametrize("diagonal", [False, True])
def test_fit_equals_the_rust_result(case, diagonal):
    data, model, zs = case
    fit = estim.fit_noise(**model, zs=zs, diagonal=diagonal)
    expected = data["diagonals" if diagonal else "scales"]
    assert fit.converged and fit.stop == "converged"
    assert fit.parameters == ("diagonals" if diagonal else "scales")
    for name in ["theta", "standard_errors"]:
        got, want = np.asarray(getattr(fit, name)), np.asarray(expected[name])
        assert got.shape == want.shape
        assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want)), name
    assert abs(fit.log_likelihood - expected["log_likelihood"]) <= 1e-12 * abs(expected["log_likelihood"])
    Q, R = noise(model, fit.theta, diagonal)
    np.testing.assert_array_equal(fit.Q, Q)
    np.testing.assert_array_equal(fit.R, R)


@pytest.mark.parametrize("diagonal", [False, True])
def test_optimum_of_a_numpy_likelihood(case, diagonal):
    """At the estimate, the NumPy likelihood equals the fit's, its central-difference
    gradient is zero to within 1e-6 of a nat per standard error, and its
    central-difference Hessian is the observed information to 1e-5 relative."""
    _, model, zs = case
    fit = estim.fit_noise(**model, zs=zs, diagonal=diagonal)
    theta, se = fit.theta, fit.standard_errors
    at = lambda t: numpy_at(model, zs, t, diagonal)
    value = at(theta)
    # Two filter codes, the same operations in another order: round-off only.
    assert abs(value - fit.log_likelihood) <= 1e-12 * abs(value), (value, fit.log_likelihood)
    p = len(theta)
    step = 1e-4 * theta
    shifted = lambda i, d: theta + d * np.eye(p)[i]
    gradient = np.array([(at(shifted(i, step[i])) - at(shifted(i, -step[i]))) / (2 * step[i]) for i in range(p)])
    # The change of ln p over one standard error, linear part: zero at the optimum.
    # Measured 5.0e-8 in both cases (finite-difference truncation and round-off).
    per_se = np.abs(gradient) * se
    assert np.max(per_se) < 1e-6, per_se
    hessian = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            hessian[i, j] = (
                at(shifted(i, step[i]) + step[j] * np.eye(p)[j])
                - at(shifted(i, step[i]) - step[j] * np.eye(p)[j])
                - at(shifted(i, -step[i]) + step[j] * np.eye(p)[j])
                + at(shifted(i, -step[i]) - step[j] * np.eye(p)[j])
            ) / (4 * step[i] * step[j])
    # Second differences of step 1e-4 theta (truncation and round-off): measured 3.6e-7
    # (scales) and 4.2e-7 (diagonals) relative to the largest entry; the standard
    # errors from that Hessian 2.9e-7 and 1.1e-6 relative.
    relative = np.max(np.abs(-hessian - fit.information)) / np.max(np.abs(fit.information))
    assert relative < 1e-5, relative
    np.testing.assert_allclose(fit.standard_errors, np.sqrt(np.diag(np.linalg.inv(-hessian))), rtol=1e-5)


def test_kalman_filter_log_likelihood_at_the_fit(case):
    _, model, zs = case
    fit = estim.fit_noise(**model, zs=zs)
    out = estim.kalman_filter(model["F"], fit.Q, model["H"], fit.R, model["x0"], model["P0"], zs)
    assert abs(out.log_likelihood - fit.log_likelihood) <= 1e-12 * abs(fit.log_likelihood)


def test_errors_name_the_argument(case):
    _, model, zs = case
    with pytest.raises(EstimError, match="zs"):
        estim.fit_noise(**model, zs=np.zeros((5, 3)))
    partly = zs.copy()
    partly[4, 0] = np.nan
    with pytest.raises(EstimError, match="zs: row 4 is partly NaN"):
        estim.fit_noise(**model, zs=partly)
    bad = dict(model, Q=np.diag([1.0, -1.0]))
    with pytest.raises(EstimError, match="process noise Q"):
        estim.fit_noise(**bad, zs=zs)
    zero = dict(model, Q=np.diag([1.0, 0.0]))
    with pytest.raises(EstimError, match="start must be positive; diagonal entry 1"):
        estim.fit_noise(**zero, zs=zs, diagonal=True)
    with pytest.raises(EstimError, match="observation matrix H"):
        estim.fit_noise(**dict(model, H=np.eye(3)), zs=zs)
