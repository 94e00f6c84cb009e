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

from depth_nodes.core.cross_check import SPECKLE_SIZE, remove_speckles
from depth_nodes.core.settings import check_settings, setting
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
#: How a settings error names the matcher.
LABEL = 'SGM parameter'
#: The largest P2 (with 4 paths; fewer with more: the 16-bit sum of the paths).
P2_MAX = 65535 // min(VERTICAL_DIRECTIONS) - OUT_OF_RANGE_COST


@dataclass(frozen=True)
class SgmParams:
    """Matcher settings (names follow stereo_image_proc where the meaning is the same).

    Each field's meaning and range are given by its :func:`setting` below; the sgm_stereo
    node declares its census parameters from them, so ``ros2 param describe`` shows the
    same text. :meth:`validate` adds the rules that join fields (the census window's
    bits, P2 >= P1, P2's limit for the number of paths, the range against the width).

    The defaults were chosen on the simulator scenes and on the two Middlebury 2003 pairs
    together (README, "Accuracy on real pairs"): census 5x5 plus Birchfield-Tomasi on
    brightness-matched images, P2 adapted strongly to intensity edges.
    """

    min_disparity: int = setting(0, 'Smallest disparity searched, px (may be negative)',
                                 low=-2048, high=2048)
    disparity_range: int = setting(128, 'Number of disparities searched (any number)',
                                   low=1, high=4096)
    census_width: int = setting(5, 'census window width (odd)', low=3, high=9, odd=True)
    census_height: int = setting(5, 'census window height (odd; width x height - 1 <= 63)',
                                 low=3, high=9, odd=True)
    census_weight: int = setting(1, 'weight of the census Hamming cost (0: intensity only)',
                                 low=0, high=8)
    intensity_weight: int = setting(1, 'weight of the intensity cost (0: census only)',
                                    low=0, high=8)
    intensity_cost: str = setting('bt', 'intensity cost, bt (Birchfield-Tomasi) or ad '
                                  '(absolute difference)', choices=('bt', 'ad'))
    intensity_truncation: int = setting(30, 'cap of the intensity cost, grey levels',
                                        low=1, high=255)
    P1: int = setting(18, 'Penalty of a 1 px disparity change between neighbours',
                      low=0, high=4000)
    P2: int = setting(220, 'Penalty of a larger disparity change (>= P1; at most '
                      f'65535 / paths - {OUT_OF_RANGE_COST})', low=0, high=P2_MAX)
    p2_adaptive_scale: float = setting(8.0, 'grey-level scale of the image-adaptive P2, '
                                       "P2' = max(P1, P2 / (1 + |dI| / scale)) (0: constant "
                                       'P2)', low=0.0, high=255.0)
    paths: int = setting(8, 'aggregation paths: 4, 5 (both horizontals and the three from '
                         "above, one pass, like OpenCV's MODE_SGBM), 8 (MODE_HH's) or 16",
                         choices=tuple(VERTICAL_DIRECTIONS))
    uniqueness_ratio: float = setting(10.0, 'Percent by which the best cost must beat the '
                                      'best non-neighbouring disparity (0: off; below 100)',
                                      low=0.0, high=100.0)
    subpixel: str = setting('parabola', 'sub-pixel refinement, parabola, equiangular or '
                            'none', choices=tuple(SUBPIXEL_MODES))
    median_filter: bool = setting(False, '3x3 median on the left disparity')
    match_brightness: bool = setting(True, "give the right image the left's mean and "
                                     'spread before the intensity cost (a gain or offset '
                                     'between the cameras)')
    border_cost: float = setting(3.5, 'cost of a disparity whose match is outside the '
                                 "right image, in units of the frame's mean best cost; the "
                                 "left border strip then takes its neighbours' disparity "
                                 '(0: never chosen)', low=0.0, high=100.0)
    border_extrapolation: float = setting(0.25, 'how far past the image border an '
                                          'extrapolated disparity is published, as a '
                                          'fraction of disparity_range', low=0.0, high=1.0)
    disp12_max_diff: float = setting(2.0, 'Left-right check: largest |d_left - d_right| in '
                                     'px (<= 0: off)')
    speckle_size: int = setting(100, SPECKLE_SIZE)
    speckle_range: float = setting(2.0, 'Largest disparity step in px within one speckle '
                                   'region', low=0.0, high=64.0)

    def _bad(self, name: str, why: str) -> ArgumentError:
        return ArgumentError(f'{LABEL} {name}={getattr(self, name)!r}: {why}')

    def validate(self, width: int | None = None) -> SgmParams:
        """Check every field (and, with ``width``, :meth:`check_width`); returns self.

        Raises:
            ArgumentError: naming the first invalid field and why.
        """
        bad = self._bad
        check_settings(self, LABEL)
        if self.census_width * self.census_height - 1 > 63:
            raise bad('census_width', f'a {self.census_width}x{self.census_height} window has '
                      'more than 63 neighbours (use at most 9x7)')
        if self.census_weight == 0 and self.intensity_weight == 0:
            raise bad('census_weight', 'census_weight and intensity_weight cannot both be 0')
        if self.uniqueness_ratio == 100:
            raise bad('uniqueness_ratio', 'must be below 100')
        if self.P2 < self.P1:
            raise bad('P2', f'must be >= P1 ({self.P1})')
        limit = 65535 // self.paths - OUT_OF_RANGE_COST
        if limit < self.P2:
            raise bad('P2', f'must be <= {limit} with {self.paths} paths, so that the 16-bit '
                      'sum of the paths cannot overflow')
        return self if width is None else self.check_width(width)

    def check_width(self, width: int) -> SgmParams:
        """The rules that depend on the frame: the disparity window fits ``width``.

        Raises:
            ArgumentError: It does not.
        """
        if self.disparity_range >= width:
            raise self._bad('disparity_range', f'is not smaller than the image width {width}')
        if not -width < self.min_disparity < width:
            raise self._bad('min_disparity', f'is outside (-{width}, {width})')
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
        p = self.params.check_width(w)  # the rest was checked when the params were set
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
