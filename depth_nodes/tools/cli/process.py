"""`depth-nodes process`: run the node graph over a bag, offline."""

from __future__ import annotations

import argparse
import os
import sys

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.graph.description import (
    GraphConfig,
    load_params_file,
    unmatched_entries,
    unmatched_warning,
)
from depth_nodes.tools import signals
from depth_nodes.tools.bags.process import process_bag, select_nodes
from depth_nodes.tools.cli.graph import add_camera_arguments, add_graph_arguments, load_graph


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `process`."""
    parser.add_argument('in_bag')
    parser.add_argument('out_bag')
    add_graph_arguments(parser)
    parser.add_argument('--nodes', nargs='+', help='run only these nodes of the graph')
    parser.add_argument('--force', action='store_true', help='replace an existing OUT_BAG')
    parser.add_argument('--workers', type=int, default=1, metavar='N',
                        help='copies of the graph processing segments of the bag at once, '
                        'each in its own (spawned) process; the output is the same as with '
                        'one (default 1)')
    parser.add_argument('--ray', action='store_true',
                        help='run the workers as Ray actors on a local Ray cluster started '
                        'for the run')
    parser.add_argument('--ray-address', metavar='ADDRESS',
                        help='run the workers on the existing Ray cluster at ADDRESS (e.g. '
                        'ray://head:10001 or auto); its machines need depth_nodes installed '
                        'and the bag at the same path')
    add_camera_arguments(parser, auto=True)


def run(args: argparse.Namespace) -> int:
    """Process the bag; print what each node published."""
    # Offline processing needs no network: keep DDS discovery off unless told otherwise
    # (read when rclpy starts its context, and by the worker processes).
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')
    if args.workers < 1:
        raise ConfigError(f'--workers must be at least 1, got {args.workers}')
    config = select_nodes(load_graph(args), args.nodes)
    warn_unmatched(config, args.params)
    with signals.graceful():
        report = process_bag(args.in_bag, args.out_bag, config=config,
                             params_file=args.params, overwrite=args.force,
                             progress=sys.stderr, image_transport=args.image_transport,
                             workers=args.workers, ray=args.ray or bool(args.ray_address),
                             ray_address=args.ray_address)
    print(f'{args.in_bag} -> {args.out_bag} (graph {config.name})')
    print(report.format())
    print(report.summary())
    if report.interrupted:
        print(f'depth-nodes process: interrupted after {report.done} of {report.total} '
              f'messages; {args.out_bag} holds what was done', file=sys.stderr)
    elif not report.published:
        raise BagError(f'{report.nothing_published()}; {args.out_bag} was removed')
    return 0


def warn_unmatched(config: GraphConfig, params_file: str | None) -> None:
    """Say at once which entries of the parameter file address no node of the graph."""
    if params_file:
        for key in unmatched_entries(config, load_params_file(params_file)):
            print(f'depth-nodes process: warning: {unmatched_warning(config, key)}',
                  file=sys.stderr)
