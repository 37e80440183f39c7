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

``UnscentedKalmanFilter(dim_x, dim_z, dt, hx, fx, points, ...)`` with
``MerweScaledSigmaPoints(n, alpha, beta, kappa)`` or ``JulierSigmaPoints(n, kappa)`` has
filterpy's attributes (``x``, ``P``, ``Q``, ``R``, ``K``, ``y``, ``S``, ``SI``, ``z``,
``sigmas_f``, ``sigmas_h``, ``x_prior``, ``P_prior``, ``x_post``, ``P_post``,
``log_likelihood``, ``likelihood``, ``mahalanobis``, ``Wm``, ``Wc``) and methods
(``predict(dt=None, UT=None, fx=None, **fx_args)``, ``update(z, R=None, UT=None,
hx=None, **hx_args)``, ``batch_filter``, ``rts_smoother``, ``cross_variance``,
``compute_process_sigmas``) and hooks (``residual_x``, ``residual_z``, ``x_mean_fn``,
``z_mean_fn``, ``state_add``). The sigma points, their sums and the update run in Rust
(``estim_core::dynamic::DynUnscentedKalmanFilter``), calling ``fx``/``hx`` and the hooks
once per sigma point as filterpy does. With a user ``UT``, or a points object whose
``sqrt_method`` or ``subtract`` is not the default, that step runs filterpy's own
algorithm in NumPy. Differences from filterpy, on purpose:

- ``update`` draws its sigma points from the current ``x`` and ``P``: after a second
  ``update`` without a ``predict`` in between, or after ``x``/``P`` were edited, filterpy
  reuses the stale ``sigmas_f`` of the last predict (its ``compute_process_sigmas``
  docstring asks the user to refresh them by hand).
- ``rts_smoother`` uses ``Qs[k + 1]`` and ``dts[k + 1]`` between steps k and k + 1, the
  process noise and time step of the predict that produced step k + 1 in
  ``batch_filter``; filterpy ignores ``Qs`` (always ``self.Q``) and uses ``dts[k]``.
  With a constant Q and dt both agree.
- With a negative kappa whose centre covariance weight is negative (Julier's
  ``kappa = 3 - n`` for n > 3), covariances use Julier's centre-point-modified form,
  positive semidefinite by construction (estim-core's ``sigma_point`` docs); filterpy
  uses the plain weighted sum, which can be indefinite. For kappa >= 0 both agree.
- ``predict`` needs ``dt > 0`` and ``P``, ``Q``, ``R`` are checked (symmetric positive
  semidefinite) where they change; errors raise :class:`estim.EstimError`, and an
  exception raised by ``fx``, ``hx`` or a hook propagates unchanged, the filter left
  as it was.
"""

from copy import deepcopy

import numpy as np

from ._estim import EstimError, FilterpyKalmanFilter, _UnscentedCore

__all__ = [
    "KalmanFilter",
    "UnscentedKalmanFilter",
    "MerweScaledSigmaPoints",
    "JulierSigmaPoints",
    "EstimError",
]


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


def _cholesky_upper(A):
    """scipy.linalg.cholesky's default: upper U with U' U = A (NumPy only)."""
    return np.linalg.cholesky(A).T


class MerweScaledSigmaPoints:
    """filterpy's ``MerweScaledSigmaPoints(n, alpha, beta, kappa, sqrt_method=None,
    subtract=None)``: Van der Merwe's scaled sigma points, 2n + 1 of them, with weights
    ``Wm`` and ``Wc`` and ``sigma_points(x, P)`` in filterpy's order (x, then x + U_k,
    then x - U_k, U' U = (n + lambda) P)."""

    def __init__(self, n, alpha, beta, kappa, sqrt_method=None, subtract=None):
        self.n, self.alpha, self.beta, self.kappa = n, alpha, beta, kappa
        self.sqrt = _cholesky_upper if sqrt_method is None else sqrt_method
        self.subtract = np.subtract if subtract is None else subtract
        lambda_ = alpha ** 2 * (n + kappa) - n
        c = 0.5 / (n + lambda_)
        self.Wm = np.full(2 * n + 1, c)
        self.Wc = np.full(2 * n + 1, c)
        self.Wm[0] = lambda_ / (n + lambda_)
        self.Wc[0] = lambda_ / (n + lambda_) + (1 - alpha ** 2 + beta)

    def num_sigmas(self):
        """2n + 1."""
        return 2 * self.n + 1

    def sigma_points(self, x, P):
        """The (2n + 1, n) sigma points of (x, P)."""
        return _sigma_points(self, x, P, self.alpha ** 2 * (self.n + self.kappa))

    def _transform(self):
        return (self.alpha, self.beta, self.kappa)


class JulierSigmaPoints:
    """filterpy's ``JulierSigmaPoints(n, kappa=0., sqrt_method=None, subtract=None)``:
    Julier's sigma points (``Wm = Wc``, centre weight kappa / (n + kappa))."""

    def __init__(self, n, kappa=0.0, sqrt_method=None, subtract=None):
        self.n, self.kappa = n, kappa
        self.sqrt = _cholesky_upper if sqrt_method is None else sqrt_method
        self.subtract = np.subtract if subtract is None else subtract
        self.Wm = np.full(2 * n + 1, 0.5 / (n + kappa))
        self.Wm[0] = kappa / (n + kappa)
        self.Wc = self.Wm

    def num_sigmas(self):
        """2n + 1."""
        return 2 * self.n + 1

    def sigma_points(self, x, P):
        """The (2n + 1, n) sigma points of (x, P)."""
        return _sigma_points(self, x, P, self.n + self.kappa)

    def _transform(self):
        return (1.0, 0.0, self.kappa)


def _sigma_points(points, x, P, spread):
    n = points.n
    if np.isscalar(x):
        x = np.asarray([x])
    x = np.asarray(x, dtype=float).reshape(-1)
    if np.isscalar(P):
        P = np.eye(n) * P
    U = points.sqrt(spread * np.asarray(P, dtype=float))
    sigmas = np.zeros((2 * n + 1, n))
    sigmas[0] = x
    for k in range(n):
        sigmas[k + 1] = points.subtract(x, -U[k])
        sigmas[n + k + 1] = points.subtract(x, U[k])
    return sigmas


def _unscented_transform(sigmas, Wm, Wc, noise_cov=None, mean_fn=None, residual_fn=None):
    """filterpy's ``unscented_transform`` (the NumPy path)."""
    x = np.dot(Wm, sigmas) if mean_fn is None else mean_fn(sigmas, Wm)
    P = np.zeros((sigmas.shape[1], sigmas.shape[1]))
    for k in range(sigmas.shape[0]):
        y = residual_fn(sigmas[k], x)
        P += Wc[k] * np.outer(y, y)
    if noise_cov is not None:
        P += noise_cov
    return x, P


class UnscentedKalmanFilter:
    """filterpy's ``UnscentedKalmanFilter(dim_x, dim_z, dt, hx, fx, points, sqrt_fn=None,
    x_mean_fn=None, z_mean_fn=None, residual_x=None, residual_z=None, state_add=None)``
    on estim's Rust core. ``x`` starts at zeros (dim_x,), ``P``, ``Q`` and ``R`` at the
    identity. See the module docstring for the differences from filterpy.
    """

    def __init__(self, dim_x, dim_z, dt, hx, fx, points, sqrt_fn=None, x_mean_fn=None,
                 z_mean_fn=None, residual_x=None, residual_z=None, state_add=None):
        self.x = np.zeros(dim_x)
        self.P = np.eye(dim_x)
        self.Q = np.eye(dim_x)
        self.R = np.eye(dim_z)
        self._dim_x, self._dim_z, self._dt = dim_x, dim_z, dt
        self.points_fn = points
        self._num_sigmas = points.num_sigmas()
        self.hx, self.fx = hx, fx
        self.x_mean, self.z_mean = x_mean_fn, z_mean_fn
        self.msqrt = _cholesky_upper if sqrt_fn is None else sqrt_fn
        self.Wm, self.Wc = points.Wm, points.Wc
        self.residual_x = np.subtract if residual_x is None else residual_x
        self.residual_z = np.subtract if residual_z is None else residual_z
        self.state_add = np.add if state_add is None else state_add
        self.sigmas_f = np.zeros((self._num_sigmas, dim_x))
        self.sigmas_h = np.zeros((self._num_sigmas, dim_z))
        self.K = np.zeros((dim_x, dim_z))
        self.y = np.zeros(dim_z)
        self.z = np.array([[None] * dim_z]).T
        self.S = np.zeros((dim_z, dim_z))
        self.SI = np.zeros((dim_z, dim_z))
        self.inv = np.linalg.inv
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()
        self.x_post, self.P_post = self.x.copy(), self.P.copy()
        self._log_likelihood = np.log(np.finfo(float).tiny)
        self._likelihood = np.finfo(float).tiny
        self._mahalanobis = None
        transform = getattr(points, "_transform", None)
        if transform is None:
            if hasattr(points, "alpha") and hasattr(points, "beta"):
                transform = (points.alpha, points.beta, points.kappa)
            elif hasattr(points, "kappa"):
                transform = (1.0, 0.0, points.kappa)
        else:
            transform = transform()
        # The Rust path needs estim's sigma points: Merwe or Julier parameters, the
        # Cholesky square root and the plain subtraction.
        native = (
            transform is not None
            and getattr(points, "sqrt", _cholesky_upper) in (_cholesky_upper, _scipy_cholesky())
            and getattr(points, "subtract", np.subtract) is np.subtract
        )
        self._core = _UnscentedCore(dim_x, dim_z, *transform) if native else None

    @property
    def dim_x(self):
        """Number of states."""
        return self._dim_x

    @property
    def dim_z(self):
        """Number of measurements."""
        return self._dim_z

    def predict(self, dt=None, UT=None, fx=None, **fx_args):
        """Prior over ``dt`` (default: the constructor's) through ``fx(x, dt, **fx_args)``.

        ``x``, ``P`` become the prior; ``sigmas_f`` the sigma points of the prior (the
        points ``update`` maps through ``hx``).
        """
        dt = self._dt if dt is None else dt
        fx = self.fx if fx is None else fx
        if UT is None and self._core is not None:
            self.x, self.P = self._core.predict(
                self.x, self.P, self.Q, float(dt), fx, fx_args or None,
                self.residual_x, self.x_mean, self.Wm)
        else:
            UT = _unscented_transform if UT is None else UT
            self.compute_process_sigmas(dt, fx, **fx_args)
            self.x, self.P = UT(self.sigmas_f, self.Wm, self.Wc, self.Q, self.x_mean,
                                self.residual_x)
        self.sigmas_f = self.points_fn.sigma_points(self.x, self.P)
        self.x_prior, self.P_prior = np.copy(self.x), np.copy(self.P)

    def update(self, z, R=None, UT=None, hx=None, **hx_args):
        """Posterior given ``z`` through ``hx(x, **hx_args)`` (``None``: no
        measurement, ``x``/``P`` unchanged)."""
        if z is None:
            self.z = np.array([[None] * self._dim_z]).T
            self.x_post, self.P_post = self.x.copy(), self.P.copy()
            return
        hx = self.hx if hx is None else hx
        if R is None:
            R = self.R
        elif np.isscalar(R):
            R = np.eye(self._dim_z) * R
        x_prior = self.x
        if UT is None and self._core is not None:
            out = self._core.update(self.x, self.P, z, R, hx, hx_args or None,
                                    self.residual_z, self.z_mean, self.Wm)
            self.x, self.P = out["x"], out["P"]
            self.K, self.y, self.S, self.SI = out["K"], out["y"], out["S"], out["SI"]
            self.sigmas_h = out["sigmas_h"]
            self._log_likelihood = out["log_likelihood"]
        else:
            UT = _unscented_transform if UT is None else UT
            self.sigmas_f = self.points_fn.sigma_points(self.x, self.P)
            self.sigmas_h = np.atleast_2d([hx(s, **hx_args) for s in self.sigmas_f])
            zp, self.S = UT(self.sigmas_h, self.Wm, self.Wc, R, self.z_mean,
                            self.residual_z)
            self.SI = self.inv(self.S)
            Pxz = self.cross_variance(self.x, zp, self.sigmas_f, self.sigmas_h)
            self.K = np.dot(Pxz, self.SI)
            self.y = self.residual_z(z, zp)
            self.x = x_prior + np.dot(self.K, self.y)
            self.P = self.P - np.dot(self.K, np.dot(self.S, self.K.T))
            self._log_likelihood = None
        if self.state_add is not np.add:
            self.x = self.state_add(x_prior, np.dot(self.K, self.y))
        self.z = deepcopy(z)
        self.x_post, self.P_post = self.x.copy(), self.P.copy()
        self._likelihood = None
        self._mahalanobis = None

    def cross_variance(self, x, z, sigmas_f, sigmas_h):
        """sum_i Wc_i residual_x(sigmas_f[i], x) residual_z(sigmas_h[i], z)'."""
        Pxz = np.zeros((sigmas_f.shape[1], sigmas_h.shape[1]))
        for i in range(sigmas_f.shape[0]):
            Pxz += self.Wc[i] * np.outer(self.residual_x(sigmas_f[i], x),
                                         self.residual_z(sigmas_h[i], z))
        return Pxz

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        """``sigmas_f`` = fx of the sigma points of (x, P) (filterpy's helper)."""
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = np.array([fx(s, dt, **fx_args) for s in sigmas], dtype=float)

    def batch_filter(self, zs, Rs=None, dts=None, UT=None, saver=None):
        """predict then update for each z of ``zs`` (None: missing); returns
        ``(means, covariances)``, means of shape (T, dim_x)."""
        n = len(zs)
        Rs = [self.R] * n if Rs is None else Rs
        dts = [self._dt] * n if dts is None else ([dts] * n if np.isscalar(dts) else dts)
        shape = (n, self._dim_x) if np.ndim(self.x) == 1 else (n, self._dim_x, 1)
        means = np.zeros(shape)
        covariances = np.zeros((n, self._dim_x, self._dim_x))
        for i, (z, r, dt) in enumerate(zip(zs, Rs, dts)):
            self.predict(dt=dt, UT=UT)
            self.update(z, r, UT=UT)
            means[i, :] = self.x
            covariances[i, :, :] = self.P
            if saver is not None:
                saver.save()
        return means, covariances

    def rts_smoother(self, Xs, Ps, Qs=None, dts=None, UT=None):
        """Saerkkae's unscented RTS smoother over filtered ``(Xs, Ps)``; returns
        ``(xs, Ps, Ks)``. Between steps k and k + 1 it uses ``Qs[k + 1]`` (default
        ``self.Q``) and ``dts[k + 1]`` (see the module docstring)."""
        if len(Xs) != len(Ps):
            raise ValueError("Xs and Ps must have the same length")
        n = len(Xs)
        dts = [self._dt] * n if dts is None else ([dts] * n if np.isscalar(dts) else dts)
        if UT is None and self._core is not None:
            Qs_arr = None if Qs is None else np.asarray(
                [np.eye(self._dim_x) * q if np.isscalar(q) else q for q in Qs], dtype=float)
            xs, ps, ks = self._core.rts_smoother(
                np.asarray(Xs, dtype=float), np.asarray(Ps, dtype=float), self.Q, Qs_arr,
                [float(dt) for dt in dts], self.fx, self.residual_x, self.x_mean, self.Wm)
            return xs.reshape(np.shape(Xs)), ps, ks
        UT = _unscented_transform if UT is None else UT
        Qs = [self.Q] * n if Qs is None else Qs
        Ks = np.zeros((n, self._dim_x, self._dim_x))
        xs, ps = np.array(Xs, dtype=float), np.array(Ps, dtype=float)
        for k in reversed(range(n - 1)):
            sigmas = self.points_fn.sigma_points(xs[k], ps[k])
            sigmas_f = np.array([self.fx(s, dts[k + 1]) for s in sigmas], dtype=float)
            xb, Pb = UT(sigmas_f, self.Wm, self.Wc, Qs[k + 1], self.x_mean, self.residual_x)
            Pxb = 0
            for i in range(self._num_sigmas):
                Pxb += self.Wc[i] * np.outer(self.residual_x(sigmas[i], Xs[k]),
                                             self.residual_x(sigmas_f[i], xb))
            K = np.dot(Pxb, self.inv(Pb))
            xs[k] += np.dot(K, self.residual_x(xs[k + 1], xb))
            ps[k] += np.dot(K, ps[k + 1] - Pb).dot(K.T)
            Ks[k] = K
        return xs, ps, Ks

    @property
    def log_likelihood(self):
        """ln N(y; 0, S) of the last measurement."""
        if self._log_likelihood is None:
            d = np.asarray(self.y, dtype=float).reshape(-1)
            _, logdet = np.linalg.slogdet(self.S)
            self._log_likelihood = float(-0.5 * (len(d) * np.log(2 * np.pi) + logdet
                                                 + d @ np.linalg.solve(self.S, d)))
        return self._log_likelihood

    @property
    def likelihood(self):
        """exp(log_likelihood), at least the smallest positive float."""
        if self._likelihood is None:
            self._likelihood = np.exp(self.log_likelihood)
            if self._likelihood == 0:
                self._likelihood = np.finfo(float).tiny
        return self._likelihood

    @property
    def mahalanobis(self):
        """sqrt(y' S^-1 y) of the last measurement."""
        if self._mahalanobis is None:
            self._mahalanobis = float(np.sqrt(float(np.dot(np.dot(self.y.T, self.SI),
                                                              self.y))))
        return self._mahalanobis


def _scipy_cholesky():
    """scipy.linalg.cholesky when SciPy is installed (filterpy's points use it)."""
    try:
        from scipy.linalg import cholesky
    except ImportError:
        return _cholesky_upper
    return cholesky
