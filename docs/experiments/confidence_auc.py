"""How well each confidence ranks the raw matcher's errors, on every data set with ground
truth: the hand-made map and the learned one (shipped, or other weights), scored by the
sparsification AUC over the optimum (bad-2, over the pixels the raw matcher estimated, as
`eval` reports it), with bad-2 of the pixels kept at 50 % and 70 % density.

    .venv/bin/python docs/experiments/confidence_auc.py [--weights A.npz B.npz ...]

Data: the three bundled simulator bags (their raw images rectified, as the graph does),
Teddy and Cones (test/data) and the motorcycle pair (scikit-image's), through the shipped
graph's matcher and cross_check (GRAPH_SGM, GRAPH_CHECK of the confidence training). About
a minute on two cores.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from depth_nodes.core.cross_check import cross_check
from depth_nodes.core.learned.confidence import ConfidenceModel, shipped_confidence
from depth_nodes.core.metrics import sparsification_auc
from depth_nodes.core.sgm import SgmMatcher
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.evaluate import rectified_pair
from depth_nodes.tools.train.confidence import GRAPH_CHECK, GRAPH_SGM

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from defaults_loo import scenes  # noqa: E402  (the real pairs, loaded the same way)

BAGS = {'stereo_vga': 128, 'stereo_qvga_color': 64, 'stereo_qvga_fisheye': 64}


def sim_pairs() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """The bundled stereo bags' first frame: rectified grey pair, true disparity, range."""
    out = {}
    for name, n in BAGS.items():
        with BagReader(REPO / 'bags' / name) as reader:
            data: dict[str, dict[int, object]] = {}
            for msg in reader.messages():
                if msg.topic.endswith(('image_raw', 'camera_info', 'disparity_gt')):
                    parsed = msg.deserialize()
                    data.setdefault(msg.topic, {})[stamp_ns(parsed)] = parsed
        stamp = min(data['/stereo/left/disparity_gt'])
        left, right = rectified_pair(data, '/stereo', stamp)
        truth = read_disparity(data['/stereo/left/disparity_gt'][stamp]).disparity
        out[name] = (left, right, truth, n)
    return out


def scores(confidence: np.ndarray, raw: np.ndarray, truth: np.ndarray) -> tuple[float, ...]:
    """AUC / optimum over the raw pixels with ground truth, bad-2 at 50 and 70 % density."""
    known = np.isfinite(raw) & np.isfinite(truth)
    error = np.abs(raw - truth)
    auc = sparsification_auc(confidence, error, valid_mask=known, n=2.0)
    order = np.argsort(-confidence[known], kind='stable')
    bad = (error[known] > 2.0)[order]
    at = [float(bad[:max(1, int(f * bad.size))].mean()) for f in (0.5, 0.7)]
    return auc.ratio, float(bad.mean()), *at


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--weights', nargs='*', default=[])
    args = parser.parse_args()
    models: dict[str, ConfidenceModel | None] = {'hand-made': None,
                                                 'learned (shipped)': shipped_confidence()}
    models |= {Path(w).name: ConfidenceModel.load(w) for w in args.weights}
    data = {**sim_pairs(), **scenes()}
    print(f'{"data set":22s}{"errors":>8s}' + ''.join(f'{m[:20]:>24s}' for m in models))
    print(' ' * 30 + ''.join(f'{"AUC/opt b2@50 b2@70":>24s}' for _ in models))
    for name, (left, right, truth, n) in data.items():
        result = SgmMatcher(replace(GRAPH_SGM, disparity_range=n)).match(left, right)
        raw = result.disparity.copy()
        row = ''
        errors = 0.0
        for model in models.values():
            checked = cross_check(raw, result.disparity_right, result.cost_ratio,
                                  **GRAPH_CHECK.arguments(), model=model)
            ratio, errors, at50, at70 = scores(checked.confidence, raw, truth)
            row += f'{ratio:10.2f}{100 * at50:7.1f}{100 * at70:7.1f}'
        print(f'{name:22s}{100 * errors:7.1f}%' + row)
    return 0


if __name__ == '__main__':
    sys.exit(main())
