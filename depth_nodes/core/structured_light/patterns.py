"""Projector pattern sets and their frame layouts.

A pattern set is an ordered list of frames; each frame has a role (:class:`Frame`). The
layouts (``W_p``, ``H_p``: projector width and height in pixels):

* ``gray``: white, black, then for each decoded axis (columns, then rows when ``axes`` is
  ``both``) ``ceil(log2(size))`` reflected-Gray-code bit planes, most significant first,
  each followed by its inverse.
* ``phase``: the ``gray`` layout, then per axis ``steps`` sinusoidal frames
  ``0.5 + 0.5 cos(2 pi u / period - 2 pi k / steps)``, ``k = 0 .. steps - 1``. The full-
  resolution Gray code gives the period order with a tolerance of half a period.
* ``opencv``: exactly what ``cv2.structured_light.GrayCodePattern.create(W_p, H_p)``
  generates (column bit planes MSB first, each followed by its inverse, then the row bit
  planes likewise), followed by the black and then the white image of its
  ``getImagesForShadowMasks``. OpenCV always codes both axes.
* ``speckle``: one frame, a fixed pseudo-random dot pattern.

Projector pixel ``j`` (column) covers ``u`` in ``[j - 0.5, j + 0.5]``: pixel centres are at
integer coordinates, as for camera images in ROS and OpenCV.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ConfigError

MODES = ('gray', 'phase', 'opencv', 'speckle')
AXES = ('columns', 'both')

WHITE, BLACK, GRAY, GRAY_INVERSE, PHASE, SPECKLE = (
    'white', 'black', 'gray', 'gray_inverse', 'phase', 'speckle')


@dataclass(frozen=True)
class Frame:
    """Role of one frame of a pattern set.

    Attributes:
        kind: ``white``, ``black``, ``gray``, ``gray_inverse``, ``phase`` or ``speckle``.
        axis: 0 for columns (varies along projector x), 1 for rows; -1 when not coded.
        index: Gray bit (0 = most significant) or phase step ``k``; 0 otherwise.
    """

    kind: str
    axis: int = -1
    index: int = 0


@dataclass(frozen=True)
class PatternSet:
    """A pattern set: mode, projector size, axes and phase parameters.

    Attributes:
        mode: One of :data:`MODES`.
        width: Projector width in pixels.
        height: Projector height in pixels.
        axes: ``columns`` or ``both`` (``opencv`` always codes both).
        steps: Phase steps N (>= 3), phase mode only.
        period: Phase period in projector pixels (>= 2), phase mode only.
    """

    mode: str
    width: int
    height: int
    axes: str = 'columns'
    steps: int = 4
    period: float = 16.0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f'pattern mode must be one of {", ".join(MODES)}, got {self.mode!r}')
        if self.axes not in AXES:
            raise ConfigError(f'axes must be one of {", ".join(AXES)}, got {self.axes!r}')
        if self.width < 2 or self.height < 2:
            raise ConfigError(f'projector size must be at least 2x2, got '
                              f'{self.width}x{self.height}')
        if self.mode == 'phase':
            if self.steps < 3:
                raise ConfigError(f'phase steps must be >= 3, got {self.steps}')
            if not 2.0 <= self.period <= max(self.width, self.height):
                raise ConfigError(f'phase period must be in [2, projector size], got {self.period}')

    @property
    def coded_axes(self) -> tuple[int, ...]:
        """0 (columns) and, when rows are coded too, 1."""
        return (0, 1) if self.axes == 'both' or self.mode == 'opencv' else (0,)

    def bits(self, axis: int) -> int:
        """Number of Gray bits of ``axis``: ``ceil(log2(size))``."""
        return max(1, math.ceil(math.log2(self.width if axis == 0 else self.height)))

    @property
    def frames(self) -> list[Frame]:
        """The layout: the role of every frame, in projection order."""
        if self.mode == 'speckle':
            return [Frame(SPECKLE)]
        gray: list[Frame] = []
        for axis in self.coded_axes:
            for b in range(self.bits(axis)):
                gray += [Frame(GRAY, axis, b), Frame(GRAY_INVERSE, axis, b)]
        if self.mode == 'opencv':
            return [*gray, Frame(BLACK), Frame(WHITE)]
        out = [Frame(WHITE), Frame(BLACK), *gray]
        if self.mode == 'phase':
            for axis in self.coded_axes:
                out += [Frame(PHASE, axis, k) for k in range(self.steps)]
        return out

    @property
    def count(self) -> int:
        """Number of frames in one sequence."""
        return len(self.frames)


def gray_code(values: NDArray[np.integer]) -> NDArray[np.int64]:
    """Reflected binary Gray code of non-negative integers."""
    v = np.asarray(values, dtype=np.int64)
    return v ^ (v >> 1)


def gray_to_binary(codes: NDArray[np.integer], bits: int) -> NDArray[np.int64]:
    """Inverse of :func:`gray_code` for codes of ``bits`` bits."""
    out = np.asarray(codes, dtype=np.int64).copy()
    shift = 1
    while shift < bits:
        out ^= out >> shift
        shift <<= 1
    return out


def speckle_pattern(width: int, height: int, *, seed: int = 0,
                    density: float = 0.12) -> NDArray[np.float32]:
    """A pseudo-random binary dot pattern (fraction ``density`` of pixels lit)."""
    rng = np.random.default_rng([seed, 991])
    return (rng.random((height, width)) < density).astype(np.float32)


def generate_patterns(pattern_set: PatternSet, *, speckle_seed: int = 0) -> NDArray[np.float32]:
    """The projector images of ``pattern_set``.

    Returns:
        (F, H_p, W_p) float32 in [0, 1], in the order of :attr:`PatternSet.frames`. The
        ``opencv`` set equals OpenCV's ``generate()`` images / 255 followed by black, white.
    """
    w, h = pattern_set.width, pattern_set.height
    coords = (np.arange(w, dtype=np.float64)[None, :], np.arange(h, dtype=np.float64)[:, None])
    out = np.empty((pattern_set.count, h, w), dtype=np.float32)
    for i, frame in enumerate(pattern_set.frames):
        if frame.kind in (WHITE, BLACK):
            out[i] = 1.0 if frame.kind == WHITE else 0.0
        elif frame.kind == SPECKLE:
            out[i] = speckle_pattern(w, h, seed=speckle_seed)
        elif frame.kind in (GRAY, GRAY_INVERSE):
            bits = pattern_set.bits(frame.axis)
            code = gray_code(coords[frame.axis].astype(np.int64))
            bit = (code >> (bits - 1 - frame.index)) & 1
            if frame.kind == GRAY_INVERSE:
                bit = 1 - bit
            out[i] = np.broadcast_to(bit, (h, w))
        else:
            u = coords[frame.axis]
            phase = 2 * np.pi * u / pattern_set.period - 2 * np.pi * frame.index / pattern_set.steps
            out[i] = np.broadcast_to(0.5 + 0.5 * np.cos(phase), (h, w))
    return out
