"""The coarse search (``disparity_search: coarse``): a wrapper of the full search.

The idea is tSGM's (Rothermel et al. 2012, "SURE: Photogrammetric surface reconstruction
from imagery"): match the pair at half resolution over half the range, then give each
full-resolution pixel the window of disparities its coarse neighbourhood found, widened
by a margin (:func:`search_ranges`), and match again over those windows only
(``ranged.py``, ``schedule.RangedFrame``).

:class:`CoarseSearch` runs the half-resolution pass with a full matcher of its own, then
the second pass it is given. Windows aligned to :data:`ALIGN` are tried first, tight ones
when those do not fit ``memory_mb``; when neither fits (or the range does not halve
within the width) there is no coarse result, and the matcher takes the full search for
that frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.sgm.params import SgmParams
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
T = TypeVar('T')

#: Paths of the coarse search's half-resolution pass, by the frame's (only its windows
#: depend on it).
COARSE_PATHS = {8: 5, 16: 5}
#: Windows start and end on multiples of this many disparities when the volumes still
#: fit: the kernels' loops then meet fewer distinct trip counts and offsets (the
#: downward sweep of a VGA frame ran 27 % faster for 16 % more cells).
ALIGN = 8
#: Coarse pixels either side whose disparities a fine pixel's window spans (5 x 5 coarse,
#: about 10 x 10 fine pixels: a depth edge near the pixel puts both sides in its window).
NEAR_RADIUS = 2
#: Where no coarse disparity within :data:`NEAR_RADIUS` survived the checks (occlusions,
#: no texture): the span of the valid ones within this radius; the full range if none.
WIDE_RADIUS = 8


def coarse_size(h: int, w: int) -> tuple[int, int]:
    """(height, width) of the half-resolution pass of an (h, w) frame."""
    return (h + 1) // 2, (w + 1) // 2


def coarse_window(min_disparity: int, disparity_range: int) -> tuple[int, int]:
    """(min_disparity, disparity_range) of the half-resolution pass: every full-resolution
    disparity d has d / 2 inside it."""
    lo = math.floor(min_disparity / 2)
    hi = math.ceil((min_disparity + disparity_range - 1) / 2)
    return lo, hi - lo + 1


def _span(valid: NDArray[np.bool_], values: F32, radius: int) -> tuple[F32, F32]:
    """Min and max of ``values`` where ``valid`` within a (2 radius + 1)^2 square (+inf and
    -inf where the square holds no valid value)."""
    size = 2 * radius + 1
    kernel = np.ones((size, size), np.uint8)
    low = cv2.erode(np.where(valid, values, np.float32(np.inf)).astype(np.float32), kernel,
                    borderType=cv2.BORDER_REPLICATE)
    high = cv2.dilate(np.where(valid, values, np.float32(-np.inf)).astype(np.float32),
                      kernel, borderType=cv2.BORDER_REPLICATE)
    return low.astype(np.float32), high.astype(np.float32)


def search_ranges(coarse: F32, shape: tuple[int, int], *, min_disparity: int,
                  disparity_range: int, margin: float, outside: float = 0.0,
                  align: int = 1) -> tuple[I32, I32]:
    """Each full-resolution pixel's window from the half-resolution disparity ``coarse``.

    A pixel's window spans twice the smallest and largest valid coarse disparity within
    :data:`NEAR_RADIUS` of its coarse pixel, widened by ``margin`` px either side; where
    none is valid, those within :data:`WIDE_RADIUS`; where none is either, the full range.
    In the left border strip, where some disparities match outside the right image, a
    window starts at disparity index 0 and reaches at least the largest disparity that
    may be published there (its match ``outside`` px past the border): the coarse pass
    is least reliable there, and the disparities are extrapolated from the neighbours
    (``border.fill_outside``). Teddy's bad-2 after the shipped graph's cross-check (5
    paths): 0.0584 with the full search, 0.0686 with the coarse windows in the strip,
    0.0630 with these, 0.0586 with the full range there (whose volumes at 1280x720 / 256
    no longer fit the default memory_mb).

    Args:
        coarse: (ceil(H / 2), ceil(W / 2)) float32 disparity, NaN where invalid.
        shape: (H, W) of the full-resolution frame.
        min_disparity: The full-resolution smallest disparity.
        disparity_range: The full-resolution number of disparities D.
        margin: Widening either side, full-resolution px.
        outside: How far past the left image border a disparity's match may lie and the
            disparity still be published, px (the matcher's border extrapolation).
        align: Windows start and end on multiples of this many disparity indices (the
            full range's end excepted): see :data:`ALIGN`.

    Returns:
        (lo, wid): (H, W) int32 first disparity index (0 .. D - 1) and width (>= 1).
    """
    h, w = shape
    valid = np.isfinite(coarse)
    values = np.where(valid, coarse, 0).astype(np.float32)
    low, high = _span(valid, values, NEAR_RADIUS)
    wide_low, wide_high = _span(valid, values, WIDE_RADIUS)
    empty = low > high
    low = np.where(empty, wide_low, low)
    high = np.where(empty, wide_high, high)
    full = low > high
    n = disparity_range
    with np.errstate(invalid='ignore'):
        first = np.floor(2.0 * low - margin) - min_disparity
        last = np.ceil(2.0 * high + margin) - min_disparity
    first = np.where(full, 0, np.clip(first, 0, n - 1))
    last = np.where(full, n - 1, np.clip(last, first, n - 1))
    first = first // align * align
    last = np.minimum(n - 1, (last // align + 1) * align - 1)
    lo = _doubled(first.astype(np.int32), h, w)  # pixel (y, x) takes (y // 2, x // 2)'s
    wid = _doubled((last - first + 1).astype(np.int32), h, w)
    strip = min(w, max(0, min_disparity + n - 1))  # x - d < 0 for some d: the border strip
    # there from 0 to the largest disparity that may still be published (or further)
    top = np.minimum(n, np.arange(strip) - min_disparity + math.floor(outside) + 1)
    end = np.maximum(lo[:, :strip] + wid[:, :strip], top[None, :])
    lo[:, :strip] = 0
    wid[:, :strip] = end
    return lo, wid


def _doubled(coarse: I32, h: int, w: int) -> I32:
    """Each coarse pixel repeated 2 x 2, cut to (h, w)."""
    return np.ascontiguousarray(np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)[:h, :w])


class Disparity(Protocol):
    """What the half-resolution pass returns: at least a disparity image."""

    disparity: F32


class FullMatcher(Protocol):
    """The full matcher the half-resolution pass runs on (:class:`~.matcher.SgmMatcher`)."""

    params: SgmParams

    def set_params(self, params: SgmParams) -> None:
        """Use ``params`` from the next frame on."""

    def match(self, left: NDArray[Any], right: NDArray[Any]) -> Disparity:
        """Match a pair (its buffers are reused by the next call)."""

    @property
    def workspace_bytes(self) -> int:
        """Bytes of its buffers."""


def half_resolution_params(params: SgmParams, half_width: int) -> SgmParams | None:
    """The half-resolution pass's settings for a frame whose half is ``half_width`` px
    wide: half the disparities (:func:`coarse_window`), fewer paths
    (:data:`COARSE_PATHS`), speckles a quarter the size; None when the range does not
    halve within that width (a window at the edge of what the width allows)."""
    p = params
    c_min, c_range = coarse_window(p.min_disparity, p.disparity_range)
    half = replace(p, disparity_search='full', min_disparity=c_min,
                   disparity_range=min(c_range, half_width - 1),
                   speckle_size=p.speckle_size // 4, speckle_range=p.speckle_range / 2,
                   median_filter=False, band_rows=0, paths=COARSE_PATHS.get(p.paths, p.paths))
    try:
        half.validate(half_width)
    except ArgumentError:
        return None
    return half


class CoarseSearch:
    """The coarse search of one matcher: its half-resolution matcher, kept across frames.

    Args:
        new_matcher: Makes the full matcher of the half-resolution pass (the matcher's
            own class: this module needs no import of it).

    Attributes:
        half: The half-resolution matcher, once a frame needed it.
        half_disparity: The last half-resolution disparity (the half matcher's buffer).
    """

    def __init__(self, new_matcher: Callable[[SgmParams], FullMatcher]) -> None:
        self._new_matcher = new_matcher
        self.half: FullMatcher | None = None
        self.half_disparity: F32 | None = None

    @property
    def workspace_bytes(self) -> int:
        """Bytes of the half-resolution matcher's buffers."""
        return self.half.workspace_bytes if self.half is not None else 0

    def match(self, left: NDArray[Any], right: NDArray[Any], params: SgmParams,
              match_windows: Callable[[I32, I32], T | None]) -> T | None:
        """The half-resolution pass, then ``match_windows(lo, wid)`` over the windows it
        gives (aligned ones first, then tight ones); the first that fits is returned.

        Args:
            left: (H, W) rectified left image.
            right: (H, W) rectified right image.
            params: The frame's settings (``search_margin``, the border extrapolation).
            match_windows: The second pass over (H, W) int32 windows ``lo`` .. ``lo + wid
                - 1``; None when they do not fit ``memory_mb``.

        Returns:
            What ``match_windows`` returned, or None when no windows fit or the range does
            not halve within the width (the caller then runs the full search).
        """
        h, w = left.shape
        ch, cw = coarse_size(h, w)
        half_params = half_resolution_params(params, cw)
        if half_params is None:
            return None
        if self.half is None:
            self.half = self._new_matcher(half_params)
        elif self.half.params != half_params:
            self.half.set_params(half_params)
        coarse = self.half.match(cv2.resize(left, (cw, ch), interpolation=cv2.INTER_AREA),
                                 cv2.resize(right, (cw, ch), interpolation=cv2.INTER_AREA))
        self.half_disparity = coarse.disparity
        p = params
        outside = p.border_extrapolation * p.disparity_range if p.border_cost > 0 else 0.0
        for align in (ALIGN, 1):  # aligned windows when they fit, else tight ones
            lo, wid = search_ranges(coarse.disparity, (h, w),
                                           min_disparity=p.min_disparity,
                                           disparity_range=p.disparity_range,
                                           margin=p.search_margin, outside=outside,
                                           align=align)
            found = match_windows(lo, wid)
            if found is not None:
                return found
        return None
