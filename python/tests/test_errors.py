"""Nothing panics across the boundary: malformed calls of every entry point raise
estim.EstimError (a ValueError) or TypeError, never pyo3's PanicException (which is
not an Exception subclass and would escape an `except Exception`)."""

import numpy as np
import pytest

import estim
from estim import EstimError
from estim.filterpy import KalmanFilter as FilterpyKF

GOOD = dict(F=np.eye(2), Q=np.eye(2) * 0.1, H=np.array([[1.0, 0.0]]), R=np.eye(1),
            x0=np.zeros(2), P0=np.eye(2))

BAD_VALUES = [
    None, "abc", [], np.zeros((0, 0)), np.zeros((2, 2, 2)), np.full((2, 2), np.nan),
    np.full((2, 2), np.inf), np.eye(3), np.ones(7), [[1, 2], [3]], object(), 1e308,
    np.array([[1.0, 2.0], [3.0, 4.0]]), -np.eye(2), np.zeros((2, 1)),
]


def call(fn, *args, **kwargs):
    """Run fn; any exception must be an ordinary one (EstimError, ValueError, TypeError)."""
    try:
        fn(*args, **kwargs)
    except (EstimError, ValueError, TypeError):
        pass


@pytest.mark.parametrize("name", list(GOOD))
def test_constructor_and_functions_with_bad_arguments(name):
    zs = np.ones((4, 1))
    for bad in BAD_VALUES:
        kw = dict(GOOD, **{name: bad})
        call(estim.KalmanFilter, kw["F"], kw["Q"], kw["H"], kw["R"], kw["x0"], kw["P0"])
        call(estim.kalman_filter, zs=zs, **kw)
        call(estim.kalman_smoother, zs=zs, **kw)
        call(estim.kalman_smoother, zs=zs, M=bad, **GOOD)
        call(estim.kalman_filter, zs=bad, **GOOD)
        call(estim.kalman_filter, zs=zs, mask=bad, **GOOD)
        call(estim.joint_check, bad, np.zeros((2, 1)), np.eye(1))
        call(estim.joint_check, np.eye(2), bad, np.eye(1))
        call(estim.nees, bad, np.zeros(2), np.eye(2))
        call(estim.nis, np.zeros(2), bad)


def test_methods_with_bad_arguments():
    kf = estim.KalmanFilter(**{k.replace("0", "0"): v for k, v in GOOD.items()})
    for bad in BAD_VALUES:
        call(kf.predict, bad)
        call(kf.update, bad)
        call(kf.update, np.ones(1), bad)
        call(kf.filter, bad)
        call(kf.smooth, bad)
    kf.predict()
    assert np.all(np.isfinite(kf.x))


@pytest.mark.parametrize("attribute", ["x", "P", "F", "Q", "H", "R", "M", "B"])
def test_filterpy_layer_with_bad_attributes(attribute):
    for bad in BAD_VALUES:
        kf = FilterpyKF(2, 1)
        kf.H = np.array([[1.0, 0.0]])
        setattr(kf, attribute, bad)
        call(kf.predict)
        call(kf.predict, u=np.ones(1))
        call(kf.update, 1.0)
        call(kf.update_correlated, 1.0)
        call(kf.batch_filter, [1.0, None, 2.0])
        call(kf.rts_smoother, np.zeros((3, 2, 1)), np.stack([np.eye(2)] * 3))
    kf = FilterpyKF(2, 1)
    for bad in BAD_VALUES:
        call(kf.update, bad)
        call(kf.batch_filter, bad)
        call(kf.rts_smoother, bad, bad)
        call(kf.predict, Q=bad)
        call(kf.update, 1.0, R=bad, H=bad)
