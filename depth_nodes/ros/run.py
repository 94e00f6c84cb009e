"""Running one node as a process: the body of every node's console script ``main``."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.utilities import ok, try_shutdown

from depth_nodes.errors import DepthNodesError
from depth_nodes.ros.dds import use_large_message_profile
from depth_nodes.ros.memory import keep_freed_memory


def run_node(node_class: Callable[[], Node], args: list[str] | None = None) -> int:
    """Run one node until Ctrl-C: the body of every node's console script ``main``.

    ``-h`` / ``--help`` before any ``--ros-args`` prints the node's module notes (topics,
    parameters, drop reasons) instead.

    Returns:
        The process exit status: 0, or 1 when the node could not start (bad parameters).
    """
    argv = sys.argv[1:] if args is None else list(args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    name = node_class.__name__
    if '-h' in own or '--help' in own:
        doc = sys.modules[node_class.__module__].__doc__ or ''
        try:
            print(f'{doc.strip()}\n\nusage: {Path(sys.argv[0]).name} [--ros-args -p '
                  'NAME:=VALUE -r FROM:=TO --params-file FILE ...]\n(ros2 param list / '
                  'describe on the running node, or depth-nodes param, show every parameter)')
            sys.stdout.flush()
        except BrokenPipeError:  # `| head`: the reader has what it wanted
            sys.stdout = open(os.devnull, 'w')  # noqa: SIM115 (stays open until exit)
        return 0
    use_large_message_profile()
    keep_freed_memory()
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rclpy's UnknownROSArgsError, RCLError: bad --ros-args
        print(f'{name}: error: bad --ros-args: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 1
    node = None
    try:
        node = node_class()
        rclpy.spin(node)
    except DepthNodesError as exc:
        print(f'{name}: error: {exc}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        try:
            try_shutdown()
        except Exception:  # rclpy's signal handler shut the context down meanwhile: fine
            if ok():
                raise
    return 0
