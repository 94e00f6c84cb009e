"""`depth-nodes eval-depth-filter`: the depth filter against the simulator's exact depth,
stage by stage, beside librealsense's filters."""

from __future__ import annotations

import argparse
import sys

from depth_nodes.errors import BagError
from depth_nodes.tools import signals
from depth_nodes.tools.evaluation.depth_filter_stages import compare, read_sequence


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `eval-depth-filter`."""
    parser.add_argument('bag', help='a bag written by generate --preset depth_* (or '
                        'processed from one with config/depth_filter_pipeline.yaml: its '
                        'filtered depth is scored too)')
    parser.add_argument('--librealsense', action='store_true',
                        help='run librealsense\'s own filters on the same frames, stage by '
                        'stage (needs the realsense extra: pip install .[realsense])')
    parser.add_argument('--skip', type=int, default=3, metavar='N',
                        help='score from frame N, once the temporal stage has a past '
                        '(default 3)')
    parser.add_argument('--persistence', type=int, default=3, metavar='N',
                        help='trails: frames an uncovered pixel may keep the object\'s '
                        'depth (the temporal persistence; default 3)')


def run(args: argparse.Namespace) -> int:
    """Print the tables (a signal stops between stages)."""
    if args.skip < 0 or args.persistence < 0:
        raise BagError('--skip and --persistence must be >= 0')
    seq = read_sequence(args.bag)
    if args.skip >= len(seq.depth):
        raise BagError(f'--skip {args.skip}: the bag has {len(seq.depth)} frames')
    with signals.graceful():
        def progress(name: str) -> None:
            if signals.stop_requested():
                raise KeyboardInterrupt
            print(f'  {name} ...', file=sys.stderr)

        try:
            print(compare(seq, librealsense=args.librealsense, skip=args.skip,
                          persistence=args.persistence, on_stage=progress))
        except KeyboardInterrupt:
            print('depth-nodes eval-depth-filter: interrupted', file=sys.stderr)
            return 130
    return 0
