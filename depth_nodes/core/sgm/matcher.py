"""The census Semi-Global Matching stereo matcher: public function and reusable workspace.

Typical use::

    matcher = SgmMatcher(SgmParams(disparity_range=128))
    result = matcher.match(left, right)        # buffers are reused on the next call
    result.disparity, result.disparity_right, result.cost_ratio
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.cross_check import SPECKLE_SIZE, remove_speckles
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.core.sgm import ranged
from depth_nodes.core.sgm.aggregate import (
    SENTINEL,
    SINGLE_PASS,
    VERTICAL_DIRECTIONS,
    new_line_buffers,
    p2_table,
    sweep_down,
)
from depth_nodes.core.sgm.bands import (
    CACHED_BAND_BYTES,
    CELL_BYTES,
    MIN_BAND_ROWS,
    MIN_BANDS,
    Band,
    Task,
    band_layout,
    band_rows,
    run_tasks,
)
from depth_nodes.core.sgm.check import check_disparity
from depth_nodes.core.sgm.cost import (
    OUT_OF_RANGE_COST,
    CostInputs,
    _best_cost_sum,
    _full_range_columns,
    census_dtype,
    cost_inputs,
    fill_outside,
    mean_best_count,
    sampled_best_cost_sum,
)
from depth_nodes.core.sgm.select import SUBPIXEL_MODES, band_select
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]

#: Bands in flight the automatic band height is sized for (a downward sweep and two
#: selections: two threads never wait for a free band). Each thread beyond two adds one.
SIZED_SLOTS = 3
#: Rows below a band whose costs a worker holds at once while its upward paths go
#: through them (they are never all held: see ``_Frame._select``).
OVERLAP_CHUNK = 8
#: Row step of the frame statistic behind ``border_cost`` (:func:`cost.mean_best_cost`).
BORDER_ROW_STEP = 4
#: disparity_search: every disparity, or windows from a half-resolution pass (ranged.py).
SEARCH_MODES = ('full', 'coarse')
#: Paths of the coarse search's half-resolution pass, by the frame's (only its windows
#: depend on it).
COARSE_PATHS = {8: 5, 16: 5}
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
    band_rows: int = setting(0, 'rows per band of the banded matcher (0: automatic, an '
                             'eighth of the image at most and within memory_mb; the image '
                             'height or more: one band, the exact unbanded SGM)',
                             low=0, high=100000)
    band_overlap: int = setting(64, 'rows below each band from which its upward paths '
                                'start (the only approximation of the banded matcher)',
                                low=0, high=100000)
    memory_mb: float = setting(160.0, 'memory for the cost volumes, MB: whole-frame volumes '
                               '(exact) when they fit, else bands in flight sized to it '
                               '(about constant whatever the disparity range; 0: always '
                               'bands)', low=0.0, high=1e6)
    disparity_search: str = setting('full', 'full: every disparity at every pixel; coarse: '
                                    'a half-resolution pass first, then each pixel searches '
                                    'only the disparities its neighbourhood found there '
                                    '(tSGM; falls back to full for a frame whose windows do '
                                    'not fit memory_mb)', choices=SEARCH_MODES)
    search_margin: float = setting(8.0, 'coarse search: px added either side of the '
                                   "disparities a pixel's coarse neighbourhood found",
                                   low=0.0, high=4096.0)

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
        self._total = np.empty((0, 0, 0), np.uint16)
        self._kept_total = False
        self.allocations = 0
        #: The out-of-image cost the last match used (0: none, extrapolation off).
        self.border_cost = 0
        #: Coarse search: frames matched with the full search because their windows did
        #: not fit ``memory_mb`` (or the range does not halve within the width); the last
        #: frame's cells as a fraction of the full volume.
        self.fallbacks = 0
        self.search_cells = 1.0
        self._coarse: SgmMatcher | None = None
        self._ranged_shape: tuple[object, ...] = ()
        self._ranged_buf: dict[str, Any] = {}

    def set_params(self, params: SgmParams) -> None:
        """Use ``params`` from the next frame on (validated now)."""
        self.params = params.validate()

    def whole_volumes(self, h: int, w: int) -> bool:
        """Whether an (h, w) frame is matched with whole-frame volumes (exact; the
        downward and upward paths as two chains of bands running at once) rather than
        bands in flight whose upward paths start ``band_overlap`` rows below them (memory
        bounded): when the volumes (3 bytes a cell) fit ``memory_mb``, or the overlap
        reaches the image bottom anyway. Single-pass path counts need no whole volume."""
        p = self.params
        if p.paths in SINGLE_PASS:
            return False
        return p.band_overlap >= h or CELL_BYTES * h * w * p.disparity_range <= p.memory_mb * 1e6

    def bands(self, h: int, w: int) -> list[Band]:
        """The bands of an (h, w) frame with the current settings (independent of the
        thread count, so every thread count gives the same result)."""
        p = self.params
        if self.whole_volumes(h, w):
            return band_layout(h, min(h, p.band_rows or -(-h // MIN_BANDS)), 0)
        overlap = 0 if p.paths in SINGLE_PASS else p.band_overlap
        rows = p.band_rows or band_rows(h, w, p.disparity_range, memory_mb=p.memory_mb,
                                        slots=SIZED_SLOTS, overlap=overlap)
        if p.paths in SINGLE_PASS and not p.band_rows:  # exact with any bands: cache-sized
            cached = int(CACHED_BAND_BYTES // (w * p.disparity_range * CELL_BYTES))
            rows = min(rows, max(MIN_BAND_ROWS, cached))
        return band_layout(h, min(rows, h), overlap)

    def _buffers(self, h: int, w: int, threads: int) -> dict[str, Any]:
        p = self.params
        n = p.disparity_range
        dirs = VERTICAL_DIRECTIONS[p.paths]
        census = census_dtype((p.census_height, p.census_width))
        bands = self.bands(h, w)
        whole = self.whole_volumes(h, w)
        slots = 1 if whole else min(len(bands), max(SIZED_SLOTS, threads + 1))
        rows = h if whole else max(b.rows for b in bands)
        chunk = min(OVERLAP_CHUNK, max(b.reach - b.rows for b in bands)) if not whole else 0
        # the thread count is not part of the key: a frame on another number of threads
        # (bench sgm --busy alternates two and one) reuses the volumes and only adds the
        # scratch of the extra workers (reallocating the 118 MB of a VGA frame's volumes
        # on every such call cost more than the match itself under contention)
        shape = (h, w, n, p.paths, census, tuple(bands), whole, slots)

        def rings() -> tuple[tuple[Any, Any, Any], Any]:
            return new_line_buffers(len(dirs), w, n)

        if shape != self._shape:
            self._buf = {
                'census': (np.empty((h, w), census), np.empty((h, w), census)),
                'bands': bands,
                'whole': whole,
                'cost': [np.empty((rows, w, n), np.uint8) for _ in range(slots)],
                'partial': [np.empty((rows, w, n), np.uint16) for _ in range(slots)],
                'down': rings(),
                'up': rings() if whole else None,
                'workers': [],
                **_outputs(h, w, dirs),
            }
            self._shape = shape
            self.allocations += 1
        workers = self._buf['workers']
        while len(workers) < threads:
            workers.append({'rings': rings(), 'total': np.empty((w, n), np.uint16),
                            'ltr': np.empty((2, w, n), np.uint16),
                            'rtl': np.empty((2, w, n), np.uint16),
                            'hlines': _lines(4, n),
                            'keys': np.empty(w, np.uint32),
                            'sample': np.empty((1, w, n), np.uint8),
                            'below': np.empty((chunk, w, n), np.uint8)})
        self._update_table()
        return self._buf

    def _update_table(self) -> None:
        """The adaptive-P2 table of the current settings."""
        p = self.params
        table_key = (p.P1, p.P2, p.p2_adaptive_scale)
        if table_key != self._table_key:
            self._table = p2_table(*table_key)
            self._table_key = table_key

    @property
    def workspace_bytes(self) -> int:
        """Bytes of the buffers the matcher keeps between frames."""
        def size(value: Any) -> int:
            if isinstance(value, np.ndarray):
                return value.nbytes
            if isinstance(value, (list, tuple)):
                return sum(size(v) for v in value)
            if isinstance(value, dict):
                return sum(size(v) for v in value.values())
            return 0
        coarse = self._coarse.workspace_bytes if self._coarse is not None else 0
        return size(self._buf) + size(self._total) + size(self._ranged_buf) + coarse

    def match(self, left: NDArray[Any], right: NDArray[Any], *,
              keep_total: bool = False) -> SgmResult:
        """Match a rectified grey pair, on ``numba.get_num_threads()`` threads.

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
        threads = max(1, numba.get_num_threads())
        if p.disparity_search == 'coarse' and not keep_total:
            b = self._ranged_match(left, right, p, threads)
            if b is not None:
                return self._finish(b, p)
            self.fallbacks += 1
            self.search_cells = 1.0
        b = self._buffers(h, w, threads)
        inputs = _cost_inputs(left, right, p, b['census'])
        if keep_total and self._total.shape != (h, w, p.disparity_range):
            self._total = np.empty((h, w, p.disparity_range), np.uint16)
        self._kept_total = keep_total
        frame = _Frame(self, p, b, inputs, np.ascontiguousarray(left, dtype=np.float32),
                       keep_total, threads)
        run_tasks(frame.tasks(), threads)
        self.border_cost = frame.border_cost
        del frame, inputs  # the per-frame intensities, before the filters' temporaries
        return self._finish(b, p)

    def _finish(self, b: dict[str, Any], p: SgmParams) -> SgmResult:
        """The filters after the selection (either search), on ``b``'s outputs."""
        if p.median_filter:
            _median3(b['disparity'], p.min_disparity)
        check_disparity(b['disparity'], b['disparity_right'], max_diff=p.disp12_max_diff,
                        max_outside=p.border_extrapolation * p.disparity_range)
        if p.speckle_size > 0:
            speckles = remove_speckles(b['disparity'], max_size=p.speckle_size,
                                       max_diff=p.speckle_range)
            b['disparity'][speckles] = np.nan
        return SgmResult(b['disparity'], b['disparity_right'], b['ratio'])

    def _ranged_match(self, left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                      threads: int) -> dict[str, Any] | None:
        """The coarse-to-fine search (``ranged.py``): a half-resolution full match, then
        the full-resolution one over each pixel's window. Returns the buffers holding the
        selection, or None when the windows' volumes exceed ``memory_mb`` or the
        half-resolution pass cannot hold the range."""
        h, w = left.shape
        ch, cw = ranged.coarse_size(h, w)
        c_min, c_range = ranged.coarse_window(p.min_disparity, p.disparity_range)
        coarse_params = replace(
            p, disparity_search='full', min_disparity=c_min,
            disparity_range=min(c_range, cw - 1), speckle_size=p.speckle_size // 4,
            speckle_range=p.speckle_range / 2, median_filter=False, band_rows=0,
            paths=COARSE_PATHS.get(p.paths, p.paths))
        try:  # a window at the edge of what the width allows may not halve
            coarse_params.validate(cw)
        except ArgumentError:
            return None
        if self._coarse is None:
            self._coarse = SgmMatcher(coarse_params)
        elif self._coarse.params != coarse_params:
            self._coarse.set_params(coarse_params)
        coarse = self._coarse.match(cv2.resize(left, (cw, ch), interpolation=cv2.INTER_AREA),
                                    cv2.resize(right, (cw, ch), interpolation=cv2.INTER_AREA))
        outside = p.border_extrapolation * p.disparity_range if p.border_cost > 0 else 0.0
        for align in (ranged.ALIGN, 1):  # aligned windows when they fit, else tight ones
            lo, wid = ranged.search_ranges(coarse.disparity, (h, w),
                                           min_disparity=p.min_disparity,
                                           disparity_range=p.disparity_range,
                                           margin=p.search_margin, outside=outside,
                                           align=align)
            b = self._match_windows(left, right, p, threads, lo, wid)
            if b is not None:
                return b
        return None

    def match_windows(self, left: NDArray[Any], right: NDArray[Any], lo: NDArray[np.int32],
                      wid: NDArray[np.int32]) -> SgmResult | None:
        """Match over given windows, as the coarse search's second pass does: pixel (y,
        x) searches disparity indices lo[y, x] .. lo[y, x] + wid[y, x] - 1 only (tests;
        ``disparity_search`` is ignored). None when the windows exceed ``memory_mb``."""
        h, w = left.shape
        p = self.params.check_width(w)
        if lo.shape != (h, w) or wid.shape != (h, w) or (wid < 1).any() or (lo < 0).any() \
                or (lo + wid > p.disparity_range).any():
            raise ArgumentError('windows must be (H, W), non-empty and inside the range')
        b = self._match_windows(left, right, p, max(1, numba.get_num_threads()),
                                np.ascontiguousarray(lo, np.int32),
                                np.ascontiguousarray(wid, np.int32))
        return None if b is None else self._finish(b, p)

    def _match_windows(self, left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                       threads: int, lo: NDArray[np.int32],
                       wid: NDArray[np.int32]) -> dict[str, Any] | None:
        h, w = left.shape
        base = ranged.flat_offsets(wid)
        cells = int(base[-1])
        if ranged.CELL_BYTES * cells > p.memory_mb * 1e6:
            return None
        self.search_cells = cells / (h * w * p.disparity_range)
        b = self._ranged_buffers(h, w, threads, cells)
        inputs = _cost_inputs(left, right, p, b['census'])
        frame = _RangedFrame(self, p, b, inputs, np.ascontiguousarray(left, dtype=np.float32),
                             lo, wid, base)
        run_tasks(frame.tasks(), threads)
        self.border_cost = frame.border_cost
        return b

    def _ranged_buffers(self, h: int, w: int, threads: int, cells: int) -> dict[str, Any]:
        """The coarse-to-fine search's buffers; the flat volumes grow to the largest
        frame's windows (by a quarter more, so that they seldom grow again, but never past
        ``memory_mb``)."""
        p = self.params
        n = p.disparity_range
        dirs = VERTICAL_DIRECTIONS[p.paths]
        census = census_dtype((p.census_height, p.census_width))
        shape = (h, w, n, p.paths, census)  # the thread count: as in _buffers
        if shape != self._ranged_shape:
            def rings() -> tuple[tuple[Any, Any, Any], Any]:
                return new_line_buffers(len(dirs), w, n)

            self._ranged_buf = {
                'census': (np.empty((h, w), census), np.empty((h, w), census)),
                'bands': band_layout(h, -(-h // MIN_BANDS), 0),
                'cost': np.empty(0, np.uint8),
                'partial': np.empty(0, np.uint16),
                'down': rings(),
                'up': rings(),
                'workers': [],
                **_outputs(h, w, dirs),
            }
            self._ranged_shape = shape
            self.allocations += 1
        b = self._ranged_buf
        while len(b['workers']) < threads:
            b['workers'].append({'total': np.empty((w, n), np.uint16),
                                 'ltr': np.empty((w, n), np.uint16),
                                 'rtl': np.empty((w, n), np.uint16),
                                 'lines': np.empty((2, n + 2), np.uint16),
                                 'keys': np.empty(w, np.uint32)})
        if b['cost'].size < cells:
            grown = max(cells, min(cells + cells // 4,
                                   int(p.memory_mb * 1e6) // ranged.CELL_BYTES))
            b['cost'] = b['partial'] = None  # let the old ones go before the new ones
            b['cost'] = np.empty(grown, np.uint8)
            b['partial'] = np.empty(grown, np.uint16)
            self.allocations += 1
        self._update_table()
        return b

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
        return self._total


def _cost_inputs(left: NDArray[Any], right: NDArray[Any], p: SgmParams,
                 census: tuple[Any, Any]) -> CostInputs:
    """The frame's cost inputs with the settings ``p``, into the census buffers."""
    return cost_inputs(
        left, right, min_disparity=p.min_disparity, disparity_range=p.disparity_range,
        census_window=(p.census_height, p.census_width), census_weight=p.census_weight,
        intensity_weight=p.intensity_weight, intensity_cost=p.intensity_cost,
        intensity_truncation=p.intensity_truncation, match_brightness=p.match_brightness,
        census_buffers=census)


def _border_cost(p: SgmParams, total: float, h: int, w: int) -> int:
    """The out-of-image cost: ``border_cost`` times the frame's mean best cost, from the
    sum ``total`` of the best costs of the sampled rows (1 .. 254)."""
    count = mean_best_count(h, w, p.disparity_range, p.min_disparity, BORDER_ROW_STEP)
    return min(254, max(1, round(p.border_cost * total / count)))


def _lines(count: int, n: int) -> NDArray[np.uint16]:
    """``count`` path lines of D + 2 entries, SENTINEL at both ends (``band_select``)."""
    lines = np.empty((count, n + 2), np.uint16)
    lines[:, 0] = lines[:, -1] = SENTINEL
    return lines


def _outputs(h: int, w: int, dirs: tuple[tuple[int, int], ...]) -> dict[str, Any]:
    """The buffers both searches share: the vertical directions' steps, the outputs."""
    return {'dxs': np.array([d[0] for d in dirs], np.int64),
            'dys': np.array([d[1] for d in dirs], np.int64),
            'disparity': np.empty((h, w), np.float32),
            'disparity_right': np.empty((h, w), np.float32),
            'ratio': np.empty((h, w), np.float32)}


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


class _Frame:
    """One match as tasks for :func:`bands.run_tasks`.

    First the border statistic (two halves of its sampled rows, then their sum). Whole
    volumes: per band its costs, its downward sweep (a chain from the top: each continues
    the paths of the band above), its upward sweep (a chain from the bottom) and, once both
    have passed it, its selection. Bands in flight: per band its costs and downward sweep
    (the chain), then its selection with its own upward paths; a band's buffers are reused
    once the selection that last held them is done."""

    def __init__(self, matcher: SgmMatcher, params: SgmParams, buffers: dict[str, Any],
                 inputs: CostInputs, image: F32, keep_total: bool, threads: int) -> None:
        self.p = params
        self.buf = buffers
        self.inputs = inputs
        self.image = image
        self.table = matcher._table
        self.total = matcher._total
        self.keep_total = keep_total
        self.extrapolate = params.border_cost > 0
        self.border_cost = 0
        self.samples = [0.0, 0.0]
        # on one thread with whole volumes the border statistic is taken from the stored
        # costs once they are all there (the same rows, so the same value) instead of from
        # rows computed again for it: 4 % of a frame's work saved; with more threads the
        # sampled rows come first, so that the chains can start on the first bands' costs
        self.from_volume = buffers['whole'] and self.extrapolate and threads == 1
        self.h, self.w = image.shape
        bands = len(buffers['bands'])
        self.band_locks = [threading.Lock() for _ in range(bands)]
        self.swept = [False] * bands

    def tasks(self) -> list[Task]:
        """The frame's tasks, dependencies first."""
        tasks: list[Task] = []
        if self.extrapolate and not self.from_volume:
            ys = range(0, self.h, BORDER_ROW_STEP)
            half = (len(ys) + 1) // 2
            tasks += [Task(self._sample(part, rows))
                      for part, rows in enumerate((ys[:half], ys[half:]))]
            tasks.append(Task(lambda worker: self._border(), [0, 1]))
        border = [len(tasks) - 1] if tasks else []
        bands = len(self.buf['bands'])
        if self.buf['whole']:
            # costs from both ends inwards, the two chains meeting in the middle
            cost = [len(tasks) + k for k in range(bands)]
            tasks += [Task(self._cost(k), border, 2 * min(k, bands - 1 - k))
                      for k in range(bands)]
            if self.from_volume:  # every band's costs, then the statistic and the fill
                tasks.append(Task(lambda worker: self._border_from_volume(), cost))
                cost = [len(tasks) - 1] * bands
            down = [len(tasks) + k for k in range(bands)]
            tasks += [Task(self._sweep(k, upward=False), [cost[k], *down[k - 1:k]], 2 * k + 1)
                      for k in range(bands)]
            up = [len(tasks) + bands - 1 - k for k in range(bands)]  # added bottom first
            tasks += [Task(self._sweep(k, upward=True), [cost[k], *up[k + 1:k + 2]],
                           2 * (bands - 1 - k) + 1) for k in reversed(range(bands))]
            tasks += [Task(self._select(k), [down[k], up[k]], 2 * bands + k)
                      for k in range(bands)]
            return tasks
        # per band its costs, its downward sweep (the chain) and its selection; the costs
        # are a task of their own, so that a free thread makes the next bands' costs
        # while the chain sweeps (into a slot whose last selection is done): the chain is
        # then the sweeps alone
        first_band = len(tasks)
        slots = len(self.buf['cost'])
        for k in range(bands):
            cost_k = first_band + 3 * k
            after = list(border)
            if k >= slots:
                after.append(cost_k - 3 * slots + 2)  # the selection that last used the slot
            tasks.append(Task(self._band_cost(k), after, priority=1))
            tasks.append(Task(self._down(k), [cost_k, *([cost_k - 2] if k else [])],
                              priority=0))
            tasks.append(Task(self._select(k), [cost_k + 1], priority=2))
        return tasks

    def _border(self) -> None:
        """Set :attr:`border_cost` from the sampled rows."""
        self.border_cost = _border_cost(self.p, sum(self.samples), self.h, self.w)

    def _cost(self, k: int) -> Any:
        """Whole volumes: the cost of band k (a slice of the frame's volume)."""
        def run(worker: int) -> None:
            band = self.buf['bands'][k]
            cost = self.inputs.rows(band.y0, self.buf['cost'][0][band.y0:band.y0 + band.rows])
            if self.extrapolate and not self.from_volume:
                fill_outside(cost, self.p.min_disparity, self.border_cost)
        return run

    def _border_from_volume(self) -> None:
        """:meth:`_border` from the stored volume's rows, then its out-of-image cells."""
        volume = self.buf['cost'][0]
        x_lo, x_hi = _full_range_columns(self.w, self.p.disparity_range, self.p.min_disparity)
        total = float(_best_cost_sum(volume, x_lo, x_hi, BORDER_ROW_STEP))
        self.border_cost = _border_cost(self.p, total, self.h, self.w)
        fill_outside(volume, self.p.min_disparity, self.border_cost)

    def _sweep(self, k: int, *, upward: bool) -> Any:
        """Whole volumes: one chain's paths through band k, into the frame's partial sum
        (the chain that comes second adds to the first one's; never both at once)."""
        def run(worker: int) -> None:
            p, b = self.p, self.buf
            band = b['bands'][k]
            rows = slice(band.y0, band.y0 + band.rows)
            (lb0, lb1, lb2), mbuf = b['up' if upward else 'down']
            with self.band_locks[k]:
                sweep_down(b['cost'][0][rows], self.image, band.y0, band.rows, b['dxs'],
                           b['dys'], int(p.P1), int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                           b['partial'][0][rows], upward, self.swept[k])
                self.swept[k] = True
        return run

    def _sample(self, part: int, ys: range) -> Any:
        def run(worker: int) -> None:
            self.samples[part] = sampled_best_cost_sum(self.inputs, ys,
                                                       self.buf['workers'][worker]['sample'])
        return run

    def _band_cost(self, k: int) -> Any:
        """Bands in flight: the costs of band k, into its slot."""
        def run(worker: int) -> None:
            b = self.buf
            band = b['bands'][k]
            cost = self.inputs.rows(band.y0, b['cost'][k % len(b['cost'])][:band.rows])
            if self.extrapolate:
                fill_outside(cost, self.p.min_disparity, self.border_cost)
        return run

    def _down(self, k: int) -> Any:
        """Bands in flight: the downward sweep of band k, continuing band k - 1's paths."""
        def run(worker: int) -> None:
            p, b = self.p, self.buf
            band = b['bands'][k]
            slot = k % len(b['cost'])
            cost = b['cost'][slot][:band.rows]
            (lb0, lb1, lb2), mbuf = b['down']
            sweep_down(cost, self.image, band.y0, band.rows, b['dxs'], b['dys'], int(p.P1),
                       int(p.P2), self.table, lb0, lb1, lb2, mbuf, b['partial'][slot])
        return run

    def _select(self, k: int) -> Any:
        def run(worker: int) -> None:
            p, b = self.p, self.buf
            band = b['bands'][k]
            if b['whole']:  # both vertical sums are in the partial: horizontals and select
                rows = slice(band.y0, band.y0 + band.rows)
                cost, partial, upward = b['cost'][0][rows], b['partial'][0][rows], False
            else:
                slot = k % len(b['cost'])
                cost, partial = b['cost'][slot][:band.rows], b['partial'][slot]
                upward = p.paths not in SINGLE_PASS
            scratch = b['workers'][worker]
            (lb0, lb1, lb2), mbuf = scratch['rings']

            def select(cost: Any, y0: int, rows: int, ring0: int) -> None:
                band_select(cost, self.image, partial, y0, rows, b['dxs'], b['dys'],
                            int(p.P1), int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                            int(p.min_disparity), float(p.uniqueness_ratio),
                            SUBPIXEL_MODES[p.subpixel], scratch['total'], scratch['ltr'],
                            scratch['rtl'], scratch['keys'], b['disparity'],
                            b['disparity_right'], b['ratio'], self.total, self.keep_total,
                            upward, self.extrapolate, ring0, scratch['hlines'])

            swept = 0
            if upward and band.reach > band.rows:  # the rows below, a few at a time,
                # bottom up: their paths only
                below = scratch['below']
                for end in range(band.y0 + band.reach, band.y0 + band.rows, -len(below)):
                    start = max(band.y0 + band.rows, end - len(below))
                    part = self.inputs.rows(start, below[:end - start])
                    if self.extrapolate:
                        fill_outside(part, p.min_disparity, self.border_cost)
                    select(part, start, 0, swept)
                    swept += end - start
            select(cost, band.y0, band.rows, swept)
        return run


class _RangedFrame:
    """One coarse-to-fine match as tasks (``ranged.py``): the whole-volume order of
    :class:`_Frame` on the windows' flat volumes. Per band its costs; once every band's
    are there, the border statistic (its rows' minima over the windows) and the
    out-of-image cells; then the downward chain from the top and the upward one from the
    bottom (none with a single-pass path count), and each band's selection once both
    have passed it."""

    def __init__(self, matcher: SgmMatcher, params: SgmParams, buffers: dict[str, Any],
                 inputs: CostInputs, image: F32, lo: NDArray[np.int32],
                 wid: NDArray[np.int32], base: NDArray[np.int64]) -> None:
        self.p = params
        self.buf = buffers
        self.inputs = inputs
        self.image = image
        self.lo, self.wid, self.base = lo, wid, base
        self.table = matcher._table
        self.extrapolate = params.border_cost > 0
        self.border_cost = 0
        self.h, self.w = image.shape
        bands = len(buffers['bands'])
        self.band_locks = [threading.Lock() for _ in range(bands)]
        self.swept = [False] * bands

    def tasks(self) -> list[Task]:
        """The frame's tasks, dependencies first."""
        bands = len(self.buf['bands'])
        tasks = [Task(self._cost(k), (), 2 * min(k, bands - 1 - k)) for k in range(bands)]
        cost = list(range(bands))
        if self.extrapolate:
            tasks.append(Task(lambda worker: self._border(), cost))
            cost = [bands] * bands
        down = [len(tasks) + k for k in range(bands)]
        tasks += [Task(self._sweep(k, upward=False), [cost[k], *down[k - 1:k]], 2 * k + 1)
                  for k in range(bands)]
        up: list[int] = []
        if self.p.paths not in SINGLE_PASS:
            up = [len(tasks) + bands - 1 - k for k in range(bands)]  # added bottom first
            tasks += [Task(self._sweep(k, upward=True), [cost[k], *up[k + 1:k + 2]],
                           2 * (bands - 1 - k) + 1) for k in reversed(range(bands))]
        tasks += [Task(self._select(k), [down[k], *up[k:k + 1]], 2 * bands + k)
                  for k in range(bands)]
        return tasks

    def _cost(self, k: int) -> Any:
        def run(worker: int) -> None:
            band = self.buf['bands'][k]
            ranged.ranged_costs(self.inputs, band.y0, band.rows, self.lo, self.wid,
                                self.base, self.buf['cost'])
        return run

    def _border(self) -> None:
        """:class:`_Frame`'s border statistic from the windows' costs, then the
        out-of-image cells of every window set to it."""
        p = self.p
        n, h, w = p.disparity_range, self.h, self.w
        x_lo, x_hi = _full_range_columns(w, n, p.min_disparity)
        total = ranged.ranged_best_cost_sum(self.buf['cost'], self.lo, self.wid, self.base,
                                            x_lo, x_hi, BORDER_ROW_STEP)
        self.border_cost = _border_cost(p, total, h, w)
        ranged.ranged_fill_outside(self.buf['cost'], self.lo, self.wid, self.base, 0, h,
                                   p.min_disparity, n, self.border_cost)

    def _sweep(self, k: int, *, upward: bool) -> Any:
        def run(worker: int) -> None:
            p, b = self.p, self.buf
            band = b['bands'][k]
            (lb0, lb1, lb2), mbuf = b['up' if upward else 'down']
            with self.band_locks[k]:
                ranged.ranged_sweep(b['cost'], self.base, self.lo, self.wid, self.image,
                                    band.y0, band.rows, b['dxs'], b['dys'], int(p.P1),
                                    int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                                    b['partial'], upward, self.swept[k])
                self.swept[k] = True
        return run

    def _select(self, k: int) -> Any:
        def run(worker: int) -> None:
            p, b = self.p, self.buf
            band = b['bands'][k]
            s = b['workers'][worker]
            ranged.ranged_select(b['cost'], self.base, self.lo, self.wid, self.image,
                                 b['partial'], band.y0, band.rows, int(p.P1), int(p.P2),
                                 self.table, int(p.disparity_range), int(p.min_disparity),
                                 float(p.uniqueness_ratio), SUBPIXEL_MODES[p.subpixel],
                                 s['total'], s['ltr'], s['rtl'], s['lines'], s['keys'],
                                 b['disparity'], b['disparity_right'], b['ratio'],
                                 self.extrapolate)
        return run
