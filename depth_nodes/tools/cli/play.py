"""`depth-nodes play`: publish a bag into the live graph."""

from __future__ import annotations

import argparse
import sys

from depth_nodes.errors import ConfigError
from depth_nodes.tools import signals
from depth_nodes.tools.bags.live import PlayOptions, play_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `play`."""
    parser.add_argument('bag')
    parser.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    parser.add_argument('--loop', action='store_true',
                        help='play again and again; each repeat\'s header stamps move on by '
                        'the bag\'s length plus one period, so nodes take it as a stream that '
                        'goes on')
    parser.add_argument('--keep-stamps', action='store_true',
                        help='--loop: publish every repeat with the recorded stamps (nodes '
                        'start over on a jump back of 1 s or more, drop shorter ones)')
    parser.add_argument('--remap', nargs='+', metavar='FROM:=TO',
                        help='publish topic FROM as TO (absolute names)')
    parser.add_argument('--clock', action='store_true', help='publish /clock with bag time')
    parser.add_argument('--topics', nargs='+', help='only these topics')
    parser.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='SECONDS',
                        help='wait up to SECONDS for every topic played to have a '
                        'subscriber (with --topics, leave out what nothing reads, such as a '
                        "bundled bag's ground truth)")
    parser.add_argument('--delay', type=float, default=0.0, metavar='SECONDS',
                        help='then wait SECONDS more before the first message')
    parser.add_argument('--linger', type=float, default=1.0, metavar='SECONDS',
                        help='stay SECONDS after the last message, so best-effort '
                        'subscriptions receive it (default 1)')


def remappings(rules: list[str]) -> dict[str, str]:
    """``FROM:=TO`` rules as a mapping.

    Raises:
        ConfigError: A rule is not of that form.
    """
    remap = {}
    for rule in rules:
        source, sep, target = rule.partition(':=')
        if not sep or not source or not target:
            raise ConfigError(f'--remap {rule!r}: expected FROM:=TO')
        remap[source] = target
    return remap


def run(args: argparse.Namespace) -> int:
    """Play the bag; print how many messages went out."""
    options = PlayOptions(rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics,
                          wait_for_subscribers=args.wait_for_subscribers, delay=args.delay,
                          linger=args.linger, restamp=not args.keep_stamps,
                          remap=remappings(args.remap or []))
    with signals.graceful():
        count = play_bag(args.bag, options, log=sys.stdout)
    print(f'played {count} messages')
    return 0
