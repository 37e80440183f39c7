"""estim.ExtendedKalmanFilter against independent references, on a planar target with
quadratic drag seen in range and bearing from a station (n = 4, m = 2):

- filterpy's ExtendedKalmanFilter (its predict with F set to the Jacobian and x moved
  by f, its update with HJacobian and Hx), step by step, M = 0;
- the correlated update (Simon 2006, sec. 7.1) written here in NumPy;
- the extended RTS smoother (x^s_k = x_k + G_k (x^s_{k+1} - f(x_k)),
  G_k = P_k F_k' (F_k P_k F_k' + Q)^-1) written here in NumPy over the filtered
  estimates;
- exceptions of the callables raised as they are, shapes named.
"""

import numpy as np
import pytest

import estim
from estim import EstimError

DRAG = 0.05
STATION = np.array([-20.0, -5.0])


def f(x, dt):
    x = np.asarray(x, float).ravel()
    speed = np.hypot(x[2], x[3])
    return np.array([x[0] + dt * x[2], x[1] + dt * x[3],
                     x[2] - dt * DRAG * speed * x[2], x[3] - dt * DRAG * speed * x[3]])


def F(x, dt):
    x = np.asarray(x, float).ravel()
    v = x[2:]
    speed = np.hypot(*v)
    d = speed * np.eye(2) + np.outer(v, v) / speed
    out = np.eye(4)
    out[0, 2] = out[1, 3] = dt
    out[2:, 2:] -= dt * DRAG * d
    return out


def h(x):
    x = np.asarray(x, float).ravel()
    d = x[:2] - STATION
    return np.array([np.hypot(*d), np.arctan2(d[1], d[0])])


def H(x):
    x = np.asarray(x, float).ravel()
    dx, dy = x[:2] - STATION
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    return np.array([[dx / r, dy / r, 0.0, 0.0], [-dy / r2, dx / r2, 0.0, 0.0]])


def problem(seed, steps, missing):
    """Noise from [[Q, M], [M', R]] = L L' (valid by construction), seeded."""
    rng = np.random.default_rng(seed)
    L = np.tril(rng.uniform(-0.04, 0.04, (6, 6)))
    np.fill_diagonal(L, [0.05, 0.05, 0.1, 0.1, 0.3, 0.01])
    J = L @ L.T
    Q, M, R = J[:4, :4], J[:4, 4:], J[4:, 4:]
    x0 = np.array([0.0, 0.0, 3.0, 1.5])
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    dts = 0.5 + 0.1 * (np.arange(steps) % 3)
    x, zs = x0.copy(), np.empty((steps, 2))
    for k in range(steps):
        e = L @ rng.normal(size=6)
        x = f(x, dts[k]) + e[:4]
        zs[k] = h(x) + e[4:]
        if missing and (k + 1) % missing == 0:
            zs[k] = np.nan
    return dict(Q=Q, M=M, R=R, x0=x0, P0=P0, dts=dts, zs=zs)


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape, (a.shape, b.shape)
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_steps_equal_filterpy():
    fp = pytest.importorskip("filterpy.kalman")
    p = problem(1, 60, 5)

    class Drag(fp.ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = f(self.x, self.dt).reshape(-1, 1)

    theirs = Drag(4, 2)
    theirs.x, theirs.P, theirs.Q, theirs.R = p["x0"].reshape(-1, 1), p["P0"].copy(), p["Q"], p["R"]
    ours = estim.ExtendedKalmanFilter(p["Q"], p["R"], p["x0"], p["P0"])
    worst = 0.0
    for k, z in enumerate(p["zs"]):
        dt = p["dts"][k]
        theirs.F, theirs.dt = F(theirs.x, dt), dt
        theirs.predict()
        ours.predict(f, F, dt)
        if not np.isnan(z).any():
            theirs.update(z.reshape(-1, 1), H, lambda x: h(x).reshape(-1, 1))
            report = ours.update(z, h, H)
            assert report.accepted
            worst = max(worst, rel(report.innovation, theirs.y.ravel()), rel(report.S, theirs.S))
        worst = max(worst, rel(ours.x, theirs.x.ravel()), rel(ours.P, theirs.P))
    # filterpy's Joseph form and K = P H' S^-1 against the correlated form's expansion:
    # round-off only (measured 7.5e-14).
    assert worst < 1e-10, worst


def test_correlated_update_equals_numpy():
    p = problem(2, 20, 0)
    Q, M, R = p["Q"], p["M"], p["R"]
    ours = estim.ExtendedKalmanFilter(Q, R, p["x0"], p["P0"])
    x, P = p["x0"].copy(), p["P0"].copy()
    worst = 0.0
    for k, z in enumerate(p["zs"]):
        dt = p["dts"][k]
        Fk = F(x, dt)
        x, P = f(x, dt), Fk @ P @ Fk.T + Q
        Hk = H(x)
        S = Hk @ P @ Hk.T + Hk @ M + M.T @ Hk.T + R
        K = (P @ Hk.T + M) @ np.linalg.inv(S)
        x, P = x + K @ (z - h(x)), P - K @ (Hk @ P + M.T)
        ours.predict(f, F, dt)
        report = ours.update(z, h, H, M=M)
        assert report.joint_min_eigenvalue >= 0.0
        worst = max(worst, rel(ours.x, x), rel(ours.P, (P + P.T) / 2))
    # Measured 8.9e-16 (two algebraic forms of the posterior covariance).
    assert worst < 1e-10, worst


def numpy_ekf_rts(p, xs, Ps):
    """The extended RTS smoother over the filtered estimates xs (T, n), Ps (T, n, n);
    the first entry of each is x0, P0 (epoch 0), then one per step."""
    xs_s, Ps_s = xs.copy(), Ps.copy()
    for k in range(len(xs) - 2, -1, -1):
        dt = p["dts"][k]
        Fk = F(xs[k], dt)
        prior = Fk @ Ps[k] @ Fk.T + p["Q"]
        G = Ps[k] @ Fk.T @ np.linalg.inv(prior)
        xs_s[k] = xs[k] + G @ (xs_s[k + 1] - f(xs[k], dt))
        Ps_s[k] = Ps[k] + G @ (Ps_s[k + 1] - prior) @ G.T
    return xs_s, Ps_s


def test_smooth_equals_the_extended_rts_smoother():
    p = problem(3, 50, 4)
    ekf = estim.ExtendedKalmanFilter(p["Q"], p["R"], p["x0"], p["P0"])
    out = ekf.smooth(p["zs"], f, F, h, H, dt=p["dts"])
    filtered = ekf.filter(p["zs"], f, F, h, H, dt=p["dts"])
    assert rel(out.x_filtered, filtered.x) < 1e-15 and out.log_likelihood == filtered.log_likelihood
    xs = np.vstack([p["x0"], out.x_filtered])
    Ps = np.concatenate([p["P0"][None], out.P_filtered])
    xs_s, Ps_s = numpy_ekf_rts(p, xs, Ps)
    worst = max(rel(out.x, xs_s[1:]), rel(out.P, Ps_s[1:]), rel(out.x0, xs_s[0]), rel(out.P0, Ps_s[0]))
    # Measured 1.7e-15 (the recorded backward pass against the textbook form).
    assert worst < 1e-10, worst
    assert rel(out.x[0], out.x_filtered[0]) > 1e-3  # the smoother moved the early estimates
    # The filter advanced through filter(), not through smooth().
    np.testing.assert_array_equal(ekf.x, filtered.x[-1])


def test_callable_errors_are_raised_as_they_are():
    p = problem(4, 3, 0)
    ekf = estim.ExtendedKalmanFilter(p["Q"], p["R"], p["x0"], p["P0"])

    def broken(x, dt):
        raise ZeroDivisionError("inside f")

    with pytest.raises(ZeroDivisionError, match="inside f"):
        ekf.predict(broken, F, 0.5)
    with pytest.raises(EstimError, match=r"F: expected shape \(4, 4\)"):
        ekf.predict(f, lambda x, dt: np.eye(3), 0.5)
    with pytest.raises(EstimError, match="h returned shape"):
        ekf.update(p["zs"][0], lambda x: np.zeros(3), H)
    with pytest.raises(EstimError, match="h: expected a callable"):
        ekf.update(p["zs"][0], 3.0, H)
    with pytest.raises(EstimError, match="dt"):
        ekf.predict(f, F, -1.0)
    np.testing.assert_array_equal(ekf.x, p["x0"])
    np.testing.assert_array_equal(ekf.P, p["P0"])
    with pytest.raises(ValueError, match="from the series"):
        ekf.filter(p["zs"], f, F, lambda x: (_ for _ in ()).throw(ValueError("from the series")), H, dt=0.5)
