"""`depth-nodes pipeline`: every node of a graph description composed into one process.

The nodes are the same classes the console scripts run, created from the YAML graph
description (names, namespaces, parameters, remappings; see ``depth_nodes.graph.description``).
Each node is spun by its own single-threaded executor on its own thread, so a node handles
one message at a time while different nodes run concurrently (the numba kernels and
OpenCV release the GIL). Messages between the nodes still travel over the middleware, so
the composed graph behaves as separate processes do, and external tools (`depth-nodes
param`, `play`, `record`) reach every node by its name.

Why not one multi-threaded executor for all: rclpy's MultiThreadedExecutor keeps waking
for a subscription whose data is ready while its node's (mutually exclusive) callback is
still running on a worker, so its main thread spun at 75 - 81 % of a core holding the GIL,
and at 5 Hz the composed graph delivered 4 of 100 frames that five processes all delivered
(`depth-nodes bench live --composed`). A node's own executor only waits for its node, and
sleeps while that node works.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import rclpy
from rclpy.context import Context
from rclpy.executors import (
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import (
    GraphConfig,
    camera_readers,
    create_nodes,
    load_graph_config,
    load_params_file,
    unmatched_entries,
    unmatched_warning,
    with_transport,
)

#: Seconds each node's executor gets to finish its callback when the pipeline stops.
STOP_TIMEOUT_S = 10.0
#: Most executor threads `pipeline --threads` accepts (each node runs one callback at a
#: time, so more threads than callbacks only wait).
MAX_EXECUTOR_THREADS = 64


def user_remappings(ros_args: list[str]) -> list[tuple[str, str]]:
    """The ``-r FROM:=TO`` / ``--remap FROM:=TO`` rules of ``--ros-args`` that apply to every
    node (a ``node:FROM:=TO`` rule names its node and is left to rclpy)."""
    rules = []
    for flag, rule in itertools.pairwise(ros_args):
        if flag in ('-r', '--remap') and ':=' in rule:
            source, _, target = rule.partition(':=')
            if ':' not in source:
                rules.append((source, target))
    return rules


def _resolve(name: str, namespace: str) -> str:
    return name if name.startswith('/') else f'{namespace.rstrip("/")}/{name}'


def compose_remappings(config: GraphConfig, rules: list[tuple[str, str]]) -> GraphConfig:
    """The graph with the user's remapping rules applied after its own: a rule whose source
    is where a node's own remapping leads replaces that destination. (ROS applies only the
    first rule that matches a name, and a node's own rules come first, so a user's
    ``-r /stereo/left/image_raw:=/camera/left/image_raw`` never reached the rectifier's
    ``image``, which the graph remaps to ``image_raw``.)"""
    nodes = []
    for spec in config.nodes:
        remaps = {}
        for source, target in spec.remappings.items():
            resolved = _resolve(target, spec.namespace)
            for match, replacement in rules:
                if _resolve(match, spec.namespace) == resolved:
                    target = replacement
                    break
            remaps[source] = target
        nodes.append(dataclasses.replace(spec, remappings=remaps))
    return GraphConfig(config.name, nodes, config.source)


def run_pipeline(config_path: str | Path | GraphConfig, *,
                 params_file: str | Path | None = None, threads: int | None = None,
                 ros_args: list[str] | None = None, log: TextIO | None = None,
                 image_transport: str | None = None) -> int:
    """Run the graph of ``config_path`` until Ctrl-C or SIGTERM.

    Args:
        config_path: The graph description (e.g. config/stereo_pipeline.yaml), or the
            graph itself.
        params_file: A ROS 2 parameter file applied on top of the config's parameters.
        threads: Threads of each node's executor: by default (and with 1) one, the node
            handling one callback at a time; more only help a node whose callbacks may
            overlap (none of the package's do).
        ros_args: Extra ``--ros-args ...`` arguments (e.g. ``--log-level debug``); its
            remapping rules also apply after the graph's own (:func:`compose_remappings`).
        log: Where to announce the nodes once they are up.
        image_transport: How the nodes that read the camera's images take them (raw,
            compressed, compressedDepth; default raw).

    Returns:
        0 after a clean shutdown.

    Raises:
        ConfigError: Invalid config, parameter file or thread count.
    """
    config = config_path if isinstance(config_path, GraphConfig) else load_graph_config(
        config_path)
    if not config.nodes:
        raise ConfigError(f'graph config {config.source or config.name} has no nodes')
    config = compose_remappings(config, user_remappings(ros_args or []))
    params = load_params_file(params_file) if params_file else {}
    for key in unmatched_entries(config, params):
        print(f'depth-nodes pipeline: warning: {unmatched_warning(config, key)}',
              file=sys.stderr)
    if threads is not None and not 1 <= threads <= MAX_EXECUTOR_THREADS:
        raise ConfigError(f'--threads must be in 1..{MAX_EXECUTOR_THREADS}, got {threads}')
    context = Context()
    # rclpy installs no signal handler for a context of its own unless asked: without
    # one, SIGTERM killed the process (leaving its Fast DDS segment in /dev/shm) and a
    # background start ignored SIGINT. Its handlers wake the executors and shut them down.
    rclpy.init(args=['depth-nodes', *(ros_args or [])], context=context,
               signal_handler_options=SignalHandlerOptions.ALL)
    nodes: list[Any] = []
    executors: list[Any] = []
    spinners: list[threading.Thread] = []
    try:
        if image_transport is not None:
            params = with_transport(params, camera_readers(config), image_transport)
        nodes = create_nodes(config, params, context=context)
        for node in nodes:
            if threads is not None and threads > 1:
                executor: Any = MultiThreadedExecutor(num_threads=threads, context=context)
            else:
                executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            executors.append(executor)
            spinners.append(threading.Thread(target=_spin, args=(executor,), daemon=True,
                                             name=f'spin {node.get_fully_qualified_name()}'))
        for spinner in spinners:
            spinner.start()
        if log is not None:
            names = ', '.join(n.get_fully_qualified_name() for n in nodes)
            log.write(f'pipeline {config.name}: {len(nodes)} nodes up ({names})\n')
            log.flush()
        while context.ok() and all(t.is_alive() for t in spinners):
            time.sleep(0.1)  # the main thread only waits: signals are handled here
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        _stop(context, nodes, executors, spinners, log)
    return 0


def _stop(context: Context, nodes: list[Any], executors: list[Any],
          spinners: list[threading.Thread], log: TextIO | None) -> None:
    """Shut the context down, which wakes every executor and ends its spin, and only then
    tear the executors and nodes down. (Shutting an executor down from here while its
    thread still waited freed the guard condition it waited on: a segfault in about one
    stop in six.)"""
    try:
        try_shutdown(context=context)
    except Exception:  # rclpy's signal handler shut it down in between: fine
        if context.ok():
            raise
    for spinner in spinners:
        spinner.join(timeout=STOP_TIMEOUT_S)
    for node, executor, spinner in zip(nodes, executors, spinners, strict=False):
        if spinner.is_alive():  # stuck in a callback: leave it to the process exit
            if log is not None:
                log.write(f'pipeline: {node.get_fully_qualified_name()} did not stop within '
                          f'{STOP_TIMEOUT_S:g} s\n')
            continue
        executor.shutdown(timeout_sec=1)
        node.destroy_node()


def _spin(executor: Any) -> None:
    """One node's executor until the context shuts down (Ctrl-C, SIGTERM).

    A shutdown that lands while the executor builds its wait set raises rclpy's RCLError
    ("the given context is not valid") instead of ExternalShutdownException: that is the
    same stop, not an error (seen once in a test run, SIGTERM while frames flowed)."""
    with contextlib.suppress(ExternalShutdownException, KeyboardInterrupt):
        try:
            executor.spin()
        except RuntimeError:  # rclpy's RCLError
            if executor.context.ok():
                raise
