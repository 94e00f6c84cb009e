"""Plain numpy references of time of flight's kernels (``depth_nodes/core/tof/``): the
phasors of the correlation samples and the flying-pixel test; for ``test_tof.py``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.tof.flying import BETWEEN_SIGMAS, NOISE_SIGMAS, PAD, SLIT_SHARE

F32 = NDArray[np.float32]


# -- depth_nodes.core.tof.phase ----------------------------------------------------------------
def phasors_reference(samples: NDArray[Any], n_freq: int, steps: int, saturation: float
                      ) -> tuple[F32, F32, F32, NDArray[np.bool_]]:
    """Plain numpy reference of :func:`phasors` (for the tests)."""
    arr = np.asarray(samples, np.float64).reshape(n_freq, steps, *samples.shape[1:])
    theta = 2 * np.pi * np.arange(steps) / steps
    re = np.tensordot(np.cos(theta), arr, axes=([0], [1]))
    im = np.tensordot(np.sin(theta), arr, axes=([0], [1]))
    phase = np.mod(np.arctan2(im, re), 2 * np.pi)
    saturated: NDArray[np.bool_] = np.asarray((arr >= saturation).any(axis=(0, 1)))
    return (phase.astype(np.float32), (2 / steps * np.hypot(re, im)).astype(np.float32),
            arr.mean(axis=1).astype(np.float32), saturated)


# -- depth_nodes.core.tof.flying ---------------------------------------------------------------
#: The four directions the flying-pixel test looks along: (dy, dx).
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def flying_reference(range_m: F32, absolute: float, jump: float = 0.0,
                     sigma: F32 | None = None, margin: float = 0.0,
                     spikes: bool = False) -> NDArray[np.bool_]:
    """Plain numpy reference of :func:`remove_flying_pixels` (for the tests)."""
    r = np.asarray(range_m, np.float64)
    h, w = r.shape
    noise = np.zeros((h, w)) if sigma is None else np.nan_to_num(
        np.asarray(sigma, np.float64), nan=0.0, posinf=0.0)
    pad = np.pad(r, PAD, constant_values=np.nan)
    pad_s = np.pad(noise, PAD)

    def at(dy: int, dx: int, image: NDArray[np.float64] = pad) -> NDArray[np.float64]:
        return image[PAD + dy:PAD + dy + h, PAD + dx:PAD + dx + w]

    out = np.zeros((h, w), bool)
    with np.errstate(invalid='ignore'):
        if jump > 0:
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    out |= np.abs(r - at(dy, dx)) > jump * r + NOISE_SIGMAS * np.sqrt(
                        noise ** 2 + at(dy, dx, pad_s) ** 2)
        for dy, dx in _DIRECTIONS if absolute > 0 else ():
            a, b = at(-dy, -dx), at(dy, dx)
            beyond = np.abs(a - at(-2 * dy, -2 * dx)) + np.abs(b - at(2 * dy, 2 * dx))
            unexplained = np.abs(a - b) - beyond
            sa, sb = at(-dy, -dx, pad_s), at(dy, dx, pad_s)
            clear = np.minimum(np.abs(r - a), np.abs(r - b)) > margin * np.abs(a - b)
            noise = absolute + BETWEEN_SIGMAS * np.sqrt(sa ** 2 + sb ** 2)
            out |= ((r - a) * (r - b) < 0) & clear & (unexplained > noise)
            if spikes:
                gap = np.abs(a - b)
                out |= ((r > np.maximum(a, b) + noise) | (r < np.minimum(a, b) - noise)) & \
                    (gap > noise) & (gap > SLIT_SHARE * np.minimum(np.abs(r - a),
                                                                   np.abs(r - b)))
    return out & np.isfinite(r)
