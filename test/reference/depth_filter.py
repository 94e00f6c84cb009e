"""Plain numpy references of the depth filter's kernels (``depth_nodes/core/depth_filter/``):
decimation, the domain, hole filling and its spread, spatial and temporal smoothing, and the
temporal state's warp; for ``test_depth_filter_kernels.py``."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_filter.decimate import MEDIAN_VARIANCE
from depth_nodes.core.depth_filter.decimate import _check as _check_decimate
from depth_nodes.core.depth_filter.holes import _mode
from depth_nodes.core.depth_filter.spatial import _check as _check_spatial
from depth_nodes.core.depth_filter.temporal import TemporalState, _persistence, fresh_state
from depth_nodes.core.geometry import Intrinsics, Motion, check_rotation

F32 = NDArray[np.float32]
B = NDArray[np.bool_]


# -- depth_nodes.core.depth_filter.decimate ----------------------------------------------------
def decimate_reference(depth: F32, factor: int, var: F32 | None = None) -> tuple[F32, F32]:
    """Plain numpy reference of :func:`decimate` (for the tests)."""
    z, v = _check_decimate(depth, var, factor)
    h, w = z.shape[0] // factor, z.shape[1] // factor
    out = np.full((h, w), np.nan, np.float32)
    out_var = np.full((h, w), np.nan, np.float32)
    for oy in range(h):
        for ox in range(w):
            zb = z[oy * factor:(oy + 1) * factor, ox * factor:(ox + 1) * factor].ravel()
            vb = v[oy * factor:(oy + 1) * factor, ox * factor:(ox + 1) * factor].ravel()
            keep = (zb > 0) & (zb < np.inf)
            n = int(keep.sum())
            if not n:
                continue
            spread = vb[keep].sum() / n ** 2
            if factor <= 3 and n > 2:
                out[oy, ox] = np.median(zb[keep])
                out_var[oy, ox] = spread * MEDIAN_VARIANCE
            else:
                out[oy, ox] = zb[keep].mean()
                out_var[oy, ox] = spread
    return out, out_var


# -- depth_nodes.core.depth_filter.domain ------------------------------------------------------
def domain_reference(depth: F32, sigma: F32 | None, disparity: bool
                     ) -> tuple[F32, F32, F32, F32]:
    """Plain numpy reference of :func:`to_domain` and then :func:`from_domain`: the
    values, their variance, and the depth and standard deviation they give back."""
    z = np.asarray(depth, np.float32)
    s2 = np.zeros(z.shape, np.float32) if sigma is None else \
        np.square(np.asarray(sigma, np.float32))
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        inv = (np.float32(1.0) / z).astype(np.float32)
        ok = (z > 0) & (z < np.inf) & (~np.isinf(inv) if disparity else True)
        v = np.where(ok, inv if disparity else z, np.nan).astype(np.float32)
        var = np.where(ok, s2 * (inv * inv) * (inv * inv) if disparity else s2,
                       np.nan).astype(np.float32)
        back = (np.float32(1.0) / v).astype(np.float32) if disparity else v
        sd = np.sqrt(var) * back * back if disparity else np.sqrt(var)
    return v, var, back, sd.astype(np.float32)


# -- depth_nodes.core.depth_filter.holes -------------------------------------------------------
#: Neighbours the around modes look at (dy, dx): the first three already filled.
AROUND = ((0, -1), (-1, -1), (-1, 0), (1, -1), (1, 0))


def fill_reference(depth: F32, mode: str) -> tuple[F32, B]:
    """Plain reference of :func:`fill_holes` (for the tests)."""
    m = _mode(mode)
    z = np.asarray(depth, np.float32)
    out = z.copy()
    filled = np.zeros(z.shape, bool)
    if m == 0:
        return out, filled
    h, w = z.shape
    for y in range(h):
        for x in range(w):
            if not np.isnan(z[y, x]):
                continue
            if m == 1:
                candidates = [out[y, x - 1]] if x > 0 else []
            else:
                candidates = []
                for k, (dy, dx) in enumerate(AROUND):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w:
                        candidates.append(out[yy, xx] if k < 3 else z[yy, xx])
            known = [c for c in candidates if not np.isnan(c)]
            if known:
                out[y, x] = known[0] if m == 1 else (max(known) if m == 2 else min(known))
                filled[y, x] = True
    return out, filled


def spread_reference(depth: F32, filled: B) -> F32:
    """Plain numpy reference of :func:`fill_spread` (for the tests)."""
    z = np.asarray(depth, np.float32)
    w = z.shape[1]
    spread = np.full(z.shape, np.nan, np.float32)
    cols = np.arange(w)
    for y in np.flatnonzero(filled.any(axis=1)):
        row = z[y]
        valid = np.isfinite(row)
        if not valid.any():
            continue
        left_idx = np.maximum.accumulate(np.where(valid, cols, -1))
        right_idx = np.minimum.accumulate(np.where(valid, cols, w)[::-1])[::-1]
        ok = filled[y] & (left_idx >= 0) & (right_idx < w)
        spread[y, ok] = np.abs(row[right_idx[ok]] - row[left_idx[ok]])
    return spread


# -- depth_nodes.core.depth_filter.spatial -----------------------------------------------------
def spatial_reference(values: F32, alpha: float, delta: float, iterations: int,
                      holes: int = 0) -> tuple[F32, B]:
    """Plain reference of :func:`spatial_smooth` (for the tests): every pass written out
    along its own direction, in float64 with float32 rounding after each update."""
    v = _check_spatial(values, alpha, delta, iterations, holes)
    h, w = v.shape
    filled = np.zeros(v.shape, bool)

    def update(cur: float, prev: float) -> float:
        return float(np.float32(alpha * cur + (1.0 - alpha) * prev))

    for it in range(iterations):
        for reverse in (False, True):
            for y in range(h):
                prev, run = float('nan'), 0
                for x in (range(w - 1, -1, -1) if reverse else range(w)):
                    cur = float(v[y, x])
                    if not np.isnan(cur):
                        if abs(cur - prev) <= delta:
                            cur = update(cur, prev)
                            v[y, x] = cur
                        prev, run = cur, 0
                    elif it == 0 and not reverse and holes and not np.isnan(prev) \
                            and run < holes:
                        v[y, x], filled[y, x] = prev, True
                        run += 1
                    else:
                        prev, run = float('nan'), run + 1
        for reverse in (False, True):
            for x in range(w):
                prev = float(v[h - 1 if reverse else 0, x])
                for y in (range(h - 2, -1, -1) if reverse else range(1, h)):
                    cur = float(v[y, x])
                    if not np.isnan(cur) and abs(cur - prev) <= delta:
                        cur = update(cur, prev)
                        v[y, x] = cur
                    prev = cur
    return v, filled


# -- depth_nodes.core.depth_filter.temporal ----------------------------------------------------
def temporal_reference(values: F32, var: F32, state: TemporalState, alpha: float,
                       delta: float, persistence: int) -> tuple[F32, F32, B]:
    """Plain numpy reference of :func:`temporal_step` (for the tests)."""
    v = np.asarray(values, np.float32)
    need, mask = _persistence(persistence)
    p, pv, bits = state.values, state.var, state.history.astype(np.int64)
    valid = np.isfinite(v)
    with np.errstate(invalid='ignore'):
        close = valid & (np.abs(v - p) <= delta)
    counts = np.array([bin(b & mask).count('1') for b in bits.ravel()]).reshape(v.shape)
    kept = ~valid & np.isfinite(p) & ((need < 0) | ((need > 0) & (counts >= need)))
    out = np.where(close, (alpha * v + (1 - alpha) * p).astype(np.float32), v)
    out = np.where(kept, p, out).astype(np.float32)
    out_var = np.where(close, alpha ** 2 * var + (1 - alpha) ** 2 * pv, var)
    out_var = np.where(kept, pv, np.where(valid, out_var, np.nan)).astype(np.float32)
    state.history = (((bits << 1) | valid) & 0xFF).astype(np.uint8)
    state.values, state.var = out.copy(), out_var.copy()
    return out, out_var, kept


# -- depth_nodes.core.depth_filter.temporal: the warp -------------------------------------------
def warp_reference(state: TemporalState, camera: Intrinsics, motion: Motion,
                   disparity: bool) -> TemporalState:
    """:func:`~depth_nodes.core.depth_filter.temporal.warp_state` written out: each target
    pixel takes, of all the past points whose box footprint covers its centre, the nearest.
    """
    R = check_rotation(motion[0])
    t = np.asarray(motion[1], np.float64)
    src, dst = state.camera.vector, camera.vector
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
