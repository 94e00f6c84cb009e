"""Launch the stereo pipeline of config/stereo_pipeline.yaml, one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes stereo_pipeline.launch.py`). It reads
the graph description that `depth-nodes pipeline` and `depth-nodes process` run, through
the package's own ``depth_nodes.graph.launching``, so the three cannot drift apart. Launch
arguments (all optional): params_file (a stereo_image_proc parameter file works unchanged),
namespace, left, right, image (a camera driver's names) and image_transport, e.g.
`ros2 launch depth_nodes stereo_pipeline.launch.py namespace:=/camera image_transport:=compressed
params_file:=/path/to/disparity_params.yaml`.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from depth_nodes.graph.launching import LAUNCH_ARGUMENTS, launch_nodes


def _nodes(context, *args, **kwargs):
    config = os.path.join(get_package_share_directory('depth_nodes'), 'config',
                          'stereo_pipeline.yaml')
    given = {name: LaunchConfiguration(name).perform(context) for name in LAUNCH_ARGUMENTS}
    return [Node(package='depth_nodes', output='screen', **node)
            for node in launch_nodes(config, **given)]


def generate_launch_description():
    arguments = [DeclareLaunchArgument(name, default_value='', description=text)
                 for name, text in LAUNCH_ARGUMENTS.items()]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes)])
