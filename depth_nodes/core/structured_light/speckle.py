"""Single-shot speckle depth (Kinect-style): match against a reference image, row by row.

The reference is the camera's image of the dot pattern on a fronto-parallel plane at a
known depth ``Z_ref``. With the projector displaced by ``b`` metres along the camera's x
axis (no rotation), a dot seen at column ``x_ref`` in the reference appears at
``x = x_ref + s`` with ``s = f b (1 / Z - 1 / Z_ref)`` (``f``: camera focal length in
pixels), so ``Z = 1 / (1 / Z_ref + s / (f b))``. ``s`` is found per pixel by zero-mean
normalised cross-correlation (ZNCC) of a square window along the same row of the
reference, over the shifts that the depth range allows, refined to sub-pixel by a
parabola through the best score and its two neighbours.

The ZNCC of every shift is computed with box filters (O(1) per pixel and shift, any
window), so no compiled kernel is needed; :func:`match_rows_reference` is the direct
per-pixel definition the tests compare against.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ConfigError, InputFileError

F32 = NDArray[np.float32]
#: Windows with a standard deviation below this (grey levels) have no usable texture.
MIN_STD = 1.0


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


def _check_pair(image: NDArray[np.generic], reference: NDArray[np.generic], window: int) -> None:
    if np.ndim(image) != 2 or np.shape(image) != np.shape(reference):
        raise ConfigError(f'image and reference must be 2-D of one size, got '
                          f'{np.shape(image)} and {np.shape(reference)}')
    if window < 3 or window % 2 == 0:
        raise ConfigError(f'window must be odd and >= 3, got {window}')


def match_rows(image: NDArray[np.generic], reference: NDArray[np.generic], *,
               shift_min: int, shift_max: int, window: int = 9,
               min_score: float = 0.5) -> tuple[F32, F32]:
    """Best sub-pixel row shift ``x - x_ref`` of every pixel, by ZNCC.

    Args:
        image: (H, W) grey image.
        reference: (H, W) grey reference image.
        shift_min: Smallest shift searched (pixels).
        shift_max: Largest shift searched (pixels).
        window: Odd side of the square correlation window.
        min_score: Pixels whose best ZNCC is below this are invalid.

    Returns:
        (shift, score): (H, W) float32 shift (NaN invalid, also where the best shift is an
        end of the range) and the best ZNCC score in [-1, 1] (NaN without texture).

    Raises:
        ConfigError: Sizes differ, an even or too small window, or an empty range.
    """
    _check_pair(image, reference, window)
    if shift_max < shift_min:
        raise ConfigError(f'empty shift range {shift_min}..{shift_max}')
    h, w = np.shape(image)
    r = window // 2
    # Reflect-padded copies: the windows of every pixel lie inside them, so box sums over
    # the central region equal the per-window sums of the reference definition exactly.
    img: F32 = np.pad(np.asarray(image, dtype=np.float32), r, mode='symmetric')
    ref: F32 = np.pad(np.asarray(reference, dtype=np.float32), r, mode='symmetric')
    ksize = (window, window)

    def box(a: F32) -> F32:
        out = cv2.boxFilter(a, cv2.CV_32F, ksize)[r:r + h, r:r + w]
        return np.asarray(out, dtype=np.float32)

    mean_i, mean_r = box(img), box(ref)
    var_i = np.maximum(box(img * img) - mean_i * mean_i, 0.0)
    var_r = np.maximum(box(ref * ref) - mean_r * mean_r, 0.0)
    best = np.full((h, w), -np.inf, dtype=np.float32)
    best_s = np.full((h, w), shift_min - 10, dtype=np.int32)
    left = np.full((h, w), -np.inf, dtype=np.float32)
    right = np.full((h, w), -np.inf, dtype=np.float32)
    prev = np.full((h, w), -np.inf, dtype=np.float32)
    score = np.empty((h, w), dtype=np.float32)
    product = np.zeros_like(img)
    wp = w + 2 * r
    for s in range(shift_min, shift_max + 1):
        score.fill(-np.inf)
        lo, hi = max(0, s), min(w, w + s)  # camera columns whose reference column exists
        if lo < hi:
            plo, phi = max(0, s), min(wp, wp + s)
            np.multiply(img[:, plo:phi], ref[:, plo - s:phi - s], out=product[:, plo:phi])
            cov = box(product)[:, lo:hi] - mean_i[:, lo:hi] * mean_r[:, lo - s:hi - s]
            den = np.sqrt(var_i[:, lo:hi] * var_r[:, lo - s:hi - s])
            with np.errstate(divide='ignore', invalid='ignore'):
                score[:, lo:hi] = np.where(den > MIN_STD**2, cov / den, -np.inf)
        np.copyto(right, score, where=best_s == s - 1)
        better = score > best
        np.copyto(best, score, where=better)
        np.copyto(best_s, s, where=better)
        np.copyto(left, prev, where=better)
        np.copyto(right, -np.inf, where=better)
        prev, score = score, prev
    return _refine(best, best_s, left, right, min_score)


def _refine(best: F32, best_s: NDArray[np.int32], left: F32, right: F32,
            min_score: float) -> tuple[F32, F32]:
    ok = np.isfinite(best) & np.isfinite(left) & np.isfinite(right) & (best >= min_score)
    with np.errstate(divide='ignore', invalid='ignore'):
        curv = left - 2 * best + right
        delta = np.clip(np.where(curv < 0, 0.5 * (left - right) / curv, 0.0), -0.5, 0.5)
    shift = np.where(ok, best_s + delta, np.nan).astype(np.float32)
    return shift, np.where(np.isfinite(best), best, np.nan).astype(np.float32)


def match_rows_reference(image: NDArray[np.generic], reference: NDArray[np.generic], *,
                         shift_min: int, shift_max: int, window: int = 9,
                         min_score: float = 0.5) -> tuple[F32, F32]:
    """Direct per-pixel ZNCC (slow; the definition :func:`match_rows` must reproduce).

    Same arguments and results as :func:`match_rows`; windows are read with reflected
    borders (OpenCV's BORDER_REFLECT), so the two agree everywhere.
    """
    _check_pair(image, reference, window)
    r = window // 2
    img = np.pad(np.asarray(image, dtype=np.float64), r, mode='symmetric')
    ref = np.pad(np.asarray(reference, dtype=np.float64), r, mode='symmetric')
    h, w = np.shape(image)
    n = shift_max - shift_min + 1
    scores = np.full((n, h, w), -np.inf)
    for y in range(h):
        for x in range(w):
            a = img[y:y + window, x:x + window].ravel()
            a = a - a.mean()
            for k, s in enumerate(range(shift_min, shift_max + 1)):
                if not 0 <= x - s < w:
                    continue
                b = ref[y:y + window, x - s:x - s + window].ravel()
                b = b - b.mean()
                den = math.sqrt(float(a @ a) * float(b @ b)) / window**2
                if den > MIN_STD**2:
                    scores[k, y, x] = float(a @ b) / window**2 / den
    k_best = np.argmax(scores, axis=0)
    best = np.take_along_axis(scores, k_best[None], 0)[0]
    pad = np.full((1, h, w), -np.inf)
    padded = np.concatenate([pad, scores, pad])
    left = np.take_along_axis(padded, k_best[None], 0)[0]
    right = np.take_along_axis(padded, k_best[None] + 2, 0)[0]
    return _refine(best.astype(np.float32), (k_best + shift_min).astype(np.int32),
                   left.astype(np.float32), right.astype(np.float32), min_score)


def speckle_depth(image: NDArray[np.generic], reference: NDArray[np.generic], *,
                  focal: float, baseline: float, reference_depth: float,
                  depth_min: float = 0.3, depth_max: float = 5.0, window: int = 9,
                  min_score: float = 0.5) -> tuple[F32, F32]:
    """Depth of a speckle image against its reference.

    Args:
        image: (H, W) grey camera image of the dot pattern.
        reference: (H, W) grey image of the pattern on a plane at ``reference_depth``.
        focal: Camera focal length fx in pixels.
        baseline: Projector x offset from the camera in metres (signed; projector centre
            at (baseline, 0, 0) in the camera frame).
        reference_depth: Depth of the reference plane, metres.
        depth_min: Nearest depth searched, metres.
        depth_max: Farthest depth searched, metres.
        window: Odd correlation window side.
        min_score: Minimum ZNCC.

    Returns:
        (depth, confidence): (H, W) float32 metres (NaN unknown) and the ZNCC score
        clipped to [0, 1] (0 where invalid).
    """
    lo, hi = shift_range(focal, baseline, reference_depth, depth_min, depth_max)
    shift, score = match_rows(image, reference, shift_min=lo, shift_max=hi, window=window,
                              min_score=min_score)
    depth = shift_to_depth(shift, focal, baseline, reference_depth)
    with np.errstate(invalid='ignore'):
        depth[(depth < depth_min) | (depth > depth_max)] = np.nan
    conf = np.where(np.isfinite(depth), np.clip(np.nan_to_num(score), 0, 1), 0)
    return depth, conf.astype(np.float32)


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
        if self._image.shape != shape:
            raise InputFileError(f'speckle_reference {path!r} is {self._image.shape[1]}x'
                                 f'{self._image.shape[0]}, images are {shape[1]}x{shape[0]}')
        return self._image
