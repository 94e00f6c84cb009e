"""The coarse search (``disparity_search: coarse``, tSGM): a wrapper of the full search.

:class:`CoarseSearch` matches the pair at half resolution over half the range with a full
matcher of its own, then hands each full-resolution pixel the window of disparities its
coarse neighbourhood found (``ranged.search_ranges``) to the second pass, the matcher's
match over windows (``ranged.py``, ``schedule.RangedFrame``). Windows aligned to
``ranged.ALIGN`` are tried first, tight ones when those do not fit ``memory_mb``; when
neither fits (or the range does not halve within the width) there is no coarse result,
and the matcher takes the full search for that frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.sgm import ranged
from depth_nodes.core.sgm.params import SgmParams
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
T = TypeVar('T')

#: Paths of the coarse search's half-resolution pass, by the frame's (only its windows
#: depend on it).
COARSE_PATHS = {8: 5, 16: 5}


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
    wide: half the disparities (:func:`ranged.coarse_window`), fewer paths
    (:data:`COARSE_PATHS`), speckles a quarter the size; None when the range does not
    halve within that width (a window at the edge of what the width allows)."""
    p = params
    c_min, c_range = ranged.coarse_window(p.min_disparity, p.disparity_range)
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
        ch, cw = ranged.coarse_size(h, w)
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
        for align in (ranged.ALIGN, 1):  # aligned windows when they fit, else tight ones
            lo, wid = ranged.search_ranges(coarse.disparity, (h, w),
                                           min_disparity=p.min_disparity,
                                           disparity_range=p.disparity_range,
                                           margin=p.search_margin, outside=outside,
                                           align=align)
            found = match_windows(lo, wid)
            if found is not None:
                return found
        return None
