"""A filterpy-compatible layer: ``from estim.filterpy import KalmanFilter``.

``KalmanFilter(dim_x, dim_z, dim_u=0)`` has filterpy's attributes (``x``, ``P``, ``F``,
``Q``, ``H``, ``R``, ``M``, ``B``, ``K``, ``y``, ``S``, ``SI``, ``z``, ``x_prior``,
``P_prior``, ``x_post``, ``P_post``, ``log_likelihood``, ``likelihood``,
``mahalanobis``, ``alpha``) and methods (``predict(u=None, B=None, F=None, Q=None)``,
``update(z, R=None, H=None)``, ``update_correlated(z, R=None, H=None)``,
``batch_filter(zs, ...)``, ``rts_smoother(Xs, Ps, Fs=None, Qs=None)``,
``get_prediction``, ``get_update``, ``residual_of``, ``measurement_of_state``,
``log_likelihood_of``) with filterpy's semantics: ``x`` is a column (dim_x, 1) by
default and a 1-D ``x`` is kept 1-D; ``x`` and ``P`` are new arrays after every step;
any attribute may be replaced or edited in place between steps.

The per-step work runs in Rust (``estim_core::dynamic::DynKalmanFilter``).
Differences from filterpy, on purpose:

- Covariances are checked where they change: a ``P``, ``Q`` or ``R`` that is not
  symmetric positive semidefinite raises :class:`estim.EstimError` instead of
  filtering on.
- ``update_correlated`` checks that ``[[Q_acc, M], [M', R]]`` is a covariance
  (``Q_acc``: the process noise accumulated since the last update) and raises
  ``EstimError`` when it is not; its posterior covariance uses the Joseph-like form
  (filterpy: ``P - K (H P + M')``; equal at the optimal gain up to round-off).
- A scalar ``Q``, ``R`` or ``P`` means that multiple of the identity (filterpy
  broadcasts a scalar over every entry, which for ``Q`` adds it to the off-diagonal
  covariances too).
- ``rts_smoother`` accepts ``us=`` (the control inputs of the forward pass): filterpy
  ignores ``B u`` in the smoother's predicted mean, which biases it when a control
  input was used.
- ``update(None)`` leaves the accumulated process noise to grow until the next
  measurement (it matters only for the joint check of ``update_correlated``).
"""

from copy import deepcopy

import numpy as np

from ._estim import EstimError, FilterpyKalmanFilter

__all__ = ["KalmanFilter", "EstimError"]


class KalmanFilter(FilterpyKalmanFilter):
    """filterpy's ``KalmanFilter(dim_x, dim_z, dim_u=0)`` on estim's Rust core.

    Attributes as filterpy's: ``x`` (dim_x, 1) zeros, ``P`` identity, ``F``
    identity, ``Q`` identity, ``H`` zeros (dim_z, dim_x), ``R`` identity, ``M``
    zeros (dim_x, dim_z), ``B`` None. See the module docstring for the few
    deliberate differences.
    """

    def __init__(self, dim_x, dim_z, dim_u=0):
        # The Rust base built everything in __new__; filterpy's own extras:
        self._I = np.eye(dim_x)
        self.inv = np.linalg.inv

    def batch_filter(self, zs, Fs=None, Qs=None, Hs=None, Rs=None, Bs=None, us=None,
                     update_first=False, saver=None):
        """Filter a sequence of measurements (None: missing), as filterpy's.

        Returns ``(means, covariances, means_predictions, covariances_predictions)``;
        ``means`` has shape (n, dim_x, 1), or (n, dim_x) when ``x`` is 1-D. Without
        per-step matrices, ``update_first`` or a ``saver`` the whole loop runs in Rust.
        """
        if (Fs is None and Qs is None and Hs is None and Rs is None and Bs is None
                and us is None and not update_first and saver is None):
            return self._batch_filter(_series(zs, self.dim_z))
        n = np.size(zs, 0)
        Fs = [self.F] * n if Fs is None else Fs
        Qs = [self.Q] * n if Qs is None else Qs
        Hs = [self.H] * n if Hs is None else Hs
        Rs = [self.R] * n if Rs is None else Rs
        Bs = [self.B] * n if Bs is None else Bs
        us = [None] * n if us is None else us
        shape = (n, self.dim_x) if np.ndim(self.x) == 1 else (n, self.dim_x, 1)
        means, means_p = np.zeros(shape), np.zeros(shape)
        covariances = np.zeros((n, self.dim_x, self.dim_x))
        covariances_p = np.zeros((n, self.dim_x, self.dim_x))
        for i, (z, F, Q, H, R, B, u) in enumerate(zip(zs, Fs, Qs, Hs, Rs, Bs, us)):
            if update_first:
                self.update(z, R=R, H=H)
                means[i], covariances[i] = self.x, self.P
                self.predict(u=u, B=B, F=F, Q=Q)
                means_p[i], covariances_p[i] = self.x, self.P
            else:
                self.predict(u=u, B=B, F=F, Q=Q)
                means_p[i], covariances_p[i] = self.x, self.P
                self.update(z, R=R, H=H)
                means[i], covariances[i] = self.x, self.P
            if saver is not None:
                saver.save()
        return means, covariances, means_p, covariances_p

    def rts_smoother(self, Xs, Ps, Fs=None, Qs=None, inv=np.linalg.inv, us=None, Bs=None):
        """Rauch-Tung-Striebel smoother over a filter's output, as filterpy's.

        Returns ``(x, P, K, Pp)``: smoothed means and covariances, smoother gains and
        predicted covariances. ``us`` (and ``Bs``, default ``self.B``): the control
        inputs of the forward pass, entry k the input of the predict into step k
        (filterpy has no such argument and leaves ``B u`` out).
        """
        if len(Xs) != len(Ps):
            raise ValueError("length of Xs and Ps must be the same")
        if Fs is None and Qs is None and us is None:
            return self._rts_smoother(Xs, Ps)
        n = Xs.shape[0]
        dim_x = Xs.shape[1]
        Fs = [self.F] * n if Fs is None else Fs
        Qs = [self.Q] * n if Qs is None else Qs
        Bs = [self.B] * n if Bs is None else Bs
        K = np.zeros((n, dim_x, dim_x))
        x, P, Pp = Xs.copy(), Ps.copy(), Ps.copy()
        for k in range(n - 2, -1, -1):
            Pp[k] = Fs[k + 1] @ P[k] @ Fs[k + 1].T + Qs[k + 1]
            K[k] = P[k] @ Fs[k + 1].T @ inv(Pp[k])
            predicted = Fs[k + 1] @ x[k]
            if us is not None and Bs[k + 1] is not None and us[k + 1] is not None:
                predicted = predicted + np.reshape(Bs[k + 1] @ np.atleast_1d(us[k + 1]),
                                                   np.shape(predicted))
            x[k] += K[k] @ (x[k + 1] - predicted)
            P[k] += K[k] @ (P[k + 1] - Pp[k]) @ K[k].T
        return x, P, K, Pp

    def get_prediction(self, u=None, B=None, F=None, Q=None):
        """The prior ``(x, P)`` of the next predict, without changing the filter."""
        B = self.B if B is None else B
        F = self.F if F is None else F
        Q = self.Q if Q is None else Q
        if np.isscalar(Q):
            Q = np.eye(self.dim_x) * Q
        x = F @ self.x
        if B is not None and u is not None:
            x = x + np.reshape(B @ np.atleast_1d(u), np.shape(x))
        P = self.alpha ** 2 * (F @ self.P @ F.T) + Q
        return x, P

    def get_update(self, z=None):
        """The posterior ``(x, P)`` of an update with ``z``, without changing the filter."""
        if z is None:
            return self.x, self.P
        clone = KalmanFilter(self.dim_x, self.dim_z, self.dim_u)
        for name in ("x", "P", "F", "Q", "H", "R", "M", "B"):
            setattr(clone, name, deepcopy(getattr(self, name)))
        clone.update(z)
        return clone.x, clone.P

    def residual_of(self, z):
        """z - H x_prior, without changing the filter."""
        z = _reshape_z(z, self.dim_z, np.ndim(self.x))
        return z - self.H @ self.x_prior

    def measurement_of_state(self, x):
        """H x."""
        return self.H @ x

    def log_likelihood_of(self, z):
        """ln N(z; H x, S) with the last S (call after update)."""
        if z is None:
            return np.log(np.finfo(float).tiny)
        z = np.asarray(z, dtype=float).reshape(-1)
        mean = np.asarray(self.H @ self.x, dtype=float).reshape(-1)
        S = np.asarray(self.S, dtype=float)
        d = z - mean
        _, logdet = np.linalg.slogdet(S)
        return float(-0.5 * (len(d) * np.log(2 * np.pi) + logdet + d @ np.linalg.solve(S, d)))

    def __repr__(self):
        return "\n".join([
            "estim.filterpy.KalmanFilter object",
            f"dim_x = {self.dim_x}", f"dim_z = {self.dim_z}", f"dim_u = {self.dim_u}",
            f"x = {self.x}", f"P = {self.P}", f"F = {self.F}", f"Q = {self.Q}",
            f"R = {self.R}", f"H = {self.H}", f"K = {self.K}", f"y = {self.y}",
            f"S = {self.S}", f"M = {self.M}", f"B = {self.B}", f"z = {self.z}",
            f"log-likelihood = {self.log_likelihood}", f"alpha = {self.alpha}",
        ])


def _reshape_z(z, dim_z, ndim):
    """filterpy.common.reshape_z."""
    z = np.atleast_2d(z)
    if z.shape[1] == dim_z:
        z = z.T
    if z.shape != (dim_z, 1):
        raise ValueError(f"z (shape {z.shape}) must be convertible to shape ({dim_z}, 1)")
    if ndim == 1:
        z = z[:, 0]
    if ndim == 0:
        z = z[0, 0]
    return z


def _series(zs, dim_z):
    """zs (a list with None entries, or an array) as a (T, dim_z) float array, NaN rows
    for the missing measurements."""
    if isinstance(zs, np.ndarray) and zs.dtype != object:
        arr = np.asarray(zs, dtype=float)
        return arr.reshape(arr.shape[0], dim_z) if arr.size == arr.shape[0] * dim_z else arr
    rows = np.full((len(zs), dim_z), np.nan)
    for i, z in enumerate(zs):
        if z is not None:
            rows[i] = _reshape_z(z, dim_z, 1)
    return rows
