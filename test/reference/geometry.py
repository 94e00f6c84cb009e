"""Plain references of :mod:`depth_nodes.core.geometry`'s kernels (small images only)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Motion, Splat


def splat_reference(values: NDArray[Any], source: Intrinsics, target: Intrinsics,
                    motion: Motion, *, footprint: str, inverse: bool = False) -> Splat:
    """:func:`~depth_nodes.core.geometry.splat.splat` one target pixel at a time: of all
    the source points whose footprint covers its centre (or, for a footprint covering no
    centre, whose centre it holds), the nearest; the first in row order on a tie."""
    R, t = (np.asarray(m, np.float64) for m in motion)
    v = np.asarray(values, np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        z = 1.0 / v if inverse else v.copy()
    known = v > 0
    ys, xs = np.mgrid[0:source.height, 0:source.width].astype(np.float64)

    def project(du: float, dv: float, centre: bool = False) -> tuple[Any, Any, Any]:
        # the kernel's arithmetic, term by term, so that Z compares bit for bit
        px = (xs + du - source.cx) * (1.0 / source.fx) * z
        py = ((ys + dv - source.cy) * (1.0 / source.fy)) * z
        x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * z + t[0]
        y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * z + t[1]
        zz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * z + t[2]
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            if centre:
                inv = 1.0 / zz
                return target.fx * x * inv + target.cx, target.fy * y * inv + target.cy, zz
            return target.fx * x / zz + target.cx, target.fy * y / zz + target.cy, zz

    uc, vc, zc = project(0.0, 0.0, centre=True)
    with np.errstate(invalid='ignore'):
        ok = known & (zc > 0)
    if footprint == 'point':
        u_lo = u_hi = uc
        v_lo = v_hi = vc
    elif footprint == 'box':
        with np.errstate(divide='ignore', invalid='ignore'):
            ratio = z * (1.0 / zc)
        hu, hv = 0.5 * target.fx / source.fx * ratio, 0.5 * target.fy / source.fy * ratio
        u_lo, u_hi, v_lo, v_hi = uc - hu, uc + hu, vc - hv, vc + hv
    else:  # corners: their bounding box, of those ahead of the camera
        corners = [project(du, dv) for du in (-0.5, 0.5) for dv in (-0.5, 0.5)]
        cu = np.array([np.where(c[2] > 0, c[0], np.nan) for c in corners])
        cv = np.array([np.where(c[2] > 0, c[1], np.nan) for c in corners])
        ahead = np.isfinite(cu).any(axis=0)
        with np.errstate(invalid='ignore'):
            u_lo = np.where(ahead, np.nanmin(np.where(ahead, cu, 0), axis=0), uc)
            u_hi = np.where(ahead, np.nanmax(np.where(ahead, cu, 0), axis=0), uc)
            v_lo = np.where(ahead, np.nanmin(np.where(ahead, cv, 0), axis=0), vc)
            v_hi = np.where(ahead, np.nanmax(np.where(ahead, cv, 0), axis=0), vc)
    with np.errstate(invalid='ignore'):
        covers_none = ~((np.ceil(u_lo) <= np.ceil(u_hi) - 1) &
                        (np.ceil(v_lo) <= np.ceil(v_hi) - 1))
        near_u = np.floor(0.5 * (u_lo + u_hi) + 0.5)
        near_v = np.floor(0.5 * (v_lo + v_hi) + 0.5)
    depth = np.full((target.height, target.width), np.inf)
    index = np.full((target.height, target.width), -1, np.int32)
    flat_zc = np.where(ok, zc, np.inf).ravel()
    for r in range(target.height):
        for c in range(target.width):
            with np.errstate(invalid='ignore'):
                covers = ok & ~covers_none & (u_lo <= c) & (c < u_hi) & (v_lo <= r) & \
                    (r < v_hi)
                holds = ok & covers_none & (near_u == c) & (near_v == r)
            hits = np.flatnonzero((covers | holds).ravel())
            if hits.size:
                best = hits[np.argmin(flat_zc[hits])]  # argmin: the first on a tie
                depth[r, c] = flat_zc[best]
                index[r, c] = best
    return Splat(depth, index)
