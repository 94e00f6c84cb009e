"""The census Semi-Global Matching stereo matcher: public function and reusable matcher.

Typical use::

    matcher = SgmMatcher(SgmParams(disparity_range=128))
    result = matcher.match(left, right)        # buffers are reused on the next call
    result.disparity, result.disparity_right, result.cost_ratio

A match is the full search (``schedule.FullFrame``) or, with ``disparity_search: coarse``,
the coarse search (``coarse.py``) with the full search as its fallback; then the
post-filters of this module (:func:`finish`): median, left-right and border check,
speckles. The buffers live in ``workspace.py``, the settings in ``params.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.disparity_filters import remove_speckles
from depth_nodes.core.learned.network import FeatureExtractor, FeatureNet, shipped_features
from depth_nodes.core.sgm import ranged
from depth_nodes.core.sgm.bands import Band, run_tasks
from depth_nodes.core.sgm.check import check_disparity
from depth_nodes.core.sgm.coarse import CoarseSearch
from depth_nodes.core.sgm.cost import CostInputs, CostRows, cost_inputs
from depth_nodes.core.sgm.learned_cost import LearnedCosts, learned_costs
from depth_nodes.core.sgm.params import SgmParams
from depth_nodes.core.sgm.schedule import FullFrame, RangedFrame
from depth_nodes.core.sgm.workspace import (
    FrameBuffers,
    RangedWorkspace,
    Workspaces,
    frame_bands,
    whole_volumes,
)
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]


@dataclass
class SgmResult:
    """Outputs of one match; arrays belong to the matcher and are reused by the next call.

    Attributes:
        disparity: (H, W) float32 left disparity, NaN where invalid.
        disparity_right: (H, W) float32 right-view disparity (x_left = x_right + d).
        cost_ratio: (H, W) float32 best / second-best aggregated cost of the left winner
            (0 = unambiguous, 1 = no preference).
    """

    disparity: F32
    disparity_right: F32
    cost_ratio: F32


class SgmMatcher:
    """Census SGM with buffers preallocated for one image size and reused across frames.

    Args:
        params: Settings; :meth:`set_params` changes them between frames.

    Attributes:
        workspaces: The buffers kept between frames.
        coarse: The coarse search (its half-resolution matcher once one ran).
        border_cost: The out-of-image cost the last match used (0: none, extrapolation
            off).
        fallbacks: Coarse search: frames matched with the full search because their
            windows did not fit ``memory_mb`` (or the range does not halve within the
            width).
        search_cells: Coarse search: the last frame's cells as a fraction of the full
            volume.
    """

    def __init__(self, params: SgmParams | None = None) -> None:
        self.params = (params or SgmParams()).validate()
        self.workspaces = Workspaces()
        self.coarse = CoarseSearch(SgmMatcher)
        self.border_cost = 0
        self.fallbacks = 0
        self.search_cells = 1.0
        self._kept_total = False
        self._net: FeatureExtractor | None = None
        self._net_path = ''  # the learned_weights self._net was read from
        # the learned cost's quantised features, kept from frame to frame
        self._features: tuple[NDArray[np.int16], NDArray[np.int16]] | None = None

    @property
    def allocations(self) -> int:
        """How many times the matcher allocated volumes (a new frame size, settings that
        change the volumes, flat volumes that grew)."""
        return self.workspaces.allocations

    def set_params(self, params: SgmParams) -> None:
        """Use ``params`` from the next frame on (validated now)."""
        self.params = params.validate()

    def whole_volumes(self, h: int, w: int) -> bool:
        """Whether an (h, w) frame is matched with whole-frame volumes (exact) rather
        than bands in flight (memory bounded): see :func:`workspace.whole_volumes`."""
        return whole_volumes(self.params, h, w)

    def bands(self, h: int, w: int) -> list[Band]:
        """The bands of an (h, w) frame with the current settings (independent of the
        thread count, so every thread count gives the same result)."""
        return frame_bands(self.params, h, w)

    @property
    def workspace_bytes(self) -> int:
        """Bytes of the buffers the matcher keeps between frames."""
        return self.workspaces.nbytes + self.coarse.workspace_bytes

    def match(self, left: NDArray[Any], right: NDArray[Any], *,
              keep_total: bool = False) -> SgmResult:
        """Match a rectified grey pair, on ``numba.get_num_threads()`` threads.

        Args:
            left: (H, W) rectified left image (uint8, uint16 or float).
            right: (H, W) rectified right image, same shape.
            keep_total: Leave the full aggregated volume in :attr:`total` (tests; the
                full search is then used whatever ``disparity_search`` says).

        Raises:
            ArgumentError: Shapes differ or are not 2-D, or the range does not fit the width.
        """
        if left.ndim != 2 or right.ndim != 2:
            raise ArgumentError(f'left {left.shape} and right {right.shape} must be grey '
                                '(H, W) images')
        if left.shape != right.shape:
            raise ArgumentError(f'left {left.shape} and right {right.shape} must have one '
                                'size')
        h, w = left.shape
        p = self.params.check_width(w)  # the rest was checked when the params were set
        threads = max(1, numba.get_num_threads())
        if p.disparity_search == 'coarse' and not keep_total:
            found = self.coarse.match(left, right, p, lambda lo, wid: self._match_windows(
                left, right, p, threads, lo, wid))
            if found is not None:
                return finish(found.frame, p)
            self.fallbacks += 1
            self.search_cells = 1.0
        ws = self.workspaces.for_full(p, h, w, threads)
        inputs = self._frame_costs(left, right, p, ws.frame.census)
        total = self.workspaces.total_volume(h, w, p.disparity_range) if keep_total else \
            self.workspaces.total
        self._kept_total = keep_total
        frame = FullFrame(p, ws, inputs, np.ascontiguousarray(left, dtype=np.float32),
                          self.workspaces.p2_table(p), total, keep_total, threads)
        run_tasks(frame.tasks(), threads)
        self.border_cost = frame.border_cost
        del frame, inputs  # the per-frame intensities, before the filters' temporaries
        return finish(ws.frame, p)

    def match_costs(self, costs: CostRows, image: NDArray[Any]) -> SgmResult:
        """SGM over labels whose costs another module provides (the plane sweep of
        ``depth_nodes.core.mvs``), on ``numba.get_num_threads()`` threads.

        ``costs.rows`` fills bands of the (H, W, disparity_range) uint8 volume; ``image``
        (H, W) drives the adaptive P2. The labels are not a stereo pair's: there is no
        border statistic (``border_cost`` must be 0) and no left-right or border check;
        the median and the speckle filter apply as set. ``disparity`` holds the
        fractional label plus ``min_disparity``, ``cost_ratio`` the winner's ambiguity
        (``disparity_right`` is the selection's by-product, meaningless here).

        Raises:
            ArgumentError: ``image`` is not 2-D, or ``border_cost`` is not 0.
        """
        if image.ndim != 2:
            raise ArgumentError(f'image {image.shape} must be a grey (H, W) image')
        p = self.params
        if p.border_cost > 0:
            raise ArgumentError('match_costs needs border_cost 0 (its labels have no border)')
        h, w = image.shape
        threads = max(1, numba.get_num_threads())
        ws = self.workspaces.for_full(p, h, w, threads)
        self._kept_total = False
        frame = FullFrame(p, ws, costs, np.ascontiguousarray(image, dtype=np.float32),
                          self.workspaces.p2_table(p), self.workspaces.total, False, threads)
        run_tasks(frame.tasks(), threads)
        self.border_cost = 0
        return finish(ws.frame, p, stereo=False)

    def match_windows(self, left: NDArray[Any], right: NDArray[Any], lo: I32,
                      wid: I32) -> SgmResult | None:
        """Match over given windows, as the coarse search's second pass does: pixel (y,
        x) searches disparity indices lo[y, x] .. lo[y, x] + wid[y, x] - 1 only (tests;
        ``disparity_search`` is ignored). None when the windows exceed ``memory_mb``.

        Raises:
            ArgumentError: The windows are not (H, W), empty somewhere or outside the
                range, or ``matching_cost`` is not census (the windows' kernels are
                census's).
        """
        h, w = left.shape
        p = self.params.check_width(w)
        if p.matching_cost != 'census':
            raise ArgumentError(f'match_windows needs matching_cost census, not '
                                f'{p.matching_cost}')
        if lo.shape != (h, w) or wid.shape != (h, w) or (wid < 1).any() or (lo < 0).any() \
                or (lo + wid > p.disparity_range).any():
            raise ArgumentError('windows must be (H, W), non-empty and inside the range')
        ws = self._match_windows(left, right, p, max(1, numba.get_num_threads()),
                                 np.ascontiguousarray(lo, np.int32),
                                 np.ascontiguousarray(wid, np.int32))
        return None if ws is None else finish(ws.frame, p)

    def _match_windows(self, left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                       threads: int, lo: I32, wid: I32) -> RangedWorkspace | None:
        """The second pass over the windows (selection into the returned buffers, before
        the post-filters); None when their volumes exceed ``memory_mb``."""
        h, w = left.shape
        base = ranged.flat_offsets(wid)
        cells = int(base[-1])
        if ranged.CELL_BYTES * cells > p.memory_mb * 1e6:
            return None
        self.search_cells = cells / (h * w * p.disparity_range)
        ws = self.workspaces.for_ranged(p, h, w, threads, cells)
        inputs = _cost_inputs(left, right, p, ws.frame.census)
        frame = RangedFrame(p, ws, inputs, np.ascontiguousarray(left, dtype=np.float32),
                            self.workspaces.p2_table(p), lo, wid, base)
        run_tasks(frame.tasks(), threads)
        self.border_cost = frame.border_cost
        return ws

    def _frame_costs(self, left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                     census: tuple[Any, Any]) -> CostInputs | LearnedCosts:
        """The frame's costs for ``matching_cost``: census (+ intensity), the learned
        features' or both (the network is read on first use)."""
        if p.matching_cost == 'census':
            return _cost_inputs(left, right, p, census)
        if self._net is None or self._net_path != p.learned_weights:
            net = FeatureNet.load(p.learned_weights) if p.learned_weights else \
                shipped_features()
            self._net, self._net_path = FeatureExtractor(net), p.learned_weights
            self._features = None
        both = _cost_inputs(left, right, p, census) if p.matching_cost == 'census+learned' \
            else None
        costs = learned_costs(self._net, left, right, min_disparity=p.min_disparity,
                              weight=p.learned_weight, census=both, buffers=self._features)
        self._features = (costs.left, costs.right_mirrored)
        return costs

    @property
    def total(self) -> NDArray[np.uint16]:
        """The aggregated volume of the last match, which must have been
        ``match(..., keep_total=True)``.

        Raises:
            RuntimeError: The last match did not keep it.
        """
        if not self._kept_total:
            raise RuntimeError('the last match kept no total: call match(..., '
                               'keep_total=True)')
        return self.workspaces.total


def _cost_inputs(left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                 census: tuple[Any, Any]) -> CostInputs:
    """The frame's cost inputs with the settings ``p``, into the census buffers."""
    return cost_inputs(
        left, right, min_disparity=p.min_disparity, disparity_range=p.disparity_range,
        census_window=(p.census_height, p.census_width), census_weight=p.census_weight,
        intensity_weight=p.intensity_weight, intensity_cost=p.intensity_cost,
        intensity_truncation=p.intensity_truncation, match_brightness=p.match_brightness,
        census_buffers=census)


# ------------------------------------------------------------------- post-filters
def finish(buffers: FrameBuffers, params: SgmParams, *, stereo: bool = True) -> SgmResult:
    """The filters after the selection (either search), in place on ``buffers``' outputs:
    the 3x3 median (``median_filter``), the left-right and border rules
    (``check.check_disparity``; only for a stereo pair's labels, ``stereo``), the
    speckles (``speckle_size``)."""
    p, b = params, buffers
    if p.median_filter:
        median3(b.disparity, p.min_disparity)
    if stereo:
        check_disparity(b.disparity, b.disparity_right, max_diff=p.disp12_max_diff,
                        max_outside=p.border_extrapolation * p.disparity_range)
    if p.speckle_size > 0:
        speckles = remove_speckles(b.disparity, max_size=p.speckle_size,
                                   max_diff=p.speckle_range)
        b.disparity[speckles] = np.nan
    return SgmResult(b.disparity, b.disparity_right, b.ratio)


def median3(disparity: F32, min_disparity: int) -> None:
    """3x3 median in place. Invalid pixels stay invalid; they enter the median as very
    small values, so a pixel with mostly invalid neighbours keeps its own value."""
    invalid = np.isnan(disparity)
    marker = np.float32(min_disparity - 1e4)
    filled = np.where(invalid, marker, disparity).astype(np.float32)
    smoothed = cv2.medianBlur(filled, 3)
    keep = ~invalid & (smoothed > marker)
    disparity[keep] = smoothed[keep]


def sgm_match(left: NDArray[Any], right: NDArray[Any], params: SgmParams | None = None,
              **overrides: Any) -> SgmResult:
    """One-shot census SGM (allocates its buffers; use :class:`SgmMatcher` for streams)."""
    p = replace(params or SgmParams(), **overrides)
    result = SgmMatcher(p).match(left, right)
    return SgmResult(result.disparity.copy(), result.disparity_right.copy(),
                     result.cost_ratio.copy())
