"""`depth-nodes eval-tof`: an alias of `eval` for time-of-flight bags (depth against the
simulator's ground truth)."""

from __future__ import annotations

import argparse

from depth_nodes.tools.cli import evaluate
from depth_nodes.tools.evaluation.kinds import TOF


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options `eval` takes for a time-of-flight bag."""
    parser.description = ('An alias of `depth-nodes eval` for a time-of-flight bag (processed '
                          'from generate --preset tof_vga with config/tof_pipeline.yaml): '
                          'eval tells the kind by itself.')
    evaluate.add_options(parser, TOF)


def run(args: argparse.Namespace) -> int:
    """Print the scores."""
    return evaluate.run_kind(TOF, args)
