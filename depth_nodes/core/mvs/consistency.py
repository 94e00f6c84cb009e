"""Geometric consistency of a depth map with the depth maps of other views (numba).

A reference pixel's 3-D point is projected into another view that has a depth map; the
depth found there is lifted back into the reference. The pixel agrees with that view when
the round trip lands within ``max_px`` pixels of where it started and the two depths
differ by at most ``max_relative`` (COLMAP's geometric consistency, Schoenberger et al.
2016). A view whose depth map has no value there, or that does not see the point, is not
counted. The plain version the tests compare with is ``consistency_reference`` in
``test/reference/mvs.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ['consistency']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


@njit(cache=True, nogil=True)
def _consistency_kernel(depth: F32, k_inv: F64, other: F32, k_other: F64, k_other_inv: F64,
                        k_ref: F64, rotation: F64, translation: F64, max_px: float,
                        max_relative: float, checked: U8, agreed: U8) -> None:
    h, w = depth.shape
    oh, ow = other.shape
    for y in range(h):
        for x in range(w):
            z = depth[y, x]
            if not (z > 0 and math.isfinite(z)):
                continue
            px = (k_inv[0, 0] * x + k_inv[0, 1] * y + k_inv[0, 2]) * z
            py = (k_inv[1, 0] * x + k_inv[1, 1] * y + k_inv[1, 2]) * z
            pz = (k_inv[2, 0] * x + k_inv[2, 1] * y + k_inv[2, 2]) * z
            qx = rotation[0, 0] * px + rotation[0, 1] * py + rotation[0, 2] * pz + translation[0]
            qy = rotation[1, 0] * px + rotation[1, 1] * py + rotation[1, 2] * pz + translation[1]
            qz = rotation[2, 0] * px + rotation[2, 1] * py + rotation[2, 2] * pz + translation[2]
            if not qz > 1e-9:
                continue
            u = (k_other[0, 0] * qx + k_other[0, 1] * qy + k_other[0, 2] * qz) / qz
            v = (k_other[1, 0] * qx + k_other[1, 1] * qy + k_other[1, 2] * qz) / qz
            if not (-0.5 <= u < ow - 0.5 and -0.5 <= v < oh - 0.5):
                continue
            ui = math.floor(u + 0.5)
            vi = math.floor(v + 0.5)
            zo = other[vi, ui]
            if not (zo > 0 and math.isfinite(zo)):
                continue
            checked[y, x] += 1
            # the other view's point, back in the reference frame: R^T (q' - t)
            ox = (k_other_inv[0, 0] * ui + k_other_inv[0, 1] * vi + k_other_inv[0, 2]) * zo
            oy = (k_other_inv[1, 0] * ui + k_other_inv[1, 1] * vi + k_other_inv[1, 2]) * zo
            oz = (k_other_inv[2, 0] * ui + k_other_inv[2, 1] * vi + k_other_inv[2, 2]) * zo
            dx, dy, dz = ox - translation[0], oy - translation[1], oz - translation[2]
            bx = rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz
            by = rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz
            bz = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
            if not bz > 1e-9:
                continue
            ru = (k_ref[0, 0] * bx + k_ref[0, 1] * by + k_ref[0, 2] * bz) / bz
            rv = (k_ref[1, 0] * bx + k_ref[1, 1] * by + k_ref[1, 2] * bz) / bz
            if (ru - x) ** 2 + (rv - y) ** 2 <= max_px * max_px and \
                    abs(bz - z) <= max_relative * z:
                agreed[y, x] += 1


def consistency(depth: F32, k_ref: F64, others: list[tuple[F32, F64, tuple[F64, F64]]], *,
                max_px: float = 1.0, max_relative: float = 0.01) -> tuple[U8, U8]:
    """Per reference pixel, how many views were checked and how many agreed.

    Args:
        depth: (H, W) reference depth Z, metres, NaN where none.
        k_ref: (3, 3) reference camera matrix.
        others: Per view ``(depth_j, K_j, (R, t))`` with ``(R, t)`` taking reference-frame
            points into view j.
        max_px: Largest round-trip distance, pixels.
        max_relative: Largest relative difference of the two depths.

    Returns:
        ``(checked, agreed)``, (H, W) uint8 counts.
    """
    checked = np.zeros(depth.shape, np.uint8)
    agreed = np.zeros(depth.shape, np.uint8)
    k_inv = np.asarray(np.linalg.inv(k_ref), np.float64)
    for other, k_other, (rotation, translation) in others:
        _consistency_kernel(np.ascontiguousarray(depth, np.float32), k_inv,
                            np.ascontiguousarray(other, np.float32),
                            np.asarray(k_other, np.float64),
                            np.asarray(np.linalg.inv(k_other), np.float64),
                            np.asarray(k_ref, np.float64), np.asarray(rotation, np.float64),
                            np.asarray(translation, np.float64), float(max_px),
                            float(max_relative), checked, agreed)
    return checked, agreed
