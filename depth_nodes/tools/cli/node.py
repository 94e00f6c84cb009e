"""`depth-nodes node list`: the nodes of the running graph, like ``ros2 node``."""

from __future__ import annotations

import argparse

from depth_nodes.tools.live.introspect import list_nodes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The verb of `node` (list) and its option."""
    verbs = parser.add_subparsers(dest='verb', required=True)
    listing = verbs.add_parser('list', help='every node, sorted')
    listing.add_argument('--wait', type=float, default=2.0, metavar='SECONDS',
                         help='least discovery time before listing (default 2; it goes on '
                         'while nodes are still announcing themselves, up to 10)')


def run(args: argparse.Namespace) -> int:
    """Print every node's name."""
    print('\n'.join(list_nodes(wait=args.wait)))
    return 0
