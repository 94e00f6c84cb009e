"""The LaunchDescription of the package's launch files (``launch/*.launch.py``).

`launch`, `launch_ros` and `ament_index_python` come with a ROS install, not from PyPI:
only the launch files import this module, when `ros2 launch` runs them. What they start
is :func:`~depth_nodes.graph.launching.launch_nodes`'s, which runs without `launch`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription  # type: ignore[attr-defined,unused-ignore]
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from depth_nodes.graph.launching import LAUNCH_ARGUMENTS, launch_nodes


def launch_description(config_name: str) -> Any:
    """The LaunchDescription of a launch file that starts the graph
    ``config/<config_name>`` of the installed package, one process per node, with the
    launch arguments of :data:`~depth_nodes.graph.launching.LAUNCH_ARGUMENTS` (all
    optional)."""

    def nodes(context: Any, *args: Any, **kwargs: Any) -> list[Any]:
        config = Path(get_package_share_directory('depth_nodes')) / 'config' / config_name
        given = {name: LaunchConfiguration(name).perform(context) for name in LAUNCH_ARGUMENTS}
        return [Node(package='depth_nodes', output='screen', **node)
                for node in launch_nodes(config, **given)]

    arguments = [DeclareLaunchArgument(name, default_value='', description=text)
                 for name, text in LAUNCH_ARGUMENTS.items()]
    return LaunchDescription([*arguments, OpaqueFunction(function=nodes)])
