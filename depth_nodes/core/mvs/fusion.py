"""Depth over time: per-pixel filters that fuse successive inverse-depth estimates of the
same surfaces, in numba (no ROS).

The state lives in the last reference view: per pixel an inverse depth ``rho`` (1/m, NaN
where none), its variance, and two counts ``a`` and ``b``. A new reference first receives
the state moved into it (:func:`warp_state`: every pixel's 3-D point moved by the camera
motion and splatted to the pixel holding it, the nearest surface winning, by the shared
:func:`~depth_nodes.core.geometry.splat.splat`; the variance carried to first order plus
process noise), then each pixel fuses its new measurement
(:func:`fuse`) with one of two filters (:data:`FILTERS`):

* ``kalman``: a Gaussian in inverse depth. A measurement within ``gate`` standard
  deviations of the prediction is fused (variance-weighted mean) and counts as an inlier
  (``a``); one outside counts as an outlier (``b``) and is ignored, unless it is more
  precise than the prediction (a wider baseline contradicting a guess from a shorter one)
  or the outliers now outnumber the inliers (a surface that moved): the pixel then starts
  over from the measurement.
* ``gauss_uniform``: Vogiatzis and Hernandez's parametric model (2011, "Video-based,
  real-time multi-view stereo"; the filter of SVO / REMODE): a measurement is a good one,
  Gaussian around the true inverse depth, with probability ``pi``, else uniform over the
  sweep's range; the posterior is approximated by a Gaussian times a Beta(a, b) on ``pi``.

Successive measurements share their source keyframes, so their errors are correlated:
before a fusion the estimate's variance grows by ``correlation`` times the measurement's
(:class:`FilterSettings`), which keeps the published standard deviation honest.

A pixel's estimate is *converged* when its relative depth standard deviation is below
``converge_sigma`` and it has at least ``min_inliers`` inlier measurements (for
``gauss_uniform``: an inlier probability a / (a + b) of at least ``min_inlier_ratio``).

Every kernel has a plain reference that the tests compare with, in ``test/reference/mvs.py``
(``fuse_reference``, ``warp_state_reference``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Motion, splat
from depth_nodes.errors import ArgumentError

__all__ = ['FILTERS', 'FilterSettings', 'FilterState', 'converged', 'fuse', 'warp_state']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
FILTERS = ('kalman', 'gauss_uniform')
_METHOD = {'kalman': 0, 'gauss_uniform': 1}
#: Beta counts of a new pixel of the ``gauss_uniform`` filter (SVO's start).
PRIOR_COUNT = 10.0


@dataclass(frozen=True)
class FilterSettings:
    """How measurements are fused.

    Attributes:
        method: One of :data:`FILTERS`.
        gate: Kalman: largest normalised innovation of a fused measurement, sigmas.
        process_sigma: Relative inverse-depth noise added per frame to a moved estimate
            (motion blur of the state: resampling, small pose errors).
        correlation: Share of a measurement's variance added to the estimate's before the
            two are fused: successive frames are swept against the same keyframes, so
            their errors are not independent, and without it the estimate would claim
            more certainty than it has (with 0.5, repeated measurements of variance r
            settle at r / 2, not r / n).
        converge_sigma: Largest relative depth standard deviation of a converged pixel.
        min_inliers: Kalman: fewest inlier measurements of a converged pixel.
        min_inlier_ratio: gauss_uniform: least a / (a + b) of a converged pixel.
        rho_range: gauss_uniform: width of the uniform outlier density, 1/m (the sweep's).
    """

    method: str = 'kalman'
    gate: float = 3.0
    process_sigma: float = 0.002
    correlation: float = 0.5
    converge_sigma: float = 0.02
    min_inliers: int = 2
    min_inlier_ratio: float = 0.6
    rho_range: float = 1.0

    def validate(self) -> FilterSettings:
        """Raises ArgumentError naming the first invalid field; returns self."""
        if self.method not in FILTERS:
            raise ArgumentError(f'filter {self.method!r}: must be one of {", ".join(FILTERS)}')
        for name, low in (('gate', 0.0), ('converge_sigma', 0.0), ('rho_range', 0.0)):
            if not getattr(self, name) > low or not math.isfinite(getattr(self, name)):
                raise ArgumentError(f'filter {name}={getattr(self, name)!r}: must be positive')
        if not 0 <= self.correlation <= 10:
            raise ArgumentError(f'filter correlation={self.correlation!r}: must be in [0, 10]')
        if not 0 <= self.process_sigma < 1:
            raise ArgumentError(f'filter process_sigma={self.process_sigma!r}: must be in [0, 1)')
        if self.min_inliers < 1:
            raise ArgumentError(f'filter min_inliers={self.min_inliers}: must be at least 1')
        if not 0 < self.min_inlier_ratio <= 1:
            raise ArgumentError(f'filter min_inlier_ratio={self.min_inlier_ratio}: must be '
                                'in (0, 1]')
        return self


@dataclass
class FilterState:
    """The filter's per-pixel state in one reference view (arrays of one shape).

    Attributes:
        rho: Inverse depth, 1/m; NaN where the pixel has no estimate.
        var: Its variance, 1/m^2.
        a: Kalman: inlier measurements; gauss_uniform: the Beta's first count.
        b: Kalman: outliers since the last inlier; gauss_uniform: the Beta's second count.
    """

    rho: F32
    var: F32
    a: F32
    b: F32

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> FilterState:
        """A state with no estimate anywhere."""
        return cls(np.full(shape, np.nan, np.float32), np.zeros(shape, np.float32),
                   np.zeros(shape, np.float32), np.zeros(shape, np.float32))

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        h, w = self.rho.shape
        return h, w

    def depth(self) -> F32:
        """Z in metres (NaN where no estimate)."""
        with np.errstate(divide='ignore', invalid='ignore'):
            out: F32 = np.where(self.rho > 0, 1.0 / self.rho, np.nan).astype(np.float32)
        return out

    def depth_sigma(self) -> F32:
        """Standard deviation of Z to first order, ``sqrt(var) / rho^2``, metres."""
        with np.errstate(divide='ignore', invalid='ignore'):
            out: F32 = np.where(self.rho > 0, np.sqrt(self.var) / (self.rho * self.rho),
                                np.nan).astype(np.float32)
        return out


# ------------------------------------------------------------------------- moving the state
@njit(cache=True, nogil=True)
def _carry_kernel(rho: F32, var: F32, a: F32, b: F32, zbuf: F64, index: I32, t_z: float,
                  process: float, out_rho: F32, out_var: F32, out_a: F32, out_b: F32) -> None:
    """Each landed pixel's estimate: the new inverse depth, the variance carried to first
    order plus process noise, the counts as they were. The source arrays are flat (their
    index is the splat's), the others (H, W)."""
    oh, ow = zbuf.shape
    for y in range(oh):
        for x in range(ow):
            k = index[y, x]
            if k < 0:
                out_rho[y, x] = np.nan
                out_var[y, x] = 0.0
                out_a[y, x] = 0.0
                out_b[y, x] = 0.0
                continue
            r = np.float64(rho[k])
            z_new = zbuf[y, x]
            new_rho = 1.0 / z_new
            # rho_new = rho / (q_z + t_z rho), q_z the old ray's z in the new frame:
            # d rho_new / d rho = q_z / (q_z + t_z rho)^2 = (Z_new - t_z) / (Z_new^2 rho)
            gain = (z_new - t_z) / (z_new * z_new * r)
            out_rho[y, x] = new_rho
            out_var[y, x] = var[k] * gain * gain + (process * new_rho) ** 2
            out_a[y, x] = a[k]
            out_b[y, x] = b[k]


def warp_state(state: FilterState, old: Intrinsics, new: Intrinsics, motion: Motion, *,
               process_sigma: float) -> FilterState:
    """``state`` moved from its view into a new one: each estimate's point splatted to the
    new view's pixel holding it (:func:`~depth_nodes.core.geometry.splat.splat`, footprint
    ``point``: a per-pixel state is not smeared), the nearest winning.

    Args:
        state: The state in the old view.
        old: The old view's camera.
        new: The new view's camera (the new state's size).
        motion: ``(R, t)`` taking old-view points into the new view.
        process_sigma: Relative inverse-depth noise added to every moved estimate.
    """
    out = FilterState.empty(new.shape)
    landed = splat(state.rho, old, new, motion, footprint='point', inverse=True)
    _carry_kernel(state.rho.reshape(-1), state.var.reshape(-1), state.a.reshape(-1),
                  state.b.reshape(-1), landed.depth, landed.index,
                  float(np.asarray(motion[1], np.float64).reshape(-1)[2]),
                  float(process_sigma), out.rho, out.var, out.a, out.b)
    return out


# ------------------------------------------------------------------------------- fusing
@njit(cache=True, nogil=True, inline='always')
def _normal_pdf(x: float, mean: float, var: float) -> float:
    return math.exp(-0.5 * (x - mean) ** 2 / var) / math.sqrt(2.0 * math.pi * var)


@njit(cache=True, nogil=True)
def _fuse_kernel(rho: F32, var: F32, a: F32, b: F32, rho_m: F32, var_m: F32, method: int,
                 gate: float, rho_range: float, correlation: float) -> None:
    h, w = rho.shape
    uniform = 1.0 / rho_range
    for y in range(h):
        for x in range(w):
            m = np.float64(rho_m[y, x])
            vm = np.float64(var_m[y, x])
            if not (m > 0 and math.isfinite(m) and vm > 0 and math.isfinite(vm)):
                continue
            p = np.float64(rho[y, x])
            vp = np.float64(var[y, x]) + correlation * vm
            if not (p > 0 and math.isfinite(p) and vp > 0):  # a new estimate
                rho[y, x] = m
                var[y, x] = vm
                a[y, x] = 1.0 if method == 0 else PRIOR_COUNT
                b[y, x] = 0.0 if method == 0 else PRIOR_COUNT
                continue
            if method == 0:
                if (m - p) ** 2 <= gate * gate * (vp + vm):
                    rho[y, x] = (p * vm + m * vp) / (vp + vm)
                    var[y, x] = vp * vm / (vp + vm)
                    a[y, x] += 1.0
                    b[y, x] = 0.0
                else:
                    b[y, x] += 1.0
                    # the outliers win, or a measurement more precise than the estimate
                    # contradicts it (a first guess from a short baseline): start over
                    if b[y, x] > a[y, x] or vm < vp:
                        rho[y, x] = m
                        var[y, x] = vm
                        a[y, x] = 1.0
                        b[y, x] = 0.0
                continue
            aa = np.float64(a[y, x])
            bb = np.float64(b[y, x])
            s2 = vp * vm / (vp + vm)
            mean = s2 * (p / vp + m / vm)
            c1 = aa / (aa + bb) * _normal_pdf(m, p, vp + vm)
            c2 = bb / (aa + bb) * uniform
            norm = c1 + c2
            if not norm > 0:
                continue
            c1 /= norm
            c2 /= norm
            f = c1 * (aa + 1.0) / (aa + bb + 1.0) + c2 * aa / (aa + bb + 1.0)
            e = c1 * (aa + 1.0) * (aa + 2.0) / ((aa + bb + 1.0) * (aa + bb + 2.0)) + \
                c2 * aa * (aa + 1.0) / ((aa + bb + 1.0) * (aa + bb + 2.0))
            new_mean = c1 * mean + c2 * p
            new_var = c1 * (s2 + mean * mean) + c2 * (vp + p * p) - new_mean * new_mean
            denominator = f - e / f
            if not (new_var > 0 and math.isfinite(new_mean) and denominator != 0):
                continue
            new_a = (e - f) / denominator
            if not (new_a > 0 and math.isfinite(new_a)):
                continue
            rho[y, x] = new_mean
            var[y, x] = new_var
            a[y, x] = new_a
            b[y, x] = new_a * (1.0 - f) / f


def fuse(state: FilterState, rho_m: F32, var_m: F32, settings: FilterSettings) -> FilterState:
    """Fuse one measurement per pixel (``rho_m``, ``var_m``; NaN where none) into ``state``
    in place; returns it.

    Raises:
        ArgumentError: Shapes that differ.
    """
    if rho_m.shape != state.shape or var_m.shape != state.shape:
        raise ArgumentError(f'measurement {rho_m.shape} / {var_m.shape} and state '
                            f'{state.shape} differ in size')
    _fuse_kernel(state.rho, state.var, state.a, state.b, np.ascontiguousarray(rho_m, np.float32),
                 np.ascontiguousarray(var_m, np.float32), _METHOD[settings.method],
                 float(settings.gate), float(settings.rho_range), float(settings.correlation))
    return state


def converged(state: FilterState, settings: FilterSettings) -> NDArray[np.bool_]:
    """Pixels whose estimate has converged (see the module notes)."""
    with np.errstate(divide='ignore', invalid='ignore'):
        relative = np.sqrt(state.var) / state.rho  # sigma_Z / Z = sigma_rho / rho
        sure = relative <= settings.converge_sigma
        if settings.method == 'kalman':
            enough = state.a >= settings.min_inliers
        else:
            enough = state.a / (state.a + state.b) >= settings.min_inlier_ratio
    out: NDArray[np.bool_] = np.isfinite(state.rho) & sure & enough
    return out
