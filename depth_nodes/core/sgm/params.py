"""The census SGM matcher's settings: :class:`SgmParams`, its limits and its validation.

Each field is declared once with :func:`~depth_nodes.core.settings.setting` (default,
description, range): the sgm_stereo node declares its parameters from them, so a rule
broken gives the same reason in the core and in the node.
"""

from __future__ import annotations

from dataclasses import dataclass

from depth_nodes.core.cross_check import SPECKLE_SIZE
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.core.sgm.aggregate import VERTICAL_DIRECTIONS
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST
from depth_nodes.core.sgm.select import SUBPIXEL_MODES
from depth_nodes.errors import ArgumentError

#: disparity_search: every disparity, or windows from a half-resolution pass
#: (``coarse.py``, ``ranged.py``).
SEARCH_MODES = ('full', 'coarse')
#: matching_cost: census (+ intensity), the learned features' cost (``learned_cost.py``), or
#: their sum.
MATCHING_COSTS = ('census', 'learned', 'census+learned')
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
    matching_cost: str = setting('census', 'census (census + intensity, below), learned '
                                 "(1 - cosine of the shipped feature network's features) "
                                 'or census+learned (their sum)', choices=MATCHING_COSTS)
    learned_weight: int = setting(20, 'cost of two orthogonal learned feature vectors '
                                  '(matching_cost learned or census+learned)', low=1,
                                  high=127)
    learned_weights: str = setting('', "the learned cost's feature network: an .npz that "
                                   'depth-nodes train-cost wrote (an adaptation to your '
                                   'camera, --adapt); empty: the shipped weights')
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
        if self.matching_cost != 'census' and self.disparity_search == 'coarse':
            raise bad('disparity_search', f'coarse needs matching_cost census (not '
                      f'{self.matching_cost})')
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
