"""What the learned cost's network size buys and costs: each size trained with
``depth-nodes train-cost`` (its defaults but ``--channels`` and ``--layers``), then timed
against census and scored on the real pairs.

    .venv/bin/python docs/experiments/cost_networks.py OUT_DIR [--sizes 6x3 8x3 ...]
        [--cache SCENES]

For each network: census+learned's time over census's (the matcher on ``bench sgm``'s
bundled 640x480 pair, 128 disparities, 8 paths, two threads, the two interleaved, median
of 15), and the geometric mean over every real case of ``defaults_loo.py`` of
census+learned's dense bad-2 over census's, at the best of its settings (the weights and
penalty scales it tries). A size whose weights are in OUT_DIR already is not trained
again. About 2.5 minutes of training a network with the scenes cached (``--cache``,
shared with ``train-cost``), 40 s of scoring.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from defaults_loo import P1, P2, SCALES, VARIANTS, WEIGHTS, bad2, degrade, geomean, scenes

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.tools.bench.sgm import bench_pair


def time_ratio(weights: Path, rounds: int = 15) -> float:
    """census+learned's median time over census's, interleaved."""
    left, right = bench_pair()
    matchers = {cost: SgmMatcher(SgmParams(disparity_range=128, paths=8, matching_cost=cost,
                                           learned_weights=str(weights)))
                for cost in ('census', 'census+learned')}
    for matcher in matchers.values():
        matcher.match(left, right)
    times: dict[str, list[float]] = {cost: [] for cost in matchers}
    for _ in range(rounds):
        for cost, matcher in matchers.items():
            start = time.perf_counter()
            matcher.match(left, right)
            times[cost].append(time.perf_counter() - start)
    return float(np.median(times['census+learned']) / np.median(times['census']))


def accuracy(weights: Path, pairs: dict, census: dict) -> tuple[float, str]:
    """The best geometric mean of bad-2 over census's among the settings tried."""
    best = (np.inf, '')
    for w in WEIGHTS:
        for k in SCALES:
            params = {'matching_cost': 'census+learned', 'learned_weight': w,
                      'learned_weights': str(weights), 'P1': round(P1 * k), 'P2': round(P2 * k)}
            ratios = [bad2(SgmParams(disparity_range=n, paths=8, **params), left,
                           degrade(right, kind), truth) / census[(name, kind)]
                      for name, (left, right, truth, n) in pairs.items() for kind in VARIANTS]
            best = min(best, (geomean(ratios), f'weight {w}, P x{k:g}'))
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('out', type=Path)
    parser.add_argument('--sizes', nargs='+', default=['16x4', '8x3', '8x2', '6x3', '6x4',
                                                       '4x3'],
                        help='CHANNELSxLAYERS (default: the ones of docs/learned.md)')
    parser.add_argument('--cache', default='', help="train-cost's --cache")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cli = [sys.executable, '-m', 'depth_nodes.tools.cli', 'train-cost']
    files = {}
    for size in args.sizes:
        channels, layers = size.split('x')
        files[size] = args.out / f'c{channels}l{layers}.npz'
        if not files[size].exists():
            subprocess.run(cli + [str(files[size]), '--channels', channels, '--layers', layers]
                           + (['--cache', args.cache] if args.cache else []), check=True,
                           stdout=subprocess.DEVNULL)
    numba.set_num_threads(2)
    pairs = scenes()
    census = {(name, kind): bad2(SgmParams(disparity_range=n, paths=8), left,
                                 degrade(right, kind), truth)
              for name, (left, right, truth, n) in pairs.items() for kind in VARIANTS}
    print('network        time x census   bad-2 x census (best setting)')
    for size, path in files.items():
        geo, setting = accuracy(path, pairs, census)
        print(f'{size:14s} {time_ratio(path):13.2f} {geo:12.3f} ({setting})', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
