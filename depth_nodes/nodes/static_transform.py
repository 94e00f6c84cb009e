"""Static transform node: where a camera's optical frame sits on the robot, on /tf_static,
so a cloud shows in the right place in RViz or Foxglove.

Publishes one tf2_msgs/TFMessage, transient local (latched, as tf2_ros's static
broadcaster), with the transform ``parent_frame`` -> ``child_frame``: a translation
``x``, ``y``, ``z`` (m) and a rotation ``roll``, ``pitch``, ``yaw`` (rad, fixed axes) of the
camera body, and with ``optical`` (default true) the body-to-optical rotation after it
(REP 103: the optical frame has z forward, x right, y down), so ``child_frame`` is the
frame the camera driver stamps its images with (e.g. ``left_camera_optical_frame``).

tf2_msgs comes with every ROS 2 install but not with the PyPI wheels this package can
also run on: without it the node stops at start-up with a one-line error.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TransformStamped

from depth_nodes.core.geometry import camera_transform
from depth_nodes.errors import ConfigError
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import NodeParameters, ParamSpec
from depth_nodes.ros.poses import TF_STATIC_QOS, TFMessage

PARAMETERS = [
    ParamSpec('parent_frame', 'base_link', 'Frame the camera is mounted on', read_only=True),
    ParamSpec('child_frame', 'left_camera_optical_frame', 'The camera\'s frame (its images\' '
              'frame_id)', read_only=True),
    *(ParamSpec(axis, 0.0, f'Camera position {axis} in the parent frame, m', -1000.0, 1000.0,
                read_only=True) for axis in ('x', 'y', 'z')),
    *(ParamSpec(angle, 0.0, f'Camera body {angle} in the parent frame, rad (fixed axes)',
                -6.3, 6.3, read_only=True) for angle in ('roll', 'pitch', 'yaw')),
    ParamSpec('optical', True, 'child_frame is an optical frame (z forward, x right, y down): '
              'add the body-to-optical rotation', read_only=True),
]

def transform(values: Any, stamp: Any) -> TransformStamped:
    """The TransformStamped of a parameter snapshot."""
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = values['parent_frame']
    msg.child_frame_id = values['child_frame']
    (x, y, z), (qx, qy, qz, qw) = camera_transform(
        values['x'], values['y'], values['z'], values['roll'], values['pitch'], values['yaw'],
        optical=values['optical'])
    msg.transform.translation.x, msg.transform.translation.y = x, y
    msg.transform.translation.z = z
    msg.transform.rotation.x, msg.transform.rotation.y = qx, qy
    msg.transform.rotation.z, msg.transform.rotation.w = qz, qw
    return msg


class StaticTransformNode(DepthNode):
    """Latches one transform on /tf_static."""

    def __init__(self, node_name: str = 'static_transform', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        values = self.params.values
        if values['parent_frame'] == values['child_frame'] or not values['child_frame']:
            raise ConfigError('static_transform: parent_frame and child_frame must be two '
                              f'different names, got {values["parent_frame"]!r} and '
                              f'{values["child_frame"]!r}')
        if TFMessage is None:
            raise ConfigError('static_transform needs tf2_msgs, which every ROS 2 install '
                              'has and the PyPI wheels do not: run it on a ROS 2 install, or '
                              'use tf2_ros\'s static_transform_publisher')
        self.message = TFMessage(transforms=[transform(values,
                                                       self.get_clock().now().to_msg())])
        self.add_output(TFMessage, '/tf_static', qos=TF_STATIC_QOS).publish(self.message)
