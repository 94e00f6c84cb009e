"""Launch the fusion graph of config/fusion_pipeline.yaml (depth_filter, then tsdf_fusion
on its output) on a depth camera driver's topics, one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes fusion_pipeline.launch.py`).
It reads the graph description that `depth-nodes pipeline` and `depth-nodes process` run,
through the package's own ``depth_nodes.graph.launch_file``. Launch arguments (all
optional): namespace (the driver's, e.g. /camera/camera for realsense-ros) and params_file
(the voxel size and the other tsdf_fusion parameters, docs/fusion.md), e.g. `ros2 launch
depth_nodes fusion_pipeline.launch.py namespace:=/camera/camera
params_file:=/path/to/fusion.yaml`.
"""

from depth_nodes.graph.launch_file import launch_description


def generate_launch_description():
    return launch_description('fusion_pipeline.yaml')
