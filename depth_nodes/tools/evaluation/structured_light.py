"""`depth-nodes eval` on a structured-light bag (or `eval-sl`): accuracy of the
structured-light decoder, beside OpenCV's GrayCodePattern (`bench structured_light`, in
tools/bench, times it).

For every sequence of a structured-light bag, each method decodes the same frames:

* ``gray``: this package, the white/black and Gray-code frames only (integer columns);
* ``phase``: this package, Gray code + N-step phase shifting (the whole sequence);
* ``opencv GrayCodePattern``: ``cv2.structured_light.GrayCodePattern.getProjPixel`` on the
  same Gray frames (its shadow mask ``white - black > blackThreshold`` with our
  ``shadow_threshold``, its default ``whiteThreshold`` 5), when ``cv2.structured_light``
  exists (the opencv-contrib wheels); otherwise the row says it is unavailable;
* ``speckle``: this package's single-shot matcher on the speckle images.

OpenCV's columns are triangulated with this package's ray-plane code and calibration, so
the depth columns compare decoders, not triangulations.

Figures: ``decoded`` = fraction of ground-truth lit pixels (``shadow_gt`` 0) with an
estimate; ``false`` = fraction of shadowed / outside pixels with one; ``rms`` = RMS error of
the projector column (projector px) over *interior* lit pixels (lit in a 5x5 neighbourhood
and no depth step over 3 % in it, i.e. away from the mixed pixels of edges and shadow
borders), ``rms all`` over every decoded lit pixel, ``>1px`` = fraction of decoded lit
pixels off by more than one projector pixel; depth RMS and median |error| in mm over
interior pixels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.structured_light import (
    PatternSet,
    ProjectorGeometry,
    SpeckleMatcher,
    camera_rays,
    speckle_depth,
    triangulate_columns,
)
from depth_nodes.core.structured_light.reconstruct import reconstruct
from depth_nodes.tools.bags.structured_light import read_structured_light_bag

F32 = NDArray[np.float32]
#: Defaults of the node's decoding parameters, used for the figures.
SHADOW_THRESHOLD = 12.0
MIN_MODULATION = 4.0
OPENCV_WHITE_THRESHOLD = 5
#: Depth range searched by the speckle matcher in the figures (the bundled scene: 0.8-1.8 m).
SPECKLE_DEPTH_RANGE = (0.5, 3.0)
#: The speckle matcher's box side in the figures (the node's default).
SPECKLE_WINDOW = 9


def opencv_available() -> bool:
    """True when ``cv2.structured_light`` (opencv-contrib) is importable."""
    return hasattr(cv2, 'structured_light')


def opencv_gray_columns(gray_frames: NDArray[np.uint8], projector_width: int, *,
                        shadow_threshold: float = SHADOW_THRESHOLD,
                        white_threshold: int = OPENCV_WHITE_THRESHOLD) -> F32:
    """Projector columns decoded by OpenCV's GrayCodePattern from our ``gray`` layout.

    Args:
        gray_frames: (2 + 2 * bits, H, W) uint8: white, black, then the column bit planes
            MSB first, each followed by its inverse (exactly OpenCV's column patterns).
        projector_width: Projector width (sets OpenCV's number of column bits).
        shadow_threshold: OpenCV's blackThreshold of the shadow mask.
        white_threshold: OpenCV's whiteThreshold (minimum pattern - inverse per bit).

    Returns:
        (H, W) float32 columns, NaN where OpenCV reports an error or the pixel is masked.

    Raises:
        RuntimeError: ``cv2.structured_light`` is not available.
    """
    if not opencv_available():
        raise RuntimeError('cv2.structured_light is not available (needs opencv-contrib)')
    sl = cv2.structured_light
    # OpenCV always codes rows too and crashes for height 1: height 2 has one row bit, fed
    # with the white and black frames (row 1, never an error). Columns are untouched.
    pattern = sl.GrayCodePattern.create(projector_width, 2)
    pattern.setWhiteThreshold(white_threshold)
    white, black = gray_frames[0], gray_frames[1]
    images = [np.ascontiguousarray(f) for f in gray_frames[2:]] + [white, black]
    if len(images) != pattern.getNumberOfPatternImages():
        raise RuntimeError(f'OpenCV expects {pattern.getNumberOfPatternImages()} images, got '
                           f'{len(images)}')
    mask = white.astype(np.int32) - black.astype(np.int32) > shadow_threshold
    out = np.full(white.shape, np.nan, dtype=np.float32)
    get = pattern.getProjPixel
    for y, x in zip(*np.nonzero(mask), strict=True):
        err, pix = get(images, int(x), int(y))
        if not err:
            out[y, x] = pix[0]
    return out


def interior_mask(depth_gt: F32, shadow_gt: NDArray[np.uint8]) -> NDArray[np.bool_]:
    """Lit pixels whose 5x5 neighbourhood is lit and free of depth steps over 3 %."""
    kernel = np.ones((5, 5), np.uint8)
    lit = cv2.erode((shadow_gt == 0).astype(np.uint8), kernel).astype(bool)
    d = np.nan_to_num(depth_gt, nan=0.0).astype(np.float32)
    return lit & ((cv2.dilate(d, kernel) - cv2.erode(d, kernel)) < 0.03 * d)


@dataclass
class SLScores:
    """Figures of one method (see the module docstring)."""

    method: str
    decoded: float | None = None
    false: float | None = None
    rms: float | None = None
    rms_all: float | None = None
    gross: float | None = None
    depth_rms_mm: float | None = None
    depth_median_mm: float | None = None
    ms: float | None = None
    note: str = ''


@dataclass
class SLReport:
    """The table printed for a bag."""

    bag: str
    size: tuple[int, int]
    sequences: int
    frames: int
    rows: list[SLScores] = field(default_factory=list)

    def format(self) -> str:
        """Plain-text table."""
        head = (f'{"method":<34}{"decoded":>8}{"false":>7}{"rms px":>8}{"rms all":>8}'
                f'{">1px":>8}{"depth rms mm":>13}{"median mm":>10}{"ms/seq":>9}')
        lines = [f'bag {self.bag}: {self.sequences} sequence(s) of {self.frames} frames, '
                 f'{self.size[0]}x{self.size[1]}', head, '-' * len(head)]

        def f(v: float | None, fmt: str, width: int) -> str:
            return f'{v:{width}{fmt}}' if v is not None else f'{"-":>{width}}'

        for r in self.rows:
            if r.note and r.decoded is None:
                lines.append(f'{r.method:<34}{r.note}')
                continue
            lines.append(f'{r.method:<34}{f(r.decoded, ".4f", 8)}{f(r.false, ".4f", 7)}'
                         f'{f(r.rms, ".3f", 8)}{f(r.rms_all, ".3f", 8)}{f(r.gross, ".4f", 8)}'
                         f'{f(r.depth_rms_mm, ".2f", 13)}{f(r.depth_median_mm, ".2f", 10)}'
                         f'{f(r.ms, ".0f", 9)}')
        return '\n'.join(lines)


def score(method: str, u: F32 | None, depth: F32, gt: dict[str, NDArray[Any]],
          ms: float | None) -> SLScores:
    """Figures of one estimate against a sequence's ground truth."""
    shadow, depth_gt = gt['shadow_gt'], gt['depth_gt']
    lit = shadow == 0
    inner = interior_mask(depth_gt, shadow)
    has = np.isfinite(depth) if u is None else np.isfinite(u)
    out = SLScores(method, decoded=float(has[lit].mean()), false=float(has[~lit].mean())
                   if (~lit).any() else 0.0, ms=ms)
    if u is not None:
        err = u - gt['projector_u_gt']
        e_in, e_all = err[inner & has], err[lit & has]
        out.rms = float(np.sqrt(np.mean(e_in**2)))
        out.rms_all = float(np.sqrt(np.mean(e_all**2)))
        out.gross = float(np.mean(np.abs(e_all) > 1))
    dz = (depth - depth_gt)[inner & np.isfinite(depth)] * 1e3
    if dz.size:
        out.depth_rms_mm = float(np.sqrt(np.mean(dz**2)))
        out.depth_median_mm = float(np.median(np.abs(dz)))
    return out


def evaluate_structured_light_bag(path: str | Path, *, opencv: bool = True) -> SLReport:
    """Score every method on every sequence of the bag (figures pooled by mean).

    Raises:
        BagError: As :func:`read_structured_light_bag`.
    """
    bag = read_structured_light_bag(path)
    cfg = bag.config
    geometry = ProjectorGeometry.from_models(bag.camera, bag.projector)
    rays = camera_rays(bag.camera)
    ps = cfg.pattern_set
    gray = PatternSet('gray', ps.width, ps.height, ps.axes)
    report = SLReport(str(path), (bag.camera.width, bag.camera.height), len(bag.sequences),
                      ps.count)
    rows: dict[str, list[SLScores]] = {}
    kw = {'shadow_threshold': SHADOW_THRESHOLD, 'min_modulation': MIN_MODULATION}
    for seq in bag.sequences:
        methods: list[tuple[str, PatternSet]] = [('gray (this package)', gray)]
        if ps.mode == 'phase':
            methods.append((f'phase N={ps.steps} P={ps.period:g} (this package)', ps))
        for name, pset in methods:
            start = time.perf_counter()
            rec = reconstruct(seq.images[:pset.count], pset, geometry, rays=rays, **kw)
            ms = (time.perf_counter() - start) * 1e3
            rows.setdefault(name, []).append(score(name, rec.decoded.u, rec.depth, seq.gt, ms))
        name = 'opencv GrayCodePattern'
        if opencv and opencv_available():
            start = time.perf_counter()
            u = opencv_gray_columns(seq.images[:gray.count], ps.width)
            ms = (time.perf_counter() - start) * 1e3
            depth = triangulate_columns(rays, u, geometry)
            rows.setdefault(name, []).append(score(name, u, depth, seq.gt, ms))
        else:
            rows[name] = [SLScores(name, note='unavailable: cv2.structured_light needs the '
                                   'opencv-contrib wheel')]
    if bag.speckle and bag.reference is not None and bag.sequences:
        name = f'speckle (this package, window {SPECKLE_WINDOW})'
        matcher = SpeckleMatcher()
        for image in bag.speckle:
            start = time.perf_counter()
            depth, _ = speckle_depth(image, bag.reference, focal=bag.camera.K[0, 0],
                                     baseline=float(geometry.centre[0]),
                                     reference_depth=cfg.reference_depth,
                                     depth_min=SPECKLE_DEPTH_RANGE[0],
                                     depth_max=SPECKLE_DEPTH_RANGE[1], window=SPECKLE_WINDOW,
                                     matcher=matcher)
            ms = (time.perf_counter() - start) * 1e3
            rows.setdefault(name, []).append(score(name, None, depth, bag.sequences[0].gt, ms))
    for name, scores in rows.items():
        report.rows.append(_mean(name, scores))
    return report


def _mean(name: str, scores: list[SLScores]) -> SLScores:
    if len(scores) == 1:
        return scores[0]
    out = SLScores(name, note=scores[0].note)
    for key in ('decoded', 'false', 'rms', 'rms_all', 'gross', 'depth_rms_mm',
                'depth_median_mm', 'ms'):
        vals = [getattr(s, key) for s in scores if getattr(s, key) is not None]
        setattr(out, key, float(np.mean(vals)) if vals else None)
    return out
