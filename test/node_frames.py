"""Valid frames for every inputs kind of the node registry, shared by the tests that feed
every node (test/nodes/test_fuzz_nodes.py, test/nodes/test_hostile_inputs.py).

:data:`KINDS` maps each kind of ``depth_nodes.nodes.registry.INPUT_KINDS`` to a
:class:`Kind`: the valid messages of a frame, by input topic suffix, built from small
simulated scenes (64 x 48: a stereo frame, the disparities the matcher makes of it, its
depth, a time-of-flight correlation frame, a phase-shift pattern sequence). A node whose
kind has no entry here fails those tests: adding a node of a new kind is one entry of
:data:`KINDS` (and, when the defaults do not fit 64 x 48 images, one of
:data:`PARAMETERS`).

``pytest.ini`` puts this folder on ``sys.path``: ``from node_frames import KINDS``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from helpers import Lazy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import header
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.structured_light import PatternSet, generate_patterns
from depth_nodes.graph.description import resolve_plugin
from depth_nodes.nodes.registry import NodeEntry
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.sim.projector import ProjectorCameraSim, ProjectorSimConfig
from depth_nodes.sim.tof import ToFSimConfig, simulate_tof

W, H, RANGE = 64, 48, 16
#: Nanoseconds between the steps of one frame (the images of a pattern sequence).
STEP_NS = 1_000_000

FRAME = Lazy(lambda: next(simulate_stereo(StereoSimConfig(
    width=W, height=H, n_frames=1, seed=9, distortion_scale=0.0, rotation_deg=0.0,
    noise_sigma=1.0, focal_px=60.0))))
MATCH = Lazy(lambda: SgmMatcher(SgmParams(disparity_range=RANGE, paths=5)).match(
    FRAME.left_rect_gt, FRAME.right_rect_gt))
TOF = Lazy(lambda: next(simulate_tof(ToFSimConfig(
    width=W, height=H, focal_px=50.0, supersample=1, emitter_step=8, multipath=False,
    n_frames=1))))
#: The phase-shift sequence the structured-light node decodes (:data:`PARAMETERS`).
PATTERNS = PatternSet('phase', W, H, steps=4, period=8.0)
SEQUENCE = Lazy(lambda: ProjectorCameraSim(ProjectorSimConfig(
    width=W, height=H, focal_px=56.0, projector_width=W, projector_height=H,
    projector_focal_px=50.0, supersample=1, seed=4)).capture(generate_patterns(PATTERNS)))
DISPARITY_COMMON = {'focal': 60.0, 'baseline': 0.1, 'min_disparity': 0.0,
                    'max_disparity': RANGE - 1.0, 'delta_d': 1 / 32}


def info(model: Any, stamp: int) -> CameraInfo:
    """A camera's CameraInfo at ``stamp`` (ns)."""
    return model_to_camera_info(model, header(stamp))


def image(pixels: Any, encoding: str, stamp: int) -> Image:
    """An Image of ``pixels`` at ``stamp`` (ns)."""
    return array_to_image(np.ascontiguousarray(pixels), encoding, header(stamp))


def disparity(values: Any, stamp: int) -> Any:
    """A DisparityImage of the matcher's ``values`` at ``stamp`` (ns)."""
    return build_disparity(values, header(stamp), **DISPARITY_COMMON)


def depth(stamp: int) -> Image:
    """The left view's depth, 32FC1 metres (NaN where the scene has none)."""
    return image(FRAME.depth_gt.astype(np.float32), '32FC1', stamp)


def millimetres(stamp: int) -> Image:
    """The left view's depth, 16UC1 millimetres (0 where the scene has none)."""
    mm = np.nan_to_num(FRAME.depth_gt * 1000.0, nan=0.0, posinf=0.0)
    return image(np.clip(mm, 0, 65535).astype(np.uint16), '16UC1', stamp)


def correlation(stamp: int) -> Image:
    """The time-of-flight correlation frame, its sample planes stacked as rows (16UC1)."""
    planes = TOF.samples
    return image(planes.reshape(-1, planes.shape[-1]), '16UC1', stamp)


def pattern_step(stamp: int, step: int) -> dict[str, Any]:
    """Image ``step`` of the phase-shift sequence, tagged ``<second>:<step>/<count>``; the
    projector's calibration first (the node uses the latest one, as a latched topic's)."""
    return {'projector/camera_info': info(SEQUENCE.projector, stamp),
            'image': image(SEQUENCE.images[step], 'mono8', stamp),
            'camera_info': info(SEQUENCE.camera, stamp),
            'pattern': header(stamp, f'{stamp // 10**9}:{step}/{PATTERNS.count}')}


def odometry(stamp: int) -> Odometry:
    """A camera moving sideways at 0.5 m/s (5 cm between two frames 0.1 s apart)."""
    msg = Odometry(header=header(stamp, 'world'), child_frame_id='camera')
    msg.pose.pose.position.x = 0.5 * stamp / 1e9
    msg.pose.pose.orientation.w = 1.0
    return msg


@dataclass(frozen=True)
class Kind:
    """An inputs kind of the registry: the valid messages of a frame.

    Attributes:
        step: ``(stamp ns, step index) -> {input topic suffix: message}``, the messages of
            one step of a frame.
        output: The output topic (resolved) every frame gives.
        steps: Steps that make one frame: the images of a pattern sequence; 1 for most.
    """

    step: Callable[[int, int], dict[str, Any]]
    output: str
    steps: int = 1

    def frame(self, stamp: int) -> list[dict[str, Any]]:
        """The steps of one frame, the first at ``stamp``, :data:`STEP_NS` apart."""
        return [self.step(stamp + k * STEP_NS, k) for k in range(self.steps)]


KINDS = {
    'camera': Kind(lambda t, _: {
        'image': image(FRAME.left_raw, 'mono8', t),
        'camera_info': info(FRAME.left_camera, t)}, '/image_rect'),
    'stereo_rect': Kind(lambda t, _: {
        'left/image_rect': image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': info(FRAME.left_camera, t),
        'right/image_rect': image(FRAME.right_rect_gt, 'mono8', t),
        'right/camera_info': info(FRAME.right_camera, t)}, '/disparity'),
    'disparity_pair': Kind(lambda t, _: {
        'disparity': disparity(MATCH.disparity, t),
        'disparity_right': disparity(MATCH.disparity_right, t),
        'cost_ratio': image(MATCH.cost_ratio, '32FC1', t)}, '/disparity_checked'),
    'stereo_disparity': Kind(lambda t, _: {
        'disparity': disparity(MATCH.disparity, t),
        'left/image_rect_color': image(FRAME.left_rect_gt, 'mono8', t),
        'left/camera_info': info(FRAME.left_camera, t),
        'right/camera_info': info(FRAME.right_camera, t),
        'confidence': image(np.full((H, W), 0.5, np.float32), '32FC1', t)}, '/points2'),
    'pattern_sequence': Kind(pattern_step, '/depth', steps=PATTERNS.count),
    'depth': Kind(lambda t, _: {
        'image_rect': depth(t),
        'camera_info': info(FRAME.left_camera, t)}, '/points'),
    'depth_colour': Kind(lambda t, _: {
        'depth_registered/image_rect': depth(t),
        'rgb/image_rect_color': image(FRAME.left_rect_gt, 'mono8', t),
        'rgb/camera_info': info(FRAME.left_camera, t)}, '/points'),
    'depth_two_cameras': Kind(lambda t, _: {
        'depth/image_rect': millimetres(t),
        'depth/camera_info': info(FRAME.left_camera, t),
        'rgb/camera_info': info(FRAME.right_camera, t)}, '/depth_registered/image_rect'),
    'depth_raw': Kind(lambda t, _: {'image_raw': millimetres(t)}, '/image'),
    'depth_stereo': Kind(lambda t, _: {
        'left/image_rect': depth(t),
        'right/camera_info': info(FRAME.right_camera, t)}, '/left/disparity'),
    'tof_correlation': Kind(lambda t, _: {
        'correlation/image_raw': correlation(t),
        'camera_info': info(TOF.camera, t)}, '/depth/image_rect'),
    'posed_camera': Kind(lambda t, _: {
        'image_rect': image(FRAME.left_rect_gt, 'mono8', t),
        'camera_info': info(FRAME.left_camera, t),
        'odom': odometry(t)}, '/depth'),
    'posed_depth': Kind(lambda t, _: {
        'image_rect': depth(t),
        'camera_info': info(FRAME.left_camera, t),
        'confidence': image(np.full((H, W), 0.8, np.float32), '32FC1', t),
        'odom': odometry(t)}, '/filtered/image_rect'),
    'posed_depth_map': Kind(lambda t, _: {
        'image_rect': depth(t),
        'camera_info': info(FRAME.left_camera, t),
        'confidence': image(np.full((H, W), 0.8, np.float32), '32FC1', t),
        'odom': odometry(t)}, '/mesh'),
}

#: Parameters a node runs with here (ranges that fit 64 x 48 images, its optional inputs
#: and checks on); the others run with their defaults.
PARAMETERS = {
    'sgm_stereo': [Parameter('disparity_range', value=RANGE), Parameter('paths', value=5),
                   Parameter('threads', value=1)],
    'cross_check': [Parameter('fill_holes', value=True), Parameter('median_size', value=5)],
    'point_cloud': [Parameter('use_confidence', value=True),
                    Parameter('min_confidence', value=0.05)],
    'structured_light': [Parameter('mode', value='phase'), Parameter('phase_steps', value=4),
                         Parameter('phase_period', value=8.0),
                         Parameter('sequence_timeout', value=0.0)],
    'register_depth': [Parameter('depth_in_rgb', value=[0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])],
    'tof': [Parameter('threads', value=1)],
    'multiview_stereo': [Parameter('planes', value=RANGE), Parameter('paths', value=5),
                         Parameter('threads', value=1), Parameter('min_depth', value=0.5),
                         Parameter('max_depth', value=10.0)],
    # its optional noise input too: the tof node's confidence
    'depth_filter': [Parameter('pose_source', value='odometry'),
                     Parameter('noise_model', value='tof'), Parameter('threads', value=1)],
    # its optional noise input too, and a mesh for every frame
    'tsdf_fusion': [Parameter('weighting_mode', value='confidence'),
                    Parameter('mesh_rate_hz', value=1000.0), Parameter('threads', value=1)],
}


def kind_of(entry: NodeEntry) -> Kind:
    """The frame builder of a registry node; fails, naming what to add, when its inputs
    kind has none."""
    assert entry.inputs in KINDS, (f'{entry.name}: no frame builder for inputs kind '
                                   f'{entry.inputs!r}; add one to KINDS in test/node_frames.py')
    return KINDS[entry.inputs]


@contextlib.contextmanager
def participant_kept(context: Context) -> Iterator[None]:
    """Keep a node alive in ``context`` meanwhile: the DDS participant lives as long as
    one of its nodes does, and the tests' large-message profile (64 MiB shared-memory
    segment) makes creating it cost about 0.1 s, paid again by every node made alone."""
    keeper = rclpy.create_node('participant_keeper', context=context)
    try:
        yield
    finally:
        keeper.destroy_node()


def make_node(entry: NodeEntry, context: Context) -> Any:
    """A registry node, with :data:`PARAMETERS`, its outputs kept as ``(topic, message)``
    in ``node.outbox`` (the sink: every output is wanted) and its input callbacks by topic
    suffix in ``node.routes``."""
    node = resolve_plugin(entry.name)(context=context,
                                      parameter_overrides=PARAMETERS.get(entry.name, []))
    node.outbox = []
    # a Serialized output (tsdf_fusion's mesh) stays bytes: deserialising its thousands of
    # points into rclpy objects would cost more than the node did
    node.sink = lambda topic, msg: node.outbox.append((topic, msg))
    node.routes = {spec.topic.lstrip('/'): spec.callback for spec in node.inputs}
    return node


def is_empty(msg: Any) -> bool:
    """An image, cloud or disparity with no pixels: no output for the frame."""
    holder = getattr(msg, 'image', msg)
    return getattr(holder, 'width', 1) * getattr(holder, 'height', 1) == 0
