"""Temporal smoothing, librealsense's temporal filter with a pixel's history.

For each pixel, with ``prev`` the last output (moved into the current frame by the
camera's motion when it is known, :func:`warp_state`):

* a valid value within ``delta`` of ``prev`` becomes ``alpha`` times itself plus
  ``1 - alpha`` times ``prev`` (its variance ``alpha^2 var + (1 - alpha)^2 var_prev``);
  a larger change is taken at once: a moving object leaves no trail where the background
  is seen again;
* a missing value keeps ``prev`` if the pixel was valid in at least ``k`` of the last
  ``n`` frames before this one (``persistence``, :data:`~.params.PERSISTENCE`), and is
  marked kept; else it stays missing.

The history is one byte per pixel, bit 0 the last frame. Values are in the filter's
domain (1 / Z or Z).

:func:`temporal_step` is the kernel's wrapper; the plain definition the tests compare
it with is ``temporal_reference`` in ``test/reference/depth_filter.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_filter.params import PERSISTENCE
from depth_nodes.core.geometry import Intrinsics, Motion, Splat, splat
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
B = NDArray[np.bool_]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass
class TemporalState:
    """The temporal filter's memory: the last output and its variance (filter domain),
    each pixel's history, the camera they are on."""

    values: F32
    var: F32
    history: U8
    camera: Intrinsics


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _popcount(bits: int) -> int:
    count = 0
    while bits:
        count += bits & 1
        bits >>= 1
    return count


@numba.njit(cache=True, nogil=True, parallel=True, error_model='numpy')
def _temporal_kernel(v: F32, var: F32, prev: F32, prev_var: F32, history: U8, alpha: float,
                     delta: float, need: int, window_mask: int, out: F32, out_var: F32,
                     kept: B) -> None:
    h, w = v.shape
    for y in numba.prange(h):
        for x in range(w):
            c = v[y, x]
            p = prev[y, x]
            bits = int(history[y, x])
            kept[y, x] = False
            if c == c:
                if abs(c - p) <= delta:  # NaN prev: False
                    out[y, x] = np.float32(alpha * c + (1.0 - alpha) * p)
                    out_var[y, x] = np.float32(alpha * alpha * var[y, x] +
                                               (1.0 - alpha) * (1.0 - alpha) * prev_var[y, x])
                else:
                    out[y, x] = c
                    out_var[y, x] = var[y, x]
                history[y, x] = np.uint8(((bits << 1) | 1) & 0xFF)
            else:
                if p == p and (need < 0 or (need > 0 and
                                            _popcount(bits & window_mask) >= need)):
                    out[y, x] = p
                    out_var[y, x] = prev_var[y, x]
                    kept[y, x] = True
                else:
                    out[y, x] = np.nan
                    out_var[y, x] = np.nan
                history[y, x] = np.uint8((bits << 1) & 0xFF)


def _persistence(mode: int) -> tuple[int, int]:
    """(valid frames needed, mask of the history bits counted); -1 needed: always."""
    if not 0 <= mode < len(PERSISTENCE):
        raise ArgumentError(f'temporal persistence must be in [0, {len(PERSISTENCE) - 1}], '
                            f'got {mode}')
    need, window = PERSISTENCE[mode]
    if window > 8:  # always: need -1
        return -1, 0
    return need, (1 << window) - 1


def temporal_step(values: F32, var: F32, state: TemporalState, alpha: float, delta: float,
                  persistence: int) -> tuple[F32, F32, B]:
    """One frame of the temporal filter (see the module notes); ``state`` (on this frame's
    grid) is updated in place.

    Returns:
        The output values and their variance (the state's own arrays: read them before
        the next frame) and the mask of kept pixels.

    Raises:
        ArgumentError: Shapes that differ from the state's, or settings out of range.
    """
    v = np.ascontiguousarray(values, np.float32)
    if v.shape != state.values.shape or np.shape(var) != v.shape:
        raise ArgumentError(f'temporal filter: a {v.shape} frame on a {state.values.shape} '
                            'state')
    if not 0.0 < alpha <= 1.0 or not delta >= 0.0:
        raise ArgumentError(f'temporal filter needs 0 < alpha <= 1 and delta >= 0, got '
                            f'{alpha}, {delta}')
    need, mask = _persistence(persistence)
    kept = np.empty(v.shape, np.bool_)
    # in place: each pixel's past is read before its output is written over it
    _temporal_kernel(v, np.ascontiguousarray(var, np.float32), state.values, state.var,
                     state.history, float(alpha), float(delta), need, mask, state.values,
                     state.var, kept)
    return state.values, state.var, kept


def fresh_state(camera: Intrinsics) -> TemporalState:
    """A state with no past on ``camera``'s grid."""
    shape = (camera.height, camera.width)
    return TemporalState(np.full(shape, np.nan, np.float32), np.full(shape, np.nan, np.float32),
                         np.zeros(shape, np.uint8), camera)


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _carry_kernel(values: F32, var: F32, history: U8, disparity: bool, zbuf: F64,
                  index: I32, out: F32, out_var: F32, out_history: U8) -> None:
    """Each landed pixel's value: the new Z (or 1 / Z), the variance scaled by the change
    of depth (in disparity), the history as it was. The source arrays are flat (their
    index is the splat's), the others (H, W)."""
    oh, ow = zbuf.shape
    for r in range(oh):
        for c in range(ow):
            k = index[r, c]
            if k < 0:
                out[r, c] = np.nan
                out_var[r, c] = np.nan
                out_history[r, c] = 0
                continue
            value = np.float64(values[k])
            z = 1.0 / value if disparity else value
            zc = zbuf[r, c]
            inv = 1.0 / zc
            out[r, c] = np.float32(inv if disparity else zc)
            ratio = z * inv
            r2 = ratio * ratio
            out_var[r, c] = np.float32(var[k] * r2 * r2 if disparity else var[k])
            out_history[r, c] = history[k]


def warp_state(state: TemporalState, camera: Intrinsics, motion: Motion, disparity: bool,
               spare: TemporalState | None = None, landed: Splat | None = None
               ) -> TemporalState:
    """The state moved into a camera that moved: each past pixel's point goes to
    ``R @ X + t`` (``motion``) in the new optical frame and covers the pixel centres of its
    ``box`` footprint there (:func:`~depth_nodes.core.geometry.splat.splat`: the nearest
    point wins where several land on one pixel). Its value is the new Z there
    (``disparity``: 1 / Z), its variance and history come along; pixels nothing lands on
    have no past.

    ``spare`` (a state of the same size no longer needed) and ``landed`` (the last call's
    splat) are written over instead of allocated, if given: a filter that warps every
    frame reuses the same memory.

    Raises:
        ArgumentError: A motion that is not rigid.
    """
    shape = (camera.height, camera.width)
    out = spare if spare is not None and spare.values.shape == shape else fresh_state(camera)
    out.camera = camera
    moved = splat(state.values, state.camera, camera, motion, footprint='box',
                  inverse=disparity, into=landed)
    _carry_kernel(state.values.reshape(-1), state.var.reshape(-1), state.history.reshape(-1),
                  disparity, moved.depth, moved.index, out.values, out.var, out.history)
    return out
