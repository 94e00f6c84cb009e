"""`depth-nodes tune`: sgm_stereo's settings searched on your own stereo bag, scored
without ground truth (:mod:`depth_nodes.tools.tune`), written as a parameter
file that `process --params`, `pipeline --params` and the launch files' params_file take."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from depth_nodes.errors import ArgumentError
from depth_nodes.tools import signals
from depth_nodes.tools.tune import TuneResult, tune, write_params


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='a stereo bag: <ns>/left|right/image_raw (or image_rect, '
                        'or compressed) with camera_info, e.g. a recording of your camera')
    parser.add_argument('--out', required=True, metavar='PARAMS.yaml',
                        help='the parameter file to write (the best settings so far, also '
                        'after Ctrl-C)')
    parser.add_argument('--frames', type=int, default=4,
                        help='pairs of the bag scored, spread over it (default 4)')
    parser.add_argument('--trials', type=int, default=24,
                        help='settings tried besides the shipped ones (default 24)')
    parser.add_argument('--camera', metavar='NAME',
                        help="a stereo camera preset (config/cameras): its driver's topics "
                        'and its settings (the disparity range among them) as the start')
    parser.add_argument('--seed', type=int, default=0, help='seed of the search (default 0)')
    parser.add_argument('--force', action='store_true', help='replace an existing --out')


def run(args: argparse.Namespace) -> int:
    """Search; keep the best settings in --out as they improve; report them."""
    out = Path(args.out)
    if out.exists() and not args.force:
        raise ArgumentError(f'{out} exists (--force replaces it)')
    if not out.parent.is_dir():
        raise ArgumentError(f'{out.parent} is not a folder')
    with signals.graceful():
        result = tune(args.bag, frames=args.frames, trials=args.trials, seed=args.seed,
                      camera=args.camera,
                      log=lambda line: print(line, file=sys.stderr, flush=True),
                      stop=signals.stop_requested,
                      on_best=lambda r: write_params(r, out, args.bag))
    write_params(result, out, args.bag)
    print(_report(result, out))
    if result.interrupted:
        print(f'depth-nodes tune: interrupted after {len(result.trials)} trial(s); {out} '
              'holds the best settings so far', file=sys.stderr)
    return 0


def _report(result: TuneResult, out: Path) -> str:
    best, start = result.best, result.start
    rows = [f'{"settings":24s} {"score":>7s} {"checked":>8s} {"photometric":>12s} '
            f'{"flicker px":>10s} {"bad-2 (truth)":>14s}']
    for label, trial in (('shipped', start), ('best', best)):
        truth = '-' if trial.bad2 is None else f'{trial.bad2:.2%}'
        rows.append(f'{label:24s} {trial.score:7.2f} {trial.density:8.1%} '
                    f'{trial.photometric:12.2f} {trial.temporal:10.2f} {truth:>14s}')
    changed = ', '.join(f'{k} {v}' for k, v in best.changes.items()) or 'nothing'
    return '\n'.join([*rows, f'changed: {changed}', f'{out}: written ({result.pairs} '
                      f'pair(s), {len(result.trials)} trial(s), {result.seconds:.0f} s)'])
