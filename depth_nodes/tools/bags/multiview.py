"""Multi-view bags: camera sequences from the simulator (depth_nodes.sim.sequence), written
with their poses and exact depth, and read back for scoring.

One moving camera (namespace ``/mvs``; one stamp per frame, the bag timestamp equals it):

==================  ==============================  =========================================
topic               type                            content
==================  ==============================  =========================================
/mvs/image_rect     sensor_msgs/Image mono8         the rectified grey image
/mvs/camera_info    sensor_msgs/CameraInfo          its pinhole camera (D zero, P = [K | 0])
/mvs/odom           nav_msgs/Odometry               the reported pose (pose noise included):
                                                    the camera optical frame in ``world``
/mvs/pose           geometry_msgs/PoseStamped       the same pose
/mvs/pose_gt        geometry_msgs/PoseStamped       the true pose
/mvs/depth_gt       sensor_msgs/Image 32FC1         exact Z, NaN where nothing is hit
==================  ==============================  =========================================

A rig (namespace ``/rig``): ``/rig/camN/image_rect``, ``/rig/camN/camera_info`` and
``/rig/camN/depth_gt`` per camera, the body's ``/rig/odom``, ``/rig/pose``,
``/rig/pose_gt``; and, for two-view stereo on the same views, the pair of the middle
camera (left) and the one to its right as ``/stereo/left`` and ``/stereo/right``
(``image_raw``, ``camera_info`` with the baseline in P, ``disparity_gt`` of the left view), so
`depth-nodes process` runs the stereo graph on the same bag and `depth-nodes eval` scores
both.

The simulator configuration is stored in the bag's metadata (``custom_data``, key
:data:`CONFIG_KEY`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim.sequence import SequenceConfig, SequenceView, rig_extrinsics, simulate_sequence
from depth_nodes.tools.bags.simulated import Frame, SimulatedBag, stamped_header

CONFIG_KEY = 'depth_nodes.sim.sequence'
WORLD = 'world'
STEREO = '/stereo'

#: The presets (320 x 240; `generate --size` makes them larger).
PRESETS: dict[str, SequenceConfig] = {
    'mvs_sideways': SequenceConfig(motion='sideways', n_frames=16),
    'mvs_forward': SequenceConfig(motion='forward', n_frames=16, step_m=0.02),
    'mvs_orbit': SequenceConfig(motion='orbit', n_frames=16, orbit_deg=1.0),
    'mvs_rig': SequenceConfig(motion='rig', n_frames=6, rig_cameras=3),
}
#: Those committed in bags/.
BUNDLED = ('mvs_sideways', 'mvs_rig')


def namespace(config: SequenceConfig) -> str:
    """The bag's namespace: ``/rig`` for a rig, else ``/mvs``."""
    return '/rig' if config.motion == 'rig' else '/mvs'


def camera_model(camera: Intrinsics, frame_id: str, tx: float = 0.0) -> CameraModel:
    """A rectified pinhole CameraModel (``tx``: P's -f B of a right stereo camera)."""
    k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    p = np.hstack([k, [[tx], [0.0], [0.0]]])
    return CameraModel(camera.width, camera.height, K=k, D=np.zeros(5), R=np.eye(3), P=p,
                       frame_id=frame_id)


def pose_message(pose: Pose, stamp_ns: int) -> PoseStamped:
    """``pose`` as a PoseStamped in the world frame."""
    msg = PoseStamped(header=stamped_header(stamp_ns, WORLD))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (
        float(v) for v in pose.position)
    q = pose.quaternion
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


def odometry_message(pose: Pose, stamp_ns: int, child: str) -> Odometry:
    """``pose`` as the Odometry a VIO publishes (``child``: the moving frame)."""
    msg = Odometry(header=stamped_header(stamp_ns, WORLD), child_frame_id=child)
    msg.pose.pose = pose_message(pose, stamp_ns).pose
    return msg


def view_messages(view: SequenceView, ns: str, frame_id: str) -> list[tuple[str, Any]]:
    """The image, camera_info and depth of one view under ``ns``."""
    h = stamped_header(view.stamp_ns, frame_id)
    return [(f'{ns}/image_rect', array_to_image(view.image, 'mono8', h)),
            (f'{ns}/camera_info', model_to_camera_info(camera_model(view.intrinsics, frame_id),
                                                       h)),
            (f'{ns}/depth_gt', array_to_image(view.depth, '32FC1', h))]


def _stereo_messages(left: SequenceView, right: SequenceView,
                     baseline: float) -> list[tuple[str, Any]]:
    """The stereo graph's inputs for the pair (left, right) of a rig step, with the left
    view's disparity ground truth."""
    camera = left.intrinsics
    out = []
    for side, view, tx in (('left', left, 0.0), ('right', right, -camera.fx * baseline)):
        frame = f'stereo_{side}_optical'
        h = stamped_header(view.stamp_ns, frame)
        out += [(f'{STEREO}/{side}/image_raw', array_to_image(view.image, 'mono8', h)),
                (f'{STEREO}/{side}/camera_info',
                 model_to_camera_info(camera_model(camera, frame, tx), h))]
    with np.errstate(divide='ignore', invalid='ignore'):
        disparity = (camera.fx * baseline / left.depth).astype(np.float32)
    header = stamped_header(left.stamp_ns, 'stereo_left_optical')
    out.append((f'{STEREO}/left/disparity_gt', array_to_image(disparity, '32FC1', header)))
    return out


def step_messages(config: SequenceConfig, views: list[SequenceView]) -> list[tuple[str, Any]]:
    """Every message of one time step (one view, or a rig's views)."""
    ns = namespace(config)
    stamp = views[0].stamp_ns
    out: list[tuple[str, Any]] = []
    if config.motion != 'rig':
        view = views[0]
        out += view_messages(view, ns, 'camera_optical')
        out += [(f'{ns}/odom', odometry_message(view.reported_pose, stamp, 'camera_optical')),
                (f'{ns}/pose', pose_message(view.reported_pose, stamp)),
                (f'{ns}/pose_gt', pose_message(view.pose, stamp))]
        return out
    for view in views:
        out += view_messages(view, f'{ns}/cam{view.camera}', f'cam{view.camera}_optical')
    reported = views[0].reported_pose.compose(rig_extrinsics(config)[0].inverse())
    out += [(f'{ns}/odom', odometry_message(reported, stamp, 'rig')),
            (f'{ns}/pose', pose_message(reported, stamp)),
            (f'{ns}/pose_gt', pose_message(views[0].body_pose, stamp))]
    middle = config.rig_cameras // 2
    if middle + 1 < len(views):
        out += _stereo_messages(views[middle], views[middle + 1], config.rig_baseline_m)
    return out


BAG: SimulatedBag[SequenceConfig] = SimulatedBag(
    CONFIG_KEY, 'a multi-view sequence bag', 'depth-nodes generate --preset mvs_*, then '
    'process', lambda doc: SequenceConfig(**doc).validate())


def write_sequence_bag(path: str | Path, config: SequenceConfig, *,
                       overwrite: bool = False) -> int:
    """Simulate ``config`` and write the bag at ``path``; returns the number of messages. A
    signal stops between whole time steps.

    Raises:
        ConfigError: An invalid configuration.
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    config.validate()
    return BAG.write(path, config, _steps(config), overwrite=overwrite)


def _steps(config: SequenceConfig) -> Iterator[Frame]:
    """One frame per time step: a view, or a rig's views (at the step's last stamp)."""
    per_step = config.rig_cameras if config.motion == 'rig' else 1
    step: list[SequenceView] = []
    for view in simulate_sequence(config):
        step.append(view)
        if len(step) == per_step:
            yield view.stamp_ns, step_messages(config, step)
            step = []


def config_from_metadata(custom_data: dict[str, str], path: str | Path) -> SequenceConfig:
    """The simulator configuration a sequence bag (or a bag processed from one) records.

    Raises:
        BagError: No such metadata, or it does not parse.
    """
    return BAG.config(custom_data, path)
