"""`depth-nodes eval-depth-filter`: an alias of `eval` for depth-filter bags (the depth
filter against the simulator's exact depth, stage by stage, beside librealsense's
filters)."""

from __future__ import annotations

import argparse

from depth_nodes.tools.cli import evaluate
from depth_nodes.tools.evaluation.kinds import DEPTH_FILTER


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options `eval` takes for a depth-filter bag."""
    parser.description = ('An alias of `depth-nodes eval` for a depth-filter bag (written by '
                          'generate --preset depth_*, or processed from one with '
                          'config/depth_filter_pipeline.yaml: its filtered depth is scored '
                          'too): eval tells the kind by itself.')
    evaluate.add_options(parser, DEPTH_FILTER)


def run(args: argparse.Namespace) -> int:
    """Print the tables (a signal stops between stages)."""
    return evaluate.run_kind(DEPTH_FILTER, args)
