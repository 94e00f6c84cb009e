"""Launch the structured-light pipeline of config/structured_light_pipeline.yaml, one
process per node.

For users with a full ROS 2 install
(`ros2 launch depth_nodes structured_light_pipeline.launch.py`). It reads the graph
description that `depth-nodes pipeline` and `depth-nodes process` run, through the
package's own ``depth_nodes.graph.launch_file``, so the three cannot drift apart. Launch
arguments (all optional): params_file, namespace, left, right, image and image_transport,
as in the stereo launch file. The speckle node's speckle_reference in its config is
relative to the repository root: from anywhere else, give it an absolute path there.
"""

from depth_nodes.graph.launch_file import launch_description


def generate_launch_description():
    return launch_description('structured_light_pipeline.yaml')
