"""Projective integration of a depth image into the volume's blocks (KinectFusion's TSDF
update, per voxel): which blocks a frame touches, which of the allocated blocks it sees,
and the update of their voxels. No ROS; the kernels take arrays and scalars only (their
plain references are in ``test/reference/fusion.py``).

Voxel ``(a, b, c)`` of block ``(i, j, k)`` sits at the grid point
``((i B + a) s, (j B + b) s, (k B + c) s)`` of the world (``s`` the voxel size), and is
element ``(c B + b) B + a`` of the block's arrays. A voxel is projected into the image; its
signed distance is the projective one, ``sdf = D - Z``: the depth of the nearest pixel
minus the voxel's own (as Open3D's; reading the depth bilinearly within one surface cut the
error on noise-free frames but not on noisy ones, and doubled the integration time). With
``sdf`` below minus the truncation ``T`` the voxel is hidden and keeps its value. A depth
beyond ``max_integration_distance`` makes no surface; with ``allow_clear`` it still clears:
voxels nearer than that limit and more than ``T`` before the depth are updated as free
space (voxblox's clearing rays), so an object that leaves before a far background is
carved. Otherwise a voxel takes ``min(1, sdf / T)`` with the observation's weight ``w``::

    value = (value * W + min(1, sdf / T) * w) / (W + w),   W = min(W + w, max_weight)

``w`` is the weighting mode's (:mod:`~depth_nodes.core.fusion.params`), lowered linearly
behind the surface (``weight_dropoff``: by ``(T + sdf) / (T - s)`` once ``sdf < -s``). With
``free_space_carving`` a voxel seen through by more than two truncation distances
(``sdf > 2 T``: not a noisy measurement just past it) that held a surface (value below 1)
first loses half its weight.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.blocks import block_key

__all__ = ['MODE_CODES', 'integrate_blocks', 'touch_samples', 'touch_stride', 'touched_keys',
           'visible_blocks']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
B1 = NDArray[np.bool_]

#: Weighting modes' codes in the kernel.
MODE_CODES = {'constant': 0, 'inverse_square': 1, 'sigma': 2, 'confidence': 3}
#: The weight a voxel keeps when a frame sees through it (free_space_carving) ...
CARVE_FACTOR = 0.5
#: ... by more than this many truncation distances: not a measurement's noise past a
#: surface (measured on depth_orbit, noise 0.0015 Z^2: carving past 1 truncation distance
#: put the median vertex 0.5 mm farther from the surface; past 2, no farther than without).
CARVE_MARGIN = 2.0


@numba.njit(cache=True, nogil=True, parallel=True)
def _touched_rows(depth: F32, cam: F64, rotation: F64, position: F64, voxel: float,
                  shift: int, truncation: float, min_depth: float, max_depth: float,
                  samples: int, stride: int, out: I64, counts: I32) -> None:
    """Per image row, the keys of the blocks the truncation band of its pixels crosses
    (``samples`` points from ``D - T`` to ``D + T`` along each pixel's ray; blocks of
    ``2^shift`` voxels), a key written again only when it differs from the last one of the
    same sample in the row; every ``stride``-th row and column."""
    h, w = depth.shape
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    step = 2.0 * truncation / (samples - 1)
    inv = 1.0 / voxel
    for row in numba.prange((h + stride - 1) // stride):
        y = row * stride
        base = y * w * samples
        n = 0
        last = np.full(samples, -1, np.int64)
        ry = (y - cy) / fy
        for x in range(0, w, stride):
            d = depth[y, x]
            if not (d > 0.0) or d < min_depth or d > max_depth:
                continue
            rx = (x - cx) / fx
            # the ray in the world, per metre of Z, in voxels
            dx = (rotation[0, 0] * rx + rotation[0, 1] * ry + rotation[0, 2]) * inv
            dy = (rotation[1, 0] * rx + rotation[1, 1] * ry + rotation[1, 2]) * inv
            dz = (rotation[2, 0] * rx + rotation[2, 1] * ry + rotation[2, 2]) * inv
            for s in range(samples):
                t = d - truncation + s * step
                if t <= 0.0:
                    continue
                # the block of the voxel (grid point) nearest the sample
                i = math.floor(dx * t + position[0] * inv + 0.5) >> shift
                j = math.floor(dy * t + position[1] * inv + 0.5) >> shift
                k = math.floor(dz * t + position[2] * inv + 0.5) >> shift
                key = block_key(i, j, k)
                if key != last[s]:
                    last[s] = key
                    out[base + n] = key
                    n += 1
        counts[y] = n


def touched_keys(depth: F32, cam: F64, rotation: F64, position: F64, *, voxel: float,
                 block: int, truncation: float, min_depth: float, max_depth: float,
                 buffer: I64) -> I64:
    """The unique keys of the blocks holding a voxel within ``truncation`` (metres) of a
    measured surface (a depth in ``[min_depth, max_depth]``), seen from a camera at
    ``(rotation, position)`` (camera -> world).

    Args:
        depth: (H, W) float32 Z, metres; NaN or <= 0 unknown.
        cam: ``(fx, fy, cx, cy)``.
        buffer: int64 scratch of at least ``H W samples`` (see :func:`touch_samples`).
    """
    h, w = depth.shape
    samples = touch_samples(voxel, block, truncation)
    stride = touch_stride(voxel, cam, max_depth)
    counts = np.zeros(h, np.int32)
    shift = block.bit_length() - 1
    if 1 << shift != block:
        raise ValueError(f'a block of {block} voxels: a power of 2 expected')
    _touched_rows(depth, cam, rotation, position, voxel, shift, truncation, min_depth,
                  max_depth, samples, stride, buffer, counts)
    parts = [buffer[y * w * samples:y * w * samples + counts[y]] for y in range(h)
             if counts[y]]
    if not parts:
        return np.empty(0, np.int64)
    return np.unique(np.concatenate(parts))


def touch_stride(voxel: float, cam: F64, max_depth: float) -> int:
    """Pixels between two rays :func:`touched_keys` casts: rays at most a voxel apart at
    ``max_depth`` (nearer, closer still), so a surface a voxel wide is never missed, and a
    frame at 5 cm casts 25 times fewer rays than every pixel."""
    return max(1, math.floor(float(voxel * min(cam[0], cam[1]) / max_depth)))


def touch_samples(voxel: float, block: int, truncation: float) -> int:
    """Points along each ray's truncation band: at most half a block (and one voxel past
    a band narrower than that) apart."""
    step = min(0.5 * block * voxel, truncation)
    return math.ceil(2.0 * truncation / step) + 1


@numba.njit(cache=True, nogil=True, parallel=True)
def visible_blocks(coords: I32, used: B1, voxel: float, block: int, rotation: F64,
                   translation: F64, cam: F64, width: int, height: int,
                   max_depth: float) -> B1:
    """Which of the allocated blocks the camera may see: the block's bounding sphere in
    front of the camera, nearer than ``max_depth`` plus its radius, and over the image.
    ``(rotation, translation)`` takes world points into the camera."""
    n = coords.shape[0]
    out = np.zeros(n, np.bool_)
    side = voxel * block
    half = 0.5 * (block - 1) * voxel
    radius = math.sqrt(3.0) * 0.5 * side
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    for b in numba.prange(n):
        if not used[b]:
            continue
        wx = coords[b, 0] * side + half
        wy = coords[b, 1] * side + half
        wz = coords[b, 2] * side + half
        x = rotation[0, 0] * wx + rotation[0, 1] * wy + rotation[0, 2] * wz + translation[0]
        y = rotation[1, 0] * wx + rotation[1, 1] * wy + rotation[1, 2] * wz + translation[1]
        z = rotation[2, 0] * wx + rotation[2, 1] * wy + rotation[2, 2] * wz + translation[2]
        if z <= -radius or z - radius > max_depth:
            continue
        if z > radius:
            reach_x = radius * fx / (z - radius)
            reach_y = radius * fy / (z - radius)
            u = fx * x / z + cx
            v = fy * y / z + cy
            if u + reach_x < -0.5 or u - reach_x > width - 0.5 or \
                    v + reach_y < -0.5 or v - reach_y > height - 0.5:
                continue
        out[b] = True
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def integrate_blocks(depth: F32, aux: F32, mode: int, cam: F64, rotation: F64,
                     translation: F64, slots: I32, coords: I32, tsdf: F32, weight: F32,
                     voxel: float, block: int, truncation: float, min_depth: float,
                     max_depth: float,
                     max_weight: float, dropoff: bool, carving: bool, clear: bool, updated: B1,
                     counts: I64) -> None:
    """Update the voxels of blocks ``slots`` with one depth image (see the module notes);
    ``(rotation, translation)`` takes world points into the camera; ``aux`` is the sigma
    or confidence image of modes 2 and 3. Sets ``updated`` of each block with a voxel
    updated, and ``counts[n]`` to the voxels of block ``slots[n]`` updated."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    height, width = depth.shape
    for n in numba.prange(len(slots)):
        slot = slots[n]
        ox = coords[slot, 0] * block
        oy = coords[slot, 1] * block
        oz = coords[slot, 2] * block
        count = 0
        # a step along the block's x axis, in the camera
        sx, sy, sz = rotation[0, 0] * voxel, rotation[1, 0] * voxel, rotation[2, 0] * voxel
        wx0 = ox * voxel
        for c in range(block):
            for b in range(block):
                wy = (oy + b) * voxel
                wz = (oz + c) * voxel
                # the row's first voxel in the camera, then one step per voxel
                x = rotation[0, 0] * wx0 + rotation[0, 1] * wy + rotation[0, 2] * wz + \
                    translation[0] - sx
                y = rotation[1, 0] * wx0 + rotation[1, 1] * wy + rotation[1, 2] * wz + \
                    translation[1] - sy
                z = rotation[2, 0] * wx0 + rotation[2, 1] * wy + rotation[2, 2] * wz + \
                    translation[2] - sz
                for a in range(block):
                    x += sx
                    y += sy
                    z += sz
                    if z <= 0.0:
                        continue
                    inverse = 1.0 / z
                    u = fx * x * inverse + cx
                    v = fy * y * inverse + cy
                    xn = math.floor(u + 0.5)
                    yn = math.floor(v + 0.5)
                    if xn < 0 or yn < 0 or xn >= width or yn >= height:
                        continue
                    d = depth[yn, xn]
                    if not (d > 0.0) or d < min_depth or d == math.inf:
                        continue
                    sdf = d - z
                    if sdf < -truncation:
                        continue
                    # a depth past max_depth only clears the free space before it (clear)
                    if d > max_depth and (not clear or z > max_depth or sdf <= truncation):
                        continue
                    if mode == 0:
                        obs = 1.0
                    elif mode == 1:
                        obs = 1.0 / (d * d)
                    elif mode == 2:
                        sigma = aux[yn, xn]
                        if not (sigma > 0.0) or not math.isfinite(sigma):
                            continue
                        obs = (voxel / sigma) ** 2
                    else:
                        obs = aux[yn, xn]
                        if not (obs > 0.0) or not math.isfinite(obs):
                            continue
                    if dropoff and sdf < -voxel:
                        obs *= (truncation + sdf) / (truncation - voxel)
                        if obs <= 0.0:
                            continue
                    e = (c * block + b) * block + a
                    value = min(1.0, sdf / truncation)
                    old = weight[slot, e]
                    if carving and sdf > CARVE_MARGIN * truncation and tsdf[slot, e] < 1.0:
                        old *= CARVE_FACTOR
                    total_weight = old + obs
                    tsdf[slot, e] = (tsdf[slot, e] * old + value * obs) / total_weight
                    weight[slot, e] = min(total_weight, max_weight)
                    count += 1
        if count:
            updated[slot] = True
        counts[n] = count


@numba.njit(cache=True, nogil=True, parallel=True)
def decay_blocks(slots: I32, tsdf: F32, weight: F32, factor: float, min_weight: float,
                 observed: I32) -> None:
    """Multiply the weights of blocks ``slots`` by ``factor``; a voxel that falls below
    ``min_weight`` becomes unobserved (weight and value 0); ``observed[n]`` counts the
    voxels block ``slots[n]`` still observes."""
    for n in numba.prange(len(slots)):
        slot = slots[n]
        kept = 0
        for e in range(weight.shape[1]):
            w = weight[slot, e] * factor
            if w < min_weight or w <= 0.0:
                weight[slot, e] = 0.0
                tsdf[slot, e] = 0.0
            else:
                weight[slot, e] = w
                kept += 1
        observed[n] = kept
