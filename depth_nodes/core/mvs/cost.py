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

The plain numpy version the tests compare with is ``sweep_cost_reference`` in
``test/reference/mvs.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics
from depth_nodes.core.jit import no_nrt_kernel
from depth_nodes.core.mvs.planes import SweepPlanes
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.sgm.census import census_dtype, census_transform, popcount
from depth_nodes.errors import ArgumentError

__all__ = ['COSTS', 'DEPRECATED_COSTS', 'MAX_SOURCES', 'SweepCostInputs',
           'reference_windows', 'sweep_cost_inputs', 'sweep_cost_volume']

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
#: The matching costs: the stereo matcher's (census and intensity, named as sgm_stereo's
#: ``matching_cost`` names it), or ZNCC.
COSTS = ('census', 'zncc')
#: Old names of costs, accepted for one more release as the cost each maps to; a caller
#: that has the name from a user (the multiview_stereo node) can tell them from this table.
DEPRECATED_COSTS = {'census_intensity': 'census'}
#: Most source views one sweep combines (the kernel's per-pixel scratch is sized by it).
MAX_SOURCES = 16
#: The largest cost of a seen label (255 is left for the stereo matcher's out-of-range).
TOP_COST = 254
#: A homogeneous depth below this (in the source camera) counts as behind it.
MIN_W = 1e-9


@dataclass(frozen=True)
class SweepCostInputs:
    """What the cost of any row needs, prepared once per reference frame; :meth:`rows`
    fills any band of rows (the matcher never holds more than its bands).

    Images are flat (H * W, row after row).

    Attributes:
        ref_census: (H * W,) census of the reference image.
        ref_grey: (H * W,) float32 reference intensities.
        src_census: (K, H * W) census of the source images.
        src_grey: (K, H * W) float32 source intensities, brightness matched to the
            reference.
        k_inv: (3, 3) inverse of the reference camera matrix.
        normal: (3,) the planes' unit normal, reference frame.
        a_matrix: (K, 3, 3) ``K_j R_j K_ref^-1``.
        b_vector: (K, 3) ``K_j t_j``.
        rho: (D,) float32 inverse depth of each label.
        census_weight: Weight of the Hamming distance.
        intensity_weight: Weight of the absolute difference.
        truncation: Cap of the absolute difference, grey levels.
        best_k: Views averaged per label (at most the views that see the point).
        unseen_cost: Cost of a label no source view sees.
        height: H.
        width: W.
        zncc: The cost is ZNCC's (a 3 x 3 window), not census and intensity.
        ref_window: ZNCC: (H * W, 10) float32: per reference pixel its 3 x 3 values less
            their mean, over their spread, and (index 9) the spread.
    """

    ref_census: NDArray[Any]
    ref_grey: F32
    src_census: NDArray[Any]
    src_grey: F32
    k_inv: F64
    normal: F64
    a_matrix: F64
    b_vector: F64
    rho: F32
    census_weight: int
    intensity_weight: int
    truncation: int
    best_k: int
    unseen_cost: int

    height: int
    width: int
    zncc: bool = False
    ref_window: F32 = field(default_factory=lambda: np.zeros((0, 10), np.float32))

    @property
    def shape(self) -> tuple[int, int, int]:
        """(H, W, D) of the volume."""
        return self.height, self.width, len(self.rho)

    def rows(self, y0: int, out: U8) -> U8:
        """Rows y0 .. y0 + len(out) - 1 of the cost volume, into ``out`` (one thread)."""
        n = len(self.rho)
        _sweep_rows(self.ref_census, self.ref_grey, self.src_census, self.src_grey, self.k_inv,
                    self.normal, self.a_matrix, self.b_vector, self.rho, y0,
                    self.census_weight, self.intensity_weight, self.truncation, self.best_k,
                    self.unseen_cost, np.empty((self.best_k, n), np.int32),
                    np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32),
                    np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.bool_),
                    self.zncc, self.ref_window, out)
        return out


def sweep_cost_inputs(reference: NDArray[Any], camera: Intrinsics, sources: list[NDArray[Any]],
                      source_cameras: list[Intrinsics], relative: list[tuple[F64, F64]],
                      planes: SweepPlanes, *, census_window: tuple[int, int] = (5, 5),
                      census_weight: int = 1, intensity_weight: int = 1,
                      truncation: int = 30, best_k: int = 2, unseen_cost: int = 64,
                      match_brightness: bool = True,
                      source_census: list[NDArray[Any] | None] | None = None,
                      cost: str = 'census') -> SweepCostInputs:
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
        cost: ``census`` (the stereo matcher's: census and truncated intensity
            difference, by their weights) or ``zncc`` (a 3 x 3 window's ZNCC); a name of
            :data:`DEPRECATED_COSTS` stands for its cost.

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
    cost = DEPRECATED_COSTS.get(cost, cost)
    if cost not in COSTS:
        raise ArgumentError(f'cost {cost!r} is not one of {", ".join(COSTS)}')
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
    k_inv = np.asarray(np.linalg.inv(camera.matrix), np.float64)
    a_matrix = np.empty((len(sources), 3, 3))
    b_vector = np.empty((len(sources), 3))
    for j, ((rotation, translation), cam) in enumerate(zip(relative, source_cameras,
                                                           strict=True)):
        k_src = cam.matrix
        a_matrix[j] = k_src @ np.asarray(rotation, np.float64) @ k_inv
        b_vector[j] = k_src @ np.asarray(translation, np.float64)
    h, w = ref.shape
    window = reference_windows(ref_grey) if cost == 'zncc' else np.zeros((0, 10), np.float32)
    return SweepCostInputs(ref_census.reshape(-1), ref_grey.reshape(-1),
                           src_census.reshape(len(sources), -1),
                           src_grey.reshape(len(sources), -1), k_inv, planes.unit_normal,
                           a_matrix, b_vector, planes.inverse_depths().astype(np.float32),
                           int(census_weight), int(intensity_weight), int(truncation),
                           int(best_k), int(unseen_cost), h, w, cost == 'zncc', window)


#: Cost of a view that does not see a label, in the kernel's sorting (above any real one).
_UNSEEN = 1 << 20


@njit(cache=True, nogil=True, inline='always')
def _zncc_cost(grey: F32, i0: int, w: int, fu: np.float32, fv: np.float32,
               ref_window: F32, at: int) -> np.int32:
    """``round(32 (1 - ZNCC))`` of the reference pixel ``at``'s window and the source's
    3 x 3 window at base pixel ``i0`` with fractions ``(fu, fv)`` (see :func:`_sweep_rows`)."""
    total = np.float32(0.0)
    squares = np.float32(0.0)
    cross = np.float32(0.0)
    c = 0
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            b = i0 + dy * w + dx
            top = grey[b] + fu * (grey[b + 1] - grey[b])
            bottom = grey[b + w] + fu * (grey[b + w + 1] - grey[b + w])
            value = top + fv * (bottom - top)
            total += value
            squares += value * value
            cross += ref_window[at, c] * value
            c += 1
    mean = total / np.float32(9.0)
    spread = squares / np.float32(9.0) - mean * mean
    norm = ref_window[at, 9]
    if not (spread > np.float32(1e-2) and norm > np.float32(0.0)):
        return np.int32(32)  # a flat window: no preference
    zncc = cross / (np.float32(9.0) * np.float32(np.sqrt(spread)))
    return np.int32(np.float32(32.0) * (np.float32(1.0) - min(zncc, np.float32(1.0))) +
                    np.float32(0.5))


@no_nrt_kernel(parallel=True)
def _sweep_rows(ref_census: NDArray[Any], ref_grey: F32, src_census: NDArray[Any],
                src_grey: F32, k_inv: F64, normal: F64, a_matrix: F64, b_vector: F64,
                rho: F32, y0: int, census_weight: int, intensity_weight: int,
                truncation: int, best_k: int, unseen_cost: int, best: NDArray[np.int32],
                row: NDArray[np.int32], seen: NDArray[np.int32], index: NDArray[np.int32],
                frac_u: F32, frac_v: F32, inside: NDArray[np.bool_], zncc: bool,
                ref_window: F32, out: U8) -> None:
    """Rows of the volume. Images are flat (H * W); per pixel and view, a first loop over
    the labels (vectorised) finds each label's source pixel, its bilinear fractions and
    whether it is inside; a second one reads the source there; a third merges the view's
    costs into the ``best_k`` smallest so far of each label (``best``, sorted, a
    compare-exchange per rank: branch-free over the labels).

    With ``zncc`` the cost of a view is ``round(32 (1 - ZNCC))`` of the 3 x 3 window
    around the pixel (``ref_window``: its values less their mean, over their spread) and the
    source's 3 x 3 window at the projection, sampled bilinearly with the same fractions
    (a window translated, not warped: the fronto-parallel approximation of a small patch);
    a flat window costs 32.

    One thread (the matcher runs several bands at once), compiled ``parallel=True``
    around a ``prange`` of one iteration, as the stereo matcher's band kernels
    (``aggregate.py``, ONE_THREAD_GUFUNC): 7.8 against 12.1 ns a view-plane cost here.
    """
    rows, w, n = out.shape
    views = src_grey.shape[0]
    h = ref_grey.shape[0] // w
    zero = np.float32(0.0)
    one = np.float32(1.0)
    half = np.float32(0.5)
    umax = np.float32(w - 1)
    vmax = np.float32(h - 1)
    # the bilinear base pixel stays one short of the last row and column
    ulast = np.float32(w - 1) - np.float32(1e-3)
    vlast = np.float32(h - 1) - np.float32(1e-3)
    cap = np.float32(truncation)
    # a ZNCC window reads one pixel before the base pixel and two after it
    lo = one if zncc else zero
    uhi = np.float32(w - 3) if zncc else umax
    vhi = np.float32(h - 3) if zncc else vmax
    for _ in prange(1):  # one iteration: see aggregate.ONE_THREAD_GUFUNC
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
                at = y * w + x
                cr = ref_census[at]
                ir = ref_grey[at]
                for i in range(best_k):
                    for k in range(n):
                        best[i, k] = _UNSEEN
                for k in range(n):
                    seen[k] = 0
                for j in range(views):
                    a0 = np.float32(a_matrix[j, 0, 0] * x + a_matrix[j, 0, 1] * y +
                                     a_matrix[j, 0, 2])
                    a1 = np.float32(a_matrix[j, 1, 0] * x + a_matrix[j, 1, 1] * y +
                                     a_matrix[j, 1, 2])
                    a2 = np.float32(a_matrix[j, 2, 0] * x + a_matrix[j, 2, 1] * y +
                                     a_matrix[j, 2, 2])
                    b0 = np.float32(b_vector[j, 0] * s)
                    b1 = np.float32(b_vector[j, 1] * s)
                    b2 = np.float32(b_vector[j, 2] * s)
                    for k in range(n):  # vectorises
                        r = rho[k]
                        wz = a2 + r * b2
                        inv = one / wz
                        u = (a0 + r * b0) * inv
                        v = (a1 + r * b1) * inv
                        inside[k] = (wz > zero) & (u >= lo) & (u <= uhi) & (v >= lo) & \
                            (v <= vhi)
                        uc = min(max(u, zero), ulast)
                        vc = min(max(v, zero), vlast)
                        xi = np.int32(uc)
                        yi = np.int32(vc)
                        frac_u[k] = uc - np.float32(xi)
                        frac_v[k] = vc - np.float32(yi)
                        index[k] = yi * np.int32(w) + xi
                    census_j = src_census[j]
                    grey_j = src_grey[j]
                    for k in range(n):
                        if not inside[k]:
                            row[k] = _UNSEEN
                            continue
                        i0 = np.intp(index[k])
                        fu = frac_u[k]
                        fv = frac_v[k]
                        value = np.int32(0)
                        if zncc:
                            value = _zncc_cost(grey_j, int(i0), w, fu, fv, ref_window, at)
                        elif census_weight:
                            near = i0 + np.intp(fu >= half) + np.intp(w) * np.intp(fv >= half)
                            bits = np.int32(popcount(cr ^ census_j[near]))
                            value += np.int32(census_weight) * bits
                        if intensity_weight and not zncc:
                            p00 = grey_j[i0]
                            p01 = grey_j[i0 + 1]
                            p10 = grey_j[i0 + w]
                            p11 = grey_j[i0 + w + 1]
                            top = p00 + fu * (p01 - p00)
                            bottom = p10 + fu * (p11 - p10)
                            diff = min(abs(ir - (top + fv * (bottom - top))), cap)
                            value += np.int32(np.float32(intensity_weight) * diff + half)
                        row[k] = min(value, np.int32(TOP_COST))
                    for k in range(n):
                        seen[k] += np.int32(row[k] < _UNSEEN)
                    for i in range(best_k):  # row carries the larger one on down the ranks
                        for k in range(n):
                            low = min(best[i, k], row[k])
                            row[k] = max(best[i, k], row[k])
                            best[i, k] = low
                for k in range(n):
                    used = min(seen[k], best_k)
                    total = np.int32(0)
                    for i in range(best_k):
                        total += best[i, k] if i < used else np.int32(0)
                    mean = (2 * total + used) // max(2 * used, 1)
                    cell[k] = np.uint8(mean if used > 0 else unseen_cost)


def reference_windows(grey: F32) -> F32:
    """(H * W, 10): each pixel's 3 x 3 window (edges replicated) less its mean, over its
    spread (so that the sum of its products with a window is 9 cov / spread), and the
    spread (index 9; 0 for a flat window, whose first nine are then 0)."""
    h, w = grey.shape
    padded = np.pad(grey.astype(np.float32), 1, mode='edge')
    stack = np.stack([padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=-1)
    mean = stack.mean(axis=-1, keepdims=True, dtype=np.float32)
    centred = stack - mean
    spread = np.sqrt((centred * centred).mean(axis=-1, dtype=np.float32)).astype(np.float32)
    with np.errstate(divide='ignore', invalid='ignore'):
        scaled = np.where(spread[..., None] > 1e-3, centred / spread[..., None], 0.0)
    out = np.concatenate([scaled.astype(np.float32), np.where(spread > 1e-3, spread, 0.0)[
        ..., None].astype(np.float32)], axis=-1)
    result: F32 = np.ascontiguousarray(out.reshape(h * w, 10))
    return result


def sweep_cost_volume(inputs: SweepCostInputs) -> U8:
    """The whole (H, W, D) uint8 cost volume (tests, small images)."""
    out = np.empty(inputs.shape, np.uint8)
    return inputs.rows(0, out)
