"""`depth-nodes reindex`: make a recording cut off (killed, a full disk, a power loss) a
complete bag again."""

from __future__ import annotations

import argparse

from depth_nodes.tools.bags.recover import reindex_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `reindex`."""
    parser.add_argument('bag', help='the folder of the cut recording')
    parser.add_argument('--out', metavar='OUT_BAG',
                        help='write the recovered bag there and leave BAG as it is '
                        '(default: in place, each cut file kept as <file>.cut)')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')


def run(args: argparse.Namespace) -> int:
    """Recover every complete message into a complete bag; say what was recovered."""
    print(reindex_bag(args.bag, args.out, overwrite=args.force).format())
    return 0
