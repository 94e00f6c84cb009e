"""Does `depth-nodes tune` carry to a camera it did not see? Leave one real scene out: tune
on the others' pairs (their ground truth unused), apply the best settings to the scene
left out, and score both the shipped settings and the tuned ones there against its ground
truth (the raw matcher's dense bad-2, as docs/experiments/defaults_loo.py scores).

    .venv/bin/python docs/experiments/tune_loo.py [--trials 24] [--seed 0]

The scenes: Middlebury 2003 Teddy and Cones (test/data, quarter size) and Middlebury
2014's motorcycle (scikit-image's data set, the ``train`` extra), each clean and with its
right image degraded three ways (defaults_loo.py's variants: 0.6 px lower, JPEG 60,
gamma 1.5 with gain 1.1), eight pairs tuned on for each scene left out. The disparity
range is not searched (it belongs to the rig): while tuning, the largest of the tuned
scenes'; applied, each scene's own (64, 64, 80). About a minute on two cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from defaults_loo import VARIANTS, degrade, scenes

from depth_nodes.core.metrics import disparity_errors
from depth_nodes.core.sgm import SgmMatcher
from depth_nodes.tools.train.adapt import Pair
from depth_nodes.tools.tune import SPACE, _params, _shipped_settings, search


def bad2(settings: dict, left: np.ndarray, right: np.ndarray, truth: np.ndarray) -> float:
    disparity = SgmMatcher(_params(settings)).match(left, right).disparity
    return float(disparity_errors(disparity, truth, n=2.0).bad_dense)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--trials', type=int, default=24)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    data = scenes()
    space = dict(SPACE)
    shipped = _shipped_settings()
    print(f'{"left out":12s} {"variant":8s} {"shipped bad-2":>14s} {"tuned bad-2":>12s} '
          f'{"ratio":>6s}  tuned on the others: changed')
    ratios = []
    for out, (left, right, truth, disparities) in data.items():
        # every pair its own source: stills, no frame-to-frame term
        pairs = [Pair(f'{name}/{kind}', 0, other[0], degrade(other[1], kind))
                 for name, other in data.items() if name != out for kind in VARIANTS]
        # while tuning, every pair matched over the largest range of the scenes tuned on
        base = {**shipped, 'disparity_range': max(v[3] for n, v in data.items() if n != out)}
        result = search(pairs, base, trials=args.trials, seed=args.seed, space=space)
        tuned = {**shipped, **result.best.changes, 'disparity_range': disparities}
        start = {**shipped, 'disparity_range': disparities}
        changed = ', '.join(f'{k} {v}' for k, v in result.best.changes.items()) or 'nothing'
        for kind in VARIANTS:
            r = degrade(right, kind)
            before, after = bad2(start, left, r, truth), bad2(tuned, left, r, truth)
            ratios.append(after / before)
            print(f'{out:12s} {kind:8s} {before:14.2%} {after:12.2%} {after / before:6.3f}  '
                  f'{changed if kind == "clean" else ""}', flush=True)
    print(f'geometric mean of the ratios: {float(np.exp(np.mean(np.log(ratios)))):.3f}; '
          f'worse than the shipped settings in {sum(r > 1.0 for r in ratios)} of '
          f'{len(ratios)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
