"""`depth-nodes eval` on a depth-filter bag: filtered depth against the exact depth.

Scores of a sequence of depth frames (a depth_* bag: the camera's depth as measured, and
any filtered version of it: the depth_filter node's output in a processed bag, this
package's filter or librealsense's run on the same frames), each against the truth:

* **error**: median ``|Z - Z_gt| / Z_gt`` over the pixels with a depth (measured or
  filled), from frame ``skip`` on, and its signed median on flat surfaces (the bias);
* **fill**: the share of the pixels that see a surface with a depth;
* **temporal noise**: the median over flat-surface pixels of the depth's standard
  deviation over the frames from ``skip`` on, relative to Z (a still camera only);
* **edges**: the share of pixels within 3 px of a depth edge of the truth that are more
  than 10 % off (ghosts, trails and smeared edges);
* **flying pixels**: the share of the mixed pixels (``labels_gt``) that kept their depth
  (a depth the filter marks as filled is not theirs), and the share of the measured pixels
  that see one surface that lost theirs;
* **trails** (a moving object): pixels an object has just uncovered, ``persistence + 1``
  frames later, still more than 10 % off the background (the object's depth left behind);
* **filled**: the pixels with a depth where the camera measured none, their median error,
  and how many of them the filter's mask did not mark (must be 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
B = NDArray[np.bool_]
#: Relative error above which a pixel is wrong (edges, trails).
WRONG = 0.10
#: Pixels of the band around the truth's depth edges.
EDGE_BAND_PX = 3
#: Relative depth step between neighbours that is an edge of the truth.
EDGE_STEP = 0.05


def edge_band(truth: F32, px: int = EDGE_BAND_PX) -> B:
    """Pixels within ``px`` of a depth edge of ``truth`` (a step of more than
    :data:`EDGE_STEP` of Z to a neighbour, or a surface's border)."""
    z = np.nan_to_num(truth, nan=0.0)
    step = np.zeros(z.shape, bool)
    with np.errstate(invalid='ignore', divide='ignore'):
        dx = np.abs(np.diff(z, axis=1)) > EDGE_STEP * np.maximum(z[:, 1:], z[:, :-1])
        dy = np.abs(np.diff(z, axis=0)) > EDGE_STEP * np.maximum(z[1:], z[:-1])
    step[:, 1:] |= dx
    step[:, :-1] |= dx
    step[1:] |= dy
    step[:-1] |= dy
    kernel = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    out: B = cv2.dilate(step.astype(np.uint8), kernel).astype(bool)
    return out


def flat_surfaces(truth: F32) -> B:
    """Pixels that see a surface and are at least 6 px from any depth edge."""
    return np.isfinite(truth) & ~edge_band(truth, 6)


@dataclass
class Scores:
    """The scores of one version of a sequence (see the module notes)."""

    name: str
    error: float
    bias: float
    fill: float
    noise: float
    edges: float
    flying_kept: float
    valid_lost: float
    trails: float
    filled: int
    filled_error: float
    unmarked: int
    ms: float = float('nan')
    extra: dict[str, float] = field(default_factory=dict)


@dataclass
class Version:
    """One version of a sequence: per frame, its depth (on the truth's grid), the mask of
    pixels it marks as filled (None: it marks none), and seconds per frame."""

    name: str
    depths: list[F32]
    filled: list[B] | None = None
    seconds: list[float] = field(default_factory=list)


def score(version: Version, truths: Sequence[F32], measured: Sequence[F32],
          labels: Sequence[NDArray[np.uint8]], *, skip: int, still: bool,
          persistence: int) -> Scores:
    """Score ``version`` against the truth (``measured``: the camera's depth; ``labels``:
    the bag's ``labels_gt``: 1 mixed, 2 hole, 4 moving)."""
    frames = range(min(skip, len(truths) - 1), len(truths))
    err, bias, fill, edges = [], [], [], []
    kept = lost = mixed_n = valid_n = filled_n = unmarked = 0
    filled_err: list[F32] = []
    for k in frames:
        z, t, m = version.depths[k], truths[k], measured[k]
        seen = np.isfinite(t)
        has = np.isfinite(z) & seen
        with np.errstate(invalid='ignore', divide='ignore'):
            rel = (z - t) / t
        err.append(np.median(np.abs(rel[has])) if has.any() else np.nan)
        flat = flat_surfaces(t) & has
        bias.append(np.median(rel[flat]) if flat.any() else np.nan)
        fill.append(has.sum() / max(seen.sum(), 1))
        band = edge_band(t) & has
        edges.append(np.mean(np.abs(rel[band]) > WRONG) if band.any() else np.nan)
        mixed = (labels[k] & 1).astype(bool)
        measured_here = np.isfinite(z) if version.filled is None else \
            np.isfinite(z) & ~version.filled[k]
        kept += int((mixed & measured_here).sum())
        mixed_n += int(mixed.sum())
        valid = np.isfinite(m) & ~(labels[k] & 8).astype(bool) & seen
        lost += int((valid & ~np.isfinite(z)).sum())
        valid_n += int(valid.sum())
        new = np.isfinite(z) & ~np.isfinite(m) & seen
        filled_n += int(new.sum())
        filled_err.append(np.abs(rel[new]))
        if version.filled is not None:
            unmarked += int((new & ~version.filled[k]).sum())
    noise = np.nan
    if still and len(frames) > 2:
        stack = np.stack([version.depths[k] for k in frames])
        t = truths[frames[-1]]
        flat = flat_surfaces(t) & np.isfinite(stack).all(axis=0)
        if flat.any():
            noise = float(np.median(stack[:, flat].std(axis=0) / t[flat]))
    all_filled = np.concatenate(filled_err) if filled_err else np.zeros(0)
    return Scores(
        version.name, float(np.nanmean(err)), float(np.nanmedian(bias)),
        float(np.mean(fill)), noise, float(np.nanmean(edges)),
        kept / max(mixed_n, 1), lost / max(valid_n, 1),
        trails(version.depths, truths, labels, persistence),
        filled_n, float(np.median(all_filled)) if all_filled.size else np.nan, unmarked,
        1000.0 * float(np.median(version.seconds)) if version.seconds else np.nan)


def trails(depths: Sequence[F32], truths: Sequence[F32], labels: Sequence[NDArray[np.uint8]],
           persistence: int) -> float:
    """The share of the pixels a moving object uncovers at frame ``k`` (moving at ``k - 1``,
    background at ``k``, which is farther) whose depth at ``k + persistence + 1`` is still
    more than :data:`WRONG` off there (NaN when the object uncovers nothing)."""
    wrong = total = 0
    later = persistence + 1
    for k in range(1, len(truths) - later):
        was = (labels[k - 1] & 4).astype(bool)
        now = (labels[k] & 4).astype(bool)
        with np.errstate(invalid='ignore'):
            uncovered = was & ~now & (truths[k] > truths[k - 1] * (1 + WRONG))
        # still background then, and not covered again
        j = k + later
        stays = uncovered & ~(labels[j] & 4).astype(bool) & np.isfinite(truths[j])
        if not stays.any():
            continue
        z, t = depths[j], truths[j]
        with np.errstate(invalid='ignore'):
            off = np.isfinite(z) & (np.abs(z - t) > WRONG * t)
        wrong += int((off & stays).sum())
        total += int(stays.sum())
    return wrong / total if total else float('nan')


def format_table(rows: Sequence[Scores], title: str) -> str:
    """The scores as a table, one version a row."""
    def pct(v: float, digits: int = 2) -> str:
        return 'n/a' if not np.isfinite(v) else f'{100 * v:.{digits}f} %'

    head = (f'{"":28s} {"error":>8s} {"bias":>9s} {"fill":>8s} {"noise":>8s} {"edges":>8s} '
            f'{"flying":>8s} {"lost":>7s} {"trails":>8s} {"filled":>7s} {"its err":>8s} '
            f'{"ms":>7s}')
    lines = [title, head]
    for r in rows:
        ms = 'n/a' if not np.isfinite(r.ms) else f'{r.ms:.1f}'
        lines.append(
            f'{r.name:28s} {pct(r.error):>8s} {pct(r.bias, 3):>9s} {pct(r.fill, 1):>8s} '
            f'{pct(r.noise):>8s} {pct(r.edges):>8s} {pct(r.flying_kept, 1):>8s} '
            f'{pct(r.valid_lost, 1):>7s} {pct(r.trails, 1):>8s} {r.filled:>7d} '
            f'{pct(r.filled_error, 1):>8s} {ms:>7s}' + (
                f'  ({r.unmarked} filled pixels not in the mask)' if r.unmarked else ''))
    return '\n'.join(lines)
