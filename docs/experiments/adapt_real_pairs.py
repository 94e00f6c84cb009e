"""Does adapting the learned cost to one camera's recordings (``train-cost --adapt``, no
ground truth) help on that camera's other scenes? Leave one pair out: adapt on Cones and
score on Teddy (and the reverse), every pair clean and with a disagreeing right camera.

    .venv/bin/python docs/experiments/adapt_real_pairs.py OUT_DIR

Teddy and Cones come from one rig (Middlebury 2003), so each plays "the same camera, a
scene it was not adapted on" for the other. Each pair is imported as a bag
(``depth-nodes import-pair``) and the network adapted on it with the command's defaults;
then the raw matcher (census+learned at ``config/learned.yaml``'s settings, 8 paths) runs
with the shipped and the adapted weights on every pair and variant of
``defaults_loo.py``, and the ratio adapted / shipped of dense bad-2 is printed (below 1:
the adaptation helps). About a minute on two cores.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numba

sys.path.insert(0, str(Path(__file__).resolve().parent))
from defaults_loo import REPO, VARIANTS, bad2, degrade, geomean, scenes

from depth_nodes.core.sgm import SgmParams

LEARNED = {'matching_cost': 'census+learned', 'learned_weight': 20, 'P1': 36, 'P2': 440}


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__.split('\n\n')[1].strip(), file=sys.stderr)
        return 2
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    cli = [sys.executable, '-m', 'depth_nodes.tools.cli']
    data = REPO / 'test' / 'data' / 'middlebury2003'
    weights = {}
    for name in ('teddy', 'cones'):
        bag = out / name
        if not bag.exists():
            subprocess.run([*cli, 'import-pair', str(data / name / 'im2.png'),
                            str(data / name / 'im6.png'), str(bag)], check=True,
                           stdout=subprocess.DEVNULL)
        weights[name] = out / f'adapted_on_{name}.npz'
        subprocess.run([*cli, 'train-cost', '--adapt', str(bag), '--out',
                        str(weights[name]), '--force'], check=True,
                       stdout=subprocess.DEVNULL)
    numba.set_num_threads(2)
    pairs = scenes()
    cases = [(s, k) for s in pairs for k in VARIANTS]

    def errors(extra: dict[str, object]) -> dict[tuple[str, str], float]:
        return {(s, k): bad2(SgmParams(disparity_range=pairs[s][3], paths=8, **extra),
                             pairs[s][0], degrade(pairs[s][1], k), pairs[s][2])
                for s, k in cases}

    shipped = errors(LEARNED)
    print('raw dense bad-2, adapted / shipped weights (census+learned, P1 36, P2 440)')
    print('adapted on'.ljust(14) + ''.join(f'{s[:5]}/{k[:6]}'.rjust(14) for s, k in cases))
    print('shipped bad-2'.ljust(14) + ''.join(f'{shipped[c]:14.4f}' for c in cases))
    for name, path in weights.items():
        adapted = errors({**LEARNED, 'learned_weights': str(path)})
        ratio = {c: adapted[c] / shipped[c] for c in cases}
        print(name.ljust(14) + ''.join(f'{ratio[c]:14.3f}' for c in cases))
        for scene in pairs:
            print(f'  on {scene:12s} geo-mean {geomean([ratio[(scene, k)] for k in VARIANTS]):.3f}'
                  + ('  (adapted on it)' if scene == name else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
