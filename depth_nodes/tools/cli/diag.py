"""`depth-nodes diag`: every node's diagnostics, refreshed."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from depth_nodes.tools import signals
from depth_nodes.tools.live.introspect import diagnostics_view


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `diag`."""
    parser.add_argument('--period', type=float, default=2.0, metavar='SECONDS',
                        help='refresh every SECONDS (default 2)')
    parser.add_argument('--once', action='store_true', help='print one table and stop')
    parser.add_argument('--timeout', type=float, default=10.0, metavar='SECONDS',
                        help='--once: wait this long for the first diagnostics (default 10)')


def _clear() -> None:
    sys.stdout.write('\x1b[H\x1b[2J')


def run(args: argparse.Namespace) -> int:
    """Print the table every period (on a terminal, in place) until a signal."""
    clear: Callable[[], None] | None = (
        _clear if sys.stdout.isatty() and not args.once else None)
    with signals.graceful():
        diagnostics_view(period=args.period, once=args.once, timeout=args.timeout,
                         clear=clear)
    return 0
