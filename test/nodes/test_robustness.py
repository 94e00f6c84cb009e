"""The failures of the reliability campaign, one test each: a message that used to kill a
node is a counted drop with its reason, the node goes on with the next good frame, and a
lost frame is counted once per frame; plus the last line of defence itself."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, header
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.nodes.cross_check import CrossCheckNode
from depth_nodes.nodes.rectify import RectifyNode
from depth_nodes.nodes.structured_light import StructuredLightNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.sync import ApproximateTimeSynchronizer, ExactTimeSynchronizer
from depth_nodes.ros.workers import use_threads
from depth_nodes.sim import StereoSimConfig, simulate_stereo

pytestmark = pytest.mark.ros

FRAME = Lazy(lambda: next(simulate_stereo(StereoSimConfig(width=64, height=48, n_frames=1, seed=3,
                                                          distortion_scale=0.0, rotation_deg=0.0))))


def _wired(node: Any) -> Any:
    capture(node, history=True)
    node.cb = {spec.topic: spec.callback for spec in node.inputs}
    return node


def _rectify_frame(node: Any, stamp: int, info: CameraInfo | None = None) -> None:
    stamped = header(stamp)
    node.cb['/image'](array_to_image(FRAME.left_raw, 'mono8', stamped))
    msg = info or model_to_camera_info(FRAME.left_camera)
    msg.header = stamped
    node.cb['/camera_info'](msg)


def test_an_invalid_stamp_is_a_counted_drop_and_does_not_poison_the_next(
        context: Context) -> None:
    """nanosec >= 1e9 is a legal uint32 but not a time: it used to raise out of the
    synchroniser (the process exited), and before that be read as a stamp up to 4.3 s in
    the future, so the good frames after it were dropped as out of order."""
    node = _wired(RectifyNode(context=context))
    try:
        _rectify_frame(node, 10**9)
        bad = array_to_image(FRAME.left_raw, 'mono8')
        bad.header.stamp.sec, bad.header.stamp.nanosec = 1, 4_000_000_000
        node.cb['/image'](bad)
        _rectify_frame(node, 2 * 10**9)
        assert node.drops == {'bad_stamp': 1}
        assert [t for t, _ in node.outbox] == ['/image_rect', '/image_rect']
    finally:
        node.destroy_node()


@pytest.mark.parametrize('image_first', [True, False])
def test_a_stamp_far_ahead_costs_only_its_own_frame(context: Context,
                                                    image_first: bool) -> None:
    """A camera_info stamped 68 years ahead, then the next frame: its camera_info jumps
    back, which starts the inputs over. The image of that frame, already waiting when its
    camera_info came second, was discarded with the rest (time_jump), so the frame after
    the hostile stamp was lost too (a looping bag lost the first frame of each
    repeat the same way). What waits stamped no later than the stamp that jumped back
    belongs to the new timeline and is kept."""
    node = _wired(RectifyNode(context=context))
    try:
        _rectify_frame(node, 10**9)
        ahead = model_to_camera_info(FRAME.left_camera)
        ahead.header.stamp.sec = 2**31 - 1
        node.cb['/camera_info'](ahead)
        stamped = header(3 * 10**9)
        info = model_to_camera_info(FRAME.left_camera)
        info.header = stamped
        image = array_to_image(FRAME.left_raw, 'mono8', stamped)
        for topic, msg in (('/image', image), ('/camera_info', info))[::1 if image_first
                                                                        else -1]:
            node.cb[topic](msg)
        assert [m.header.stamp.sec for _, m in node.outbox] == [1, 3]
        assert node.drops == {'time_jump': 1}  # the frame stamped ahead, never matched
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('width', 'height', 'bx', 'by'), [(0, 0, 1000, 1000),
                                                           (64, 48, 1000, 0),
                                                           (64, 48, 0, 60)])
def test_binning_that_leaves_no_pixel_is_bad_calibration(context: Context, width: int,
                                                         height: int, bx: int,
                                                         by: int) -> None:
    node = _wired(RectifyNode(context=context))
    try:
        info = model_to_camera_info(FRAME.left_camera)
        info.width, info.height, info.binning_x, info.binning_y = width, height, bx, by
        _rectify_frame(node, 10**9, info)
        assert set(node.drops) == {'bad_calibration'}
        _rectify_frame(node, 2 * 10**9)  # and the next good frame comes through
        assert len(node.outbox) == 1
    finally:
        node.destroy_node()


DISPARITY = np.full((48, 64), 5.0, np.float32)
COMMON = {'focal': 60.0, 'baseline': 0.1, 'min_disparity': 0.0, 'max_disparity': 15.0,
          'delta_d': 1 / 32}


def _broken(field: str, value: Any) -> Any:
    msg = build_disparity(DISPARITY, None, **COMMON)
    if field == 'valid_window':
        msg.valid_window.x_offset, msg.valid_window.width = 60, 30
        msg.valid_window.height = 10
    elif field == 'empty':
        msg.image = array_to_image(np.zeros((0, 0), np.float32), '32FC1')
    else:
        setattr(msg, field, value)
    return msg


@pytest.mark.parametrize(('field', 'value', 'message'), [
    ('f', float('nan'), 'f is nan'), ('t', float('inf'), 't is inf'),
    ('delta_d', float('nan'), 'delta_d is nan'), ('min_disparity', 20.0, 'is greater than'),
    ('min_disparity', float('-inf'), 'min_disparity is -inf'),
    ('min_disparity', float('nan'), 'min_disparity is nan'),
    ('valid_window', None, 'valid_window'), ('empty', None, 'is empty'),
    ('delta_d', -1.0, 'delta_d -1.0 is negative')])
@pytest.mark.parametrize('side', ['disparity', 'disparity_right'])
def test_cross_check_counts_every_bad_disparity_image(context: Context, field: str,
                                                      value: Any, message: str,
                                                      side: str) -> None:
    """The seven kinds the campaign found (plus an empty one and a negative step), on
    either input: counted as malformed with the field named, and the next good set is
    checked as usual."""
    node = _wired(CrossCheckNode(context=context))
    logged: list[str] = []
    node.get_logger().warning = logged.append  # type: ignore[method-assign]
    try:
        for stamp, broken in ((10**9, True), (2 * 10**9, False)):
            msgs = {'disparity': build_disparity(DISPARITY, header(stamp), **COMMON),
                    'disparity_right': build_disparity(DISPARITY, header(stamp), **COMMON),
                    'cost_ratio': array_to_image(np.zeros((48, 64), np.float32), '32FC1',
                                                 header(stamp))}
            if broken:
                stamped = msgs[side].header
                msgs[side] = _broken(field, value)
                msgs[side].header = stamped
            for topic, msg in msgs.items():
                node.cb[f'/{topic}'](msg)
        assert node.drops == {'malformed_image': 1}
        assert message in logged[0]
        assert [t for t, _ in node.outbox] == ['/disparity_checked', '/confidence']
    finally:
        node.destroy_node()


def _tag(node: Any, stamp: int, tag: str) -> None:
    node.cb['/pattern'](header(stamp, tag))
    node.cb['/image'](array_to_image(FRAME.left_rect_gt, 'mono8', header(stamp)))
    info = model_to_camera_info(FRAME.left_camera)
    info.header = header(stamp)
    node.cb['/camera_info'](info)


def test_structured_light_refuses_a_huge_sequence_before_projector_info(
        context: Context) -> None:
    """A tag announcing a million frames, before the projector's camera_info says the real
    count: it used to be taken on trust and held (RSS grew without limit)."""
    node = _wired(StructuredLightNode(context=context, parameter_overrides=[
        Parameter('mode', value='gray')]))
    try:
        for k in range(50):
            _tag(node, 10**9 + k * 10**6, f'0:{k}/1000000')
        assert node.drops == {'pattern_count_too_large': 50}
        assert node.assembler.pending == 0
    finally:
        node.destroy_node()


def test_an_incomplete_sequence_times_out_and_is_counted_at_the_end(
        context: Context) -> None:
    node = _wired(StructuredLightNode(context=context, parameter_overrides=[
        Parameter('mode', value='gray'), Parameter('sequence_timeout', value=2.0)]))
    try:
        for k in range(3):
            _tag(node, 10**9 + k * 10**6, f'0:{k}/24')
        assert node.assembler.pending == 3
        node.check_sequence_timeout(now=node._last_sequence_frame + 1.0)
        assert node.assembler.pending == 3  # not yet
        node.check_sequence_timeout(now=node._last_sequence_frame + 2.5)
        assert node.assembler.pending == 0
        assert node.drops == {'sequence_incomplete': 1}
        for k in range(2):  # another one begins, the stream ends
            _tag(node, 2 * 10**9 + k * 10**6, f'1:{k}/24')
        node.cb['/pattern'](header(3 * 10**9, '2:0/24'))  # a tag without its image
        node.finish_stream()
        assert node.drops == {'sequence_incomplete': 2, 'pattern_tag_unmatched': 1}
    finally:
        node.destroy_node()


class _Msg:
    def __init__(self, stamp: int) -> None:
        self.header = header(stamp)


@pytest.mark.parametrize('approximate', [False, True])
def test_one_set_evicting_three_waiting_ones_counts_three_frames(approximate: bool) -> None:
    """Three images whose camera_info never came, then a complete set: three lost frames,
    not one (the count was 1 per event before)."""
    sets: list[Any] = []
    sync: Any = (ApproximateTimeSynchronizer(2, lambda *m: sets.append(m), queue_size=10)
                 if approximate else
                 ExactTimeSynchronizer(2, lambda *m: sets.append(m), queue_size=10))
    for k in range(3):
        sync.add(0, _Msg(10**9 + k * 10**8))
    sync.add(0, _Msg(2 * 10**9))
    sync.add(1, _Msg(2 * 10**9))
    assert len(sets) == 1
    assert sync.lost_frames == {'unmatched': 3}
    assert sync.dropped == {'unmatched': 3}


def test_node_counts_each_lost_frame(context: Context) -> None:
    node = _wired(RectifyNode(context=context))
    try:
        for k in range(3):  # images whose camera_info never comes
            node.cb['/image'](array_to_image(FRAME.left_raw, 'mono8',
                                             header(10**9 + k * 10**8)))
        _rectify_frame(node, 2 * 10**9)
        assert node.drops == {'sync_unmatched': 3}
    finally:
        node.destroy_node()


class _Faulty(DepthNode):
    """A node whose callback raises what it did not expect on odd stamps."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('faulty', **kwargs)
        self.add_input(Image, 'image', self.on_image)
        self.out = self.add_output(Image, 'out')

    def on_image(self, msg: Image) -> None:
        if msg.header.stamp.sec % 2:
            raise ZeroDivisionError('a bug')
        self.out.publish(msg)


def test_an_unexpected_exception_is_counted_logged_once_and_the_node_goes_on(
        context: Context) -> None:
    node = _wired(_Faulty(context=context))
    errors: list[str] = []
    node.get_logger().error = errors.append  # type: ignore[method-assign]
    try:
        for sec in range(1, 7):
            node.cb['/image'](array_to_image(np.zeros((2, 2), np.uint8), 'mono8',
                                              header(sec * 10**9)))
        assert node.drops == {'internal_error': 3}
        assert len(node.outbox) == 3
        assert len(errors) == 1  # the traceback once per kind and place
        assert 'ZeroDivisionError' in errors[0]
        assert 'Traceback' in errors[0]
    finally:
        node.destroy_node()


def test_more_threads_than_cores_are_clamped() -> None:
    use_threads(1024)
    assert cv2.getNumThreads() <= cv2.getNumberOfCPUs()
    use_threads(1)
    assert cv2.getNumThreads() == 1


def test_approximate_sync_counts_a_secondary_message_alone_as_no_frame() -> None:
    """A camera_info at three times the image rate: the extra ones are unmatched messages,
    not lost frames."""
    sets: list[Any] = []
    sync = ApproximateTimeSynchronizer(2, lambda *m: sets.append(m), queue_size=10)
    for k in range(4):
        for j in range(3):
            sync.add(1, _Msg(10**9 + k * 3 * 10**8 + j * 10**8))
        sync.add(0, _Msg(10**9 + k * 3 * 10**8))
    assert len(sets) >= 3
    assert not sync.lost_frames
    assert sync.dropped['unmatched'] > 0
