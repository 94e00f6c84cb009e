"""Edge-preserving spatial smoothing: librealsense's domain-transform filter.

Each iteration runs four recursive passes over the image (left to right, right to left,
top to bottom, bottom to top). Along a pass, a valid pixel whose value differs from the
previous pixel's (already smoothed) value by at most ``delta`` becomes ``alpha`` times its
own value plus ``1 - alpha`` times the previous one's; a larger step is an edge, where the
recursion starts again, and so does an unknown pixel. The values are in the filter's domain
(1 / Z or Z, see :mod:`depth_nodes.core.depth_filter.params`).

With ``holes`` > 0 the first left-to-right pass also fills each hole from the left: its
first ``holes`` pixels take the last valid value before it (librealsense's ``holes_fill``);
those pixels are marked in ``filled`` and are smoothed as valid ones afterwards.

:func:`noise_factor` is how much the filter lowers white noise on a flat surface (the
standard deviation's ratio, measured once per setting on a simulated flat patch), the
factor a smoothed pixel's standard deviation is given.

:func:`spatial_smooth` is the kernel's wrapper; the plain definition the tests compare
it with is ``spatial_reference`` in ``test/reference/depth_filter.py``.
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
B = NDArray[np.bool_]


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _pass(v: F32, alpha: float, delta: float, reverse: bool) -> None:
    """One recursive pass down (or up) the columns of ``v``; every column at once, so the
    row loop vectorises. A horizontal pass is this pass on the transposed image."""
    h, w = v.shape
    a, b, d = np.float32(alpha), np.float32(1.0 - alpha), np.float32(delta)
    for k in range(1, h):
        y = h - 1 - k if reverse else k
        above = y + 1 if reverse else y - 1
        for x in range(w):
            cur = v[y, x]
            prev = v[above, x]
            v[y, x] = a * cur + b * prev if abs(cur - prev) <= d else cur  # NaN: False


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _fill_pass(vt: F32, alpha: float, delta: float, holes: int, filled: B,
               run: NDArray[np.int64]) -> None:
    """The first left-to-right pass with the hole filling, on the transposed image ``vt``
    (its rows are the image's columns; ``filled`` is on the image)."""
    w, h = vt.shape
    a, b, d = np.float32(alpha), np.float32(1.0 - alpha), np.float32(delta)
    run[:] = 0
    for k in range(1, w):
        for y in range(h):
            cur = vt[k, y]
            prev = vt[k - 1, y]
            if cur == cur:
                if abs(cur - prev) <= d:
                    vt[k, y] = a * cur + b * prev
                run[y] = 0
            else:
                if prev == prev and run[y] < holes:
                    vt[k, y] = prev
                    filled[y, k] = True
                run[y] += 1


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _transpose(src: F32, dst: F32) -> None:
    h, w = src.shape
    for y0 in range(0, h, 32):
        for x0 in range(0, w, 32):
            for y in range(y0, min(y0 + 32, h)):
                for x in range(x0, min(x0 + 32, w)):
                    dst[x, y] = src[y, x]


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _smooth_kernel(v: F32, vt: F32, alpha: float, delta: float, iterations: int, holes: int,
                   filled: B, run: NDArray[np.int64]) -> None:
    for it in range(iterations):
        _transpose(v, vt)
        if it == 0 and holes > 0:
            _fill_pass(vt, alpha, delta, holes, filled, run)
        else:
            _pass(vt, alpha, delta, False)
        _pass(vt, alpha, delta, True)
        _transpose(vt, v)
        _pass(v, alpha, delta, False)
        _pass(v, alpha, delta, True)


def _check(values: F32, alpha: float, delta: float, iterations: int, holes: int) -> F32:
    v = np.asarray(values)
    if v.ndim != 2:
        raise ArgumentError(f'values must be (H, W), got shape {v.shape}')
    if not 0.0 < alpha <= 1.0 or not delta >= 0.0 or iterations < 1 or holes < 0:
        raise ArgumentError(f'spatial filter needs 0 < alpha <= 1, delta >= 0, iterations '
                            f'>= 1, holes >= 0; got {alpha}, {delta}, {iterations}, {holes}')
    return np.array(v, dtype=np.float32, order='C')


def spatial_smooth(values: F32, alpha: float, delta: float, iterations: int,
                   holes: int = 0) -> tuple[F32, B]:
    """Smooth ``values`` (NaN unknown; see the module notes).

    Returns:
        The smoothed values (a new array) and the mask of the pixels the hole filling gave
        a value.

    Raises:
        ArgumentError: A value out of range or an image that is not 2-D.
    """
    v = _check(values, alpha, delta, iterations, holes)
    filled = np.zeros(v.shape, np.bool_)
    vt = np.empty(v.shape[::-1], np.float32)
    run = np.zeros(v.shape[0], np.int64)
    _smooth_kernel(v, vt, float(alpha), float(delta), int(iterations), int(holes), filled,
                   run)
    return v, filled


@functools.lru_cache(maxsize=64)
def noise_factor(alpha: float, iterations: int) -> float:
    """The ratio of the standard deviations of white noise on a flat surface after and
    before :func:`spatial_smooth` (no edges: ``delta`` unbounded), measured away from the
    borders of a 96 x 96 patch (fixed seed)."""
    rng = np.random.default_rng(0)
    noise = rng.standard_normal((96, 96)).astype(np.float32)
    out, _ = spatial_smooth(noise, alpha, float('inf'), iterations)
    return float(out[24:-24, 24:-24].std() / noise[24:-24, 24:-24].std())


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _scale_kernel(v: F32, var: F32, delta: float, factor2: float) -> None:
    h, w = v.shape
    d = np.float32(delta)
    for y in range(1, h - 1):
        for x in range(1, w - 1):
            c = v[y, x]
            # NaN anywhere: a comparison is False
            if abs(v[y, x - 1] - c) <= d and abs(v[y, x + 1] - c) <= d and \
                    abs(v[y - 1, x] - c) <= d and abs(v[y + 1, x] - c) <= d:
                var[y, x] = np.float32(var[y, x] * factor2)


def scale_smoothed(values: F32, var: F32, delta: float, factor: float) -> None:
    """Multiply, in place, the variance of the pixels :func:`smoothed` finds (in
    ``values``, before the smoothing) by ``factor`` squared."""
    _scale_kernel(np.ascontiguousarray(values, np.float32), var, float(delta),
                  float(factor) ** 2)


def smoothed(values: F32, delta: float) -> B:
    """Pixels smoothed with all four neighbours: valid, and their four neighbours valid and
    within ``delta`` of them (the pixels :func:`noise_factor` describes)."""
    v = np.asarray(values, np.float32)
    pad = np.pad(v, 1, constant_values=np.nan)
    out = np.isfinite(v)
    with np.errstate(invalid='ignore'):
        for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
            out &= np.abs(pad[dy:dy + v.shape[0], dx:dx + v.shape[1]] - v) <= delta
    return out
