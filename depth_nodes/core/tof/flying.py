"""Flying pixels: a pixel that sees two surfaces at a depth edge measures a mixture of
both, a range in between that belongs to neither (:func:`remove_flying_pixels`).
:func:`flying_reference` is the plain numpy definition the tests compare the kernel with.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

#: Standard deviations of two ranges' combined noise a jump must exceed besides
#: ``jump_edge_threshold`` of the range.
NOISE_SIGMAS = 3.0
#: Standard deviations of two neighbours' combined noise their gap must exceed besides
#: ``flying_pixel_threshold`` and the slopes beyond them for the pixel between them to be
#: flying.
BETWEEN_SIGMAS = 2.5
#: The four directions the flying-pixel test looks along: (dy, dx).
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


@numba.njit(cache=True, nogil=True, parallel=True)
def _flying_kernel(r: F32, sigma: F32, absolute: float, jump: float,
                   out: NDArray[np.bool_]) -> None:
    """``r`` and ``sigma`` padded by two pixels (NaN and 0): no bounds to check."""
    height, width = out.shape
    for y in numba.prange(height):
        for x in range(width):
            out[y, x] = False
            d = r[y + 2, x + 2]
            if not np.isfinite(d):
                continue
            s = sigma[y + 2, x + 2]
            flying = False
            if jump > 0.0:  # next to a jump to any of the 8 neighbours
                limit = jump * d
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        step = abs(d - r[y + 2 + dy, x + 2 + dx])  # NaN: never true
                        if step > limit:
                            sn = sigma[y + 2 + dy, x + 2 + dx]
                            if step > limit + NOISE_SIGMAS * np.sqrt(s * s + sn * sn):
                                flying = True
            if absolute > 0.0 and not flying:
                # along the four directions: between its two neighbours, in a gap wider
                # than their noise and than the slopes beyond them explain (unknown pixels
                # there: not judged in that direction)
                for k in range(4):
                    dy, dx = (0, 1) if k == 0 else (1, 0) if k == 1 else (1, 1) if k == 2 \
                        else (1, -1)
                    a = r[y + 2 - dy, x + 2 - dx]
                    b = r[y + 2 + dy, x + 2 + dx]
                    if not (d - a) * (d - b) < 0.0:
                        continue
                    sa = sigma[y + 2 - dy, x + 2 - dx]
                    sb = sigma[y + 2 + dy, x + 2 + dx]
                    gap = abs(a - b)
                    if not gap > absolute + BETWEEN_SIGMAS * max(sa, sb):  # cheap first
                        continue
                    beyond = abs(a - r[y + 2 - 2 * dy, x + 2 - 2 * dx]) + \
                        abs(b - r[y + 2 + 2 * dy, x + 2 + 2 * dx])
                    # NaN beyond: not judged
                    if gap - beyond > absolute + BETWEEN_SIGMAS * np.sqrt(sa * sa + sb * sb):
                        flying = True
            out[y, x] = flying


def remove_flying_pixels(range_m: F32, absolute: float, jump: float = 0.0,
                         sigma: F32 | None = None) -> NDArray[np.bool_]:
    """The flying pixels of a range image (see the module notes), True where:

    * (``absolute`` > 0) along one of the four directions through the pixel, its range
      lies between the two neighbours', and their gap, less the steps from each of them to
      the pixel beyond it, exceeds ``absolute`` plus ``BETWEEN_SIGMAS`` times their
      combined noise: a pixel in a gap between two surfaces is a mixture of them, wherever
      in the gap it lies; a surface seen at a slant steps as much beyond the neighbours as
      between them, and passes;
    * (``jump`` > 0) its range differs from one of its 8 neighbours' by more than ``jump``
      times the range plus ``NOISE_SIGMAS`` times their combined noise: both sides of every
      depth edge, where mixed pixels close to one surface and the grazing edges of objects
      (whose weak direct return the light bounced off the surface behind outweighs) leave
      ranges that belong to neither surface.

    ``sigma`` is the range's expected noise (default 0). Neighbours outside the image or
    unknown are not used (nor a direction whose pixel beyond a neighbour is); unknown
    pixels are never flying.
    """
    r = np.ascontiguousarray(range_m, np.float32)
    out = np.zeros(r.shape, np.bool_)
    noise = np.zeros(r.shape, np.float32) if sigma is None else \
        np.ascontiguousarray(np.nan_to_num(sigma, nan=0.0, posinf=0.0), np.float32)
    if absolute > 0 or jump > 0:
        _flying_kernel(np.pad(r, 2, constant_values=np.nan), np.pad(noise, 2),
                       float(absolute), float(jump), out)
    return out


def flying_reference(range_m: F32, absolute: float, jump: float = 0.0,
                     sigma: F32 | None = None) -> NDArray[np.bool_]:
    """Plain numpy reference of :func:`remove_flying_pixels` (for the tests)."""
    r = np.asarray(range_m, np.float64)
    h, w = r.shape
    noise = np.zeros((h, w)) if sigma is None else np.nan_to_num(
        np.asarray(sigma, np.float64), nan=0.0, posinf=0.0)
    pad = np.pad(r, 2, constant_values=np.nan)
    pad_s = np.pad(noise, 2)

    def at(dy: int, dx: int, image: NDArray[np.float64] = pad) -> NDArray[np.float64]:
        return image[2 + dy:2 + dy + h, 2 + dx:2 + dx + w]

    out = np.zeros((h, w), bool)
    with np.errstate(invalid='ignore'):
        if jump > 0:
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    out |= np.abs(r - at(dy, dx)) > jump * r + NOISE_SIGMAS * np.sqrt(
                        noise ** 2 + at(dy, dx, pad_s) ** 2)
        if absolute > 0:
            for dy, dx in _DIRECTIONS:
                a, b = at(-dy, -dx), at(dy, dx)
                beyond = np.abs(a - at(-2 * dy, -2 * dx)) + np.abs(b - at(2 * dy, 2 * dx))
                unexplained = np.abs(a - b) - beyond
                sa, sb = at(-dy, -dx, pad_s), at(dy, dx, pad_s)
                out |= ((r - a) * (r - b) < 0) & \
                    (unexplained > absolute + BETWEEN_SIGMAS * np.sqrt(sa ** 2 + sb ** 2))
    return out & np.isfinite(r)
