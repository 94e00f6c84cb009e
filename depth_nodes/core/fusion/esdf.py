"""The Euclidean signed distance field (ESDF) of the fused volume, for planning: a
horizontal slice, and the distance at any point. No ROS.

Sites are the observed voxels within one voxel of the surface (|sdf| <= s); a site's
distance is its own TSDF value, any other observed voxel's is the Euclidean distance to the
nearest site's centre, positive in free space, negative behind the surface (the TSDF's
sign), up to ``max_distance`` (farther: ``max_distance``). Unobserved voxels have none:
unknown space is neither free nor occupied.

The slice at ``height`` along ``axis`` (``z`` for a REP 103 world, ``y`` for the
simulator's optical-frame worlds, whose y points down) covers the square of half side
``radius`` around ``centre`` (the camera). The 3-D distance from a cell p of the slice to
the sites within ``max_distance`` of its plane is ``min over columns q of |p - q|^2 +
f(q)``, with ``f(q)`` the smallest squared height of a site above or below q: one 2-D
distance transform of a sampled function (Felzenszwalb and Huttenlocher, 2012), two passes
of lower envelopes of parabolas, exact, in time linear in the cells whatever the band's
height. It is recomputed over the square when asked, not updated voxel by voxel as
voxblox's and nvblox's are; ``bench fusion`` reports its time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.blocks import block_key, lookup
from depth_nodes.core.fusion.volume import TsdfVolume
from depth_nodes.errors import ArgumentError

__all__ = ['AXES', 'EsdfSlice', 'esdf_distance', 'esdf_slice']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

#: The axis a slice is across.
AXES = ('x', 'y', 'z')


@dataclass
class EsdfSlice:
    """A slice of the distance field.

    Attributes:
        points: (N, 3) float32 world positions of the slice's observed voxels.
        distance: (N,) float32 their signed distance, metres.
    """

    points: F32
    distance: F32


@numba.njit(cache=True, nogil=True)
def _scatter(slots: I32, coords: I32, tsdf: F32, weight: F32, block: int, axis: int,
             mid: int, reach: int, origin_u: int, origin_v: int, truncation: float,
             voxel: float, min_weight: float, value: F32, lowest: F64) -> None:
    """The band's voxels into the slice's grids: ``value`` the sdf of the slice's own voxels
    (NaN unobserved), ``lowest`` the smallest squared height (in voxels) of a site over
    each cell."""
    u_axis = 1 if axis == 0 else 0
    v_axis = 1 if axis == 2 else 2
    nu, nv = value.shape
    for n in range(len(slots)):
        slot = slots[n]
        for c in range(block):
            for b in range(block):
                for a in range(block):
                    g = (coords[slot, 0] * block + a, coords[slot, 1] * block + b,
                         coords[slot, 2] * block + c)
                    height = g[axis] - mid
                    if height < -reach or height > reach:
                        continue
                    u = g[u_axis] - origin_u
                    v = g[v_axis] - origin_v
                    if u < 0 or v < 0 or u >= nu or v >= nv:
                        continue
                    e = (c * block + b) * block + a
                    if not weight[slot, e] > min_weight:
                        continue
                    sdf = tsdf[slot, e] * truncation
                    if height == 0:
                        value[u, v] = sdf
                    if abs(sdf) <= voxel:
                        lowest[u, v] = min(lowest[u, v], float(height * height))


@numba.njit(cache=True, nogil=True)
def _envelope(f: F64, out: F64, hull: I64, bounds: F64) -> None:
    """``out[p] = min_q (p - q)^2 + f[q]`` along one line (the lower envelope of
    parabolas; infinite ``f`` is no parabola)."""
    n = len(f)
    k = -1
    for q in range(n):
        if not f[q] < math.inf:
            continue
        while k >= 0:
            r = hull[k]
            cut = ((f[q] + q * q) - (f[r] + r * r)) / (2.0 * (q - r))
            if cut <= bounds[k]:
                k -= 1
            else:
                break
        k += 1
        hull[k] = q
        bounds[k] = -math.inf if k == 0 else \
            ((f[q] + q * q) - (f[hull[k - 1]] + hull[k - 1] ** 2)) / (2.0 * (q - hull[k - 1]))
    if k < 0:
        for p in range(n):
            out[p] = math.inf
        return
    j = 0
    for p in range(n):
        while j < k and bounds[j + 1] < p:
            j += 1
        r = hull[j]
        out[p] = (p - r) * (p - r) + f[r]


@numba.njit(cache=True, nogil=True, parallel=True)
def _transform(f: F64) -> F64:
    """The 2-D transform of ``f``: rows, then columns."""
    nu, nv = f.shape
    rows = np.empty_like(f)
    for u in numba.prange(nu):
        hull = np.empty(nv, np.int64)
        bounds = np.empty(nv, np.float64)
        _envelope(f[u], rows[u], hull, bounds)
    out = np.empty_like(f)
    for v in numba.prange(nv):
        hull = np.empty(nu, np.int64)
        bounds = np.empty(nu, np.float64)
        column = np.empty(nu, np.float64)
        _envelope(rows[:, v].copy(), column, hull, bounds)
        out[:, v] = column
    return out


def esdf_slice(volume: TsdfVolume, *, axis: str = 'z', height: float = 0.0,
               max_distance: float = 2.0, centre: F64 | None = None,
               radius: float = 10.0) -> EsdfSlice:
    """The distance field on the plane ``axis = height`` within ``radius`` (metres, a
    square) of ``centre`` (default: the origin) (see the module notes).

    Raises:
        ArgumentError: An unknown axis, or a max_distance or radius that is not positive.
    """
    if axis not in AXES:
        raise ArgumentError(f'esdf axis {axis!r}: must be one of {", ".join(AXES)}')
    if not max_distance > 0 or not radius > 0:
        raise ArgumentError(f'esdf max_distance {max_distance} and radius {radius}: must be '
                            'positive')
    p = volume.params
    s, bsize = p.voxel_size, p.block_size
    k = AXES.index(axis)
    others = [m for m in range(3) if m != k]
    mid = math.floor(height / s + 0.5)
    reach = math.ceil(max_distance / s)
    where = np.zeros(3) if centre is None else np.asarray(centre, np.float64)
    half = math.ceil(radius / s)
    # sites up to max_distance beyond the square still count for its cells
    origin = [math.floor(where[m] / s + 0.5) - half - reach for m in others]
    size = 2 * (half + reach) + 1
    slots = volume.slots()
    first = volume.coords[slots] * bsize
    near = (first[:, k] + bsize - 1 >= mid - reach) & (first[:, k] <= mid + reach)
    for m, low in zip(others, origin, strict=True):
        near &= (first[:, m] + bsize - 1 >= low) & (first[:, m] < low + size)
    slots = slots[near]
    empty = EsdfSlice(np.empty((0, 3), np.float32), np.empty(0, np.float32))
    if not len(slots):
        return empty
    value = np.full((size, size), np.nan, np.float32)
    lowest = np.full((size, size), np.inf, np.float64)
    _scatter(slots, volume.coords, volume.tsdf, volume.weight, bsize, k, mid, reach,
             origin[0], origin[1], p.truncation_m, s, p.min_weight, value, lowest)
    inner = np.zeros((size, size), bool)
    inner[reach:size - reach, reach:size - reach] = True
    known = inner & np.isfinite(value)
    if not known.any():
        return empty
    nearest = np.sqrt(_transform(lowest)) * s
    distance = np.minimum(nearest, max_distance)
    sdf = value
    distance = np.where(np.abs(sdf) <= s, sdf, np.where(sdf < 0, -distance, distance))
    u, v = np.nonzero(known)
    grid = np.empty((len(u), 3), np.float64)
    grid[:, k] = mid
    grid[:, others[0]] = u + origin[0]
    grid[:, others[1]] = v + origin[1]
    return EsdfSlice((grid * s).astype(np.float32), distance[known].astype(np.float32))


@numba.njit(cache=True, nogil=True, parallel=True)
def _distances(points: F64, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
               table_slots: I32, block: int, voxel: float, truncation: float,
               min_weight: float, max_distance: float, out: F64) -> None:
    reach = math.ceil(max_distance / (voxel * block)) + 1
    for n in numba.prange(points.shape[0]):
        gx = math.floor(points[n, 0] / voxel + 0.5)
        gy = math.floor(points[n, 1] / voxel + 0.5)
        gz = math.floor(points[n, 2] / voxel + 0.5)
        own = lookup(table_keys, table_slots, block_key(gx // block, gy // block, gz // block))
        if own < 0:
            out[n] = math.nan
            continue
        e = ((gz - coords[own, 2] * block) * block + gy - coords[own, 1] * block) * block + \
            gx - coords[own, 0] * block
        if not weight[own, e] > min_weight:
            out[n] = math.nan
            continue
        own_sdf = tsdf[own, e] * truncation
        if abs(own_sdf) <= voxel:
            # a site: its own value, as the slice's
            out[n] = own_sdf
            continue
        sign = -1.0 if own_sdf < 0.0 else 1.0
        best = max_distance
        for dk in range(-reach, reach + 1):
            for dj in range(-reach, reach + 1):
                for di in range(-reach, reach + 1):
                    i, j, k = gx // block + di, gy // block + dj, gz // block + dk
                    slot = lookup(table_keys, table_slots, block_key(i, j, k))
                    if slot < 0:
                        continue
                    for f in range(block * block * block):
                        if not weight[slot, f] > min_weight:
                            continue
                        sdf = tsdf[slot, f] * truncation
                        if abs(sdf) > voxel:
                            continue
                        a = f % block
                        b = (f // block) % block
                        c = f // (block * block)
                        dx = (i * block + a) * voxel - points[n, 0]
                        dy = (j * block + b) * voxel - points[n, 1]
                        dz = (k * block + c) * voxel - points[n, 2]
                        d = math.sqrt(dx * dx + dy * dy + dz * dz)
                        if d < best:
                            best = d
        out[n] = sign * best


def esdf_distance(volume: TsdfVolume, points: F64, *, max_distance: float = 2.0) -> F64:
    """The signed distance at each of (N, 3) world points (NaN where the voxel holding a
    point is unobserved); the distance to the nearest site's centre, as the slice's.

    Raises:
        ArgumentError: Points not (N, 3), or a max_distance that is not positive.
    """
    pts = np.ascontiguousarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ArgumentError(f'points must be (N, 3), got {pts.shape}')
    if not max_distance > 0:
        raise ArgumentError(f'esdf max_distance {max_distance}: must be positive')
    p = volume.params
    out = np.empty(len(pts), np.float64)
    _distances(pts, volume.coords, volume.tsdf, volume.weight, volume.table.keys,
               volume.table.slots, p.block_size, p.voxel_size, p.truncation_m, p.min_weight,
               max_distance, out)
    return out
