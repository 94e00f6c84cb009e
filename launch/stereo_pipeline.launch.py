"""Launch the stereo pipeline of config/stereo_pipeline.yaml, one process per node.

For users with a full ROS 2 install (`ros2 launch depth_nodes stereo_pipeline.launch.py`). It reads
the graph description that `depth-nodes pipeline` and `depth-nodes process` run, through
the package's own ``depth_nodes.graph.launch_file``, so the three cannot drift apart. Launch
arguments (all optional): params_file (a stereo_image_proc parameter file works unchanged),
namespace, left, right, image (a camera driver's names) and image_transport, e.g.
`ros2 launch depth_nodes stereo_pipeline.launch.py namespace:=/camera image_transport:=compressed
params_file:=/path/to/disparity_params.yaml`.

camera:=NAME starts a camera preset of config/cameras instead (its graph, on its driver's
topics, with its settings), e.g. `ros2 launch depth_nodes stereo_pipeline.launch.py
camera:=realsense_d435`.
"""

from depth_nodes.graph.launch_file import launch_description


def generate_launch_description():
    return launch_description('stereo_pipeline.yaml')
