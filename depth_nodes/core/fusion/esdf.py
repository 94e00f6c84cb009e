"""The Euclidean signed distance field (ESDF) of the fused volume, for planning: a
horizontal slice, and the distance at any point. No ROS.

Sites are the observed voxels within one voxel of the surface (|sdf| <= s); a site's
distance is its own TSDF value, any other observed voxel's is the Euclidean distance to the
nearest site's centre, positive in free space, negative behind the surface (the TSDF's
sign), within ``max_distance`` (farther: ``max_distance``). Unobserved voxels have none
(NaN): unknown space is neither free nor occupied.

The slice at ``height`` along ``axis`` (``z`` for a REP 103 world, ``y`` for the
simulator's optical-frame worlds, whose y points down) is computed over the blocks of the
band ``height +- max_distance``: per layer of the band an exact 2-D Euclidean distance
transform to that layer's sites (OpenCV's), then for each cell of the slice the nearest
site over the layers, ``min_l sqrt(D_l^2 + (l - l_slice)^2)``: exact to the sites'
centres. It is recomputed over the band when asked, not updated voxel by voxel as
voxblox's and nvblox's are; :func:`esdf_slice`'s time is what ``bench fusion`` reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
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


@numba.njit(cache=True, nogil=True, parallel=True)
def _scatter(slots: I32, coords: I32, tsdf: F32, weight: F32, block: int, axis: int,
             low: int, origin_u: int, origin_v: int, truncation: float, voxel: float,
             min_weight: float, value: F32, site: NDArray[np.uint8]) -> None:
    """The band's voxels into dense (layers, U, V) arrays: ``value`` the sdf (NaN
    unobserved), ``site`` 0 at a site, 1 elsewhere (OpenCV's distance is to the 0s)."""
    u_axis = 1 if axis == 0 else 0
    v_axis = 1 if axis == 2 else 2
    layers = value.shape[0]
    for n in numba.prange(len(slots)):
        slot = slots[n]
        for c in range(block):
            for b in range(block):
                for a in range(block):
                    g0 = coords[slot, 0] * block + a
                    g1 = coords[slot, 1] * block + b
                    g2 = coords[slot, 2] * block + c
                    g = (g0, g1, g2)
                    layer = g[axis] - low
                    if layer < 0 or layer >= layers:
                        continue
                    u = g[u_axis] - origin_u
                    v = g[v_axis] - origin_v
                    e = (c * block + b) * block + a
                    if weight[slot, e] > min_weight:
                        sdf = tsdf[slot, e] * truncation
                        value[layer, u, v] = sdf
                        if abs(sdf) <= voxel:
                            site[layer, u, v] = 0


def esdf_slice(volume: TsdfVolume, *, axis: str = 'z', height: float = 0.0,
               max_distance: float = 2.0) -> EsdfSlice:
    """The distance field on the plane ``axis = height`` (see the module notes).

    Raises:
        ArgumentError: An unknown axis, or a max_distance that is not positive.
    """
    if axis not in AXES:
        raise ArgumentError(f'esdf axis {axis!r}: must be one of {", ".join(AXES)}')
    if not max_distance > 0:
        raise ArgumentError(f'esdf max_distance {max_distance}: must be positive')
    p = volume.params
    s, bsize = p.voxel_size, p.block_size
    k = AXES.index(axis)
    centre = math.floor(height / s + 0.5)
    reach = math.ceil(max_distance / s)
    low, high = centre - reach, centre + reach
    slots = volume.slots()
    first = volume.coords[slots, k] * bsize
    slots = slots[(first + bsize - 1 >= low) & (first <= high)]
    empty = EsdfSlice(np.empty((0, 3), np.float32), np.empty(0, np.float32))
    if not len(slots):
        return empty
    others = [m for m in range(3) if m != k]
    lo = volume.coords[slots][:, others].min(axis=0) * bsize
    hi = (volume.coords[slots][:, others].max(axis=0) + 1) * bsize
    layers = high - low + 1
    value = np.full((layers, hi[0] - lo[0], hi[1] - lo[1]), np.nan, np.float32)
    site = np.ones(value.shape, np.uint8)
    _scatter(slots, volume.coords, volume.tsdf, volume.weight, bsize, k, low, int(lo[0]),
             int(lo[1]), p.truncation_m, s, p.min_weight, value, site)
    mid = centre - low
    known = np.isfinite(value[mid])
    if not known.any():
        return empty
    nearest = np.full(known.shape, np.inf, np.float32)
    for layer in range(layers):
        if site[layer].all():
            continue
        d2 = cv2.distanceTransform(site[layer], cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        np.minimum(nearest, np.sqrt(d2 * d2 + float((layer - mid) ** 2)), out=nearest)
    sdf = value[mid]
    distance = np.minimum(nearest * s, max_distance)
    distance = np.where(site[mid] == 0, sdf, np.where(sdf < 0, -distance, distance))
    u, v = np.nonzero(known)
    grid = np.empty((len(u), 3), np.float64)
    grid[:, k] = centre
    grid[:, others[0]] = u + lo[0]
    grid[:, others[1]] = v + lo[1]
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
        sign = -1.0 if tsdf[own, e] < 0.0 else 1.0
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
                        if d == 0.0:
                            d = abs(sdf)
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
