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
from depth_nodes.core.depth_image import Intrinsics
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
B = NDArray[np.bool_]
F64 = NDArray[np.float64]


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
def _warp_kernel(values: F32, var: F32, history: U8, disparity: bool, src: F64, dst: F64,
                 R: F64, t: F64, out: F32, out_var: F32, out_history: U8, zbuf: F64) -> None:
    h, w = values.shape
    oh, ow = out.shape
    # the camera and the motion as scalars: the first loop then vectorises
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], \
        R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    fu, fv, cu, cv = dst[0], dst[1], dst[2], dst[3]
    half_u, half_v = 0.5 * dst[0] / src[0], 0.5 * dst[1] / src[1]
    inv_fx, inv_fy, cx, cy = 1.0 / src[0], 1.0 / src[1], src[2], src[3]
    zs = np.empty(w)
    moved = np.empty(w)
    ratios = np.empty(w)
    box = np.empty((4, w))  # each point's footprint: u and v from, u and v to
    for y in range(h):
        ny = (y - cy) * inv_fy
        for x in range(w):  # the row's points, projected (no branch: NaN flows through)
            value = np.float64(values[y, x])
            z = 1.0 / value if disparity else value
            px, py = (x - cx) * inv_fx * z, ny * z
            zc = r20 * px + r21 * py + r22 * z + t2
            inv = 1.0 / zc
            uc = fu * (r00 * px + r01 * py + r02 * z + t0) * inv + cu
            vc = fv * (r10 * px + r11 * py + r12 * z + t1) * inv + cv
            ratio = z * inv
            zs[x] = zc
            moved[x] = inv if disparity else zc
            ratios[x] = ratio
            box[0, x], box[2, x] = uc - half_u * ratio, uc + half_u * ratio
            box[1, x], box[3, x] = vc - half_v * ratio, vc + half_v * ratio
        for x in range(w):  # ... and splatted
            zc = zs[x]
            if not zc > 0.0:  # behind the camera, or unknown
                continue
            u0, v0, u1, v1 = box[0, x], box[1, x], box[2, x], box[3, x]
            if not (u0 < ow and u1 > -1.0 and v0 < oh and v1 > -1.0):
                continue
            c0, c1 = int(np.ceil(u0)), int(np.ceil(u1)) - 1
            r0, r1 = int(np.ceil(v0)), int(np.ceil(v1)) - 1
            if c0 > c1 or r0 > r1:  # covers no pixel centre: the one holding its centre
                c0 = c1 = int(np.floor(0.5 * (u0 + u1) + 0.5))
                r0 = r1 = int(np.floor(0.5 * (v0 + v1) + 0.5))
            c0, c1, r0, r1 = max(c0, 0), min(c1, ow - 1), max(r0, 0), min(r1, oh - 1)
            landed = np.float32(moved[x])
            r2 = ratios[x] * ratios[x]
            moved_var = np.float32(var[y, x] * r2 * r2 if disparity else var[y, x])
            past = history[y, x]
            for r in range(r0, r1 + 1):
                for c in range(c0, c1 + 1):
                    if zc < zbuf[r, c]:
                        zbuf[r, c] = zc
                        out[r, c] = landed
                        out_var[r, c] = moved_var
                        out_history[r, c] = past


def _pinhole(camera: Intrinsics) -> F64:
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy])


def _check_motion(rotation: F64, translation: F64) -> tuple[F64, F64]:
    R = np.ascontiguousarray(rotation, np.float64)
    t = np.ascontiguousarray(translation, np.float64).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and
                                                    np.isfinite(t).all()):
        raise ArgumentError('a motion needs a finite (3, 3) rotation and (3,) translation')
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ArgumentError('the rotation is not a rotation matrix')
    return R, t


def warp_state(state: TemporalState, camera: Intrinsics, rotation: F64, translation: F64,
               disparity: bool, spare: TemporalState | None = None,
               zbuf: F64 | None = None) -> TemporalState:
    """The state moved into a camera that moved: each past pixel's point goes to
    ``rotation @ X + translation`` in the new optical frame and covers the pixel centres
    of its footprint there (the pixel's size scaled by the change of depth and focal
    length; the nearest point wins where several land on one pixel). Its value is the new
    Z there (``disparity``: 1 / Z), its variance and history come along; pixels nothing
    lands on have no past.

    ``spare`` (a state of the same size no longer needed) and ``zbuf`` (float64 of that
    size) are written over instead of allocated, if given: a filter that warps every frame
    reuses the same memory.

    Raises:
        ArgumentError: A rotation that is not one.
    """
    R, t = _check_motion(rotation, translation)
    shape = (camera.height, camera.width)
    out = spare if spare is not None and spare.values.shape == shape else fresh_state(camera)
    out.values.fill(np.nan)
    out.var.fill(np.nan)
    out.history.fill(0)
    out.camera = camera
    if zbuf is None or zbuf.shape != shape:
        zbuf = np.empty(shape)
    zbuf.fill(np.inf)
    _warp_kernel(state.values, state.var, state.history, disparity, _pinhole(state.camera),
                 _pinhole(camera), R, t, out.values, out.var, out.history, zbuf)
    return out


def warp_reference(state: TemporalState, camera: Intrinsics, rotation: F64,
                   translation: F64, disparity: bool) -> TemporalState:
    """Plain reference of :func:`warp_state` (for the tests): each target pixel takes, of
    all the past points whose footprint covers its centre, the nearest. Small images only."""
    R, t = _check_motion(rotation, translation)
    src, dst = _pinhole(state.camera), _pinhole(camera)
    h, w = state.values.shape
    ys, xs = np.mgrid[0:h, 0:w]
    with np.errstate(divide='ignore', invalid='ignore'):
        z = (1.0 / state.values.astype(np.float64)) if disparity else \
            state.values.astype(np.float64)
    ok = state.values > 0
    pts = np.stack([(xs - src[2]) / src[0] * z, (ys - src[3]) / src[1] * z, z], -1) @ R.T + t
    zc = pts[..., 2]
    ok &= zc > 0
    with np.errstate(divide='ignore', invalid='ignore'):
        uc = dst[0] * pts[..., 0] / zc + dst[2]
        vc = dst[1] * pts[..., 1] / zc + dst[3]
        hu, hv = 0.5 * dst[0] / src[0] * z / zc, 0.5 * dst[1] / src[1] * z / zc
    out = fresh_state(camera)
    best = np.full((camera.height, camera.width), np.inf)
    for y, x in zip(*np.nonzero(ok), strict=True):
        c0, c1 = np.ceil(uc[y, x] - hu[y, x]), np.ceil(uc[y, x] + hu[y, x]) - 1
        r0, r1 = np.ceil(vc[y, x] - hv[y, x]), np.ceil(vc[y, x] + hv[y, x]) - 1
        if c0 > c1 or r0 > r1:
            c0 = c1 = np.floor(uc[y, x] + 0.5)
            r0 = r1 = np.floor(vc[y, x] + 0.5)
        for r in range(int(max(r0, 0)), int(min(r1, camera.height - 1)) + 1):
            for c in range(int(max(c0, 0)), int(min(c1, camera.width - 1)) + 1):
                if zc[y, x] < best[r, c]:
                    best[r, c] = zc[y, x]
                    out.values[r, c] = 1.0 / zc[y, x] if disparity else zc[y, x]
                    ratio = z[y, x] / zc[y, x]
                    out.var[r, c] = state.var[y, x] * (ratio ** 4 if disparity else 1.0)
                    out.history[r, c] = state.history[y, x]
    return out
