"""`depth-nodes pipeline`: every node of a graph description composed into one process.

The nodes are the same classes the console scripts run, created from the YAML graph
description (names, namespaces, parameters, remappings; see ``depth_nodes.ros.graph``) and
spun by one multi-threaded executor. Each node keeps rclpy's default mutually exclusive
callback group, so a node handles one message at a time while different nodes run
concurrently (the numba kernels release the GIL). Messages between the nodes still travel
over the middleware, so the composed graph behaves as separate processes do, and external
tools (`depth-nodes param`, `play`, `record`) reach every node by its name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TextIO

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from depth_nodes.errors import ConfigError
from depth_nodes.ros.graph import create_nodes, load_graph_config, load_params_file


def run_pipeline(config_path: str | Path, *, params_file: str | Path | None = None,
                 threads: int | None = None, ros_args: list[str] | None = None,
                 log: TextIO | None = None) -> int:
    """Run the graph of ``config_path`` until Ctrl-C or SIGTERM.

    Args:
        config_path: The graph description (e.g. config/stereo_pipeline.yaml).
        params_file: A ROS 2 parameter file applied on top of the config's parameters.
        threads: Executor threads; default one per node (at least 2).
        ros_args: Extra ``--ros-args ...`` arguments (e.g. ``--log-level debug``).
        log: Where to announce the nodes once they are up.

    Returns:
        0 after a clean shutdown.

    Raises:
        ConfigError: Invalid config, parameter file or thread count.
    """
    config = load_graph_config(config_path)
    if not config.nodes:
        raise ConfigError(f'graph config {config_path} has no nodes')
    if threads is not None and threads < 1:
        raise ConfigError(f'--threads must be at least 1, got {threads}')
    context = Context()
    rclpy.init(args=['depth-nodes', *(ros_args or [])], context=context)
    nodes: list[Any] = []
    executor = None
    try:
        params = load_params_file(params_file) if params_file else {}
        nodes = create_nodes(config, params, context=context)
        executor = MultiThreadedExecutor(num_threads=threads or max(2, len(nodes)),
                                         context=context)
        for node in nodes:
            executor.add_node(node)
        if log is not None:
            names = ', '.join(n.get_fully_qualified_name() for n in nodes)
            log.write(f'pipeline {config.name}: {len(nodes)} nodes up ({names})\n')
            log.flush()
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0
