"""The census Semi-Global Matching stereo matcher: public function and reusable workspace.

Typical use::

    matcher = SgmMatcher(SgmParams(disparity_range=128))
    result = matcher.match(left, right)        # buffers are reused on the next call
    result.disparity, result.disparity_right, result.cost_ratio
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.cross_check import remove_speckles
from depth_nodes.core.sgm.aggregate import (
    SINGLE_PASS,
    VERTICAL_DIRECTIONS,
    new_line_buffers,
    p2_table,
    sweep_down,
)
from depth_nodes.core.sgm.check import check_disparity
from depth_nodes.core.sgm.cost import (
    OUT_OF_RANGE_COST,
    census_dtype,
    cost_volume,
    fill_outside,
    mean_best_cost,
)
from depth_nodes.core.sgm.select import SUBPIXEL_MODES, upward_horizontal_select
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]

#: Row pieces per thread in the parallel sweeps (a few, so the threads finish together).
CHUNKS_PER_THREAD = 4


@dataclass(frozen=True)
class SgmParams:
    """Matcher settings (names follow stereo_image_proc where the meaning is the same).

    Attributes:
        min_disparity: Smallest disparity searched (may be negative).
        disparity_range: Number of disparities searched (any positive number).
        census_width: Census window width (odd, 3..9).
        census_height: Census window height (odd, 3..9); width x height - 1 <= 63.
        census_weight: Weight of the census Hamming distance (0 disables census).
        intensity_weight: Weight of the intensity cost (0 disables it).
        intensity_cost: ``'bt'`` (Birchfield-Tomasi) or ``'ad'`` (absolute difference).
        intensity_truncation: Cap of the intensity cost in grey levels.
        P1: Penalty of a disparity change of 1 between neighbours.
        P2: Penalty of a larger change (>= P1).
        p2_adaptive_scale: Grey-level scale of the image-adaptive P2
            (P2' = max(P1, P2 / (1 + |dI| / scale))); 0 keeps P2 constant.
        paths: 4, 5, 8 or 16 aggregation paths. 5 (both horizontals and the three from
            above, like OpenCV's MODE_SGBM) run in one pass without the (H, W, D) uint16
            sum of 8 and 16 (MODE_HH's directions and more).
        uniqueness_ratio: Percent by which the winner must beat the best non-neighbouring
            disparity (OpenCV's rule); 0 disables the check.
        subpixel: ``'parabola'``, ``'equiangular'`` or ``'none'``.
        median_filter: Apply a 3x3 median to the left disparity.
        match_brightness: Give the right image the left's mean and standard deviation
            before the intensity cost (a global gain and offset between the cameras).
        border_cost: Cost of a disparity whose match lies outside the right image, in
            units of the frame's mean best matching cost; the left border strip then
            takes the disparity its neighbours carry in (extrapolation) instead of being
            forced to one inside the image. 0: such disparities are never chosen.
        border_extrapolation: How far past the image border an extrapolated disparity's
            match may lie and still be published, as a fraction of disparity_range.
        disp12_max_diff: Left-right check: largest difference in px between the left
            disparity and the right view's at x - d (both from the same volume); <= 0
            disables it (stereo_image_proc's name and rule).
        speckle_size: Largest area in px of a disparity region that is removed as a
            speckle (0 disables; stereo_image_proc's name).
        speckle_range: Largest step in px between neighbours of one region.

    The defaults were chosen on the simulator scenes and on the two Middlebury 2003 pairs
    together (README, "Accuracy on real pairs"): census 5x5 plus Birchfield-Tomasi on
    brightness-matched images, P2 adapted strongly to intensity edges.
    """

    min_disparity: int = 0
    disparity_range: int = 128
    census_width: int = 5
    census_height: int = 5
    census_weight: int = 1
    intensity_weight: int = 1
    intensity_cost: str = 'bt'
    intensity_truncation: int = 30
    P1: int = 18
    P2: int = 220
    p2_adaptive_scale: float = 8.0
    paths: int = 8
    uniqueness_ratio: float = 10.0
    subpixel: str = 'parabola'
    median_filter: bool = False
    match_brightness: bool = True
    border_cost: float = 3.5
    border_extrapolation: float = 0.25
    disp12_max_diff: float = 2.0
    speckle_size: int = 100
    speckle_range: float = 2.0

    def validate(self, width: int | None = None) -> SgmParams:
        """Check every field (and the range against ``width``); returns self.

        Raises:
            ArgumentError: naming the first invalid field and why.
        """
        def bad(name: str, why: str) -> ArgumentError:
            return ArgumentError(f'SGM parameter {name}={getattr(self, name)!r}: {why}')

        if self.disparity_range < 1:
            raise bad('disparity_range', 'must be at least 1')
        for name in ('census_width', 'census_height'):
            value = getattr(self, name)
            if value % 2 == 0 or not 3 <= value <= 9:
                raise bad(name, 'must be odd, 3..9')
        if self.census_width * self.census_height - 1 > 63:
            raise bad('census_width', f'a {self.census_width}x{self.census_height} window has '
                      'more than 63 neighbours (use at most 9x7)')
        if self.census_weight < 0 or self.intensity_weight < 0:
            raise bad('census_weight', 'weights must be >= 0')
        if self.census_weight == 0 and self.intensity_weight == 0:
            raise bad('census_weight', 'census_weight and intensity_weight cannot both be 0')
        if self.intensity_cost not in ('bt', 'ad'):
            raise bad('intensity_cost', "must be 'bt' or 'ad'")
        if self.intensity_truncation < 1:
            raise bad('intensity_truncation', 'must be >= 1')
        if self.P1 < 0:
            raise bad('P1', 'must be >= 0')
        if self.P2 < self.P1:
            raise bad('P2', f'must be >= P1 ({self.P1})')
        if self.paths not in VERTICAL_DIRECTIONS:
            raise bad('paths', 'must be 4, 5, 8 or 16')
        limit = 65535 // self.paths - OUT_OF_RANGE_COST
        if limit < self.P2:
            raise bad('P2', f'must be <= {limit} with {self.paths} paths, so that the 16-bit '
                      'sum of the paths cannot overflow')
        if self.p2_adaptive_scale < 0:
            raise bad('p2_adaptive_scale', 'must be >= 0')
        if not 0 <= self.uniqueness_ratio < 100:
            raise bad('uniqueness_ratio', 'must be in [0, 100)')
        if self.subpixel not in SUBPIXEL_MODES:
            raise bad('subpixel', f'must be one of {", ".join(SUBPIXEL_MODES)}')
        if not 0 <= self.border_cost <= 100:
            raise bad('border_cost', 'must be in [0, 100]')
        if not 0 <= self.border_extrapolation <= 1:
            raise bad('border_extrapolation', 'must be in [0, 1]')
        if self.speckle_size < 0:
            raise bad('speckle_size', 'must be >= 0')
        if self.speckle_range < 0:
            raise bad('speckle_range', 'must be >= 0')
        if width is not None and self.disparity_range >= width:
            raise bad('disparity_range', f'is not smaller than the image width {width}')
        if width is not None and not -width < self.min_disparity < width:
            raise bad('min_disparity', f'is outside (-{width}, {width})')
        return self


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
    """

    def __init__(self, params: SgmParams | None = None) -> None:
        self.params = (params or SgmParams()).validate()
        self._shape: tuple[object, ...] = ()
        self._table_key: tuple[Any, ...] = ()
        self._table = p2_table(0, 0, 0.0)
        self._buf: dict[str, Any] = {}
        self._kept_total = False
        self.allocations = 0
        #: The out-of-image cost the last match used (0: none, extrapolation off).
        self.border_cost = 0

    def set_params(self, params: SgmParams) -> None:
        """Use ``params`` from the next frame on (validated now)."""
        self.params = params.validate()

    def _buffers(self, h: int, w: int) -> dict[str, Any]:
        p = self.params
        n = p.disparity_range
        dirs = VERTICAL_DIRECTIONS[p.paths]
        threads = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
        census = census_dtype((p.census_height, p.census_width))
        shape = (h, w, n, p.paths, threads, census)
        if shape != self._shape:
            rings, mbuf = new_line_buffers(len(dirs), w, n)
            self._buf = {
                'census': (np.empty((h, w), census), np.empty((h, w), census)),
                'cost': np.empty((h, w, n), np.uint8),
                # the sum of the downward paths (none in one pass; see match's keep_total)
                'partial': np.empty((0, 0, 0) if p.paths in SINGLE_PASS else (h, w, n),
                                    np.uint16),
                'rings': rings, 'mbuf': mbuf,
                'dxs': np.array([d[0] for d in dirs], np.int64),
                'dys': np.array([d[1] for d in dirs], np.int64),
                'rows': (np.empty((w, n), np.uint16), np.empty((2, w, n), np.uint16),
                         np.empty((2, w, n), np.uint16)),
                'keys': np.empty((CHUNKS_PER_THREAD * threads, w), np.uint32),
                'disparity': np.empty((h, w), np.float32),
                'disparity_right': np.empty((h, w), np.float32),
                'ratio': np.empty((h, w), np.float32),
            }
            self._shape = shape
            self.allocations += 1
        table_key = (p.P1, p.P2, p.p2_adaptive_scale)
        if table_key != self._table_key:
            self._table = p2_table(*table_key)
            self._table_key = table_key
        return self._buf

    def match(self, left: NDArray[Any], right: NDArray[Any], *,
              keep_total: bool = False) -> SgmResult:
        """Match a rectified grey pair.

        Args:
            left: (H, W) rectified left image (uint8, uint16 or float).
            right: (H, W) rectified right image, same shape.
            keep_total: Leave the full aggregated volume in :attr:`total` (tests).

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
        p = self.params.validate(w)
        b = self._buffers(h, w)
        left_f = np.ascontiguousarray(left, dtype=np.float32)
        cost = cost_volume(
            left, right, min_disparity=p.min_disparity, disparity_range=p.disparity_range,
            census_window=(p.census_height, p.census_width), census_weight=p.census_weight,
            intensity_weight=p.intensity_weight, intensity_cost=p.intensity_cost,
            intensity_truncation=p.intensity_truncation, match_brightness=p.match_brightness,
            out=b['cost'], census_buffers=b['census'])
        extrapolate = p.border_cost > 0
        if extrapolate:
            self.border_cost = min(254, max(1, round(
                p.border_cost * mean_best_cost(cost, p.min_disparity))))
            fill_outside(cost, p.min_disparity, self.border_cost)
        else:
            self.border_cost = 0
        lb0, lb1, lb2 = b['rings']
        chunks = CHUNKS_PER_THREAD * numba.get_num_threads()
        single_pass = p.paths in SINGLE_PASS
        if keep_total and b['partial'].shape != cost.shape:  # tests: room for the total
            b['partial'] = np.empty(cost.shape, np.uint16)
        self._kept_total = keep_total
        if not single_pass:
            sweep_down(cost, left_f, b['dxs'], b['dys'], int(p.P1), int(p.P2), self._table,
                       lb0, lb1, lb2, b['mbuf'], b['partial'], chunks)
        total, left_to_right, right_to_left = b['rows']
        upward_horizontal_select(
            cost, left_f, b['partial'], b['dxs'], b['dys'], int(p.P1), int(p.P2),
            self._table, lb0, lb1, lb2, b['mbuf'], int(p.min_disparity),
            float(p.uniqueness_ratio), SUBPIXEL_MODES[p.subpixel], total, left_to_right,
            right_to_left, b['keys'], b['disparity'], b['disparity_right'], b['ratio'],
            keep_total, chunks, single_pass, extrapolate)
        if p.median_filter:
            _median3(b['disparity'], p.min_disparity)
        check_disparity(b['disparity'], b['disparity_right'], max_diff=p.disp12_max_diff,
                        max_outside=p.border_extrapolation * p.disparity_range)
        if p.speckle_size > 0:
            speckles = remove_speckles(b['disparity'], max_size=p.speckle_size,
                                       max_diff=p.speckle_range)
            b['disparity'][speckles] = np.nan
        return SgmResult(b['disparity'], b['disparity_right'], b['ratio'])

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
        return self._buf['partial']  # type: ignore[no-any-return]


def _median3(disparity: F32, min_disparity: int) -> None:
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
