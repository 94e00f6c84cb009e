"""One thin module per node: subscribe, convert, call core, publish.

The registry (:mod:`depth_nodes.nodes.registry`) has one entry per node; the tables here
follow from it. Strings, so that reading them imports no node.
"""

from depth_nodes.nodes.registry import NODES

#: Plugin name -> ``module:Class``: graph descriptions (``plugin: rectify``), the composed
#: pipeline and the launch files find a node's class here, by the name that is also its
#: console script (``ros2 run depth_nodes <name>``).
NODE_PLUGINS: dict[str, str] = {entry.name: entry.target for entry in NODES}

#: Executables under image_pipeline's names, so that a launch file written for image_proc,
#: stereo_image_proc or depth_image_proc runs these nodes when only its ``package`` is
#: changed: executable -> (upstream package, plugin here, the node's default name there).
UPSTREAM_EXECUTABLES: dict[str, tuple[str, str, str]] = {
    entry.upstream.executable: (entry.upstream.package, entry.name, entry.upstream.node_name)
    for entry in NODES if entry.upstream is not None}
