"""`depth-nodes record`: record live topics into a bag."""

from __future__ import annotations

import argparse
import sys

from depth_nodes.errors import BagError
from depth_nodes.tools import signals
from depth_nodes.tools.bags.io import remove_bag
from depth_nodes.tools.bags.live import record_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `record`."""
    parser.add_argument('out_bag')
    parser.add_argument('--topics', nargs='+', required=True)
    parser.add_argument('--duration', type=float, help='stop after SECONDS')
    parser.add_argument('--max-messages', type=int, help='stop after N messages')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')


def run(args: argparse.Namespace) -> int:
    """Record until the duration, the message count or a signal; an empty bag is removed.

    Raises:
        BagError: Nothing was recorded.
    """
    with signals.graceful():
        count = record_bag(args.out_bag, args.topics, duration=args.duration,
                           max_messages=args.max_messages, overwrite=args.force,
                           log=sys.stdout)
    if count == 0:
        remove_bag(args.out_bag)
        raise BagError(f'nothing was recorded (no message on {", ".join(args.topics)}); '
                       f'{args.out_bag} was removed')
    print(f'recorded {count} messages to {args.out_bag}')
    return 0
