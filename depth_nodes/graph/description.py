"""Graph descriptions: which nodes to run, with what names, namespaces and parameters.

One YAML format (:mod:`~depth_nodes.graph.schema`) describes a graph for every way the
package runs one: the offline bag harness (``depth-nodes process``), the composed live
pipeline (``depth-nodes pipeline``, :mod:`depth_nodes.tools.live.pipeline`), one process
per node (the launch files, :mod:`depth_nodes.graph.launching`; ``bench live``). This
module gathers the public names of the four modules that do the work, which is where
callers import them from:

* :mod:`~depth_nodes.graph.schema`: the YAML schema (:class:`NodeSpec`,
  :class:`GraphConfig`, :func:`load_graph_config`);
* :mod:`~depth_nodes.graph.cameras`: a graph moved to a camera driver's names
  (:func:`rename_cameras`, :func:`checked_name`, :func:`checked_namespace`);
* :mod:`~depth_nodes.graph.parameter_files`: ROS 2 parameter files matched to the nodes
  (:func:`load_params_file`, :func:`parameters_for`, :func:`unmatched_entries`, ...);
* :mod:`~depth_nodes.graph.factory`: the nodes created (:func:`create_nodes`,
  :func:`instantiate`, :func:`resolve_plugin`, :func:`camera_readers`,
  :func:`with_transport`).
"""

from depth_nodes.graph.cameras import (
    CAMERA_TOPICS,
    checked_name,
    checked_namespace,
    rename_cameras,
    root_namespace,
)
from depth_nodes.graph.factory import (
    camera_readers,
    create_nodes,
    instantiate,
    resolve_plugin,
    with_transport,
)
from depth_nodes.graph.parameter_files import (
    addressed_parameters,
    load_params_file,
    node_keys,
    parameters_for,
    unmatched_entries,
    unmatched_warning,
)
from depth_nodes.graph.schema import GraphConfig, NodeSpec, load_graph_config

__all__ = [
    'CAMERA_TOPICS',
    'GraphConfig',
    'NodeSpec',
    'addressed_parameters',
    'camera_readers',
    'checked_name',
    'checked_namespace',
    'create_nodes',
    'instantiate',
    'load_graph_config',
    'load_params_file',
    'node_keys',
    'parameters_for',
    'rename_cameras',
    'resolve_plugin',
    'root_namespace',
    'unmatched_entries',
    'unmatched_warning',
    'with_transport',
]
