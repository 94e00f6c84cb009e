"""`depth-nodes eval-sl`: an alias of `eval` for structured-light bags (figures beside OpenCV
GrayCodePattern)."""

from __future__ import annotations

import argparse

from depth_nodes.tools.cli import evaluate
from depth_nodes.tools.evaluation.kinds import STRUCTURED_LIGHT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options `eval` takes for a structured-light bag."""
    parser.description = ('An alias of `depth-nodes eval` for a structured-light bag (a bag '
                          'written by generate --preset structured_light_vga): eval tells '
                          'the kind by itself.')
    evaluate.add_options(parser, STRUCTURED_LIGHT)


def run(args: argparse.Namespace) -> int:
    """Print the figures."""
    return evaluate.run_kind(STRUCTURED_LIGHT, args)
