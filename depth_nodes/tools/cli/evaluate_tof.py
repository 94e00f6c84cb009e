"""`depth-nodes eval-tof`: time-of-flight depth against the simulator's ground truth."""

from __future__ import annotations

import argparse

from depth_nodes.tools.evaluation.tof import evaluate_tof_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `eval-tof`."""
    parser.add_argument('bag', help='a bag processed from generate --preset tof_vga with '
                        'config/tof_pipeline.yaml')
    parser.add_argument('--depth-topic', default='/tof/depth/image_rect',
                        help='the depth to score (default /tof/depth/image_rect)')


def run(args: argparse.Namespace) -> int:
    """Print the scores."""
    print(evaluate_tof_bag(args.bag, depth_topic=args.depth_topic).format())
    return 0
