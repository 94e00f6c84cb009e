"""Launch the multi-view graph of config/multiview_pipeline.yaml (one moving camera with
poses), one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes multiview_pipeline.launch.py`).
It reads the graph description that `depth-nodes pipeline` and `depth-nodes process` run,
through the package's own ``depth_nodes.graph.launch_file``. Launch arguments (all
optional): params_file (e.g. pose_source, min_depth, max_depth for your scene), namespace
(a camera driver's, e.g. /camera: the node then reads /camera/image_rect,
/camera/camera_info and /camera/odom) and image_transport, e.g.
`ros2 launch depth_nodes multiview_pipeline.launch.py namespace:=/camera
params_file:=/path/to/multiview_params.yaml`.
"""

from depth_nodes.graph.launch_file import launch_description


def generate_launch_description():
    return launch_description('multiview_pipeline.yaml')
