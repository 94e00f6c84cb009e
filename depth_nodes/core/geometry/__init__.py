"""The package's one geometry (no ROS): rigid poses, rotations, transforms over time, the
pinhole camera, and forward splatting.

* :mod:`.rotation`: quaternions, roll / pitch / yaw, rotation matrices and the one check of
  a rotation (:func:`check_rotation`, :data:`ROTATION_TOLERANCE`);
* :mod:`.pose`: :class:`Pose`, a frame in its parent, and the :data:`Motion` between two;
* :mod:`.timed`: poses over time (:class:`PoseHistory`, wild poses held back) and the tf
  tree (:class:`TransformTree`), looked up at a stamp;
* :mod:`.pinhole`: :class:`Intrinsics`, a rectified camera at one image size;
* :mod:`.splat`: :func:`splat`, a depth image's points moved into another camera with a
  z-buffer, the footprint a parameter.

Every node that needs a pose, a transform, a projection or a warp takes it from here; the
ROS side (subscriptions, tf messages, waiting for a pose) is :mod:`depth_nodes.ros.poses`.
"""

from depth_nodes.core.geometry.pinhole import Intrinsics, intrinsics
from depth_nodes.core.geometry.pose import Motion, Pose
from depth_nodes.core.geometry.rotation import (
    OPTICAL_RPY,
    ROTATION_TOLERANCE,
    Quaternion,
    camera_transform,
    check_rotation,
    quaternion_from_rpy,
    quaternion_multiply,
    quaternion_of,
    rotation_error,
    rotation_from_vector,
    rotation_matrix,
    rotation_vector,
)
from depth_nodes.core.geometry.splat import FOOTPRINTS, Splat, splat
from depth_nodes.core.geometry.timed import Added, PoseHistory, PoseMiss, TransformTree

__all__ = ['FOOTPRINTS', 'OPTICAL_RPY', 'ROTATION_TOLERANCE', 'Added', 'Intrinsics', 'Motion',
           'Pose', 'PoseHistory', 'PoseMiss', 'Quaternion', 'Splat', 'TransformTree',
           'camera_transform', 'check_rotation', 'intrinsics', 'quaternion_from_rpy',
           'quaternion_multiply', 'quaternion_of', 'rotation_error', 'rotation_from_vector',
           'rotation_matrix', 'rotation_vector', 'splat']
