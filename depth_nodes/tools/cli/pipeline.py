"""`depth-nodes pipeline`: every node of a graph in one process, live."""

from __future__ import annotations

import argparse
import sys

from depth_nodes.tools.cli.graph import add_camera_arguments, add_graph_arguments, load_graph
from depth_nodes.tools.live.pipeline import run_pipeline


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `pipeline`."""
    parser.epilog = ('Anything after --ros-args goes to rclpy (e.g. --ros-args --log-level '
                     'debug).')
    add_graph_arguments(parser)
    parser.add_argument('--threads', type=int,
                        help='threads of each node\'s executor (default 1: a node handles one '
                        'callback at a time, the nodes run beside each other)')
    add_camera_arguments(parser, auto=False)


def run(args: argparse.Namespace) -> int:
    """Run the graph until Ctrl-C or SIGTERM."""
    return run_pipeline(load_graph(args), params_file=args.params, threads=args.threads,
                        ros_args=args.ros_args, log=sys.stdout,
                        image_transport=args.image_transport)
