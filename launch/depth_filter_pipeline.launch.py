"""Launch the depth filter graph of config/depth_filter_pipeline.yaml (depth_filter, then
point_cloud_xyz on its output) on a depth camera driver's topics, one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes
depth_filter_pipeline.launch.py`). It reads the graph description that `depth-nodes
pipeline` and `depth-nodes process` run, through the package's own
``depth_nodes.graph.launch_file``. Launch arguments (all optional): namespace (the
driver's, e.g. /camera/camera for realsense-ros: the filter then reads
/camera/camera/depth/image_rect_raw and /camera/camera/depth/camera_info) and
params_file (config/depth_filter.yaml is one to start from: the stages, the noise model,
the pose source), e.g. `ros2 launch depth_nodes depth_filter_pipeline.launch.py
namespace:=/camera/camera params_file:=/path/to/depth_filter.yaml`.

camera:=NAME starts a camera preset of config/cameras instead (its graph, on its driver's
topics, with its settings), e.g. `ros2 launch depth_nodes depth_filter_pipeline.launch.py
camera:=orbbec_femto`.
"""

from depth_nodes.graph.launch_file import launch_description


def generate_launch_description():
    return launch_description('depth_filter_pipeline.yaml')
