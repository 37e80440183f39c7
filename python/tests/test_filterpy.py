"""estim.filterpy.KalmanFilter against filterpy's own KalmanFilter (a test-only
dependency) on the same problems, step by step and in batch: every attribute filterpy
exposes after every step agrees to 1e-9 relative (absolute floor 1e-12 times the
quantity's scale)."""

import numpy as np
import pytest

filterpy_kalman = pytest.importorskip("filterpy.kalman")
from estim import EstimError  # noqa: E402
from estim.filterpy import KalmanFilter  # noqa: E402

RTOL = 1e-9


def close(a, b, what=""):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, f"{what}: shape {a.shape} vs {b.shape}"
    scale = max(np.max(np.abs(b)) if b.size else 0.0, 1e-300)
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-12 * scale, err_msg=what)


def pair(dim_x, dim_z, dim_u=0, setup=None):
    ours = KalmanFilter(dim_x, dim_z, dim_u)
    theirs = filterpy_kalman.KalmanFilter(dim_x, dim_z, dim_u)
    for kf in (ours, theirs):
        setup(kf)
    return ours, theirs


def assert_same_state(ours, theirs, what):
    for name in ("x", "P"):
        close(getattr(ours, name), getattr(theirs, name), f"{what}: {name}")


def assert_same_update(ours, theirs, what):
    assert_same_state(ours, theirs, what)
    for name in ("K", "y", "S", "SI", "x_post", "P_post"):
        close(getattr(ours, name), getattr(theirs, name), f"{what}: {name}")
    close(ours.log_likelihood, theirs.log_likelihood, f"{what}: log_likelihood")
    close(ours.mahalanobis, theirs.mahalanobis, f"{what}: mahalanobis")


def tracker(kf, dt=1.0):
    """filterpy's documentation example: constant velocity, position measured."""
    kf.x = np.array([[2.0], [0.0]])
    kf.F = np.array([[1.0, dt], [0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0]])
    kf.P *= 1000.0
    kf.R = 5
    q = 0.1
    kf.Q = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])


def random_model(seed, n, m, column=True):
    rng = np.random.default_rng(seed)
    F = np.eye(n) * 0.95 + rng.uniform(-0.05, 0.05, (n, n))
    G = rng.uniform(-0.3, 0.3, (n, n))
    Q = G @ G.T + 0.01 * np.eye(n)
    H = rng.uniform(-1, 1, (m, n))
    L = rng.uniform(-0.5, 0.5, (m, m))
    R = L @ L.T + 0.2 * np.eye(m)
    x0 = rng.uniform(-1, 1, n)
    # Columns (m, 1): filterpy's batch_filter passes H to update, which then does not
    # reshape z (a 1-D z would broadcast against H x).
    zs = [rng.normal(size=(m, 1)) if column else rng.normal(size=m) for _ in range(50)]

    def setup(kf):
        kf.x = x0.reshape(n, 1).copy() if column else x0.copy()
        kf.F, kf.Q, kf.H, kf.R = F.copy(), Q.copy(), H.copy(), R.copy()
        kf.P = np.eye(n) * 2.0

    return setup, zs


def test_tracker_step_by_step():
    ours, theirs = pair(2, 1, setup=tracker)
    rng = np.random.default_rng(1)
    for k in range(100):
        z = k + rng.normal() * 2.0
        ours.predict()
        theirs.predict()
        assert_same_state(ours, theirs, f"predict {k}")
        close(ours.x_prior, theirs.x_prior, "x_prior")
        close(ours.P_prior, theirs.P_prior, "P_prior")
        ours.update(z)
        theirs.update(z)
        assert_same_update(ours, theirs, f"update {k}")


@pytest.mark.parametrize("column", [True, False])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_six_states_three_measurements(seed, column):
    setup, zs = random_model(seed, 6, 3, column)
    ours, theirs = pair(6, 3, setup=setup)
    history = []
    for k, z in enumerate(zs):
        ours.predict()
        theirs.predict()
        if k % 7 == 3:
            ours.update(None)
            theirs.update(None)
            assert_same_state(ours, theirs, f"missing {k}")
            close(ours.y, theirs.y, "y after update(None)")
        else:
            z = z if column else z.copy()
            ours.update(z)
            theirs.update(z)
            assert_same_update(ours, theirs, f"step {k}")
        history.append(ours.x)
    # x is a new array after every step (as filterpy): the history is not aliased.
    assert len({id(x) for x in history}) == len(history)
    assert not np.allclose(history[0], history[-1])
    assert np.ndim(ours.x) == (2 if column else 1)


@pytest.mark.parametrize("seed", [4, 5])
def test_batch_filter_and_rts_smoother(seed):
    setup, zs = random_model(seed, 6, 3)
    zs = [None if k % 5 == 2 else z for k, z in enumerate(zs)]
    ours, theirs = pair(6, 3, setup=setup)
    a = ours.batch_filter(zs)
    b = theirs.batch_filter(zs)
    for name, x, y in zip(("means", "covariances", "means_p", "covariances_p"), a, b):
        close(x, y, name)
    assert_same_state(ours, theirs, "after batch")
    close(ours.x_prior, theirs.x_prior, "x_prior after batch")
    s_ours = ours.rts_smoother(a[0], a[1])
    s_theirs = theirs.rts_smoother(b[0], b[1])
    for name, x, y in zip(("x", "P", "K", "Pp"), s_ours, s_theirs):
        close(x, y, f"rts {name}")
    # The smoother changed the estimates (the comparison is not of two copies).
    assert np.max(np.abs(s_ours[0] - a[0])) > 1e-3


def test_batch_filter_slow_path_with_per_step_matrices():
    setup, zs = random_model(6, 4, 2)
    ours, theirs = pair(4, 2, setup=setup)
    Fs = [ours.F * (1.0 + 0.01 * k) for k in range(len(zs))]
    a = ours.batch_filter(zs, Fs=Fs, update_first=True)
    b = theirs.batch_filter(zs, Fs=Fs, update_first=True)
    for name, x, y in zip(("means", "covariances", "means_p", "covariances_p"), a, b):
        close(x, y, name)
    s_ours = ours.rts_smoother(a[0], a[1], Fs=Fs)
    s_theirs = theirs.rts_smoother(b[0], b[1], Fs=Fs)
    for name, x, y in zip(("x", "P", "K", "Pp"), s_ours, s_theirs):
        close(x, y, f"rts {name}")


def test_one_dimensional_state_in_batch():
    setup, zs = random_model(7, 3, 1, column=False)
    ours, theirs = pair(3, 1, setup=setup)
    zs = [float(z[0]) for z in zs]
    a = ours.batch_filter(zs)
    b = theirs.batch_filter(zs)
    assert a[0].shape == b[0].shape == (len(zs), 3)
    for name, x, y in zip(("means", "covariances", "means_p", "covariances_p"), a, b):
        close(x, y, name)


def test_control_input_and_overrides():
    def setup(kf):
        tracker(kf)
        kf.B = np.array([[0.5], [1.0]])

    ours, theirs = pair(2, 1, 1, setup=setup)
    for k in range(30):
        u = np.array([[0.1 * np.sin(k)]])
        Q = ours.Q * (2.0 if k % 3 == 0 else 1.0)
        ours.predict(u=u, Q=Q)
        theirs.predict(u=u, Q=Q)
        assert_same_state(ours, theirs, f"predict {k}")
        R = 3.0 if k % 4 == 0 else None
        ours.update(float(k) + 0.3, R=R)
        theirs.update(float(k) + 0.3, R=R)
        assert_same_update(ours, theirs, f"update {k}")


def test_in_place_edits_between_steps_are_seen():
    ours, theirs = pair(2, 1, setup=tracker)
    for k in range(10):
        for kf in (ours, theirs):
            kf.predict()
            kf.update(k * 1.5)
            kf.P[0, 0] += 0.5  # filterpy users edit arrays in place
            kf.F[0, 1] = 1.0 + 0.1 * k
            kf.R *= 1.01
        assert_same_update(ours, theirs, f"step {k}")


def test_update_correlated():
    def setup(kf):
        tracker(kf)
        # Q = q g g' (rank one, g = [1/2, 1]); M = c g is a valid Cov(w, v) iff
        # c^2 <= q R = 0.5.
        kf.M = 0.3 * np.array([[0.5], [1.0]])

    ours, theirs = pair(2, 1, setup=setup)
    for k in range(40):
        ours.predict()
        theirs.predict()
        ours.update_correlated(k + 0.5 * np.cos(k))
        theirs.update_correlated(k + 0.5 * np.cos(k))
        assert_same_update(ours, theirs, f"step {k}")


def test_invalid_cross_covariance_is_refused():
    def setup(kf):
        tracker(kf)
        kf.M = 0.9 * np.array([[0.5], [1.0]])  # c^2 = 0.81 > q R = 0.5

    ours, _ = pair(2, 1, setup=setup)
    ours.predict()
    before = ours.x.copy()
    with pytest.raises(EstimError, match="joint covariance"):
        ours.update_correlated(1.0)
    np.testing.assert_array_equal(ours.x, before)


def test_fading_memory():
    def setup(kf):
        tracker(kf)
        kf.alpha = 1.02

    ours, theirs = pair(2, 1, setup=setup)
    for k in range(20):
        ours.predict()
        theirs.predict()
        ours.update(float(k))
        theirs.update(float(k))
        assert_same_update(ours, theirs, f"step {k}")


def test_wrong_shapes_and_values_raise_estim_errors():
    kf = KalmanFilter(2, 1)
    tracker(kf)
    kf.F = np.eye(3)
    with pytest.raises(EstimError, match=r"F: expected shape \(2, 2\)"):
        kf.predict()
    kf.F = np.eye(2)
    with pytest.raises(EstimError, match="must be convertible"):
        kf.update(np.array([1.0, 2.0]))
    kf.R = np.array([[-1.0]])
    with pytest.raises(EstimError, match="measurement noise R"):
        kf.update(1.0)
    with pytest.raises(ValueError):
        KalmanFilter(0, 1)
    assert issubclass(EstimError, ValueError)
