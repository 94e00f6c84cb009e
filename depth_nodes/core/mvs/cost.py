"""The plane-sweep matching cost over a reference view and K source views (numba).

For a reference pixel p and the plane of label k (``n . X = 1 / rho_k`` in the reference
frame) the 3-D point on p's ray is ``X = r / (rho_k s)`` with ``r = K_ref^-1 (x, y, 1)``
and ``s = n . r``. Source view j (``X_j = R_j X + t_j``) sees it at the homogeneous pixel

    q = a_j + rho_k s b_j,    a_j = K_j R_j r,    b_j = K_j t_j

(the plane's homography ``K_j (R_j + rho_k t_j n^T) K_ref^-1`` applied to p, written so
that the per-pixel part ``a_j`` is computed once for all planes). There the cost is the
stereo matcher's: the Hamming distance between the census signatures of p and of the
source pixel nearest to q, plus the absolute difference of the intensities (the source
bilinearly interpolated at q, brightness matched to the reference), truncated; both
weighted, clipped to 254. A plane behind a source camera or outside its image gives that
view no cost for that label.

Views are combined per label by best-k (Kang, Szeliski and Chai 2001, "Handling occlusions
in dense multi-view stereo"): the mean of the k smallest costs of the views that see the
point, so a point hidden in some views is matched in the others. A label no view sees gets
``unseen_cost``. Layout as the stereo matcher's: the label innermost, uint8, so its
aggregation and selection kernels run on this volume unchanged.

:func:`sweep_cost_reference` is the plain numpy version the tests compare with.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.core.depth_image import Intrinsics
from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.mvs.geometry import SweepPlanes
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.sgm.census import census_dtype, census_transform, popcount
from depth_nodes.errors import ArgumentError

__all__ = ['MAX_SOURCES', 'SweepCostInputs', 'camera_matrix', 'sweep_cost_inputs',
           'sweep_cost_reference', 'sweep_cost_volume']

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
#: Most source views one sweep combines (the kernel's per-pixel scratch is sized by it).
MAX_SOURCES = 16
#: The largest cost of a seen label (255 is left for the stereo matcher's out-of-range).
TOP_COST = 254
#: A homogeneous depth below this (in the source camera) counts as behind it.
MIN_W = 1e-9


def camera_matrix(camera: Intrinsics) -> F64:
    """The (3, 3) pinhole matrix K of ``camera``."""
    return np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy],
                     [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class SweepCostInputs:
    """What the cost of any row needs, prepared once per reference frame; :meth:`rows`
    fills any band of rows (the matcher never holds more than its bands).

    Attributes:
        ref_census: (H, W) census of the reference image.
        ref_grey: (H, W) float32 reference intensities.
        src_census: (K, H, W) census of the source images.
        src_grey: (K, H, W) float32 source intensities, brightness matched to the reference.
        k_inv: (3, 3) inverse of the reference camera matrix.
        normal: (3,) the planes' unit normal, reference frame.
        a_matrix: (K, 3, 3) ``K_j R_j K_ref^-1``.
        b_vector: (K, 3) ``K_j t_j``.
        rho: (D,) inverse depth of each label.
        census_weight: Weight of the Hamming distance.
        intensity_weight: Weight of the absolute difference.
        truncation: Cap of the absolute difference, grey levels.
        best_k: Views averaged per label (at most the views that see the point).
        unseen_cost: Cost of a label no source view sees.
    """

    ref_census: NDArray[Any]
    ref_grey: F32
    src_census: NDArray[Any]
    src_grey: F32
    k_inv: F64
    normal: F64
    a_matrix: F64
    b_vector: F64
    rho: F64
    census_weight: int
    intensity_weight: int
    truncation: int
    best_k: int
    unseen_cost: int

    @property
    def shape(self) -> tuple[int, int, int]:
        """(H, W, D) of the volume."""
        h, w = self.ref_grey.shape
        return h, w, len(self.rho)

    def rows(self, y0: int, out: U8) -> U8:
        """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out`` (one thread)."""
        views = self.src_grey.shape[0]
        scratch = np.empty((views, len(self.rho)), np.int32)
        order = np.empty(views, np.int32)
        _sweep_rows(self.ref_census, self.ref_grey, self.src_census, self.src_grey, self.k_inv,
                    self.normal, self.a_matrix, self.b_vector, self.rho, y0,
                    self.census_weight, self.intensity_weight, self.truncation, self.best_k,
                    self.unseen_cost, scratch, order, out)
        return out


def sweep_cost_inputs(reference: NDArray[Any], camera: Intrinsics, sources: list[NDArray[Any]],
                      source_cameras: list[Intrinsics], relative: list[tuple[F64, F64]],
                      planes: SweepPlanes, *, census_window: tuple[int, int] = (5, 5),
                      census_weight: int = 1, intensity_weight: int = 1,
                      truncation: int = 30, best_k: int = 2, unseen_cost: int = 64,
                      match_brightness: bool = True,
                      source_census: list[NDArray[Any] | None] | None = None
                      ) -> SweepCostInputs:
    """Prepare the sweep of ``reference`` over ``sources``.

    Args:
        reference: (H, W) grey reference image.
        camera: Its pinhole camera.
        sources: Grey source images, each (H, W).
        source_cameras: Their pinhole cameras.
        relative: Per source, ``(R, t)`` taking reference-frame points into its frame
            (:meth:`Pose.relative_to`).
        planes: The labels.
        census_window: (height, width) of the census, odd, at most 63 neighbours.
        census_weight: Weight of the census term (0: intensity only).
        intensity_weight: Weight of the intensity term (0: census only).
        truncation: Cap of the intensity difference, grey levels.
        best_k: Views averaged per label (1..len(sources)).
        unseen_cost: Cost of a label no source sees (0..254).
        match_brightness: Give each source the reference's mean and spread first (an
            exposure change between frames).
        source_census: Census images of the sources already computed (a keyframe's is
            reused by every reference it serves), None where not.

    Raises:
        ArgumentError: Sizes or counts that do not fit, or settings out of range.
    """
    ref = np.asarray(reference)
    if ref.ndim != 2:
        raise ArgumentError(f'the reference must be a grey (H, W) image, got {ref.shape}')
    if not 1 <= len(sources) <= MAX_SOURCES:
        raise ArgumentError(f'a sweep needs 1 to {MAX_SOURCES} source views, got '
                            f'{len(sources)}')
    if not len(sources) == len(source_cameras) == len(relative):
        raise ArgumentError('sources, source_cameras and relative poses differ in number')
    for image in sources:
        if np.asarray(image).shape != ref.shape:
            raise ArgumentError(f'every source must be {ref.shape[1]}x{ref.shape[0]} like '
                                f'the reference, got {np.asarray(image).shape}')
    if not 1 <= best_k <= len(sources):
        raise ArgumentError(f'best_k must be in 1..{len(sources)} (the sources), got {best_k}')
    if not 0 <= unseen_cost <= TOP_COST:
        raise ArgumentError(f'unseen_cost must be in 0..{TOP_COST}, got {unseen_cost}')
    planes.validate()
    dtype = census_dtype(census_window)
    ref_census = census_transform(ref, census_window, np.empty(ref.shape, dtype))
    src_census = np.empty((len(sources), *ref.shape), dtype)
    for j, image in enumerate(sources):
        known = source_census[j] if source_census is not None else None
        if known is not None and known.dtype == dtype and known.shape == ref.shape:
            src_census[j] = known
        else:
            census_transform(image, census_window, src_census[j])
    ref_grey = np.ascontiguousarray(ref, dtype=np.float32)
    src_grey = np.empty((len(sources), *ref.shape), np.float32)
    for j, image in enumerate(sources):
        src_grey[j] = matched_brightness(ref, image) if match_brightness else image
    k_inv = np.linalg.inv(camera_matrix(camera))
    a_matrix = np.empty((len(sources), 3, 3))
    b_vector = np.empty((len(sources), 3))
    for j, ((rotation, translation), cam) in enumerate(zip(relative, source_cameras,
                                                           strict=True)):
        k_src = camera_matrix(cam)
        a_matrix[j] = k_src @ np.asarray(rotation, np.float64) @ k_inv
        b_vector[j] = k_src @ np.asarray(translation, np.float64)
    return SweepCostInputs(ref_census, ref_grey, src_census, src_grey, k_inv,
                           planes.unit_normal, a_matrix, b_vector, planes.inverse_depths(),
                           int(census_weight), int(intensity_weight), int(truncation),
                           int(best_k), int(unseen_cost))


@njit(cache=True, nogil=True, inline='always')
def _bilinear(image: F32, u: float, v: float) -> float:
    """``image`` at (u, v), both inside [0, W - 1] x [0, H - 1]."""
    h, w = image.shape
    x0 = min(int(u), w - 2)
    y0 = min(int(v), h - 2)
    fx = u - x0
    fy = v - y0
    p00 = np.float64(image[y0, x0])
    p01 = np.float64(image[y0, x0 + 1])
    p10 = np.float64(image[y0 + 1, x0])
    p11 = np.float64(image[y0 + 1, x0 + 1])
    top = p00 + fx * (p01 - p00)
    bottom = p10 + fx * (p11 - p10)
    return top + fy * (bottom - top)


@njit(cache=True, nogil=True, inline='always')
def _best_k_mean(costs: NDArray[np.int32], order: NDArray[np.int32], views: int,
                 label: int, best_k: int, unseen: int) -> int:
    """The rounded mean of the ``best_k`` smallest non-negative ``costs[:, label]`` (all
    of them when fewer see it); ``unseen`` when none does."""
    n = 0
    for j in range(views):  # insertion sort of the valid costs: K is small
        c = costs[j, label]
        if c < 0:
            continue
        i = n
        while i > 0 and order[i - 1] > c:
            order[i] = order[i - 1]
            i -= 1
        order[i] = c
        n += 1
    if n == 0:
        return unseen
    used = min(n, best_k)
    total = 0
    for i in range(used):
        total += order[i]
    return (2 * total + used) // (2 * used)


@no_nrt_kernel()
def _sweep_rows(ref_census: NDArray[Any], ref_grey: F32, src_census: NDArray[Any],
                src_grey: F32, k_inv: F64, normal: F64, a_matrix: F64, b_vector: F64,
                rho: F64, y0: int, census_weight: int, intensity_weight: int,
                truncation: int, best_k: int, unseen_cost: int,
                scratch: NDArray[np.int32], order: NDArray[np.int32], out: U8) -> None:
    rows, w, n = out.shape
    views = src_grey.shape[0]
    h = ref_grey.shape[0]
    umax = np.float64(w - 1)
    vmax = np.float64(h - 1)
    cap = np.float64(truncation)
    for yy in range(rows):
        y = y0 + yy
        for x in range(w):
            cell = out[yy, x]
            rx = k_inv[0, 0] * x + k_inv[0, 1] * y + k_inv[0, 2]
            ry = k_inv[1, 0] * x + k_inv[1, 1] * y + k_inv[1, 2]
            rz = k_inv[2, 0] * x + k_inv[2, 1] * y + k_inv[2, 2]
            s = normal[0] * rx + normal[1] * ry + normal[2] * rz
            if not s > 1e-12:  # the planes never cross this pixel's ray in front
                for k in range(n):
                    cell[k] = np.uint8(unseen_cost)
                continue
            cr = ref_census[y, x]
            ir = np.float64(ref_grey[y, x])
            for j in range(views):
                a0 = a_matrix[j, 0, 0] * x + a_matrix[j, 0, 1] * y + a_matrix[j, 0, 2]
                a1 = a_matrix[j, 1, 0] * x + a_matrix[j, 1, 1] * y + a_matrix[j, 1, 2]
                a2 = a_matrix[j, 2, 0] * x + a_matrix[j, 2, 1] * y + a_matrix[j, 2, 2]
                b0 = b_vector[j, 0] * s
                b1 = b_vector[j, 1] * s
                b2 = b_vector[j, 2] * s
                census_j = src_census[j]
                grey_j = src_grey[j]
                for k in range(n):
                    wz = a2 + rho[k] * b2
                    if not wz > MIN_W:
                        scratch[j, k] = -1
                        continue
                    u = (a0 + rho[k] * b0) / wz
                    v = (a1 + rho[k] * b1) / wz
                    if not (0.0 <= u <= umax and 0.0 <= v <= vmax):
                        scratch[j, k] = -1
                        continue
                    value = 0
                    if census_weight:
                        bits = cr ^ census_j[int(v + 0.5), int(u + 0.5)]
                        value += census_weight * int(popcount(bits))
                    if intensity_weight:
                        diff = min(abs(ir - _bilinear(grey_j, u, v)), cap)
                        value += int(intensity_weight * diff + 0.5)
                    scratch[j, k] = min(value, TOP_COST)
            for k in range(n):
                cell[k] = np.uint8(_best_k_mean(scratch, order, views, k, best_k,
                                                unseen_cost))


def sweep_cost_volume(inputs: SweepCostInputs) -> U8:
    """The whole (H, W, D) uint8 cost volume (tests, small images)."""
    out = np.empty(inputs.shape, np.uint8)
    return inputs.rows(0, out)


def sweep_cost_reference(inputs: SweepCostInputs) -> U8:
    """Plain numpy version of :func:`sweep_cost_volume` (same rounding)."""
    h, w, n = inputs.shape
    views = inputs.src_grey.shape[0]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ inputs.k_inv.T
    s = rays @ inputs.normal
    costs = np.full((views, h, w, n), -1, np.int64)
    hamming = np.vectorize(lambda v: bin(int(v)).count('1'), otypes=[np.int64])
    pixels = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    for j in range(views):
        a = pixels @ inputs.a_matrix[j].T  # (h, w, 3)
        for k, rho in enumerate(inputs.rho):
            q = a + (rho * s)[..., None] * inputs.b_vector[j]
            with np.errstate(divide='ignore', invalid='ignore'):
                u, v = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
            ok = (s > 1e-12) & (q[..., 2] > MIN_W) & (u >= 0) & (u <= w - 1) & (v >= 0) & \
                (v <= h - 1)
            value = np.zeros((h, w), np.int64)
            uu, vv = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
            if inputs.census_weight:
                near = inputs.src_census[j][(vv + 0.5).astype(int), (uu + 0.5).astype(int)]
                value += inputs.census_weight * hamming(inputs.ref_census ^ near)
            if inputs.intensity_weight:
                x0 = np.minimum(uu.astype(int), w - 2)
                y0 = np.minimum(vv.astype(int), h - 2)
                fx, fy = uu - x0, vv - y0
                g = inputs.src_grey[j].astype(np.float64)
                top = g[y0, x0] + fx * (g[y0, x0 + 1] - g[y0, x0])
                bottom = g[y0 + 1, x0] + fx * (g[y0 + 1, x0 + 1] - g[y0 + 1, x0])
                diff = np.minimum(np.abs(inputs.ref_grey - (top + fy * (bottom - top))),
                                  inputs.truncation)
                value += (inputs.intensity_weight * diff + 0.5).astype(np.int64)
            costs[j, ..., k] = np.where(ok, np.minimum(value, TOP_COST), -1)
    valid = costs >= 0
    big = np.where(valid, costs, np.iinfo(np.int64).max)
    ordered = np.sort(big, axis=0)
    seen = valid.sum(axis=0)
    used = np.minimum(seen, inputs.best_k)
    total = np.zeros((h, w, n), np.int64)
    for i in range(views):
        total += np.where(i < used, np.where(ordered[i] == np.iinfo(np.int64).max, 0,
                                             ordered[i]), 0)
    mean = (2 * total + used) // np.maximum(2 * used, 1)
    out: U8 = np.where(seen > 0, mean, inputs.unseen_cost).astype(np.uint8)
    return out
