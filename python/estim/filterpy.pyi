"""Type stubs of estim.filterpy (filterpy's KalmanFilter and UnscentedKalmanFilter on
estim's Rust core)."""

from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ._estim import EstimError as EstimError
from ._estim import FilterpyKalmanFilter

ArrayLike = npt.ArrayLike
FloatArray = npt.NDArray[np.float64]

class KalmanFilter(FilterpyKalmanFilter):
    def __init__(self, dim_x: int, dim_z: int, dim_u: int = 0) -> None: ...
    def batch_filter(
        self,
        zs: Any,
        Fs: Any = None,
        Qs: Any = None,
        Hs: Any = None,
        Rs: Any = None,
        Bs: Any = None,
        us: Any = None,
        update_first: bool = False,
        saver: Any = None,
    ) -> Tuple[FloatArray, FloatArray, FloatArray, FloatArray]: ...
    def rts_smoother(
        self,
        Xs: ArrayLike,
        Ps: ArrayLike,
        Fs: Any = None,
        Qs: Any = None,
        inv: Callable[..., Any] = ...,
        us: Any = None,
        Bs: Any = None,
    ) -> Tuple[FloatArray, FloatArray, FloatArray, FloatArray]: ...
    def get_prediction(
        self, u: Any = None, B: Any = None, F: Any = None, Q: Any = None
    ) -> Tuple[FloatArray, FloatArray]: ...
    def get_update(self, z: Any = None) -> Tuple[FloatArray, FloatArray]: ...
    def residual_of(self, z: ArrayLike) -> FloatArray: ...
    def measurement_of_state(self, x: ArrayLike) -> FloatArray: ...
    def log_likelihood_of(self, z: Any) -> float: ...

class MerweScaledSigmaPoints:
    n: int
    alpha: float
    beta: float
    kappa: float
    Wm: FloatArray
    Wc: FloatArray
    sqrt: Callable[[FloatArray], FloatArray]
    subtract: Callable[[Any, Any], Any]
    def __init__(
        self,
        n: int,
        alpha: float,
        beta: float,
        kappa: float,
        sqrt_method: Optional[Callable[[FloatArray], FloatArray]] = None,
        subtract: Optional[Callable[[Any, Any], Any]] = None,
    ) -> None: ...
    def num_sigmas(self) -> int: ...
    def sigma_points(self, x: ArrayLike, P: ArrayLike) -> FloatArray: ...

class JulierSigmaPoints:
    n: int
    kappa: float
    Wm: FloatArray
    Wc: FloatArray
    sqrt: Callable[[FloatArray], FloatArray]
    subtract: Callable[[Any, Any], Any]
    def __init__(
        self,
        n: int,
        kappa: float = 0.0,
        sqrt_method: Optional[Callable[[FloatArray], FloatArray]] = None,
        subtract: Optional[Callable[[Any, Any], Any]] = None,
    ) -> None: ...
    def num_sigmas(self) -> int: ...
    def sigma_points(self, x: ArrayLike, P: ArrayLike) -> FloatArray: ...

class UnscentedKalmanFilter:
    x: Any
    P: Any
    Q: Any
    R: Any
    K: FloatArray
    y: FloatArray
    S: FloatArray
    SI: FloatArray
    z: Any
    sigmas_f: FloatArray
    sigmas_h: FloatArray
    x_prior: FloatArray
    P_prior: FloatArray
    x_post: FloatArray
    P_post: FloatArray
    Wm: FloatArray
    Wc: FloatArray
    fx: Callable[..., Any]
    hx: Callable[..., Any]
    residual_x: Callable[[Any, Any], Any]
    residual_z: Callable[[Any, Any], Any]
    state_add: Callable[[Any, Any], Any]
    x_mean: Optional[Callable[[FloatArray, FloatArray], Any]]
    z_mean: Optional[Callable[[FloatArray, FloatArray], Any]]
    points_fn: Any
    def __init__(
        self,
        dim_x: int,
        dim_z: int,
        dt: float,
        hx: Callable[..., Any],
        fx: Callable[..., Any],
        points: Union[MerweScaledSigmaPoints, JulierSigmaPoints, Any],
        sqrt_fn: Optional[Callable[[FloatArray], FloatArray]] = None,
        x_mean_fn: Optional[Callable[[FloatArray, FloatArray], Any]] = None,
        z_mean_fn: Optional[Callable[[FloatArray, FloatArray], Any]] = None,
        residual_x: Optional[Callable[[Any, Any], Any]] = None,
        residual_z: Optional[Callable[[Any, Any], Any]] = None,
        state_add: Optional[Callable[[Any, Any], Any]] = None,
    ) -> None: ...
    @property
    def dim_x(self) -> int: ...
    @property
    def dim_z(self) -> int: ...
    def predict(
        self, dt: Optional[float] = None, UT: Any = None, fx: Any = None, **fx_args: Any
    ) -> None: ...
    def update(
        self, z: Any, R: Any = None, UT: Any = None, hx: Any = None, **hx_args: Any
    ) -> None: ...
    def cross_variance(
        self, x: ArrayLike, z: ArrayLike, sigmas_f: FloatArray, sigmas_h: FloatArray
    ) -> FloatArray: ...
    def compute_process_sigmas(self, dt: float, fx: Any = None, **fx_args: Any) -> None: ...
    def batch_filter(
        self,
        zs: Sequence[Any],
        Rs: Any = None,
        dts: Any = None,
        UT: Any = None,
        saver: Any = None,
    ) -> Tuple[FloatArray, FloatArray]: ...
    def rts_smoother(
        self,
        Xs: ArrayLike,
        Ps: ArrayLike,
        Qs: Any = None,
        dts: Any = None,
        UT: Any = None,
    ) -> Tuple[FloatArray, FloatArray, FloatArray]: ...
    @property
    def log_likelihood(self) -> float: ...
    @property
    def likelihood(self) -> float: ...
    @property
    def mahalanobis(self) -> float: ...
