"""estim.filterpy.UnscentedKalmanFilter against filterpy's own UnscentedKalmanFilter (a
test-only dependency) on filterpy's UKF test problems (test_ukf.py: the radar of
test_radar and test_rts, test_linear_2d_merwe, test_vhartman) and on a turning vehicle
seen in range and bearing with angle residuals and circular means: every attribute
filterpy exposes after every predict and update, the batch filter and the RTS smoother
agree to 1e-9 relative. Measurements are drawn once from seeded generators and fed to
both filters.

"Relative" is norm-wise: |ours - filterpy| <= 1e-9 max|filterpy| over each array. An
entry that is a small difference of large ones (the radar's altitude-range gain, 2e-5
beside 0.07, after 300 steps) carries the absolute round-off of the large ones, so an
entry-wise 1e-9 would test the cancellation, not the filter; the largest norm-wise gaps
measured are printed by test_report_worst_gaps (-s) and are about 1e-12."""

import re

import numpy as np
import pytest

fp_kalman = pytest.importorskip("filterpy.kalman")
from estim import EstimError  # noqa: E402
from estim.filterpy import (  # noqa: E402
    JulierSigmaPoints,
    MerweScaledSigmaPoints,
    UnscentedKalmanFilter,
)

RTOL = 1e-9
WORST = {}


def close(a, b, what=""):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, f"{what}: shape {a.shape} vs {b.shape}"
    scale = max(np.max(np.abs(b)) if b.size else 0.0, 1e-300)
    gap = np.max(np.abs(a - b)) / scale if b.size else 0.0
    assert gap <= RTOL, f"{what}: {gap:.2e} relative\n{a}\n{b}"
    key = re.sub(r" \d+", "", what)
    WORST[key] = max(WORST.get(key, 0.0), gap)


def pair(points, **kwargs):
    """Our filter and filterpy's on the same arguments, with points of each library."""
    ours = UnscentedKalmanFilter(points=points[0], **kwargs)
    theirs = fp_kalman.UnscentedKalmanFilter(points=points[1], **kwargs)
    return ours, theirs


def merwe(*args, **kwargs):
    return MerweScaledSigmaPoints(*args, **kwargs), fp_kalman.MerweScaledSigmaPoints(*args, **kwargs)


def julier(*args, **kwargs):
    return JulierSigmaPoints(*args, **kwargs), fp_kalman.JulierSigmaPoints(*args, **kwargs)


PREDICT = ("x", "P", "x_prior", "P_prior", "sigmas_f")
UPDATE = ("x", "P", "K", "y", "S", "SI", "sigmas_h", "x_post", "P_post")


def same(ours, theirs, names, what):
    for name in names:
        close(getattr(ours, name), getattr(theirs, name), f"{what}: {name}")


# --- filterpy's test_radar / test_rts problem ------------------------------------------

def radar_fx(x, dt):
    A = np.eye(3) + dt * np.array([[0, 1, 0], [0, 0, 0], [0, 0, 0]])
    return A.dot(x)


def radar_hx(x):
    return [np.sqrt(x[0] ** 2 + x[2] ** 2)]


def radar_ranges(dt, seed=200):
    """filterpy's RadarSim, seeded."""
    rng = np.random.RandomState(seed)
    pos, out = 0.0, []
    for _ in np.arange(0, 20 + dt, dt):
        vel = 100 + 5 * rng.randn()
        alt = 1000 + 10 * rng.randn()
        pos += vel * dt
        out.append((pos ** 2 + alt ** 2) ** 0.5 + pos * 0.05 * rng.randn())
    return out


def radar_setup(kf):
    kf.Q *= 0.01
    kf.R = 10
    kf.x = np.array([0.0, 90.0, 1100.0])
    kf.P *= 100.0


@pytest.mark.parametrize("points", [julier(3, kappa=0.0), merwe(3, 0.5, 2.0, 0.0)])
def test_radar_step_by_step(points):
    dt = 0.05
    ours, theirs = pair(points, dim_x=3, dim_z=1, dt=dt, hx=radar_hx, fx=radar_fx)
    close(ours.Wm, theirs.Wm, "Wm")
    close(ours.Wc, theirs.Wc, "Wc")
    for kf in (ours, theirs):
        radar_setup(kf)
    for i, r in enumerate(radar_ranges(dt)):
        ours.predict()
        theirs.predict()
        same(ours, theirs, PREDICT, f"predict {i}")
        ours.update([r])
        theirs.update([r])
        same(ours, theirs, UPDATE, f"update {i}")
        for name in ("log_likelihood", "likelihood", "mahalanobis"):
            close(getattr(ours, name), getattr(theirs, name), f"{name} {i}")


def test_radar_batch_and_rts():
    """filterpy's test_rts: batch_filter, then rts_smoother with Qs."""
    dt = 0.05
    ours, theirs = pair(julier(3, kappa=1.0), dim_x=3, dim_z=1, dt=dt, hx=radar_hx,
                        fx=radar_fx)
    for kf in (ours, theirs):
        radar_setup(kf)
    rs = radar_ranges(dt)
    (m1, p1), (m2, p2) = ours.batch_filter(rs), theirs.batch_filter(rs)
    close(m1, m2, "batch: means")
    close(p1, p2, "batch: covariances")
    Qs = [theirs.Q] * len(rs)
    s1, s2 = ours.rts_smoother(m1, p1, Qs=Qs), theirs.rts_smoother(m2, p2, Qs=Qs)
    for a, b, name in zip(s1, s2, ("x", "P", "K")):
        close(a, b, f"rts: {name}")


def test_linear_2d_merwe_and_rts():
    """filterpy's test_linear_2d_merwe: alpha 0.1, kappa -1 (a centre weight of -130,
    the centre-point-modified form on our side, equal on a linear model), with
    missing measurements."""

    def fx(x, dt):
        F = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1]], dtype=float)
        return np.dot(F, x)

    def hx(x):
        return np.array([x[0], x[2]])

    dt = 0.1
    ours, theirs = pair(merwe(4, 0.1, 2.0, -1), dim_x=4, dim_z=2, dt=dt, fx=fx, hx=hx)
    for kf in (ours, theirs):
        kf.x = np.array([-1.0, 1, -1, 1])
        kf.P *= 1.1
    rng = np.random.RandomState(4)
    zs = [[i + rng.randn() * 0.1, i + rng.randn() * 0.1] for i in range(20)]
    zs[7] = None
    (m1, p1), (m2, p2) = ours.batch_filter(zs), theirs.batch_filter(zs)
    close(m1, m2, "linear 2d: means")
    close(p1, p2, "linear 2d: covariances")
    s1, s2 = ours.rts_smoother(m1, p1, dts=dt), theirs.rts_smoother(m2, p2, dts=dt)
    for a, b, name in zip(s1, s2, ("x", "P", "K")):
        close(a, b, f"linear 2d rts: {name}")


def test_vhartman():
    """filterpy's test_vhartman: one state, Merwe kappa 0.1, equal to the EKF."""
    ours, theirs = pair(merwe(1, alpha=1, beta=2.0, kappa=0.1), dim_x=1, dim_z=1, dt=1.0,
                        fx=lambda x, dt: np.dot(np.array([[1.0]]), x),
                        hx=lambda x: np.array([x[0]]))
    for kf in (ours, theirs):
        kf.x, kf.P, kf.R, kf.Q = np.array([0.0]), np.array([[1]]), np.diag([1]), np.diag([1])
    rng = np.random.RandomState(0)
    for i in range(50):
        z = [rng.randn()]
        ours.predict()
        theirs.predict()
        ours.update(z)
        theirs.update(z)
        same(ours, theirs, UPDATE, f"vhartman {i}")


# --- a turning vehicle in range and bearing, angles wrapped ----------------------------

LANDMARK = np.array([10.0, -5.0])


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def turn_fx(x, dt, rate=0.3):
    return np.array([x[0] + dt * x[3] * np.cos(x[2]), x[1] + dt * x[3] * np.sin(x[2]),
                     wrap(x[2] + dt * rate), x[3]])


def range_bearing(x):
    d = x[:2] - LANDMARK
    return np.array([np.hypot(d[0], d[1]), np.arctan2(d[1], d[0])])


def residual_x(a, b):
    y = np.subtract(a, b)
    y[2] = wrap(y[2])
    return y


def residual_z(a, b):
    y = np.subtract(a, b)
    y[1] = wrap(y[1])
    return y


def x_mean(sigmas, Wm):
    x = np.dot(Wm, sigmas)
    x[2] = np.arctan2(np.dot(Wm, np.sin(sigmas[:, 2])), np.dot(Wm, np.cos(sigmas[:, 2])))
    return x


def z_mean(sigmas, Wm):
    z = np.dot(Wm, sigmas)
    z[1] = np.arctan2(np.dot(Wm, np.sin(sigmas[:, 1])), np.dot(Wm, np.cos(sigmas[:, 1])))
    return z


def turning(seed=21, steps=80):
    rng = np.random.RandomState(seed)
    truth, zs = np.array([0.0, 0.0, 2.5, 2.0]), []
    for _ in range(steps):
        truth = turn_fx(truth, 0.5) + rng.randn(4) * [0.05, 0.05, 0.01, 0.02]
        truth[2] = wrap(truth[2])
        z = range_bearing(truth) + rng.randn(2) * [0.2, 0.02]
        zs.append(np.array([z[0], wrap(z[1])]))
    return zs


def turning_pair(points):
    ours, theirs = pair(points, dim_x=4, dim_z=2, dt=0.5, hx=range_bearing, fx=turn_fx,
                        x_mean_fn=x_mean, z_mean_fn=z_mean, residual_x=residual_x,
                        residual_z=residual_z)
    for kf in (ours, theirs):
        kf.x = np.array([0.0, 0.0, 2.5, 2.0])
        kf.P = np.diag([0.5, 0.5, 0.05, 0.1])
        kf.Q = np.diag([0.05, 0.05, 0.01, 0.02]) ** 2
        kf.R = np.diag([0.2, 0.02]) ** 2
    return ours, theirs


@pytest.mark.parametrize("points", [merwe(4, 1.0, 2.0, 0.0), julier(4, kappa=0.5)])
def test_angles_step_by_step(points):
    ours, theirs = turning_pair(points)
    crossed = False
    for i, z in enumerate(turning()):
        ours.predict(rate=0.3)
        theirs.predict(rate=0.3)
        same(ours, theirs, PREDICT, f"angles predict {i}")
        ours.update(z)
        theirs.update(z)
        same(ours, theirs, UPDATE, f"angles update {i}")
        close(ours.log_likelihood, theirs.log_likelihood, f"angles log_likelihood {i}")
        crossed |= abs(theirs.x[2]) > 3.0
    assert crossed, "the heading never came near +/- pi"


def test_angles_batch_and_rts():
    ours, theirs = turning_pair(merwe(4, 0.5, 2.0, 0.0))
    zs = turning()
    (m1, p1), (m2, p2) = ours.batch_filter(zs), theirs.batch_filter(zs)
    close(m1, m2, "angles batch: means")
    close(p1, p2, "angles batch: covariances")
    s1, s2 = ours.rts_smoother(m1, p1), theirs.rts_smoother(m2, p2)
    for a, b, name in zip(s1, s2, ("x", "P", "K")):
        close(a, b, f"angles rts: {name}")


def test_user_unscented_transform_runs_filterpys_algorithm():
    """A user UT (here filterpy's own) takes the NumPy path: still equal."""
    ours, theirs = turning_pair(merwe(4, 1.0, 2.0, 0.0))
    ut = fp_kalman.unscented_transform
    for i, z in enumerate(turning(steps=10)):
        ours.predict(UT=ut)
        theirs.predict(UT=ut)
        ours.update(z, UT=ut)
        theirs.update(z, UT=ut)
        same(ours, theirs, UPDATE, f"UT {i}")


def test_sigma_points_equal_filterpys():
    x, P = np.array([1.0, -2.0, 0.5]), np.array([[2.0, 0.3, 0.1], [0.3, 1.0, 0.2],
                                                  [0.1, 0.2, 0.5]])
    for ours, theirs in (merwe(3, 0.3, 2.0, 0.1), julier(3, kappa=2.0)):
        assert ours.num_sigmas() == theirs.num_sigmas() == 7
        close(ours.Wm, theirs.Wm, "points: Wm")
        close(ours.Wc, theirs.Wc, "points: Wc")
        close(ours.sigma_points(x, P), theirs.sigma_points(x, P), "points: sigma_points")


# --- errors ----------------------------------------------------------------------------

def test_errors_name_what_was_wrong_and_leave_the_filter_unchanged():
    ours, _ = turning_pair(merwe(4, 1.0, 2.0, 0.0))
    ours.predict()
    x, P = ours.x.copy(), ours.P.copy()
    with pytest.raises(EstimError, match="z"):
        ours.update(np.zeros(3))

    def raising(x):
        raise ZeroDivisionError("hx failed on purpose")

    with pytest.raises(ZeroDivisionError, match="on purpose"):
        ours.update(np.zeros(2), hx=raising)
    with pytest.raises(EstimError, match="hx"):
        ours.update(np.zeros(2), hx=lambda x: np.zeros(3))

    def raising_fx(x, dt):
        raise RuntimeError("fx failed on purpose")

    with pytest.raises(RuntimeError, match="on purpose"):
        ours.predict(fx=raising_fx)
    with pytest.raises(EstimError, match="P"):
        ours.P = np.zeros((3, 3))
        ours.predict()
    ours.P = P
    with pytest.raises(EstimError, match="Q"):
        ours.Q = -np.eye(4)
        ours.predict()
    np.testing.assert_array_equal(ours.x, x)
    np.testing.assert_array_equal(ours.P, P)


def test_report_worst_gaps():
    """Prints the largest relative gap per quantity (run with -s)."""
    for key in sorted(WORST):
        print(f"{key}: {WORST[key]:.1e}")
