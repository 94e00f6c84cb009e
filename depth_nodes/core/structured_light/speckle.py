"""Single-shot speckle depth (Kinect-style): census matching against a reference image.

The reference is the camera's image of the dot pattern on a fronto-parallel plane at a
known depth ``Z_ref``. With the projector displaced by ``b`` metres along the camera's x
axis (no rotation), a dot seen at column ``x_ref`` in the reference appears at
``x = x_ref + s`` with ``s = f b (1 / Z - 1 / Z_ref)`` (``f``: camera focal length in
pixels), so ``Z = 1 / (1 / Z_ref + s / (f b))``. A reference may be wider than the
camera's images: its extra columns, as many on the left as on the right, hold the pattern
beyond the camera's view at ``Z_ref``, so that near and far surfaces at the image's sides,
whose dots came from there, still find them.

Matching (numba, :func:`match_speckle`): the census signature of a 7 x 9 window (62 bits,
one per neighbour darker than the centre) of every pixel of both images; per pixel and
shift the Hamming distance between the image's signature and the reference's, summed over
a ``window`` x ``window`` box. The lowest sum wins, refined to sub-pixel by a parabola
through its neighbours, and is kept only when

* its score ``1 - 2 sum / bits`` (1: identical, about 0 for unrelated patterns) is at
  least ``min_score``;
* it beats the best shift more than one pixel away by ``uniqueness`` of that one's sum
  (a repeated or featureless neighbourhood has two);
* matching the other way agrees to a pixel: among the image pixels that could show this
  reference pixel, the winner is this shift (an occluded or shadowed pixel has no
  partner, and a spurious best rarely wins both ways);
* it is not an end of the shift range.

Shadows carry no dots, so their census is the scene's own texture and matches nothing
consistently. The plain definition the tests compare the kernel against is
``match_speckle_reference`` in ``test/reference/structured_light.py``.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.sgm.census import census_transform, popcount
from depth_nodes.errors import ConfigError, InputFileError

F32 = NDArray[np.float32]
#: The census window of speckle matching (rows, columns): 62 bits.
CENSUS_WINDOW = (7, 9)
#: Cost of a shift whose reference column lies outside the reference (more than any
#: census distance).
OUTSIDE = 64
#: Rows of a band of the matcher (each thread takes bands; the box's rows around a band
#: are costed twice).
BAND_ROWS = 60


def shift_range(focal: float, baseline: float, reference_depth: float, depth_min: float,
                depth_max: float) -> tuple[int, int]:
    """Integer shifts (inclusive, one pixel of margin) of depths in [depth_min, depth_max]."""
    if not 0 < depth_min < depth_max or reference_depth <= 0 or focal <= 0 or baseline == 0:
        raise ConfigError(f'speckle geometry needs 0 < depth_min < depth_max, reference depth '
                          f'> 0, focal > 0 and a nonzero baseline; got depth {depth_min}..'
                          f'{depth_max}, reference {reference_depth}, focal {focal}, '
                          f'baseline {baseline}')
    ends = [focal * baseline * (1 / z - 1 / reference_depth) for z in (depth_min, depth_max)]
    return math.floor(min(ends)) - 1, math.ceil(max(ends)) + 1


def shift_to_depth(shift: F32, focal: float, baseline: float, reference_depth: float) -> F32:
    """Depth of row shifts ``s = x - x_ref``; NaN where the shift is NaN or Z <= 0."""
    inv = 1.0 / reference_depth + shift.astype(np.float64) / (focal * baseline)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(inv > 0, 1.0 / inv, np.nan).astype(np.float32)


def _check_pair(image: NDArray[np.generic], reference: NDArray[np.generic], window: int) -> int:
    """The reference's margin (extra columns on each side); raises on shapes that do not
    fit."""
    if np.ndim(image) != 2 or np.ndim(reference) != 2:
        raise ConfigError(f'image and reference must be 2-D, got {np.shape(image)} and '
                          f'{np.shape(reference)}')
    (h, w), (hr, wr) = np.shape(image), np.shape(reference)
    if hr != h or wr < w or (wr - w) % 2:
        raise ConfigError(f'the reference must have the image\'s {h} rows and its {w} columns '
                          f'plus as many extra on each side, got {wr}x{hr} for {w}x{h}')
    if window < 3 or window % 2 == 0:
        raise ConfigError(f'window must be odd and >= 3, got {window}')
    return int((wr - w) // 2)


@numba.njit(cache=True, nogil=True)
def _box_along_x(cost: NDArray[np.uint16], r: int, total: NDArray[np.uint16],
                 triple: NDArray[np.uint16]) -> None:
    """``total[x]`` = the sum of ``cost`` over x - r .. x + r (edges replicated). A side of
    3 m is summed as m sums of 3 (m + 2 adds instead of 3 m - 1)."""
    w = cost.shape[0]
    n = 2 * r + 1
    if n % 3 == 0 and w > n:
        # triple[x] = cost[x - 1] + cost[x] + cost[x + 1] (clamped), then every third one
        triple[0] = cost[0] + cost[0] + cost[1]
        triple[w - 1] = cost[w - 2] + cost[w - 1] + cost[w - 1]
        mid, left, right = triple[1:w - 1], cost[:w - 2], cost[2:]
        centre = cost[1:w - 1]
        for i in range(w - 2):
            mid[i] = left[i] + centre[i] + right[i]
        total[:] = 0
        for j in range(-(n // 3 // 2), n // 3 // 2 + 1):
            t = 3 * j
            lo, hi = max(0, -t), min(w, w - t)
            part, shifted = total[lo:hi], triple[lo + t:hi + t]
            for i in range(hi - lo):
                part[i] += shifted[i]
            # a triple beyond the edge is the edge cost, three times (replicated)
            for x in range(lo):
                total[x] += 3 * cost[0]
            for x in range(hi, w):
                total[x] += 3 * cost[w - 1]
        return
    total[:] = 0
    for t in range(-r, r + 1):
        lo, hi = max(0, -t), min(w, w - t)
        part, shifted = total[lo:hi], cost[lo + t:hi + t]
        for i in range(hi - lo):
            part[i] += shifted[i]
        for x in range(lo):
            total[x] += cost[0]
        for x in range(hi, w):
            total[x] += cost[w - 1]


@numba.njit(cache=True, nogil=True)
def _box_row(ci: NDArray[np.uint64], cr: NDArray[np.uint64], y: int, margin: int, smin: int,
             r: int, costs: NDArray[np.uint16], out: NDArray[np.uint16],
             triple: NDArray[np.uint16]) -> None:
    """Row ``y``'s Hamming distances summed over 2r + 1 columns (edges replicated), shift
    by shift: ``out[k, x]``. Every inner loop runs along a row view indexed by the loop
    counter alone, so it vectorises."""
    w = ci.shape[1]
    wr = cr.shape[1]
    shifts = costs.shape[0]
    image_row, reference_row = ci[y], cr[y]
    for k in range(shifts):
        offset = margin - smin - k  # the reference column of x is x + offset
        x_lo, x_hi = min(max(0, -offset), w), max(min(w, wr - offset), 0)
        cost = costs[k]
        cost[:x_lo] = OUTSIDE
        cost[max(x_hi, x_lo):] = OUTSIDE
        if x_hi > x_lo:
            dst = cost[x_lo:x_hi]
            src = image_row[x_lo:x_hi]
            ref = reference_row[x_lo + offset:x_hi + offset]
            for i in range(x_hi - x_lo):
                dst[i] = popcount(src[i] ^ ref[i])
        _box_along_x(cost, r, out[k], triple[k])


@numba.njit(cache=True, nogil=True)
def _add_rows(column: NDArray[np.uint16], new: NDArray[np.uint16], old: NDArray[np.uint16]
              ) -> None:
    """``column += new - old``, row view by row view."""
    for k in range(column.shape[0]):
        dst, plus, minus = column[k], new[k], old[k]
        for x in range(dst.shape[0]):
            dst[x] += plus[x] - minus[x]


@numba.njit(cache=True, nogil=True, parallel=True)
def _match_kernel(ci: NDArray[np.uint64], cr: NDArray[np.uint64], margin: int, smin: int,
                  shifts: int, r: int, bits: int, min_score: float, uniqueness: float,
                  shift_out: F32, score_out: F32) -> None:
    h, w = ci.shape
    wr = cr.shape[1]
    rows = 2 * r + 1
    n_bands = (h + BAND_ROWS - 1) // BAND_ROWS
    big = np.uint16(65535)
    for band in numba.prange(n_bands):
        y0 = band * BAND_ROWS
        y1 = min(y0 + BAND_ROWS, h)
        costs = np.empty((shifts, w), np.uint16)
        triple = np.empty((shifts, w), np.uint16)
        # the box's rows, top to bottom, in buffers order[0 .. rows - 1]; one more spare
        ring = np.zeros((rows + 1, shifts, w), np.uint16)
        order = np.arange(rows)
        spare = rows
        column = np.zeros((shifts, w), np.uint16)  # their sum
        best = np.empty(w, np.uint16)
        best_k = np.empty(w, np.int32)
        second = np.empty(w, np.uint16)
        ref_min = np.empty(wr, np.uint16)
        ref_k = np.empty(wr, np.int32)
        for i in range(rows):  # rows y0 - r .. y0 + r; the spare buffer holds zeros
            t = y0 - r + i
            _box_row(ci, cr, min(max(t, 0), h - 1), margin, smin, r, costs, ring[i], triple)
            _add_rows(column, ring[i], ring[rows])
        for y in range(y0, y1):
            best[:] = big
            ref_min[:] = big
            for k in range(shifts):
                sums = column[k]
                for x in range(w):
                    c = sums[x]
                    better = c < best[x]
                    best[x] = c if better else best[x]
                    best_k[x] = k if better else best_k[x]
                # the reference side: reference column x + offset, its lowest sum
                offset = margin - smin - k
                x_lo, x_hi = max(0, -offset), min(w, wr - offset)
                if x_hi > x_lo:
                    part = sums[x_lo:x_hi]
                    low = ref_min[x_lo + offset:x_hi + offset]
                    arg = ref_k[x_lo + offset:x_hi + offset]
                    for i in range(x_hi - x_lo):
                        better = part[i] < low[i]
                        low[i] = part[i] if better else low[i]
                        arg[i] = k if better else arg[i]
            second[:] = big
            for k in range(shifts):
                sums = column[k]
                for x in range(w):
                    far = abs(k - best_k[x]) > 1
                    second[x] = min(second[x], sums[x]) if far else second[x]
            for x in range(w):
                kb = best_k[x]
                cb = np.int32(best[x])
                shift_out[y, x] = np.nan
                score = 1.0 - 2.0 * cb / bits
                score_out[y, x] = score
                if kb == 0 or kb == shifts - 1 or score < min_score:
                    continue
                xr = x - (smin + kb) + margin
                if not 0 <= xr < wr or abs(ref_k[xr] - kb) > 1:
                    continue
                if np.int32(second[x]) - cb < uniqueness * second[x]:
                    continue
                left, right = np.int32(column[kb - 1, x]), np.int32(column[kb + 1, x])
                curve = left - 2 * cb + right
                delta = 0.5 * (left - right) / curve if curve > 0 else 0.0
                shift_out[y, x] = smin + kb + min(max(delta, -0.5), 0.5)
            # slide the box down a row: row y + r + 1 into the spare buffer, row y - r out
            if y + 1 < y1:
                _box_row(ci, cr, min(y + r + 1, h - 1), margin, smin, r, costs, ring[spare],
                         triple)
                leaving = order[0]
                _add_rows(column, ring[spare], ring[leaving])
                order[:-1] = order[1:].copy()
                order[rows - 1] = spare
                spare = leaving


class SpeckleMatcher:
    """:func:`match_speckle` with the reference's census kept between frames."""

    def __init__(self) -> None:
        self._reference: NDArray[np.generic] | None = None
        self._census: NDArray[np.uint64] | None = None
        self._buffer: NDArray[np.uint64] | None = None  # the image's census, reused

    def _image_census(self, shape: tuple[int, ...]) -> NDArray[np.uint64]:
        if self._buffer is None or self._buffer.shape != shape:
            self._buffer = np.empty(shape, np.uint64)
        return self._buffer

    def reference_census(self, reference: NDArray[np.generic]) -> NDArray[np.uint64]:
        """The census of ``reference``, computed again only for another array."""
        if self._census is None or reference is not self._reference:
            self._census = census_transform(reference, CENSUS_WINDOW,
                                            np.empty(np.shape(reference), np.uint64))
            self._reference = reference
        return self._census

    def match(self, image: NDArray[np.generic], reference: NDArray[np.generic], *,
              shift_min: int, shift_max: int, window: int = 9, min_score: float = 0.42,
              uniqueness: float = 0.05) -> tuple[F32, F32]:
        """See :func:`match_speckle`."""
        margin = _check_pair(image, reference, window)
        if shift_max - shift_min < 2:
            raise ConfigError(f'the shift range {shift_min}..{shift_max} needs at least 3 '
                              'shifts')
        ci = census_transform(image, CENSUS_WINDOW, self._image_census(image.shape))
        cr = self.reference_census(reference)
        h, w = ci.shape
        shift = np.empty((h, w), np.float32)
        score = np.empty((h, w), np.float32)
        bits = window * window * (CENSUS_WINDOW[0] * CENSUS_WINDOW[1] - 1)
        _match_kernel(ci, cr, margin, int(shift_min), int(shift_max - shift_min + 1),
                      window // 2, bits, float(min_score), float(uniqueness), shift, score)
        return shift, score


def match_speckle(image: NDArray[np.generic], reference: NDArray[np.generic], *,
                  shift_min: int, shift_max: int, window: int = 9, min_score: float = 0.42,
                  uniqueness: float = 0.05) -> tuple[F32, F32]:
    """Best sub-pixel row shift ``x - x_ref`` of every pixel (see the module notes).

    Args:
        image: (H, W) grey image.
        reference: (H, W + 2 m) grey reference image (``m`` extra columns each side).
        shift_min: Smallest shift searched (pixels).
        shift_max: Largest shift searched (pixels).
        window: Odd side of the box the census distances are summed over.
        min_score: Smallest score ``1 - 2 sum / bits`` kept.
        uniqueness: How much lower, as a fraction of it, the winner's sum must be than
            the best one more than a pixel away.

    Returns:
        (shift, score): (H, W) float32 shift (NaN where rejected) and the winner's score.

    Raises:
        ConfigError: Shapes that do not fit, an even or too small window, fewer than three
            shifts.
    """
    return SpeckleMatcher().match(image, reference, shift_min=shift_min, shift_max=shift_max,
                                  window=window, min_score=min_score, uniqueness=uniqueness)


def speckle_depth(image: NDArray[np.generic], reference: NDArray[np.generic], *,
                  focal: float, baseline: float, reference_depth: float,
                  depth_min: float = 0.3, depth_max: float = 5.0, window: int = 9,
                  min_score: float = 0.42, uniqueness: float = 0.05,
                  matcher: SpeckleMatcher | None = None) -> tuple[F32, F32]:
    """Depth of a speckle image against its reference.

    Args:
        image: (H, W) grey camera image of the dot pattern.
        reference: (H, W + 2 m) grey image of the pattern on a plane at
            ``reference_depth`` (``m`` extra columns on each side, possibly 0).
        focal: Camera focal length fx in pixels.
        baseline: Projector x offset from the camera in metres (signed; projector centre
            at (baseline, 0, 0) in the camera frame).
        reference_depth: Depth of the reference plane, metres.
        depth_min: Nearest depth searched, metres.
        depth_max: Farthest depth searched, metres.
        window: Odd side of the box the census distances are summed over.
        min_score: See :func:`match_speckle`.
        uniqueness: See :func:`match_speckle`.
        matcher: A :class:`SpeckleMatcher` to reuse (it keeps the reference's census).

    Returns:
        (depth, confidence): (H, W) float32 metres (NaN unknown) and the match score
        clipped to [0, 1] (0 where there is no depth).
    """
    lo, hi = shift_range(focal, baseline, reference_depth, depth_min, depth_max)
    shift, score = (matcher or SpeckleMatcher()).match(
        image, reference, shift_min=lo, shift_max=hi, window=window, min_score=min_score,
        uniqueness=uniqueness)
    depth = np.empty_like(shift)
    confidence = np.empty_like(shift)
    _depth_kernel(shift, score, focal * baseline, 1.0 / reference_depth, depth_min, depth_max,
                  depth, confidence)
    return depth, confidence


@numba.njit(cache=True, nogil=True, parallel=True)
def _depth_kernel(shift: F32, score: F32, fb: float, inv_ref: float, depth_min: float,
                  depth_max: float, depth: F32, confidence: F32) -> None:
    """Depth of each shift (:func:`shift_to_depth`), NaN outside [depth_min, depth_max],
    and the score clipped to [0, 1] as the confidence (0 without a depth)."""
    h, w = shift.shape
    for y in numba.prange(h):
        for x in range(w):
            inv = inv_ref + shift[y, x] / fb  # NaN stays NaN
            z = 1.0 / inv if inv > 0.0 else np.nan
            if not (depth_min <= z <= depth_max):
                depth[y, x] = np.nan
                confidence[y, x] = 0.0
                continue
            depth[y, x] = z
            confidence[y, x] = min(max(score[y, x], 0.0), 1.0)


class SpeckleReference:
    """The speckle reference image of a file, read again only when the file changes."""

    def __init__(self) -> None:
        self._key: tuple[str, int] | None = None
        self._image: F32 = np.zeros((0, 0), np.float32)

    def load(self, path: str, shape: tuple[int, ...]) -> F32:
        """The reference at ``path`` as float32, checked against the images' ``shape``.

        Raises:
            InputFileError: No path, a file that cannot be read or is not one-channel, or
                a size other than the images'.
        """
        if not path:
            raise InputFileError('speckle mode needs the speckle_reference parameter: an '
                                 'image file of the pattern on the reference plane')
        file = Path(path)
        try:
            key = (path, file.stat().st_mtime_ns)
        except OSError as exc:
            raise InputFileError(f'cannot read speckle_reference {path!r}: '
                                 f'{exc.strerror}') from None
        if key != self._key:
            image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
            if image is None or image.ndim != 2:
                raise InputFileError(f'speckle_reference {path!r} is not a one-channel image '
                                     'file OpenCV can read')
            self._image = image.astype(np.float32)
            self._key = key
        rh, rw = self._image.shape
        if rh != shape[0] or rw < shape[1] or (rw - shape[1]) % 2:
            raise InputFileError(f'speckle_reference {path!r} is {rw}x{rh}; images are '
                                 f'{shape[1]}x{shape[0]}: it needs their rows and their '
                                 'columns plus as many extra on each side')
        return self._image
