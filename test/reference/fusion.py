"""Plain references of :mod:`depth_nodes.core.fusion`'s kernels (small images and volumes
only): one voxel, one cube, one site at a time."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.integrate import CARVE_FACTOR, CARVE_MARGIN, MODE_CODES
from depth_nodes.core.fusion.mesh import CASE_TRIANGLES, CASES, CORNERS, EDGES
from depth_nodes.core.fusion.volume import TsdfVolume
from depth_nodes.core.geometry import Intrinsics, Pose

F32 = NDArray[np.float32]


def touched_blocks_reference(depth: F32, camera: Intrinsics, pose: Pose, *, voxel: float,
                             block: int, truncation: float, min_depth: float,
                             max_depth: float, samples: int,
                             stride: int) -> set[tuple[int, int, int]]:
    """The blocks of the voxels nearest ``samples`` points along the ray of every
    ``stride``-th pixel from ``D - T`` to ``D + T``."""
    out = set()
    step = 2.0 * truncation / (samples - 1)
    for y in range(0, depth.shape[0], stride):
        for x in range(0, depth.shape[1], stride):
            d = float(depth[y, x])
            if not d > 0 or d < min_depth or d > max_depth:
                continue
            ray = np.array([(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0])
            for s in range(samples):
                t = d - truncation + s * step
                if t <= 0:
                    continue
                g = np.floor((pose.rotation @ (ray * t) + pose.position) / voxel + 0.5)
                out.add(tuple(int(v) // block for v in g))
    return out


def measured_reference(depth: F32, u: float, v: float) -> tuple[float, int, int]:
    """The depth at image point (u, v), as the kernel reads it: the nearest pixel's."""
    h, w = depth.shape
    xn, yn = math.floor(u + 0.5), math.floor(v + 0.5)
    if not (0 <= xn < w and 0 <= yn < h):
        return math.nan, -1, -1
    d = float(depth[yn, xn])
    return (d, xn, yn) if d > 0 else (math.nan, xn, yn)


def integrate_reference(volume: TsdfVolume, slots: Any, depth: F32, camera: Intrinsics,
                        pose: Pose, noise: F32 | None) -> None:
    """Update the voxels of ``slots`` in place, one voxel at a time (the module notes of
    :mod:`depth_nodes.core.fusion.integrate`)."""
    p = volume.params
    s, bs, trunc = p.voxel_size, p.block_size, p.truncation_m
    mode = MODE_CODES[p.weighting_mode]
    to_camera = pose.inverse()
    r, t = to_camera.rotation, to_camera.position
    for slot in slots:
        origin = volume.coords[slot] * bs
        # as the kernel: each row of voxels along x from its first voxel, one step a voxel
        step = (r[0, 0] * s, r[1, 0] * s, r[2, 0] * s)
        wx0 = origin[0] * s
        for c in range(bs):
            for b in range(bs):
                wy, wz = (origin[1] + b) * s, (origin[2] + c) * s
                x = r[0, 0] * wx0 + r[0, 1] * wy + r[0, 2] * wz + t[0] - step[0]
                y = r[1, 0] * wx0 + r[1, 1] * wy + r[1, 2] * wz + t[1] - step[1]
                z = r[2, 0] * wx0 + r[2, 1] * wy + r[2, 2] * wz + t[2] - step[2]
                for a in range(bs):
                    x, y, z = x + step[0], y + step[1], z + step[2]
                    if z <= 0:
                        continue
                    u = camera.fx * x * (1.0 / z) + camera.cx
                    v = camera.fy * y * (1.0 / z) + camera.cy
                    d, xn, yn = measured_reference(depth, u, v)
                    if not d > 0 or d < p.min_integration_distance or d == math.inf:
                        continue
                    sdf = d - z
                    if sdf < -trunc:
                        continue
                    far = d > p.max_integration_distance
                    if far and (not p.allow_clear or z > p.max_integration_distance or
                                sdf <= trunc):
                        continue  # a far depth clears the free space before it only
                    if mode == 0:
                        obs = 1.0
                    elif mode == 1:
                        obs = 1.0 / (d * d)
                    else:
                        aux = float(noise[yn, xn]) if noise is not None else math.nan
                        if not (aux > 0 and math.isfinite(aux)):
                            continue
                        obs = (s / aux) ** 2 if mode == 2 else aux
                    if p.weight_dropoff and sdf < -s:
                        obs *= (trunc + sdf) / (trunc - s)
                        if obs <= 0:
                            continue
                    e = (c * bs + b) * bs + a
                    old = float(volume.weight[slot, e])
                    value = float(volume.tsdf[slot, e])
                    if p.free_space_carving and sdf > CARVE_MARGIN * trunc and value < 1.0:
                        old *= CARVE_FACTOR
                    total = old + obs
                    volume.tsdf[slot, e] = (value * old + min(1.0, sdf / trunc) * obs) / total
                    volume.weight[slot, e] = min(total, p.max_weight)


def _voxel(volume: TsdfVolume, g: tuple[int, int, int]) -> tuple[float, float]:
    """(value, weight) of the voxel at grid point g; (0, 0) in a block not allocated."""
    bs = volume.params.block_size
    key = np.array([[v // bs for v in g]], np.int32)
    from depth_nodes.core.fusion.blocks import coords_keys
    slot = int(volume.table.find(coords_keys(key))[0])
    if slot < 0:
        return 0.0, 0.0
    a, b, c = (v - bs * (v // bs) for v in g)
    e = (c * bs + b) * bs + a
    return float(volume.tsdf[slot, e]), float(volume.weight[slot, e])


def block_triangles_reference(volume: TsdfVolume, slot: int) -> F32:
    """One block's marching-cubes triangle soup, one cube at a time, through the case
    table (whose own correctness the mesh tests check by its properties)."""
    p = volume.params
    bs, s = p.block_size, p.voxel_size
    origin = volume.coords[slot] * bs
    rows: list[list[float]] = []
    for c in range(bs):
        for b in range(bs):
            for a in range(bs):
                base = origin + np.array([a, b, c])
                corners = [_voxel(volume, tuple(int(v) for v in base + CORNERS[k]))
                           for k in range(8)]
                if any(not w > p.min_weight for _, w in corners):
                    continue
                f = [v for v, _ in corners]
                case = sum(1 << k for k in range(8) if f[k] < 0)
                for m in range(3 * int(CASE_TRIANGLES[case])):
                    lo, hi = EDGES[CASES[case, m]]
                    t = f[lo] / (f[lo] - f[hi])
                    rows.append([float((base[i] + CORNERS[lo, i] +
                                        t * (CORNERS[hi, i] - CORNERS[lo, i])) * s)
                                 for i in range(3)])
    return np.array(rows, np.float32).reshape(-1, 3)


def site_distance_reference(volume: TsdfVolume, point: Any, max_distance: float) -> float:
    """The signed distance at a point: to the nearest site's centre over every block."""
    p = volume.params
    bs, s, trunc = p.block_size, p.voxel_size, p.truncation_m
    g = tuple(math.floor(v / s + 0.5) for v in point)
    value, weight = _voxel(volume, g)  # type: ignore[arg-type]
    if not weight > p.min_weight:
        return math.nan
    if abs(value * trunc) <= s:
        return value * trunc  # a site: its own value
    best = max_distance
    for slot in volume.slots():
        for e in range(bs ** 3):
            if not volume.weight[slot, e] > p.min_weight:
                continue
            sdf = float(volume.tsdf[slot, e]) * trunc
            if abs(sdf) > s:
                continue
            local = np.array([e % bs, (e // bs) % bs, e // (bs * bs)])
            centre = (volume.coords[slot] * bs + local) * s
            d = float(np.linalg.norm(centre - np.asarray(point)))
            best = min(best, d)
    return -best if value < 0 else best
