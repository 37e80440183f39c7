"""estim: Kalman filtering with correlated process and measurement noise.

A Rust core (the ``estim-core`` crate) with sizes taken from the arrays:

- :class:`KalmanFilter` -- ``KalmanFilter(F, Q, H, R, x0, P0)`` with ``predict()`` and
  ``update(z, M=None)`` returning an :class:`UpdateReport` (accepted, innovation, S,
  K, nis, log_likelihood, joint_min_eigenvalue);
- :class:`ExtendedKalmanFilter` -- ``ExtendedKalmanFilter(Q, R, x0, P0)`` with
  ``predict(f, F, dt)`` and ``update(z, h, H, M=None)`` taking Python callables for f,
  its Jacobian F(x, dt), h and H(x); ``filter`` and ``smooth`` over a series;
- :func:`kalman_filter` and :func:`kalman_smoother` over a whole series (``zs`` of
  shape (T, m), NaN rows or ``mask=False`` for missing measurements), returning NumPy
  arrays; the smoother returns the filtered and the smoothed estimates of one pass;
- :func:`joint_check` -- is ``[[Q, M], [M', R]]`` a covariance at all?
- :func:`nees`, :func:`nis` -- consistency statistics;
- :func:`em` -- expectation-maximisation of F, H, Q, R, x0, P0 and the offsets of a
  linear-Gaussian model (pykalman's ``em``), returning an :class:`EmResult`;
- :func:`fit_noise` -- maximum-likelihood scales (or diagonals) of Q and R with
  standard errors from the observed information, returning a :class:`NoiseFit`;
- :func:`navigate` -- the INS/DVL navigator on a survey's files (IMU, DVL velocity,
  beams or PD0, depth, fixes, a vehicle TOML, optionally a truth CSV), its solution,
  1-sigmas and evaluation returned as NumPy arrays;
- :mod:`estim.filterpy` -- ``from estim.filterpy import KalmanFilter``: filterpy's
  ``KalmanFilter`` API on the same core, and its ``UnscentedKalmanFilter`` with
  ``MerweScaledSigmaPoints`` / ``JulierSigmaPoints`` (Python ``fx``, ``hx`` and hooks
  called from the Rust sigma-point filter).

Errors are :class:`EstimError` (a ``ValueError``) naming the quantity at fault.

With a cross-covariance ``M = Cov(w_{k-1}, v_k)`` the update is (Simon, *Optimal State
Estimation*, 2006, sec. 7.1)::

    S = H P H' + H M + M' H' + R,   K = (P H' + M) S^-1

and the joint covariance ``[[Q_acc, M], [M', R]]`` is checked before it is used
(``joint_check='reject'`` by default; ``'report'`` uses it and reports the margin).
"""

from ._estim import (
    EmResult,
    EstimError,
    ExtendedKalmanFilter,
    FilterResult,
    KalmanFilter,
    NoiseFit,
    SmootherResult,
    UpdateReport,
    em,
    fit_noise,
    joint_check,
    kalman_filter,
    kalman_smoother,
    navigate,
    nees,
    nis,
)

__all__ = [
    "EmResult",
    "EstimError",
    "ExtendedKalmanFilter",
    "FilterResult",
    "KalmanFilter",
    "NoiseFit",
    "SmootherResult",
    "UpdateReport",
    "em",
    "fit_noise",
    "joint_check",
    "kalman_filter",
    "kalman_smoother",
    "navigate",
    "nees",
    "nis",
]
__version__ = "0.1.0"
