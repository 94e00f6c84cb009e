"""Camera transforms (depth_nodes.core.geometry.rotation) against rotation matrices, and the
static_transform node that latches one on /tf_static."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.context import Context
from rclpy.parameter import Parameter

from depth_nodes.core.geometry import (
    OPTICAL_RPY,
    camera_transform,
    quaternion_from_rpy,
    quaternion_multiply,
)


def _matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _ry(a: float) -> np.ndarray:
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _rx(a: float) -> np.ndarray:
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


@pytest.mark.parametrize(('roll', 'pitch', 'yaw'), [(0.1, -0.4, 2.0), (1.2, 0.3, -0.7),
                                                    (0.0, 0.0, 0.0)])
def test_rpy_is_rz_ry_rx(roll: float, pitch: float, yaw: float) -> None:
    q = quaternion_from_rpy(roll, pitch, yaw)
    assert math.isclose(sum(v * v for v in q), 1.0, abs_tol=1e-12)
    np.testing.assert_allclose(_matrix(q), _rz(yaw) @ _ry(pitch) @ _rx(roll), atol=1e-12)
    a, b = quaternion_from_rpy(0.3, 0, 0), quaternion_from_rpy(0, 0.5, 0)
    np.testing.assert_allclose(_matrix(quaternion_multiply(a, b)), _matrix(a) @ _matrix(b),
                               atol=1e-12)


def test_optical_axes_follow_rep_103() -> None:
    """Optical z looks forward (body x), optical x points right (-y), optical y down (-z)."""
    rotation = _matrix(quaternion_from_rpy(*OPTICAL_RPY))
    np.testing.assert_allclose(rotation @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rotation @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(rotation @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    # a camera yawed 90 degrees left on the robot looks along the robot's y
    _, q = camera_transform(0.1, 0.0, 0.5, 0.0, 0.0, math.pi / 2, optical=True)
    np.testing.assert_allclose(_matrix(q) @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    with pytest.raises(ValueError, match='must be finite'):
        camera_transform(math.nan, 0, 0, 0, 0, 0, optical=False)


def test_static_transform_node(context: Context) -> None:
    """Its transform from the parameters; where tf2_msgs is missing (the PyPI wheels) a
    one-line error, where it exists the latched message holds that transform."""
    from depth_nodes.errors import ConfigError
    from depth_nodes.nodes.static_transform import StaticTransformNode, transform

    overrides = [Parameter('parent_frame', value='base_link'),
                 Parameter('child_frame', value='cam_optical'),
                 Parameter('x', value=0.2), Parameter('z', value=0.6),
                 Parameter('yaw', value=0.5)]
    try:
        import tf2_msgs  # noqa: F401
    except ImportError:
        with pytest.raises(ConfigError, match='static_transform needs tf2_msgs, which every '
                                              'ROS 2 install has'):
            StaticTransformNode(context=context, parameter_overrides=overrides)
        values = {p.name: p.value for p in overrides} | {'y': 0.0, 'roll': 0.0, 'pitch': 0.0,
                                                          'optical': True}
    else:
        node = StaticTransformNode(context=context, parameter_overrides=overrides)
        try:
            values = dict(node.params.values)
            assert node.message.transforms[0].child_frame_id == 'cam_optical'
        finally:
            node.destroy_node()
    msg = transform(values, Time(sec=7))
    assert (msg.header.frame_id, msg.child_frame_id) == ('base_link', 'cam_optical')
    assert msg.header.stamp.sec == 7
    t, r = msg.transform.translation, msg.transform.rotation
    assert (t.x, t.y, t.z) == (0.2, 0.0, 0.6)
    expected = camera_transform(0.2, 0.0, 0.6, 0.0, 0.0, 0.5, optical=True)[1]
    assert (r.x, r.y, r.z, r.w) == pytest.approx(expected)
    with pytest.raises(ConfigError, match='two different names'):
        StaticTransformNode(context=context, parameter_overrides=[
            Parameter('parent_frame', value='a'), Parameter('child_frame', value='a')])
