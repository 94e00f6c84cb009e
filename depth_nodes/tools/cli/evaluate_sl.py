"""`depth-nodes eval-sl`: structured-light figures beside OpenCV GrayCodePattern."""

from __future__ import annotations

import argparse

from depth_nodes.tools.evaluation.structured_light import evaluate_structured_light_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `eval-sl`."""
    parser.add_argument('bag', help='a bag written by generate --preset structured_light_vga')
    parser.add_argument('--no-opencv', action='store_true',
                        help='skip OpenCV (its per-pixel API is slow)')


def run(args: argparse.Namespace) -> int:
    """Print the figures."""
    print(evaluate_structured_light_bag(args.bag, opencv=not args.no_opencv).format())
    return 0
