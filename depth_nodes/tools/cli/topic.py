"""`depth-nodes topic list|echo|hz|bw`: the topics of the running graph, like
``ros2 topic``."""

from __future__ import annotations

import argparse

from depth_nodes.tools import signals
from depth_nodes.tools.live import introspect


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The verbs of `topic` and their options."""
    verbs = parser.add_subparsers(dest='verb', required=True)
    listing = verbs.add_parser('list', help='every topic, sorted')
    listing.add_argument('-t', '--show-types', action='store_true',
                         help='print each topic\'s type')
    listing.add_argument('--wait', type=float, default=2.0, metavar='SECONDS',
                         help='least discovery time before listing (default 2; it goes on '
                         'while nodes are still announcing themselves, up to 10)')
    for verb, what in [('echo', 'print its messages (images and clouds as one summary '
                                'line)'),
                       ('hz', 'its rate every second'), ('bw', 'its bandwidth every second')]:
        cmd = verbs.add_parser(verb, help=what)
        cmd.add_argument('topic')
        cmd.add_argument('--timeout', type=float, default=10.0, metavar='SECONDS',
                         help='wait this long for the topic to appear (default 10)')
        if verb == 'echo':
            cmd.add_argument('--count', type=int, help='stop after N messages')
            cmd.add_argument('--once', action='store_true', help='print one message and stop')
        else:
            cmd.add_argument('--window', type=int, default=100,
                             help='messages the figures are taken over (default 100)')


def run(args: argparse.Namespace) -> int:
    """List the topics, or print one's messages, rate or bandwidth until stopped."""
    with signals.graceful():
        if args.verb == 'list':
            for name, types in introspect.list_topics(wait=args.wait):
                print(f'{name} [{", ".join(types)}]' if args.show_types else name)
        elif args.verb == 'echo':
            introspect.echo(args.topic, count=1 if args.once else args.count,
                            timeout=args.timeout)
        else:
            introspect.measure(args.topic, args.verb, window=args.window,
                               timeout=args.timeout)
    return 0
