"""The `depth-nodes` command.

Subcommands: ``generate`` (synthetic bags), ``convert`` (a bag as a camera driver records
it), ``process`` (run nodes over a bag offline),
``pipeline`` (the nodes of a graph live, in one process), ``param`` (a running node's
parameters), ``play`` / ``record`` (bags into and out of a live graph), ``export-mesh``
(a processed bag's final mesh as PLY), ``reindex`` (a
recording cut off made a complete bag again), ``eval``
(accuracy against the ground truth in a bag, whatever its kind; ``eval-sl``, ``eval-tof``
and ``eval-depth-filter`` are aliases of it), ``bench`` (speed beside OpenCV),
``train-cost`` / ``train-confidence`` (the learned matching cost and confidence). A user error
prints one line and exits non-zero; never a traceback.

Each command is a module of this package with ``add_arguments(parser)`` and
``run(args) -> int``; :data:`COMMANDS` names them, and the parser follows from it.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import textwrap
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, cast

from depth_nodes.errors import DepthNodesError
from depth_nodes.nodes import NODE_PLUGINS
from depth_nodes.ros.dds import use_large_message_profile
from depth_nodes.ros.memory import keep_freed_memory
from depth_nodes.tools import signals
from depth_nodes.tools.cli.options import EXIT_ERROR, Parser

__all__ = ['COMMANDS', 'Command', 'build_parser', 'main']


@dataclass(frozen=True)
class Command:
    """A subcommand: its name, its line in ``depth-nodes --help``, and its module in this
    package (which has ``add_arguments(parser)`` and ``run(args) -> int``)."""

    name: str
    help: str
    module: str


COMMANDS = (
    Command('generate', 'write synthetic stereo bags with ground truth', 'generate'),
    Command('process', 'run the node graph over a bag, offline', 'process'),
    Command('convert', 'rewrite a bag as a camera driver records it (compressed, Bayer, '
            'another namespace)', 'convert'),
    Command('import-pair', 'a real image pair (and its ground truth) as a bag for process '
            'and eval', 'import_pair'),
    Command('import-views', 'real images with known cameras (Middlebury, COLMAP) as a bag '
            'for the multi-view node', 'import_views'),
    Command('pipeline', 'run every node of a graph in one process, live', 'pipeline'),
    Command('play', 'publish a bag into the live graph', 'play'),
    Command('record', 'record live topics into a bag', 'record'),
    Command('preview', 'a processed bag as a video: each frame the sheet of eval --previews',
            'preview'),
    Command('export-mesh', 'the final mesh of a processed bag (tsdf_fusion) as a PLY file',
            'export_mesh'),
    Command('reindex', 'make a recording cut off (killed, a full disk, a power loss) a '
            'complete bag again', 'reindex'),
    Command('param', "a running node's parameters (like ros2 param)", 'param'),
    Command('node', 'the nodes of the running graph (like ros2 node)', 'node'),
    Command('topic', 'the topics of the running graph (like ros2 topic)', 'topic'),
    Command('diag', "every node's diagnostics, refreshed: rate, processing time, drops by "
            'reason', 'diag'),
    Command('eval', 'accuracy of a processed bag against its ground truth, by the scorer '
            'its kind needs (stereo, structured light, time of flight, depth filter, '
            'multi-view)', 'evaluate'),
    Command('eval-sl', 'an alias of eval for structured-light bags', 'evaluate_sl'),
    Command('eval-tof', 'an alias of eval for time-of-flight bags', 'evaluate_tof'),
    Command('eval-depth-filter', 'an alias of eval for depth-filter bags',
            'evaluate_depth_filter'),
    Command('bench', 'speed figures beside OpenCV, measured in one run', 'bench'),
    Command('tune', "search sgm_stereo's settings on your own stereo bag, no ground truth "
            'needed; write them as a parameter file', 'tune'),
    Command('train-cost', "train the learned matching cost's feature network on simulated "
            'scenes (the train extra)', 'train_cost'),
    Command('train-confidence', "train cross_check's learned confidence on simulated scenes "
            '(the train extra)', 'train_confidence'),
)
_BY_NAME = {command.name: command for command in COMMANDS}


class CommandModule(Protocol):
    """What a command's module provides."""

    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def run(self, args: argparse.Namespace) -> int: ...


def load(command: Command) -> CommandModule:
    """Import ``command``'s module.

    The one import made inside a function, so that `depth-nodes --help` stays fast: a
    command's module imports its implementation at its top, and all of them together take
    about 2.5 s (measured: process 1.5 s, numba 0.7 s, ray 1.1 s) against 0.16 s for
    ``--help`` alone; so only the chosen command's module is imported.
    """
    return cast(CommandModule, importlib.import_module(f'{__name__}.{command.module}'))


def nodes_epilog() -> str:
    """The package's nodes, for the end of ``depth-nodes --help``."""
    names = textwrap.fill(', '.join(NODE_PLUGINS), width=86, initial_indent='  ',
                          subsequent_indent='  ')
    return f'nodes (run one with: ros2 run depth_nodes NAME, or NAME --help):\n{names}'


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser of the `depth-nodes` command.

    Args:
        commands: The commands whose arguments to add (only their modules are imported);
            the others are listed with their help only. Default: every command.
    """
    wanted = set(_BY_NAME if commands is None else commands)
    parser = Parser(prog='depth-nodes', description=(__doc__ or '').split('\n')[0],
                    epilog=nodes_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)
    for command in COMMANDS:
        command_parser = sub.add_parser(command.name, help=command.help)
        if command.name in wanted:
            module = load(command)
            module.add_arguments(command_parser)
            command_parser.set_defaults(run=module.run)
    return parser


def _command_name(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names: its first word that is not an option (the top level has
    no option that takes a value)."""
    return next((word for word in argv if not word.startswith('-')), None)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `depth-nodes`; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if '--ros-args' in argv:  # rclpy's arguments, for `pipeline`
        ros_args = argv[argv.index('--ros-args'):]
        argv = argv[:argv.index('--ros-args')]
    name = _command_name(argv)
    if name in _BY_NAME:  # before the command's module, and its implementation, load
        signals.install()  # SIGINT and SIGTERM, also when started in the background
        use_large_message_profile()  # before any rclpy.init: live commands move large messages
        keep_freed_memory()  # and without a page fault per 4 KiB of each (ros/memory.py)
    try:
        args, extras = build_parser([name] if name else []).parse_known_args(argv)
        if extras:  # said by the subcommand, as every other mistake is
            print(f'depth-nodes {args.command}: error: unrecognized arguments: '
                  f'{" ".join(extras)} (see depth-nodes {args.command} --help)',
                  file=sys.stderr)
            return EXIT_ERROR
        if ros_args and args.command != 'pipeline':
            print(f'depth-nodes {args.command}: error: --ros-args is only accepted by '
                  'pipeline', file=sys.stderr)
            return EXIT_ERROR
        args.ros_args = ros_args
        run: Callable[[argparse.Namespace], int] = args.run
        return int(run(args))
    except DepthNodesError as exc:
        message = ' '.join(str(exc).split())  # one line, whatever a library put in it
        print(f'depth-nodes {name}: error: {message}', file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:  # stopped by the user (SIGINT or SIGTERM): not a failure
        print(f'depth-nodes {name}: interrupted', file=sys.stderr)
        return 0
    except BrokenPipeError:  # `depth-nodes eval ... | head`: the reader has what it wanted
        # the interpreter's final flush of stdout would fail again: point it at nothing
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
