"""The native API (estim.KalmanFilter, kalman_filter, kalman_smoother, joint_check,
nees, nis) against independent references: filterpy's batch filter and RTS smoother
(M = 0), joint-Gaussian conditioning of the whole stacked trajectory written here
with NumPy (correlated M), closed forms, and typed errors."""

import numpy as np
import pytest

import estim
from estim import EstimError


def close(a, b, rtol=1e-9, what=""):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, f"{what}: {a.shape} vs {b.shape}"
    scale = max(np.max(np.abs(b)), 1e-300)
    np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-12 * scale, err_msg=what)


def model(seed, n, m, steps, correlated=False):
    """A stable random model; with `correlated`, the joint noise [[Q, M], [M', R]] = L L'
    (valid by construction) and measurements simulated from it."""
    rng = np.random.default_rng(seed)
    F = np.eye(n) * 0.9 + rng.uniform(-0.1, 0.1, (n, n))
    L = np.tril(rng.uniform(-0.5, 0.5, (n + m, n + m))) + 0.4 * np.eye(n + m)
    J = L @ L.T
    Q, M, R = J[:n, :n], J[:n, n:], J[n:, n:]
    H = rng.uniform(-1, 1, (m, n))
    x0 = rng.uniform(-1, 1, n)
    P0 = np.eye(n) * 1.5
    x = x0.copy()
    zs = np.empty((steps, m))
    for k in range(steps):
        e = L @ rng.normal(size=n + m)
        x = F @ x + e[:n]
        zs[k] = H @ x + e[n:]
    return dict(F=F, Q=Q, H=H, R=R, x0=x0, P0=P0), (M if correlated else None), zs


def stacked_reference(F, Q, H, R, x0, P0, M, zs):
    """E and Cov of every x_k (k = 0..T) given y_1..y_K (K = len(zs), NaN rows
    skipped) by conditioning the joint Gaussian of z = [x_0; (w_k, v_k) for k = 1..T]."""
    n, m, T = F.shape[0], H.shape[0], len(zs)
    M = np.zeros((n, m)) if M is None else M
    dim = n + T * (n + m)
    cov = np.zeros((dim, dim))
    cov[:n, :n] = P0
    J = np.block([[Q, M], [M.T, R]])
    for k in range(T):
        s = n + k * (n + m)
        cov[s:s + n + m, s:s + n + m] = J
    mean = np.zeros(dim)
    mean[:n] = x0
    # x_k = A_k z (linear in z), y_k = H x_k + v_k.
    A = np.zeros((T + 1, n, dim))
    A[0][:, :n] = np.eye(n)
    rows = []
    for k in range(1, T + 1):
        s = n + (k - 1) * (n + m)
        A[k] = F @ A[k - 1]
        A[k][:, s:s + n] += np.eye(n)
        C = H @ A[k]
        C[:, s + n:s + n + m] += np.eye(m)
        rows.append(C)

    def posterior(K):
        observed = [k for k in range(K) if not np.any(np.isnan(zs[k]))]
        if not observed:
            return [(a @ mean, a @ cov @ a.T) for a in A]
        C = np.vstack([rows[k] for k in observed])
        y = np.concatenate([zs[k] for k in observed])
        S = C @ cov @ C.T
        gain = cov @ C.T @ np.linalg.inv(S)
        mu = mean + gain @ (y - C @ mean)
        sigma = cov - gain @ C @ cov
        return [(a @ mu, a @ sigma @ a.T) for a in A]

    smoothed = posterior(T)
    filtered = [posterior(k)[k] for k in range(1, T + 1)]
    return filtered, smoothed


@pytest.mark.parametrize("correlated", [False, True])
def test_smoother_equals_joint_gaussian_conditioning(correlated):
    kw, M, zs = model(3, 3, 2, 12, correlated)
    if not correlated:
        zs[[2, 7]] = np.nan  # missing measurements (a correlated M needs them all)
    out = estim.kalman_smoother(zs=zs, M=M, **kw)
    filtered, smoothed = stacked_reference(M=M, zs=zs, **kw)
    for k in range(len(zs)):
        close(out.x_filtered[k], filtered[k][0], 1e-8, f"filtered x {k}")
        close(out.P_filtered[k], filtered[k][1], 1e-8, f"filtered P {k}")
        close(out.x[k], smoothed[k + 1][0], 1e-8, f"smoothed x {k}")
        close(out.P[k], smoothed[k + 1][1], 1e-8, f"smoothed P {k}")
    close(out.x0, smoothed[0][0], 1e-8, "smoothed x0")
    close(out.P0, smoothed[0][1], 1e-8, "smoothed P0")
    filt = estim.kalman_filter(zs=zs, M=M, **kw)
    np.testing.assert_array_equal(filt.x, out.x_filtered)
    assert filt.log_likelihood == out.log_likelihood
    assert np.isnan(filt.nis).sum() == (0 if correlated else 2)


def test_filter_and_smoother_equal_filterpy():
    fp = pytest.importorskip("filterpy.kalman")
    kw, _, zs = model(5, 4, 2, 40)
    zs[[3, 4, 20]] = np.nan
    kf = fp.KalmanFilter(4, 2)
    kf.F, kf.Q, kf.H, kf.R = kw["F"], kw["Q"], kw["H"], kw["R"]
    kf.x, kf.P = kw["x0"].copy(), kw["P0"].copy()
    means, covs, _, _ = kf.batch_filter([None if np.isnan(z[0]) else z for z in zs])
    xs, Ps, _, _ = kf.rts_smoother(means, covs)
    out = estim.kalman_smoother(zs=zs, **kw)
    close(out.x_filtered, means, what="filtered x")
    close(out.P_filtered, covs, what="filtered P")
    close(out.x, xs, what="smoothed x")
    close(out.P, Ps, what="smoothed P")
    assert np.max(np.abs(out.x - out.x_filtered)) > 1e-3


def test_mask_equals_nan_rows_and_the_class_equals_the_functions():
    kw, _, zs = model(7, 3, 1, 20)
    mask = np.ones(20, dtype=bool)
    mask[[1, 5]] = False
    with_nan = zs.copy()
    with_nan[~mask] = np.nan
    a = estim.kalman_smoother(zs=zs, mask=mask, **kw)
    b = estim.kalman_smoother(zs=with_nan, **kw)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    # (T,) accepted for m = 1.
    c = estim.kalman_filter(zs=with_nan[:, 0], **kw)
    np.testing.assert_array_equal(c.x, b.x_filtered)
    kf = estim.KalmanFilter(kw["F"], kw["Q"], kw["H"], kw["R"], kw["x0"], kw["P0"])
    for k in range(20):
        kf.predict()
        if mask[k]:
            kf.update(zs[k])
        np.testing.assert_array_equal(kf.x, c.x[k])
    assert kf.log_likelihood == c.log_likelihood
    # smooth() starts from the filter's current estimate, and leaves it untouched.
    fresh = estim.KalmanFilter(kw["F"], kw["Q"], kw["H"], kw["R"], kw["x0"], kw["P0"])
    np.testing.assert_array_equal(fresh.smooth(with_nan).x, b.x)
    np.testing.assert_array_equal(fresh.x, kw["x0"])


def test_update_report_equals_the_textbook_formulas():
    kw, M, zs = model(9, 3, 2, 1, correlated=True)
    kf = estim.KalmanFilter(kw["F"], kw["Q"], kw["H"], kw["R"], kw["x0"], kw["P0"])
    kf.predict()
    x, P = kf.x, kf.P
    F, Q, H, R = kw["F"], kw["Q"], kw["H"], kw["R"]
    close(x, F @ kw["x0"], what="predicted x")
    close(P, F @ kw["P0"] @ F.T + Q, what="predicted P")
    report = kf.update(zs[0], M=M)
    S = H @ P @ H.T + H @ M + M.T @ H.T + R
    K = (P @ H.T + M) @ np.linalg.inv(S)
    nu = zs[0] - H @ x
    nis = nu @ np.linalg.solve(S, nu)
    ll = -0.5 * (2 * np.log(2 * np.pi) + np.linalg.slogdet(S)[1] + nis)
    assert report.accepted
    close(report.innovation, nu, what="innovation")
    close(report.S, S, what="S")
    close(report.K, K, what="K")
    close(report.nis, nis, what="nis")
    close(report.log_likelihood, ll, what="log-likelihood")
    close(kf.x, x + K @ nu, what="posterior x")
    close(kf.P, P - K @ (H @ P + M.T), what="posterior P")
    assert report.joint_min_eigenvalue >= 0.0


def test_joint_check_closed_form():
    # Correlation matrix [[1, 0, rho], [0, 1, 0], [rho, 0, 1]]: LDL' pivots 1, 1,
    # 1 - rho^2 (the margin when valid); smallest eigenvalue 1 - |rho| when not.
    Q, R = np.diag([0.04, 0.01]), np.array([[0.1]])
    for rho in (0.0, 0.5, 0.9):
        M = np.array([[rho * np.sqrt(0.04 * 0.1)], [0.0]])
        assert estim.joint_check(Q, M, R) == pytest.approx(1 - rho**2, abs=1e-12)
    M = np.array([[1.5 * np.sqrt(0.04 * 0.1)], [0.0]])
    assert estim.joint_check(Q, M, R) == pytest.approx(-0.5, abs=1e-12)


def test_nees_and_nis_equal_the_quadratic_form():
    rng = np.random.default_rng(2)
    G = rng.normal(size=(5, 4, 4))
    P = G @ np.transpose(G, (0, 2, 1)) + np.eye(4)
    e = rng.normal(size=(5, 4))
    expected = np.array([e[k] @ np.linalg.solve(P[k], e[k]) for k in range(5)])
    close(estim.nees(e, np.zeros((5, 4)), P), expected, 1e-12)
    close(estim.nis(e, P), expected, 1e-12)
    assert estim.nees(e[0], np.zeros(4), P[0]) == pytest.approx(expected[0], rel=1e-12)


def test_errors_name_what_was_wrong():
    kw, M, zs = model(1, 3, 2, 5, correlated=True)
    bad = dict(kw, H=np.ones((2, 4)))
    with pytest.raises(EstimError, match=r"observation matrix H \(columns\): expected 3, got 4"):
        estim.kalman_filter(zs=zs, **bad)
    with pytest.raises(EstimError, match=r"zs: expected shape \(T, 2\)"):
        estim.kalman_filter(zs=np.ones((5, 3)), **kw)
    with pytest.raises(EstimError, match="mask"):
        estim.kalman_filter(zs=zs, mask=[True, False], **kw)
    partly = zs.copy()
    partly[1, 0] = np.nan
    with pytest.raises(EstimError, match="partly NaN"):
        estim.kalman_filter(zs=partly, **kw)
    with pytest.raises(EstimError, match="measurement noise R"):
        estim.KalmanFilter(kw["F"], kw["Q"], kw["H"], -kw["R"], kw["x0"], kw["P0"])
    with pytest.raises(EstimError, match="joint covariance"):
        estim.kalman_filter(zs=zs, M=M * 50, **kw)
    report_only = estim.kalman_filter(zs=zs, M=M * 50, joint_check="report", **kw)
    assert np.all(np.isfinite(report_only.x))
    with pytest.raises(EstimError, match="joint_check"):
        estim.kalman_filter(zs=zs, joint_check="maybe", **kw)
    with pytest.raises(EstimError, match="M: expected shape"):
        estim.kalman_filter(zs=zs, M=np.ones((2, 2)), **kw)


@pytest.mark.parametrize("case", ["uncorrelated", "correlated"])
def test_smoother_equals_the_committed_static_runner_numbers(case):
    """python/tests/data/static_runner.json holds estim-core's static KalmanFilter's
    filter_batch and smooth_batch on two problems (M = 0 with missing steps, and a
    correlated M); estim-core/tests/dynamic_expected.rs keeps it equal to the Rust
    runner. The bindings reproduce it to 1e-12 relative."""
    import json
    import pathlib

    data = json.loads((pathlib.Path(__file__).parent / "data" / "static_runner.json").read_text())[case]
    zs = np.array([[np.nan] * 2 if z is None else z for z in data["zs"]])
    out = estim.kalman_smoother(
        np.array(data["F"]), np.array(data["Q"]), np.array(data["H"]), np.array(data["R"]),
        np.array(data["x0"]), np.array(data["P0"]), zs,
        M=None if data["M"] is None else np.array(data["M"]),
    )
    for ours, name in [(out.x_filtered, "filtered_x"), (out.P_filtered, "filtered_P"),
                       (out.x, "smoothed_x"), (out.P, "smoothed_P"), (out.x0, "smoothed_x0")]:
        close(ours, np.array(data[name]), 1e-12, f"{case} {name}")
    close(out.log_likelihood, data["log_likelihood"], 1e-12, "log-likelihood")
