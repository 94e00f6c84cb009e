"""The depth_image_proc nodes' failures found by the reliability campaign, one test each: a
message that gave an empty output, raised, divided by zero or wrote outside its footprint
is now a counted drop with its reason (or, for an extreme depth, the output it should
give), and the next good frame comes through."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from node_frames import FRAME, KINDS, is_empty, make_node
from rclpy.context import Context

from depth_nodes.nodes.registry import NODES, NodeEntry
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.transport import MAX_PIXELS

pytestmark = pytest.mark.ros

#: The depth image input of each depth_image_proc node's inputs kind.
DEPTH_INPUT = {'depth': 'image_rect', 'depth_colour': 'depth_registered/image_rect',
               'depth_two_cameras': 'depth/image_rect', 'depth_raw': 'image_raw',
               'depth_stereo': 'left/image_rect'}
DEPTH_NODES = [entry for entry in NODES if entry.inputs in DEPTH_INPUT]
GOOD, BAD, NEXT = 10**9, 2 * 10**9, 3 * 10**9


def _node(entry: NodeEntry, context: Context) -> Any:
    node = make_node(entry, context)
    node.logged = []
    node.get_logger().warning = node.logged.append
    return node


def _send(node: Any, msgs: dict[str, Any]) -> list[tuple[str, Any]]:
    before = len(node.outbox)
    for topic, msg in msgs.items():
        node.routes[topic](msg)
    return node.outbox[before:]


def _frame(entry: NodeEntry, stamp: int, replace: dict[str, Any] | None = None
           ) -> dict[str, Any]:
    """A valid frame of the node's kind, with the messages of ``replace`` (restamped)."""
    msgs = KINDS[entry.inputs].step(stamp, 0)
    for topic, msg in (replace or {}).items():
        msg.header = msgs[topic].header
        msgs[topic] = msg
    return msgs


def _resized(msg: Any, height: int, width: int) -> Any:
    pixels = image_to_array(msg)[:height, :width]
    return array_to_image(np.ascontiguousarray(pixels), msg.encoding, msg.header)


def test_every_depth_image_proc_node_is_here() -> None:
    assert {e.name for e in DEPTH_NODES} == {'point_cloud_xyz', 'point_cloud_xyzrgb',
                                            'register_depth', 'convert_metric',
                                            'depth_disparity'}


@pytest.mark.parametrize('entry', DEPTH_NODES, ids=lambda e: e.name)
@pytest.mark.parametrize(('height', 'width'), [(0, 0), (0, 64), (48, 0)])
def test_a_depth_image_without_pixels_is_a_counted_drop(context: Context, entry: NodeEntry,
                                                        height: int, width: int) -> None:
    """It gave an empty cloud or image without a word (depth_disparity raised)."""
    node = _node(entry, context)
    try:
        topic = DEPTH_INPUT[entry.inputs]
        msgs = _frame(entry, BAD)
        msgs[topic] = _resized(msgs[topic], height, width)
        assert _send(node, msgs) == []
        assert node.drops == {'malformed_image': 1}
        assert f'{topic} is empty ({width}x{height})' in node.logged[0]
        out = _send(node, _frame(entry, NEXT))
        assert out
        assert not any(is_empty(m) for _, m in out)
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('height', 'width'), [(0, 0), (0, 64), (48, 0)])
def test_a_colour_image_without_pixels_is_a_counted_drop(context: Context, height: int,
                                                         width: int) -> None:
    """point_cloud_xyzrgb raised IndexError resampling it (internal_error)."""
    entry = next(e for e in NODES if e.name == 'point_cloud_xyzrgb')
    node = _node(entry, context)
    try:
        msgs = _frame(entry, BAD)
        msgs['rgb/image_rect_color'] = _resized(msgs['rgb/image_rect_color'], height, width)
        assert _send(node, msgs) == []
        assert node.drops == {'malformed_image': 1}
        assert f'rgb/image_rect_color is empty ({width}x{height})' in node.logged[0]
        assert _send(node, _frame(entry, NEXT))
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('p03', 'p00', 'message'), [
    (None, 0.0, 'has no baseline: P[0, 3] is 0'),  # all of P zero: [K | 0]
    (6.0, 60.0, 'has no baseline: P[0, 3] is 6'),
    (-1e300, 60.0, 'whose disparities are not finite positive float32'),
    (-1e-300, 1e-300, 'whose disparities are not finite positive float32'),
])
def test_depth_disparity_refuses_a_right_camera_without_a_usable_baseline(
        context: Context, p03: float | None, p00: float, message: str) -> None:
    """An all-zero P (accepted as [K | 0]) divided by zero (internal_error)."""
    entry = next(e for e in NODES if e.name == 'depth_disparity')
    node = _node(entry, context)
    try:
        msgs = _frame(entry, BAD)
        p = np.zeros(12) if p03 is None else np.array(msgs['right/camera_info'].p)
        if p03 is not None:
            p[0], p[3] = p00, p03
        msgs['right/camera_info'].p = p
        assert _send(node, msgs) == []
        assert node.drops == {'bad_calibration': 1}
        assert message in node.logged[0]
        assert _send(node, _frame(entry, NEXT))
    finally:
        node.destroy_node()


def _register_depth(context: Context, depth: np.ndarray) -> tuple[Any, np.ndarray]:
    entry = next(e for e in NODES if e.name == 'register_depth')
    node = _node(entry, context)
    try:
        out = _send(node, _frame(entry, BAD, {'depth/image_rect': array_to_image(
            depth, '32FC1')}))
        (registered,) = [m for t, m in out if t == '/depth_registered/image_rect']
        return node.drops, image_to_array(registered)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('z', [1e-30, 1e-45, 3.4e38])
def test_register_an_extreme_depth_writes_its_footprint_only(context: Context,
                                                             z: float) -> None:
    """One 32FC1 pixel of 1e-30 m filled a whole row of the registered image: seen 2 cm
    beside it, it projects ~1e30 px away, a loop bound that became the most negative
    integer. Such a pixel is off the image: the output is the one without it."""
    depth = np.nan_to_num(FRAME.depth_gt, nan=0.0).astype(np.float32)
    depth[24, 32] = np.nan
    drops, without = _register_depth(context, depth)
    assert drops == {}
    assert np.isfinite(without).mean() > 0.5
    depth[24, 32] = z
    drops, registered = _register_depth(context, depth)
    assert drops == {}
    np.testing.assert_array_equal(registered, without)


def test_register_refuses_a_colour_camera_too_large_to_allocate(context: Context) -> None:
    """A colour camera_info 2**31 - 1 pixels wide: the output at its size needed hundreds of
    GiB (MemoryError, internal_error)."""
    entry = next(e for e in NODES if e.name == 'register_depth')
    node = _node(entry, context)
    try:
        msgs = _frame(entry, BAD)
        msgs['rgb/camera_info'].width = 2**31 - 1
        assert _send(node, msgs) == []
        assert node.drops == {'bad_calibration': 1}
        assert f'has more than {MAX_PIXELS} pixels' in node.logged[0]
        assert _send(node, _frame(entry, NEXT))
    finally:
        node.destroy_node()
