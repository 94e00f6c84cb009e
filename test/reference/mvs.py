"""Plain references of :mod:`depth_nodes.core.mvs`'s kernels (small images only)."""

from __future__ import annotations

import math

import numpy as np

from depth_nodes.core.geometry import Intrinsics, Motion
from depth_nodes.core.mvs.fusion import FilterState


def warp_state_reference(state: FilterState, old: Intrinsics, new: Intrinsics,
                         motion: Motion, *, process_sigma: float) -> FilterState:
    """:func:`~depth_nodes.core.mvs.fusion.warp_state` written out with rays: each estimate
    to the pixel holding its point, the nearest winning, in row order."""
    out = FilterState.empty(new.shape)
    rotation, translation = (np.asarray(v, np.float64) for v in motion)
    h, w = state.shape
    k_inv = np.linalg.inv(old.matrix)
    for y in range(h):
        for x in range(w):
            r = float(state.rho[y, x])
            if not (r > 0 and math.isfinite(r)):
                continue
            ray = k_inv @ np.array([x, y, 1.0])
            q = rotation @ ray
            s = q + translation * r
            if not s[2] > 1e-12:
                continue
            u, v = (new.matrix @ s)[:2] / s[2]
            if not (-0.5 <= u < new.width - 0.5 and -0.5 <= v < new.height - 0.5):
                continue
            xi, yi = math.floor(u + 0.5), math.floor(v + 0.5)
            new_rho = r / s[2]
            old_rho = float(out.rho[yi, xi])
            if math.isfinite(old_rho) and old_rho >= new_rho:
                continue
            gain = q[2] / (s[2] * s[2])
            out.rho[yi, xi] = new_rho
            out.var[yi, xi] = state.var[y, x] * gain * gain + (process_sigma * new_rho) ** 2
            out.a[yi, xi] = state.a[y, x]
            out.b[yi, xi] = state.b[y, x]
    return out
