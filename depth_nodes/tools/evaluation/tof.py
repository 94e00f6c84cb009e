"""`depth-nodes eval` on a time-of-flight bag (or `eval-tof`): the tof node's output
against the simulator's ground truth (`bench tof`, in tools/bench, times the node).

Scores, per frame of a processed ToF bag (``depth-nodes process bags/tof_vga OUT --config
config/tof_pipeline.yaml``), of the published depth (only pixels above the confidence
threshold carry one):

* **median relative error** ``|Z - Z_gt| / Z_gt`` over the pixels with a depth, and its
  95th percentile;
* **coverage**: the share of pixels with a depth among those the ground truth calls
  neither saturated nor too dark (``flags_gt`` 0) and that see a surface;
* **flying pixels**: pixels that see two surfaces (``mixed_*_gt``) whose depth is more than
  5 cm off both; and how many such mixed pixels got a depth at all;
* **multipath**: the median signed error on the walls near the concave corner
  (``corner_gt``), where the walls light each other;
* **range**: the unambiguous range of the frequencies together against each alone, and
  the farthest surface that got a correct depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_image import to_metres
from depth_nodes.core.tof import SPEED_OF_LIGHT, unambiguous_range
from depth_nodes.errors import BagError
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.tof import NAMESPACE, read_topics

#: Distance, metres, off both surfaces that makes a mixed pixel's depth a flying pixel.
FLYING_OFF = 0.05
#: The targets the scores are read against (docs/nodes.md, tof).
TARGET_MEDIAN, TARGET_COVERAGE, TARGET_RANGE_FACTOR = 0.01, 0.95, 4.0

F32 = NDArray[np.float32]


@dataclass
class ToFScores:
    """The scores of one frame (see the module notes)."""

    median_rel: float
    p95_rel: float
    coverage: float
    flying: int
    mixed_with_depth: int
    mixed: int
    corner_bias_mm: float
    farthest_m: float


def score_frame(depth: F32, gt: dict[str, NDArray[Any]]) -> ToFScores:
    """Score one published depth image against the frame's ground truth."""
    truth = gt['depth_gt']
    est = np.isfinite(depth) & np.isfinite(truth)
    rel = np.abs(depth - truth)[est] / truth[est]
    judged = (gt['flags_gt'] == 0) & np.isfinite(truth)
    near, far = gt['mixed_near_gt'], gt['mixed_far_gt']
    mixed = np.isfinite(near) & np.isfinite(far)
    with np.errstate(invalid='ignore'):
        flying = est & mixed & (np.abs(depth - near) > FLYING_OFF) & \
            (np.abs(depth - far) > FLYING_OFF)
    corner = est & (gt['corner_gt'] > 0)
    good = est & (np.abs(depth - truth) <= 0.01 * truth)
    return ToFScores(
        median_rel=float(np.median(rel)) if rel.size else float('nan'),
        p95_rel=float(np.quantile(rel, 0.95)) if rel.size else float('nan'),
        coverage=float(est[judged].mean()) if judged.any() else float('nan'),
        flying=int(flying.sum()), mixed_with_depth=int((est & mixed).sum()),
        mixed=int(mixed.sum()),
        corner_bias_mm=float(np.median((depth - truth)[corner]) * 1000) if corner.any()
        else float('nan'),
        farthest_m=float(truth[good].max()) if good.any() else float('nan'))


@dataclass
class ToFReport:
    """The time-of-flight figures of a processed bag (what ``eval`` prints)."""

    path: str
    frames: list[ToFScores]
    frequencies_mhz: tuple[float, ...]

    def format(self) -> str:
        """The report as printed."""
        single = max(SPEED_OF_LIGHT / (2 * f * 1e6) for f in self.frequencies_mhz)
        together = unambiguous_range(self.frequencies_mhz)
        rows = [f'tof: {self.path}, {len(self.frames)} frame(s), modulation '
                f'{", ".join(f"{f:g}" for f in self.frequencies_mhz)} MHz']
        for i, s in enumerate(self.frames):
            rows.append(
                f'  frame {i}: median |dZ|/Z {s.median_rel * 100:.2f} % (95th pct '
                f'{s.p95_rel * 100:.2f} %), coverage {s.coverage * 100:.1f} %, flying pixels '
                f'{s.flying} (mixed pixels with a depth {s.mixed_with_depth} of {s.mixed}), '
                f'multipath at the corner {s.corner_bias_mm:+.1f} mm, farthest correct '
                f'{s.farthest_m:.2f} m')
        worst_median = max(s.median_rel for s in self.frames)
        worst_cover = min(s.coverage for s in self.frames)
        flying = sum(s.flying for s in self.frames)
        factor = together / single

        def met(ok: bool) -> str:
            return 'met' if ok else 'NOT met'

        rows += [
            f'  unambiguous range {together:.2f} m together, {single:.2f} m for the lowest '
            f'frequency alone: {factor:.1f}x',
            f'  targets: median {worst_median * 100:.2f} % <= {TARGET_MEDIAN * 100:g} %: '
            f'{met(worst_median <= TARGET_MEDIAN)}; coverage {worst_cover * 100:.1f} % >= '
            f'{TARGET_COVERAGE * 100:g} %: {met(worst_cover >= TARGET_COVERAGE)}; flying '
            f'pixels {flying} = 0: {met(flying == 0)}; range {factor:.1f}x >= '
            f'{TARGET_RANGE_FACTOR:g}x: {met(factor >= TARGET_RANGE_FACTOR)}',
        ]
        return '\n'.join(rows)


GT_TOPICS = ('depth_gt', 'flags_gt', 'mixed_near_gt', 'mixed_far_gt', 'corner_gt')


def evaluate_tof_bag(path: str | Path, *, depth_topic: str = f'{NAMESPACE}/depth/image_rect'
                     ) -> ToFReport:
    """Score every frame of a processed ToF bag.

    Raises:
        BagError: Not a processed ToF bag (no ground truth, or no published depth).
    """
    topics = [f'{NAMESPACE}/{t}' for t in GT_TOPICS] + [depth_topic]
    config, found = read_topics(path, topics)
    frames = []
    for stamp, msg in sorted(found[depth_topic].items()):
        gt = {}
        for name in GT_TOPICS:
            gt_msg = found[f'{NAMESPACE}/{name}'].get(stamp)
            if gt_msg is None:
                raise BagError(f'{path}: no {NAMESPACE}/{name} at the stamp of a published '
                               'depth')
            gt[name] = image_to_array(gt_msg)
        depth = to_metres(image_to_array(msg), msg.encoding)
        frames.append(score_frame(depth, gt))
    if not frames:
        raise BagError(f'{path}: no {depth_topic} messages (run depth-nodes process with '
                       'config/tof_pipeline.yaml first)')
    return ToFReport(str(path), frames, tuple(config.frequencies_mhz))
