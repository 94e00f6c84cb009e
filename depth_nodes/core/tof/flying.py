"""Flying pixels: a pixel that sees two surfaces at a depth edge measures a mixture of
both, a range in between that belongs to neither (:func:`remove_flying_pixels`). The
plain numpy definition the tests compare the kernel with is ``flying_reference`` in
``test/reference/tof.py``.
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
#: ``spikes``: the smallest share of a pixel's smaller step its neighbours must differ by.
SLIT_SHARE = 0.25


@numba.njit(cache=True, nogil=True, inline='always')
def _between(d: float, a: float, b: float, a2: float, b2: float, sa: float, sb: float,
             absolute: float, margin: float) -> bool:
    """``d`` lies between its neighbours ``a`` and ``b``, at least ``margin`` of their gap
    from each, in a gap wider than their noise and than the slopes beyond them (``a2``,
    ``b2``) explain; NaN anywhere: False. Written without branches: on noisy depth, which
    side a pixel lies on is a coin toss that a branch predictor loses half the time, and
    the comparisons vectorise along a row."""
    gap = abs(a - b)
    beyond = abs(a - a2) + abs(b - b2)
    return bool(((d - a) * (d - b) < 0.0) & (min(abs(d - a), abs(d - b)) > margin * gap) &
                (gap - beyond > absolute + BETWEEN_SIGMAS * np.sqrt(sa * sa + sb * sb)))


#: Pixels of padding the kernel's input has.
PAD = 2


@numba.njit(cache=True, nogil=True, inline='always')
def _spike(d: float, a: float, b: float, sa: float, sb: float, absolute: float) -> bool:
    """``d`` lies beyond both neighbours (nearer than both, or farther) by more than
    ``absolute`` and their noise, and they differ by as much, and by at least a quarter of
    its smaller step: a far surface seen through a slit between two objects at different
    depths (a thin pole in front of one surface has neighbours alike, and passes)."""
    noise = absolute + BETWEEN_SIGMAS * np.sqrt(sa * sa + sb * sb)
    gap = abs(a - b)
    return bool(((d > max(a, b) + noise) | (d < min(a, b) - noise)) & (gap > noise) &
                (gap > SLIT_SHARE * min(abs(d - a), abs(d - b))))


@numba.njit(cache=True, nogil=True, parallel=True)
def _flying_kernel(r: F32, sigma: F32, absolute: float, jump: float, margin: float,
                   spikes: bool, out: NDArray[np.bool_]) -> None:
    """``r`` and ``sigma`` padded by PAD pixels (NaN and 0): no bounds to check."""
    height, width = out.shape
    for y in numba.prange(height):
        if jump > 0.0:  # next to a jump to any of the 8 neighbours
            for x in range(width):
                d = r[y + PAD, x + PAD]
                s = sigma[y + PAD, x + PAD]
                flying = False
                limit = jump * d
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        step = abs(d - r[y + PAD + dy, x + PAD + dx])  # NaN: never true
                        if step > limit:
                            sn = sigma[y + PAD + dy, x + PAD + dx]
                            if step > limit + NOISE_SIGMAS * np.sqrt(s * s + sn * sn):
                                flying = True
                out[y, x] = flying
        else:
            out[y, :] = False
        if absolute > 0.0:
            # along the four directions: between its two neighbours (unknown pixels there
            # or beyond: not judged in that direction)
            c, u, uu, dn, dd = y + 2, y + 1, y, y + 3, y + 4
            for x in range(width):
                i = x + 2
                d = r[c, i]
                out[y, x] |= (
                    _between(d, r[c, i - 1], r[c, i + 1], r[c, i - 2], r[c, i + 2],
                             sigma[c, i - 1], sigma[c, i + 1], absolute, margin) |
                    _between(d, r[u, i], r[dn, i], r[uu, i], r[dd, i],
                             sigma[u, i], sigma[dn, i], absolute, margin) |
                    _between(d, r[u, i - 1], r[dn, i + 1], r[uu, i - 2], r[dd, i + 2],
                             sigma[u, i - 1], sigma[dn, i + 1], absolute, margin) |
                    _between(d, r[u, i + 1], r[dn, i - 1], r[uu, i + 2], r[dd, i - 2],
                             sigma[u, i + 1], sigma[dn, i - 1], absolute, margin))
            if spikes:
                for x in range(width):
                    i = x + 2
                    d = r[c, i]
                    out[y, x] |= (
                        _spike(d, r[c, i - 1], r[c, i + 1], sigma[c, i - 1], sigma[c, i + 1],
                               absolute) |
                        _spike(d, r[u, i], r[dn, i], sigma[u, i], sigma[dn, i], absolute) |
                        _spike(d, r[u, i - 1], r[dn, i + 1], sigma[u, i - 1],
                               sigma[dn, i + 1], absolute) |
                        _spike(d, r[u, i + 1], r[dn, i - 1], sigma[u, i + 1],
                               sigma[dn, i - 1], absolute))
        for x in range(width):
            out[y, x] &= np.isfinite(r[y + PAD, x + PAD])


def remove_flying_pixels(range_m: F32, absolute: float, jump: float = 0.0,
                         sigma: F32 | None = None, margin: float = 0.0,
                         spikes: bool = False) -> NDArray[np.bool_]:
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

    With ``margin`` > 0 the range must also lie at least that fraction of the neighbours'
    gap from each of them: the pixel next to a mixed one, on a surface, lies between its
    neighbours by its noise alone, close to one of them. With ``spikes`` (and ``absolute``
    > 0) a pixel is also flying where, along one of the directions, it lies beyond both
    neighbours by more than ``absolute`` plus their noise, and they differ by as much and
    by at least :data:`SLIT_SHARE` of its smaller step: a slit between two objects at
    different depths, whose pixel mixes the far surface with the near ones. ``sigma`` is
    the range's expected noise (default 0). Neighbours outside the image or
    unknown are not used (nor a direction whose pixel beyond a neighbour is); unknown
    pixels are never flying.
    """
    r = np.ascontiguousarray(range_m, np.float32)
    out = np.zeros(r.shape, np.bool_)
    if absolute > 0 or jump > 0:
        h, w = r.shape
        padded = np.full((h + 2 * PAD, w + 2 * PAD), np.nan, np.float32)
        padded[PAD:-PAD, PAD:-PAD] = r
        noise = np.zeros(padded.shape, np.float32)
        if sigma is not None:  # unknown or infinite noise: none
            s = np.asarray(sigma, np.float32)
            noise[PAD:-PAD, PAD:-PAD] = np.where(np.isfinite(s), s, np.float32(0.0))
        _flying_kernel(padded, noise, float(absolute), float(jump), float(margin),
                       bool(spikes), out)
    return out
