"""Launch the structured-light pipeline of config/structured_light_pipeline.yaml, one
process per node.

For users with a full ROS 2 install
(`ros2 launch depth_nodes structured_light_pipeline.launch.py`). Like the stereo launch
file, it reads the graph description `depth-nodes pipeline` and `depth-nodes process` run,
so they cannot drift apart. The speckle node's speckle_reference in that file is relative
to the repository root: from anywhere else, give it an absolute path in the config.
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('depth_nodes')
    with open(os.path.join(share, 'config', 'structured_light_pipeline.yaml')) as stream:
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
