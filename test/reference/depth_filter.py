"""Plain references of :mod:`depth_nodes.core.depth_filter`'s kernels (small images only)."""

from __future__ import annotations

import numpy as np

from depth_nodes.core.depth_filter.temporal import TemporalState, fresh_state
from depth_nodes.core.geometry import Intrinsics, Motion, check_rotation

F64 = np.ndarray


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
