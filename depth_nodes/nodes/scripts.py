"""The nodes' console scripts, made from the registry (:mod:`depth_nodes.nodes.registry`).

setup.py declares ``<name> = depth_nodes.nodes.scripts:<name>`` for every registry name and
every image_pipeline executable name. pip's script wrappers run ``from
depth_nodes.nodes.scripts import <name>``, setuptools' (a colcon install space) look the
attribute up: both reach :func:`__getattr__` (PEP 562), which returns the ``main`` of that
script. An executable under image_pipeline's name starts the node under the default node
name upstream gives it, so a parameter file keyed by that name applies.

``python -m depth_nodes.nodes.scripts <name> [args]`` runs a script without installing the
package; ``<name>`` may also be a ``package.module:Class`` node plugin, as a graph
description allows (the live graph of processes, ``tools/live/processes.py``, starts every
node this way).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from depth_nodes.nodes.registry import NODES, NodeEntry, script_names
from depth_nodes.ros.node import DepthNode, run_node

#: Script name -> (its registry entry, the node name to start it under; None: the class's).
_SCRIPTS: dict[str, tuple[NodeEntry, str | None]] = {
    **{entry.name: (entry, None) for entry in NODES},
    **{entry.upstream.executable: (entry, entry.upstream.node_name) for entry in NODES
       if entry.upstream is not None},
}


def asks_for_help(argv: list[str]) -> bool:
    """Whether ``-h`` / ``--help`` comes before any ``--ros-args`` (as run_node reads it)."""
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    return '-h' in own or '--help' in own


def script(name: str) -> Callable[[list[str] | None], int]:
    """The ``main`` of console script ``name``: it runs the node until Ctrl-C and returns
    the exit status; ``--help`` prints the registry's summary, then the node module's notes.

    Raises:
        KeyError: No node script has that name.
    """
    entry, node_name = _SCRIPTS[name]

    def main(args: list[str] | None = None) -> int:
        argv = sys.argv[1:] if args is None else list(args)
        module_name, _, class_name = entry.target.partition(':')
        node_class = getattr(importlib.import_module(module_name), class_name)
        if asks_for_help(argv):
            upstream = '' if entry.upstream is None or node_name is None else (
                f' ({entry.upstream.package}\'s executable, node name {node_name})')
            print(f'{name}{upstream}: {entry.summary}\n')
        if node_name is None:
            return run_node(node_class, args)

        def make() -> DepthNode:
            return node_class(node_name)  # type: ignore[no-any-return]

        make.__name__ = class_name  # how run_node's errors name the node
        make.__module__ = module_name  # and whose notes its --help prints
        return run_node(make, args)

    main.__name__ = main.__qualname__ = name
    main.__module__ = __name__
    main.__doc__ = f'Console script ``{name}``: {entry.summary}.'
    return main


def __getattr__(name: str) -> Callable[[list[str] | None], int]:
    """The console script ``name`` (PEP 562: ``from depth_nodes.nodes.scripts import
    rectify``)."""
    try:
        return script(name)
    except KeyError:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}') from None


def __dir__() -> list[str]:
    return sorted([*globals(), *script_names()])


def plugin_main(target: str) -> Callable[[list[str] | None], int]:
    """The ``main`` of a node class given as ``package.module:Class`` (not in the registry).

    Raises:
        KeyError: ``target`` is not of that form, or names no class.
    """
    module_name, _, class_name = target.partition(':')
    try:
        node_class = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError, ValueError):
        raise KeyError(target) from None

    def main(args: list[str] | None = None) -> int:
        return run_node(node_class, args)

    return main


if __name__ == '__main__':
    try:
        chosen = sys.argv[1]
        main = script(chosen) if chosen in _SCRIPTS else plugin_main(chosen)
    except (IndexError, KeyError):
        print('usage: python -m depth_nodes.nodes.scripts SCRIPT|module:Class [--help | '
              f'--ros-args ...]\nscripts: {", ".join(script_names())}', file=sys.stderr)
        sys.exit(2)
    del sys.argv[0]  # the script's name in its place: rclpy and --help read sys.argv
    sys.exit(main(None))
