"""Depth over time: per-pixel filters that fuse successive inverse-depth estimates of the
same surfaces, in numba (no ROS).

The state lives in the last reference view: per pixel an inverse depth ``rho`` (1/m, NaN
where none), its variance, and two counts ``a`` and ``b``. A new reference first receives
the state moved into it (:func:`warp_state`: every pixel's 3-D point moved by the camera
motion and splatted to the nearest pixel, the nearest surface winning; the variance
carried to first order plus process noise), then each pixel fuses its new measurement
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

Every kernel has a plain reference that the tests compare with: :func:`fuse`'s is
``fuse_reference`` in ``test/reference/mvs.py``, :func:`warp_state`'s
:func:`warp_state_reference` here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

__all__ = ['FILTERS', 'FilterSettings', 'FilterState', 'converged', 'fuse', 'warp_state',
           'warp_state_reference']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
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
def _warp_kernel(rho: F32, var: F32, a: F32, b: F32, k_inv: F64, k_new: F64,
                 rotation: F64, translation: F64, process: float, out_rho: F32,
                 out_var: F32, out_a: F32, out_b: F32) -> None:
    h, w = rho.shape
    nh, nw = out_rho.shape
    for y in range(nh):
        for x in range(nw):
            out_rho[y, x] = np.nan
            out_var[y, x] = 0.0
            out_a[y, x] = 0.0
            out_b[y, x] = 0.0
    for y in range(h):
        for x in range(w):
            r = rho[y, x]
            if not (r > 0 and math.isfinite(r)):
                continue
            rx = k_inv[0, 0] * x + k_inv[0, 1] * y + k_inv[0, 2]
            ry = k_inv[1, 0] * x + k_inv[1, 1] * y + k_inv[1, 2]
            rz = k_inv[2, 0] * x + k_inv[2, 1] * y + k_inv[2, 2]
            # the point r / rho in the new frame, scaled by rho: (R r + t rho)
            qx = rotation[0, 0] * rx + rotation[0, 1] * ry + rotation[0, 2] * rz
            qy = rotation[1, 0] * rx + rotation[1, 1] * ry + rotation[1, 2] * rz
            qz = rotation[2, 0] * rx + rotation[2, 1] * ry + rotation[2, 2] * rz
            sx = qx + translation[0] * r
            sy = qy + translation[1] * r
            sz = qz + translation[2] * r
            if not sz > 1e-12:
                continue
            u = (k_new[0, 0] * sx + k_new[0, 1] * sy + k_new[0, 2] * sz) / sz
            v = (k_new[1, 0] * sx + k_new[1, 1] * sy + k_new[1, 2] * sz) / sz
            if not (-0.5 <= u < nw - 0.5 and -0.5 <= v < nh - 0.5):
                continue
            xi = math.floor(u + 0.5)
            yi = math.floor(v + 0.5)
            new_rho = r / sz  # 1 / Z_new, with Z_new = sz / r
            old = out_rho[yi, xi]
            if math.isfinite(old) and old >= new_rho:  # a nearer surface is there already
                continue
            gain = qz / (sz * sz)  # d rho_new / d rho
            out_rho[yi, xi] = new_rho
            out_var[yi, xi] = var[y, x] * gain * gain + (process * new_rho) ** 2
            out_a[yi, xi] = a[y, x]
            out_b[yi, xi] = b[y, x]


def warp_state(state: FilterState, k_old: F64, k_new: F64, relative: tuple[F64, F64],
               shape: tuple[int, int], *, process_sigma: float) -> FilterState:
    """``state`` moved from its view into a new one.

    Args:
        state: The state in the old view.
        k_old: (3, 3) camera matrix of the old view.
        k_new: (3, 3) camera matrix of the new view.
        relative: ``(R, t)`` taking old-view points into the new view.
        shape: (H, W) of the new view.
        process_sigma: Relative inverse-depth noise added to every moved estimate.
    """
    out = FilterState.empty(shape)
    rotation, translation = (np.asarray(v, np.float64) for v in relative)
    k_inv = np.asarray(np.linalg.inv(k_old), np.float64)
    _warp_kernel(state.rho, state.var, state.a, state.b, k_inv,
                 np.asarray(k_new, np.float64), rotation, translation, float(process_sigma),
                 out.rho, out.var, out.a, out.b)
    return out


def warp_state_reference(state: FilterState, k_old: F64, k_new: F64,
                         relative: tuple[F64, F64], shape: tuple[int, int], *,
                         process_sigma: float) -> FilterState:
    """Plain numpy version of :func:`warp_state` (the same splatting order)."""
    out = FilterState.empty(shape)
    rotation, translation = (np.asarray(v, np.float64) for v in relative)
    h, w = state.shape
    k_inv = np.linalg.inv(k_old)
    for y in range(h):
        for x in range(w):
            r = float(state.rho[y, x])
            if not (r > 0 and math.isfinite(r)):
                continue
            ray = k_inv @ np.array([x, y, 1.0])
            q = rotation @ ray
            s = q + translation * r
            if not s[2] > 1e-12:
                continue
            u, v = (np.asarray(k_new, np.float64) @ s)[:2] / s[2]
            if not (-0.5 <= u < shape[1] - 0.5 and -0.5 <= v < shape[0] - 0.5):
                continue
            xi, yi = math.floor(u + 0.5), math.floor(v + 0.5)
            new_rho = r / s[2]
            old = float(out.rho[yi, xi])
            if math.isfinite(old) and old >= new_rho:
                continue
            gain = q[2] / (s[2] * s[2])
            out.rho[yi, xi] = new_rho
            out.var[yi, xi] = state.var[y, x] * gain * gain + (process_sigma * new_rho) ** 2
            out.a[yi, xi] = state.a[y, x]
            out.b[yi, xi] = state.b[y, x]
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
