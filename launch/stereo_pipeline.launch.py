"""Launch the stereo pipeline of config/stereo_pipeline.yaml, one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes stereo_pipeline.launch.py`).
It reads the same graph description that `depth-nodes process` runs offline, so the two
cannot drift apart: each node's console script is named like its plugin.
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('depth_nodes')
    with open(os.path.join(share, 'config', 'stereo_pipeline.yaml')) as stream:
        graph = yaml.safe_load(stream)['graph']
    nodes = [
        Node(
            package='depth_nodes',
            executable=spec['plugin'],
            name=spec['name'],
            namespace=spec.get('namespace', '/'),
            parameters=[spec.get('parameters') or {}],
            remappings=list((spec.get('remappings') or {}).items()),
            output='screen',
        )
        for spec in graph.get('nodes') or []
    ]
    return LaunchDescription(nodes)
