"""Type stubs of the extension module estim._estim (re-exported by estim)."""

import os
from typing import Any, Callable, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

ArrayLike = npt.ArrayLike
FloatArray = npt.NDArray[np.float64]

class EstimError(ValueError):
    """An input estim refused or a numerical failure, naming the quantity."""

class UpdateReport:
    """Everything one update attempt of KalmanFilter produced."""

    @property
    def accepted(self) -> bool: ...
    @property
    def innovation(self) -> FloatArray: ...
    @property
    def S(self) -> FloatArray: ...
    @property
    def K(self) -> Optional[FloatArray]: ...
    @property
    def nis(self) -> float: ...
    @property
    def log_likelihood(self) -> float: ...
    @property
    def joint_min_eigenvalue(self) -> Optional[float]: ...

class FilterResult:
    """A filtered series: x (T, n), P (T, n, n), nis (T,), accepted, log_likelihood."""

    @property
    def x(self) -> FloatArray: ...
    @property
    def P(self) -> FloatArray: ...
    @property
    def nis(self) -> FloatArray: ...
    @property
    def accepted(self) -> list[bool]: ...
    @property
    def log_likelihood(self) -> float: ...

class SmootherResult:
    """Smoothed (x, P, x0, P0) and filtered (x_filtered, P_filtered) estimates of one pass."""

    @property
    def x(self) -> FloatArray: ...
    @property
    def P(self) -> FloatArray: ...
    @property
    def x_filtered(self) -> FloatArray: ...
    @property
    def P_filtered(self) -> FloatArray: ...
    @property
    def x0(self) -> FloatArray: ...
    @property
    def P0(self) -> FloatArray: ...
    @property
    def nis(self) -> FloatArray: ...
    @property
    def log_likelihood(self) -> float: ...

class KalmanFilter:
    """Linear Kalman filter with sizes from the arrays and the correlated update."""

    def __init__(
        self,
        F: ArrayLike,
        Q: ArrayLike,
        H: ArrayLike,
        R: ArrayLike,
        x0: ArrayLike,
        P0: ArrayLike,
        B: Optional[ArrayLike] = None,
        joint_check: str = "reject",
        nis_gate: Optional[float] = None,
    ) -> None: ...
    def predict(self, u: Optional[ArrayLike] = None) -> None: ...
    def update(self, z: ArrayLike, M: Optional[ArrayLike] = None) -> UpdateReport: ...
    def filter(
        self, zs: ArrayLike, M: Optional[ArrayLike] = None, mask: Optional[Sequence[bool]] = None
    ) -> FilterResult: ...
    def smooth(
        self, zs: ArrayLike, M: Optional[ArrayLike] = None, mask: Optional[Sequence[bool]] = None
    ) -> SmootherResult: ...
    @property
    def x(self) -> FloatArray: ...
    @property
    def P(self) -> FloatArray: ...
    @property
    def log_likelihood(self) -> float: ...

def kalman_filter(
    F: ArrayLike,
    Q: ArrayLike,
    H: ArrayLike,
    R: ArrayLike,
    x0: ArrayLike,
    P0: ArrayLike,
    zs: ArrayLike,
    M: Optional[ArrayLike] = None,
    mask: Optional[Sequence[bool]] = None,
    joint_check: str = "reject",
) -> FilterResult: ...
def kalman_smoother(
    F: ArrayLike,
    Q: ArrayLike,
    H: ArrayLike,
    R: ArrayLike,
    x0: ArrayLike,
    P0: ArrayLike,
    zs: ArrayLike,
    M: Optional[ArrayLike] = None,
    mask: Optional[Sequence[bool]] = None,
    joint_check: str = "reject",
) -> SmootherResult: ...
def joint_check(Q: ArrayLike, M: ArrayLike, R: ArrayLike) -> float: ...
def nees(x_true: ArrayLike, x_est: ArrayLike, P: ArrayLike) -> Union[float, FloatArray]: ...
def nis(innovation: ArrayLike, S: ArrayLike) -> Union[float, FloatArray]: ...

class ExtendedKalmanFilter:
    """Extended Kalman filter: x_k = f(x_{k-1}, dt) + w, z_k = h(x_k) + v; f, its
    Jacobian F(x, dt), h and its Jacobian H(x) are callables given to each call;
    optional M = Cov(w, v) per update (the correlated update, joint check first)."""
    def __init__(
        self,
        Q: ArrayLike,
        R: ArrayLike,
        x0: ArrayLike,
        P0: ArrayLike,
        joint_check: str = "reject",
        nis_gate: Optional[float] = None,
    ) -> None: ...
    def predict(
        self,
        f: Callable[[FloatArray, float], ArrayLike],
        F: Callable[[FloatArray, float], ArrayLike],
        dt: float = 1.0,
    ) -> None: ...
    def update(
        self,
        z: ArrayLike,
        h: Callable[[FloatArray], ArrayLike],
        H: Callable[[FloatArray], ArrayLike],
        M: Optional[ArrayLike] = None,
    ) -> UpdateReport: ...
    def filter(
        self,
        zs: ArrayLike,
        f: Callable[[FloatArray, float], ArrayLike],
        F: Callable[[FloatArray, float], ArrayLike],
        h: Callable[[FloatArray], ArrayLike],
        H: Callable[[FloatArray], ArrayLike],
        dt: Optional[Union[float, ArrayLike]] = None,
        M: Optional[ArrayLike] = None,
    ) -> FilterResult: ...
    def smooth(
        self,
        zs: ArrayLike,
        f: Callable[[FloatArray, float], ArrayLike],
        F: Callable[[FloatArray, float], ArrayLike],
        h: Callable[[FloatArray], ArrayLike],
        H: Callable[[FloatArray], ArrayLike],
        dt: Optional[Union[float, ArrayLike]] = None,
        M: Optional[ArrayLike] = None,
    ) -> SmootherResult: ...
    @property
    def x(self) -> FloatArray: ...
    @property
    def P(self) -> FloatArray: ...
    @property
    def log_likelihood(self) -> float: ...

class EmResult:
    """The model fitted by em and its log-likelihood per iteration."""
    @property
    def F(self) -> FloatArray: ...
    @property
    def H(self) -> FloatArray: ...
    @property
    def Q(self) -> FloatArray: ...
    @property
    def R(self) -> FloatArray: ...
    @property
    def x0(self) -> FloatArray: ...
    @property
    def P0(self) -> FloatArray: ...
    @property
    def b(self) -> FloatArray:
        """(n,) constant, or (T - 1, n) per step (kept as given when b is not learned)."""
    @property
    def d(self) -> FloatArray: ...
    @property
    def log_likelihoods(self) -> FloatArray:
        """After k iterations, k = 0 .. iterations; element 0 is the given model's."""
    @property
    def iterations(self) -> int: ...
    @property
    def stopped(self) -> Optional[str]:
        """None when every iteration ran; else the iteration and the check that refused it."""

def em(
    zs: ArrayLike,
    F: Optional[ArrayLike] = None,
    H: Optional[ArrayLike] = None,
    Q: Optional[ArrayLike] = None,
    R: Optional[ArrayLike] = None,
    x0: Optional[ArrayLike] = None,
    P0: Optional[ArrayLike] = None,
    b: Optional[ArrayLike] = None,
    d: Optional[ArrayLike] = None,
    em_vars: Optional[Union[str, Sequence[str]]] = None,
    n_iter: int = 10,
    dim_x: Optional[int] = None,
) -> EmResult:
    """EM of a linear-Gaussian model (pykalman's em): x_0 ~ N(x0, P0),
    x_{t+1} = F x_t + b_t + w_t, z_t = H x_t + d + v_t; epoch 0 measured at x_0; NaN
    rows missing (a row only partly NaN is an error). Defaults: F, H, Q, R, P0
    identity, x0, b, d zero; em_vars Q, R, x0, P0."""

class NoiseFit:
    """The maximum-likelihood noise of fit_noise."""
    @property
    def Q(self) -> FloatArray: ...
    @property
    def R(self) -> FloatArray: ...
    @property
    def theta(self) -> FloatArray:
        """[q, r] (scales) or [diag Q; diag R] (diagonals)."""
    @property
    def standard_errors(self) -> Optional[FloatArray]:
        """From the observed information; None when it is not positive definite."""
    @property
    def covariance(self) -> Optional[FloatArray]: ...
    @property
    def information(self) -> FloatArray: ...
    @property
    def gradient(self) -> FloatArray: ...
    @property
    def log_likelihood(self) -> float: ...
    @property
    def converged(self) -> bool: ...
    @property
    def stop(self) -> str: ...
    @property
    def parameters(self) -> str:
        """'scales' or 'diagonals'."""

def fit_noise(
    F: ArrayLike,
    Q: ArrayLike,
    H: ArrayLike,
    R: ArrayLike,
    x0: ArrayLike,
    P0: ArrayLike,
    zs: ArrayLike,
    diagonal: bool = False,
) -> NoiseFit:
    """Maximum-likelihood noise of x_k = F x_{k-1} + w_k, z_k = H x_k + v_k (predict,
    then update, as kalman_filter): Q = q Q0, R = r R0 with q, r > 0, or with
    diagonal=True the diagonals of Q and R (off-diagonal terms zero). NaN rows of zs
    are missing. Standard errors from the exact observed information."""

PathLike = Union[str, "os.PathLike[str]"]

def navigate(
    imu: PathLike,
    dvl: Optional[PathLike] = None,
    beams: Optional[PathLike] = None,
    pd0: Optional[PathLike] = None,
    depth: Optional[PathLike] = None,
    fixes: Optional[PathLike] = None,
    vehicle: Optional[PathLike] = None,
    truth: Optional[PathLike] = None,
    init_from_truth: bool = False,
    rate_hz: Optional[float] = None,
) -> dict[str, Any]:
    """The INS/DVL navigator on a survey's files (the loader and navigator of
    `estim navigate`). Returns a dict of NumPy arrays, one row per solution: time_s,
    kind, latitude_deg, longitude_deg, depth_m, velocity_ned_mps (n, 3),
    attitude_deg (n, 3: roll, pitch, heading), acc_bias_mps2, gyro_bias_radps, the
    1-sigmas position_sigma_m, velocity_sigma_mps, attitude_sigma_deg,
    acc_bias_sigma_mps2, gyro_bias_sigma_radps; epoch_s; dvl, depth, fixes update
    counts; dvl_nis, dvl_nis_time_s; with a truth, evaluation (dict) and errors
    (time_s, error and sigma (m, 9), nees), else None. Raises EstimError for bad
    input (file and line, or key) and for a diverged or failed run."""

class FilterpyKalmanFilter:
    """The Rust base of estim.filterpy.KalmanFilter."""

    dim_x: int
    dim_z: int
    dim_u: int
    x: Any
    P: Any
    F: Any
    Q: Any
    H: Any
    R: Any
    M: Any
    B: Any
    z: Any
    alpha: float
    def __init__(self, dim_x: int, dim_z: int, dim_u: int = 0) -> None: ...
    def predict(
        self,
        u: Optional[ArrayLike] = None,
        B: Optional[ArrayLike] = None,
        F: Optional[ArrayLike] = None,
        Q: Optional[ArrayLike] = None,
    ) -> None: ...
    def update(
        self, z: Optional[ArrayLike], R: Optional[ArrayLike] = None, H: Optional[ArrayLike] = None
    ) -> None: ...
    def update_correlated(
        self, z: Optional[ArrayLike], R: Optional[ArrayLike] = None, H: Optional[ArrayLike] = None
    ) -> None: ...
    def _batch_filter(self, zs: ArrayLike) -> Tuple[FloatArray, FloatArray, FloatArray, FloatArray]: ...
    def _rts_smoother(
        self, Xs: ArrayLike, Ps: ArrayLike
    ) -> Tuple[FloatArray, FloatArray, FloatArray, FloatArray]: ...
    @property
    def y(self) -> FloatArray: ...
    @property
    def S(self) -> FloatArray: ...
    @property
    def SI(self) -> FloatArray: ...
    @property
    def K(self) -> FloatArray: ...
    @property
    def x_prior(self) -> FloatArray: ...
    @property
    def P_prior(self) -> FloatArray: ...
    @property
    def x_post(self) -> FloatArray: ...
    @property
    def P_post(self) -> FloatArray: ...
    @property
    def log_likelihood(self) -> float: ...
    @property
    def likelihood(self) -> float: ...
    @property
    def mahalanobis(self) -> float: ...

class _UnscentedCore:
    """The Rust half of estim.filterpy.UnscentedKalmanFilter (estim-core's
    DynUnscentedKalmanFilter): sigma points, sums and update, calling the Python fx / hx
    and hooks once per sigma point. An exception a callable raises propagates as it is."""

    def __init__(self, dim_x: int, dim_z: int, alpha: float, beta: float, kappa: float) -> None: ...
    def predict(
        self,
        x: ArrayLike,
        P: ArrayLike,
        Q: ArrayLike,
        dt: float,
        fx: Any,
        kwargs: Optional[dict],
        residual_x: Optional[Any],
        x_mean_fn: Optional[Any],
        Wm: ArrayLike,
    ) -> Tuple[FloatArray, FloatArray]: ...
    def update(
        self,
        x: ArrayLike,
        P: ArrayLike,
        z: ArrayLike,
        R: ArrayLike,
        hx: Any,
        kwargs: Optional[dict],
        residual_z: Optional[Any],
        z_mean_fn: Optional[Any],
        Wm: ArrayLike,
    ) -> dict: ...
    def rts_smoother(
        self,
        Xs: ArrayLike,
        Ps: ArrayLike,
        Q: ArrayLike,
        Qs: Optional[ArrayLike],
        dts: Sequence[float],
        fx: Any,
        residual_x: Optional[Any],
        x_mean_fn: Optional[Any],
        Wm: ArrayLike,
    ) -> Tuple[FloatArray, FloatArray, FloatArray]: ...
