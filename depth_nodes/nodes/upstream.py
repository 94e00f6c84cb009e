"""The console scripts under image_pipeline's executable names
(:data:`~depth_nodes.nodes.UPSTREAM_EXECUTABLES`): each starts the node here under the
default node name upstream gives it, so a parameter file keyed by that name applies."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from depth_nodes.nodes import NODE_PLUGINS, UPSTREAM_EXECUTABLES
from depth_nodes.ros.node import DepthNode, run_node


def _runner(executable: str) -> Callable[[list[str] | None], None]:
    _, plugin, node_name = UPSTREAM_EXECUTABLES[executable]

    def main(args: list[str] | None = None) -> None:
        module, _, cls = NODE_PLUGINS[plugin].partition(':')
        node_class = getattr(importlib.import_module(module), cls)

        def make() -> DepthNode:
            return node_class(node_name)  # type: ignore[no-any-return]

        make.__name__ = cls  # how run_node's errors name the node
        make.__module__ = module  # and whose notes its --help prints
        sys.exit(run_node(make, args))

    main.__name__ = executable
    main.__doc__ = f'Console script ``{executable}``: the {plugin} node named {node_name}.'
    return main


rectify_node = _runner('rectify_node')
disparity_node = _runner('disparity_node')
point_cloud_node = _runner('point_cloud_node')
convert_metric_node = _runner('convert_metric_node')
point_cloud_xyz_node = _runner('point_cloud_xyz_node')
point_cloud_xyzrgb_node = _runner('point_cloud_xyzrgb_node')
register_node = _runner('register_node')
depth_disparity_node = _runner('depth_disparity_node')
