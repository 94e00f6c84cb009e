"""depth_image_proc's nodes (point_cloud_xyz, point_cloud_xyzrgb, register_depth,
convert_metric, depth_disparity) against exact ground truth: a depth camera and a colour
camera of different sizes and poses rendered from the stereo simulator's scene
(depth_nodes.sim.depth_camera), fed through the nodes' callbacks as messages.

Tolerances: points from 32FC1 depth equal the rendered points to a relative 1e-6 of Z
(float32); from 16UC1 within half a millimetre of Z plus 1e-6 relative (the depth is
rounded to millimetres); registration as in test/core/test_depth_image.py.
"""

from __future__ import annotations

import sys
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, header

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ConfigError
from depth_nodes.nodes import register_depth
from depth_nodes.nodes.convert_metric import ConvertMetricNode
from depth_nodes.nodes.depth_disparity import DepthDisparityNode
from depth_nodes.nodes.point_cloud_xyz import PointCloudXyzNode
from depth_nodes.nodes.point_cloud_xyzrgb import PointCloudXyzrgbNode
from depth_nodes.nodes.register_depth import RegisterNode
from depth_nodes.ros import poses
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.ros.transport import compress_depth
from depth_nodes.sim.depth_camera import render_view
from depth_nodes.sim.layout import build_scene, rotation
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

DEPTH_CAM = Intrinsics(140.0, 141.0, 79.5, 59.0, 160, 120)
RGB_CAM = Intrinsics(290.0, 290.0, 161.0, 118.5, 320, 240)
#: The colour camera at half its size: the grid a depth image registered to it may have.
RGB_HALF = Intrinsics(145.0, 145.0, (161.0 + 0.5) / 2 - 0.5, (118.5 + 0.5) / 2 - 0.5, 160, 120)
RGB_POSE = Pose(rotation(1.0, -0.5, 0.3), np.array([0.025, 0.002, -0.003]))
SCENE = Lazy(lambda: build_scene(3, 0, 140.0, 160, 120))
DEPTH = Lazy(lambda: render_view(SCENE, DEPTH_CAM))
RGB = Lazy(lambda: render_view(SCENE, RGB_CAM, RGB_POSE, colour=True))
RGB_AT_HALF = Lazy(lambda: render_view(SCENE, RGB_HALF, RGB_POSE))
STAMP = 1700 * 10**9 + 250


def _info(cam: Intrinsics, frame: str, *, tx: float = 0.0, stamp: int = STAMP) -> Any:
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    P = np.hstack([K, [[tx], [0.0], [0.0]]])
    return model_to_camera_info(CameraModel(cam.width, cam.height, K, P=P),
                                header(stamp, frame))


def _depth_msg(depth: np.ndarray, encoding: str = '32FC1', frame: str = 'depth_optical') -> Any:
    if encoding == '16UC1':
        mm = np.where(np.isfinite(depth), np.rint(depth * 1000.0), 0).astype(np.uint16)
        return array_to_image(mm, '16UC1', header(STAMP, frame))
    return array_to_image(np.ascontiguousarray(depth, np.float32), '32FC1',
                          header(STAMP, frame))


def _make(cls: type, context: Context, **params: Any) -> Any:
    return capture(cls(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]))


def _xyz(cloud: Any) -> np.ndarray:
    fields = read_pointcloud(cloud)
    return np.dstack([fields['x'], fields['y'], fields['z']]).astype(np.float64)


def _quaternion(R: np.ndarray) -> list[float]:
    vec = cv2.Rodrigues(R)[0].ravel()
    angle = float(np.linalg.norm(vec))
    axis = vec / angle
    return [*(axis * np.sin(angle / 2)), float(np.cos(angle / 2))]


# ------------------------------------------------------------ point_cloud_xyz


@pytest.mark.parametrize('encoding', ['32FC1', '16UC1'])
def test_xyz_points_are_the_rendered_points(context: Context, encoding: str) -> None:
    node = _make(PointCloudXyzNode, context)
    try:
        node.on_frame(_depth_msg(DEPTH.depth, encoding), _info(DEPTH_CAM, 'depth_optical'))
        assert node.drops == {}
        cloud = node.outbox['/points']
        assert [(f.name, f.offset) for f in cloud.fields] == [('x', 0), ('y', 4), ('z', 8)]
        assert (cloud.point_step, cloud.height, cloud.width) == (16, 120, 160)
        assert cloud.header.frame_id == 'depth_optical'
        xyz, truth = _xyz(cloud), DEPTH.points
        z = truth[..., 2]
        if encoding == '32FC1':
            assert (np.linalg.norm(xyz - truth, axis=-1) / z).max() < 1e-6
        else:  # Z rounded to mm; x and y scale with it along the pixel's ray
            assert np.abs(xyz[..., 2] - z).max() <= 0.0005 + 1e-6 * z.max()
            ray = truth / z[..., None]
            np.testing.assert_allclose(xyz, ray * xyz[..., 2:3], rtol=1e-6, atol=1e-9)
    finally:
        node.destroy_node()


def test_xyz_unknown_depth_gives_nan_points_or_invalid_depth(context: Context) -> None:
    depth = DEPTH.depth.copy()
    depth[:20] = np.nan
    for invalid, check in ((0.0, lambda p: np.isnan(p).all()),
                           (5.0, lambda p: np.allclose(p[..., 2], 5.0))):
        node = _make(PointCloudXyzNode, context, invalid_depth=invalid)
        try:
            node.on_frame(_depth_msg(depth, '16UC1'), _info(DEPTH_CAM, 'depth_optical'))
            xyz = _xyz(node.outbox['/points'])
            assert check(xyz[:20])
            assert np.isfinite(xyz[20:]).all()
        finally:
            node.destroy_node()


def test_xyz_depth_smaller_than_its_camera_info_gets_scaled_intrinsics(
        context: Context) -> None:
    half = Intrinsics(70.0, 70.5, (79.5 + 0.5) / 2 - 0.5, (59.0 + 0.5) / 2 - 0.5, 80, 60)
    view = render_view(SCENE, half)
    node = _make(PointCloudXyzNode, context)
    try:
        node.on_frame(_depth_msg(view.depth), _info(DEPTH_CAM, 'depth_optical'))
        xyz = _xyz(node.outbox['/points'])
        assert xyz.shape == (60, 80, 3)
        assert (np.linalg.norm(xyz - view.points, axis=-1) / view.points[..., 2]).max() < 1e-6
    finally:
        node.destroy_node()


def test_xyz_reads_compressed_depth(context: Context) -> None:
    node = _make(PointCloudXyzNode, context, depth_image_transport='compressedDepth')
    try:
        assert '/image_rect/compressedDepth' in [s.topic for s in node.inputs]
        mm = _depth_msg(DEPTH.depth, '16UC1')
        msg = compress_depth(image_to_array(mm), '16UC1', header=mm.header)
        node.on_frame(msg, _info(DEPTH_CAM, 'depth_optical'))
        assert np.abs(_xyz(node.outbox['/points'])[..., 2] - DEPTH.depth).max() <= 0.0005 + 1e-5
    finally:
        node.destroy_node()


def test_xyz_drops_are_counted_with_their_reason(context: Context) -> None:
    node = _make(PointCloudXyzNode, context)
    try:
        mono = array_to_image(np.zeros((120, 160), np.uint8), 'mono8', header(STAMP, 'd'))
        node.on_frame(mono, _info(DEPTH_CAM, 'd'))
        uncalibrated = _info(DEPTH_CAM, 'd')
        uncalibrated.k = np.zeros(9)
        uncalibrated.p = np.zeros(12)
        node.on_frame(_depth_msg(DEPTH.depth), uncalibrated)
        broken = _info(DEPTH_CAM, 'd')
        broken.k[0] = np.nan
        node.on_frame(_depth_msg(DEPTH.depth), broken)
        assert node.drops == {'unsupported_encoding': 1, 'uncalibrated': 1,
                              'bad_calibration': 1}
        assert '/points' not in node.outbox
    finally:
        node.destroy_node()


# --------------------------------------------------------- point_cloud_xyzrgb


def test_xyzrgb_same_size_gives_rendered_points_and_colours(context: Context) -> None:
    node = _make(PointCloudXyzrgbNode, context)
    try:
        rgb_half = render_view(SCENE, RGB_HALF, RGB_POSE, colour=True)
        node.on_frame(_depth_msg(rgb_half.depth, frame='rgb_optical'),
                      array_to_image(rgb_half.colour, 'rgb8', header(STAMP, 'rgb_optical')),
                      _info(RGB_HALF, 'rgb_optical'))
        assert node.drops == {}
        cloud = node.outbox['/points']
        assert [(f.name, f.offset) for f in cloud.fields] == [
            ('x', 0), ('y', 4), ('z', 8), ('rgb', 16)]
        fields = read_pointcloud(cloud)
        xyz = _xyz(cloud)
        z = rgb_half.points[..., 2]
        assert (np.linalg.norm(xyz - rgb_half.points, axis=-1) / z).max() < 1e-6
        np.testing.assert_array_equal(fields['rgb'], rgb_half.colour)
    finally:
        node.destroy_node()


def test_xyzrgb_depth_smaller_than_the_colour_image(context: Context) -> None:
    """Upstream drops (or crashed on) this set: ros-perception/image_pipeline#1147."""
    node = _make(PointCloudXyzrgbNode, context, exact_sync=True)
    try:
        node.on_frame(_depth_msg(RGB_AT_HALF.depth, frame='rgb_optical'),
                      array_to_image(RGB.colour[..., ::-1].copy(), 'bgr8',
                                     header(STAMP, 'rgb_optical')),
                      _info(RGB_CAM, 'rgb_optical'))
        assert node.drops == {}
        fields = read_pointcloud(node.outbox['/points'])
        xyz = _xyz(node.outbox['/points'])
        assert xyz.shape == (120, 160, 3)
        z = RGB_AT_HALF.points[..., 2]
        assert (np.linalg.norm(xyz - RGB_AT_HALF.points, axis=-1) / z).max() < 1e-6
        # depth pixel (u, v) has its centre in colour pixel (2u + 1, 2v + 1)
        np.testing.assert_array_equal(fields['rgb'], RGB.colour[1::2, 1::2])
    finally:
        node.destroy_node()


@pytest.mark.parametrize('colour_shape', [(200, 300), (90, 100), (240, 320)])
def test_xyzrgb_any_size_ratio_gives_a_cloud_at_the_depth_size(
        context: Context, colour_shape: tuple[int, int]) -> None:
    node = _make(PointCloudXyzrgbNode, context)
    try:
        colour = cv2.resize(RGB.colour, colour_shape[::-1], interpolation=cv2.INTER_AREA)
        node.on_frame(_depth_msg(RGB_AT_HALF.depth, '16UC1', frame='rgb_optical'),
                      array_to_image(colour, 'rgb8', header(STAMP, 'rgb_optical')),
                      _info(RGB_CAM, 'rgb_optical'))
        cloud = node.outbox['/points']
        assert (cloud.height, cloud.width) == (120, 160)
        assert np.isfinite(_xyz(cloud)).all()
    finally:
        node.destroy_node()


def test_xyzrgb_bad_colour_is_counted(context: Context) -> None:
    node = _make(PointCloudXyzrgbNode, context)
    try:
        weird = array_to_image(np.zeros((120, 160), np.float32), '32FC1', header(STAMP, 'c'))
        node.on_frame(_depth_msg(RGB_AT_HALF.depth), weird, _info(RGB_HALF, 'c'))
        assert node.drops == {'unsupported_encoding': 1}
    finally:
        node.destroy_node()


# ------------------------------------------------------------ register_depth


def _depth_in_rgb() -> list[float]:
    R, t = Pose().relative_to(RGB_POSE)
    return [*map(float, t), *_quaternion(R)]


def _check_registered(image: Any, encoding: str) -> None:
    assert image.encoding == encoding
    registered = image_to_array(image).astype(np.float64)
    if encoding == '16UC1':
        registered = np.where(registered > 0, registered / 1000.0, np.nan)
    truth = RGB.depth.astype(np.float64)
    both = np.isfinite(registered) & np.isfinite(truth)
    assert both.mean() > 0.97
    filled = np.where(np.isfinite(truth), truth, 0).astype(np.float32)
    kernel = np.ones((5, 5), np.uint8)
    spread = cv2.dilate(filled, kernel) - cv2.erode(filled, kernel)
    rounding = 0.0005 if encoding == '16UC1' else 1e-5 * truth[both]
    within = np.abs(registered - truth)[both] <= spread[both] + rounding + 1e-5
    assert within.mean() >= 0.999


@pytest.mark.parametrize('encoding', ['32FC1', '16UC1'])
def test_register_into_the_colour_camera_gives_its_depth(context: Context,
                                                         encoding: str) -> None:
    node = _make(RegisterNode, context, depth_in_rgb=_depth_in_rgb())
    try:
        rgb_info = _info(RGB_CAM, 'rgb_optical', stamp=STAMP + 3_000_000)
        node.on_frame(_depth_msg(DEPTH.depth, encoding), _info(DEPTH_CAM, 'depth_optical'),
                      rgb_info)
        assert node.drops == {}
        image = node.outbox['/depth_registered/image_rect']
        info = node.outbox['/depth_registered/camera_info']
        assert (image.width, image.height) == (320, 240)
        assert image.header.frame_id == info.header.frame_id == 'rgb_optical'
        assert (image.header.stamp.sec * 10**9 + image.header.stamp.nanosec) == STAMP
        assert info.header.stamp == image.header.stamp
        np.testing.assert_array_equal(info.p, rgb_info.p)
        _check_registered(image, encoding)
    finally:
        node.destroy_node()


@pytest.fixture
def fake_tf2(monkeypatch: pytest.MonkeyPatch) -> None:
    """tf2_msgs is not among the PyPI wheels: a stand-in message type lets the node
    subscribe; the test then hands it transforms directly."""
    from diagnostic_msgs.msg import DiagnosticArray
    monkeypatch.setattr(poses, 'TFMessage', DiagnosticArray)


def _tf(parent: str, child: str, pose: list[float]) -> Any:
    x, y, z, qx, qy, qz, qw = pose
    return SimpleNamespace(header=SimpleNamespace(frame_id=parent), child_frame_id=child,
                           transform=SimpleNamespace(
                               translation=SimpleNamespace(x=x, y=y, z=z),
                               rotation=SimpleNamespace(x=qx, y=qy, z=qz, w=qw)))


def test_register_takes_the_extrinsics_from_tf(context: Context, fake_tf2: None) -> None:
    node = _make(RegisterNode, context)
    try:
        assert {'/tf', '/tf_static'} <= {s.topic for s in node.inputs}
        args = (_depth_msg(DEPTH.depth), _info(DEPTH_CAM, 'depth_optical'),
                _info(RGB_CAM, 'rgb_optical'))
        node.on_frame(*args)
        assert node.drops == {'no_transform': 1}
        # rgb and depth both hang off a rig frame: rig -> rgb is the identity here
        node.tf.on_tf_static(SimpleNamespace(transforms=[
            _tf('rig', 'depth_optical', _depth_in_rgb()),
            _tf('rig', 'rgb_optical', [0, 0, 0, 0, 0, 0, 1])]))
        node.on_frame(*args)
        assert node.drops == {'no_transform': 1}
        _check_registered(node.outbox['/depth_registered/image_rect'], '32FC1')
        node.tf.on_tf_static(SimpleNamespace(transforms=[_tf('a', 'a', [0] * 6 + [1])]))
        assert node.drops == {'no_transform': 1, 'bad_pose': 1}  # counted, not raised
    finally:
        node.destroy_node()


def test_register_without_tf2_needs_depth_in_rgb(context: Context,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(poses, 'TFMessage', None)  # as on the PyPI wheels
    with pytest.raises(ConfigError, match='register_depth: set depth_in_rgb'):
        RegisterNode(context=context)


@pytest.mark.parametrize(('value', 'message'), [
    ([0.0, 0.0, 0.0], 'needs 7 finite numbers'),
    ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], '4 finite values, not all zero'),
    ([0.0, float('nan'), 0.0, 0.0, 0.0, 0.0, 1.0], 'needs 7 finite numbers'),
])
def test_register_refuses_a_bad_pose(context: Context, value: list[float],
                                     message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        RegisterNode(context=context, parameter_overrides=[Parameter('depth_in_rgb',
                                                                     value=value)])


# ------------------------------------------------------------ convert_metric


def test_convert_metric_gives_metres(context: Context) -> None:
    node = _make(ConvertMetricNode, context)
    try:
        mm = np.array([[0, 1, 1234], [65535, 7, 0]], np.uint16)
        node.on_frame(array_to_image(mm, '16UC1', header(STAMP, 'd')))
        out = node.outbox['/image']
        assert (out.encoding, out.header.frame_id) == ('32FC1', 'd')
        m = image_to_array(out)
        np.testing.assert_allclose(m[mm > 0], mm[mm > 0] / 1000.0, rtol=1e-7)
        assert np.isnan(m[mm == 0]).all()
        metres = np.array([[0.0, 2.0, np.inf]], np.float32)
        node.on_frame(array_to_image(metres, '32FC1', header(STAMP + 1, 'd')))
        m = image_to_array(node.outbox['/image'])
        assert np.isnan(m[0, [0, 2]]).all()
        assert m[0, 1] == 2.0
        node.on_frame(array_to_image(np.zeros((2, 2), np.uint8), 'mono8',
                                     header(STAMP + 2, 'd')))
        assert node.drops == {'unsupported_encoding': 1}
    finally:
        node.destroy_node()


# ------------------------------------------------------------ depth_disparity


def test_depth_disparity_is_what_the_right_camera_sees(context: Context) -> None:
    baseline = 0.09
    node = _make(DepthDisparityNode, context, min_range=1.0, max_range=5.0)
    try:
        right = _info(DEPTH_CAM, 'right_optical', tx=-DEPTH_CAM.fx * baseline)
        node.on_frame(_depth_msg(DEPTH.depth), right)
        assert node.drops == {}
        frame = read_disparity(node.outbox['/left/disparity'])
        p = DEPTH.points
        truth = DEPTH_CAM.fx * p[..., 0] / p[..., 2] - DEPTH_CAM.fx * (
            p[..., 0] - baseline) / p[..., 2]
        z = DEPTH.depth
        kept = (z >= 1.0) & (z <= 5.0)
        assert kept.any()
        assert (~kept).any()
        np.testing.assert_allclose(frame.disparity[kept], truth[kept], rtol=1e-6)
        assert np.isnan(frame.disparity[~kept]).all()
        assert frame.focal == DEPTH_CAM.fx
        assert frame.baseline == pytest.approx(baseline)
        assert frame.min_disparity == pytest.approx(DEPTH_CAM.fx * baseline / 5.0)
        assert frame.max_disparity == pytest.approx(DEPTH_CAM.fx * baseline / 1.0)
        assert frame.delta_d == 0.125
    finally:
        node.destroy_node()


def test_depth_disparity_defaults_and_a_missing_baseline(context: Context) -> None:
    node = _make(DepthDisparityNode, context)
    try:
        node.on_frame(_depth_msg(DEPTH.depth, '16UC1'), _info(DEPTH_CAM, 'r', tx=-14.0))
        frame = read_disparity(node.outbox['/left/disparity'])
        assert frame.min_disparity == 0.0
        assert frame.max_disparity == pytest.approx(14.0 / 0.001)
        assert np.isfinite(frame.disparity).all()
        node.on_frame(_depth_msg(DEPTH.depth), _info(DEPTH_CAM, 'r', stamp=STAMP + 1))
        assert node.drops == {'bad_calibration': 1}
    finally:
        node.destroy_node()


def test_depth_disparity_refuses_an_empty_range(context: Context) -> None:
    with pytest.raises(ConfigError, match='max_range \\(2\\) must be greater than min_range'):
        DepthDisparityNode(context=context, parameter_overrides=[
            Parameter('min_range', value=3.0), Parameter('max_range', value=2.0)])


# ------------------------------------------------------------ lazy outputs


def _frame_of(node_class: type) -> tuple[Any, ...]:
    """A good input set of each depth_image_proc node."""
    if node_class is PointCloudXyzrgbNode:
        return (_depth_msg(RGB_AT_HALF.depth, frame='rgb_optical'),
                array_to_image(RGB.colour, 'rgb8', header(STAMP, 'rgb_optical')),
                _info(RGB_CAM, 'rgb_optical'))
    if node_class is DepthDisparityNode:
        return _depth_msg(DEPTH.depth), _info(DEPTH_CAM, 'r', tx=-14.0)
    if node_class is ConvertMetricNode:
        return (_depth_msg(DEPTH.depth, '16UC1'),)
    return _depth_msg(DEPTH.depth), _info(DEPTH_CAM, 'depth_optical')


@pytest.mark.parametrize(('node_class', 'work'), [
    (PointCloudXyzNode, 'depth_to_points'),
    (PointCloudXyzrgbNode, 'depth_to_points'),
    (DepthDisparityNode, 'depth_to_disparity'),
    (ConvertMetricNode, 'read_depth'),
])
def test_a_frame_nobody_wants_is_skipped(context: Context, monkeypatch: pytest.MonkeyPatch,
                                         node_class: type, work: str) -> None:
    node = _make(node_class, context)
    module = sys.modules[node_class.__module__]
    calls = count_calls(monkeypatch, node if work == 'read_depth' else module, work)
    try:
        (output,) = node.outputs
        want_only(monkeypatch)
        node.on_frame(*_frame_of(node_class))
        assert (node.outbox, calls, node.drops) == ({}, {}, {})
        assert node.accounting.skipped == 1
        want_only(monkeypatch, output)
        node.on_frame(*_frame_of(node_class))
        assert set(node.outbox) == {output}
        assert calls == {work: 1}
        assert node.drops == {}
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('wanted', 'registered'), [
    (('/depth_registered/image_rect', '/depth_registered/camera_info'), 1),
    (('/depth_registered/image_rect',), 1),
    (('/depth_registered/camera_info',), 0),  # the colour camera's info needs no depth
    ((), 0),
])
def test_register_registers_only_while_its_depth_is_wanted(
        context: Context, monkeypatch: pytest.MonkeyPatch, wanted: tuple[str, ...],
        registered: int) -> None:
    node = _make(RegisterNode, context, depth_in_rgb=_depth_in_rgb())
    frame = (_depth_msg(DEPTH.depth), _info(DEPTH_CAM, 'depth_optical'),
             _info(RGB_CAM, 'rgb_optical'))
    try:
        node.on_frame(*frame)
        everything = dict(node.outbox)
        node.outbox.clear()
        calls = count_calls(monkeypatch, register_depth, 'register_depth')
        want_only(monkeypatch, *wanted)
        node.on_frame(*frame)
        assert node.outbox == {topic: everything[topic] for topic in wanted}
        assert calls['register_depth'] == registered
        assert node.drops == {}
        assert node.accounting.skipped == (0 if wanted else 1)
    finally:
        node.destroy_node()
