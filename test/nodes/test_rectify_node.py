"""The rectify node: every bad input is a counted, logged drop; parameters change live."""

from __future__ import annotations

import subprocess
import sys
import time
from typing import Any

import cv2
import numba
import numpy as np
import pytest
import rclpy
from helpers import Lazy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import capture, tuner
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.core.rectify import Rectifier
from depth_nodes.nodes import rectify
from depth_nodes.nodes.rectify import RectifyNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

CONFIG = StereoSimConfig(width=160, height=120, n_frames=1, seed=8, colour=True)
FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))



@pytest.fixture
def node(context: Context) -> Any:
    n = RectifyNode(context=context)
    capture(n, history=True)
    yield n
    n.destroy_node()


def _pair(image: np.ndarray | None = None, encoding: str = 'rgb8',
          **info_changes: Any) -> tuple[Image, CameraInfo]:
    image_msg = array_to_image(FRAME.left_raw if image is None else image, encoding)
    info = model_to_camera_info(FRAME.left_camera)
    for name, value in info_changes.items():
        setattr(info, name, value)
    return image_msg, info


def test_colour_frame_gives_colour_and_mono(node: Any) -> None:
    node.on_frame(*_pair())
    topics = [t for t, _ in node.outbox]
    assert topics == ['/image_rect_color', '/image_rect']
    color, mono = (m for _, m in node.outbox)
    assert (color.encoding, mono.encoding) == ('rgb8', 'mono8')
    expected = Rectifier().rectify(FRAME.left_raw, FRAME.left_camera)
    np.testing.assert_array_equal(image_to_array(color), expected)
    np.testing.assert_array_equal(image_to_array(mono),
                                  cv2.cvtColor(expected, cv2.COLOR_RGB2GRAY))
    assert node.drops == {}


@pytest.mark.parametrize(('pair', 'reason'), [
    (lambda: _pair(k=[0.0] * 9), 'uncalibrated'),
    (lambda: _pair(d=[0.1, np.nan, 0.0, 0.0, 0.0]), 'bad_calibration'),
    (lambda: _pair(d=[0.1, 0.0, 0.0]), 'bad_calibration'),
    (lambda: _pair(width=320), 'size_mismatch'),
    (lambda: _pair(FRAME.left_raw[:, :, 0], 'mono8', height=60), 'size_mismatch'),
    (lambda: (_yuv(), _pair()[1]), 'unsupported_encoding'),
    (lambda: (_truncated(), _pair()[1]), 'malformed_image'),
    (lambda: (_odd_bayer(), _pair(width=159)[1]), 'malformed_image'),
])
def test_bad_frames_are_counted_and_the_node_goes_on(node: Any, pair: Any, reason: str) -> None:
    node.on_frame(*pair())
    assert node.outbox == []
    assert node.drops == {reason: 1}
    node.on_frame(*_pair())  # the next good frame still comes out
    assert len(node.outbox) == 2


def _yuv() -> Image:
    msg = array_to_image(FRAME.left_raw, 'rgb8')
    msg.encoding = 'yuv420'
    return msg


def _bayer(order: str = 'rggb', bits: int = 8) -> Image:
    """The raw colour frame sampled on a Bayer tile (top-left first, as ROS names it)."""
    rgb = FRAME.left_raw if bits == 8 else FRAME.left_raw.astype(np.uint16) * 257
    mosaic = np.empty(rgb.shape[:2], rgb.dtype)
    for i, c in enumerate(order):
        dy, dx = divmod(i, 2)
        mosaic[dy::2, dx::2] = rgb[dy::2, dx::2, 'rgb'.index(c)]
    return array_to_image(mosaic, f'bayer_{order}{bits}')


def _odd_bayer() -> Image:
    msg = _bayer()
    return array_to_image(image_to_array(msg)[:, :159].copy(), msg.encoding)


@pytest.mark.parametrize('order', ['rggb', 'gbrg'])
@pytest.mark.parametrize('bits', [8, 16])
def test_bayer_is_demosaiced_before_it_is_rectified(node: Any, order: str, bits: int) -> None:
    """The colour output is the rectified demosaiced image (image_proc's debayer then
    rectify), not a demosaic of a rectified mosaic, which would mix the colours."""
    node.on_frame(_bayer(order, bits), _pair()[1])
    assert node.drops == {}
    color, mono = (m for _, m in node.outbox)
    assert (color.encoding, mono.encoding) == (('bgr8', 'mono8') if bits == 8 else
                                               ('bgr16', 'mono16'))
    scale = 1.0 if bits == 8 else 257.0
    expected = Rectifier().rectify(FRAME.left_raw[:, :, ::-1].copy(), FRAME.left_camera)
    got = image_to_array(color).astype(np.float64) / scale
    inner = (slice(8, -8), slice(8, -8))
    error = np.abs(got - expected)[inner]
    assert error.mean() < 3.0, error.mean()  # VNG on a textured scene: measured 1.7 - 2.2
    # the rectifier saw colour: remapping the mosaic first would mix its samples
    wrong = Rectifier().rectify(image_to_array(_bayer(order, bits)), FRAME.left_camera)
    code = getattr(cv2, f'COLOR_Bayer{order.upper()}2BGR')
    mixed = cv2.cvtColor(wrong, code).astype(np.float64) / scale
    assert np.abs(mixed - expected)[inner].mean() > 2.5 * error.mean()  # measured: 3.1 - 3.9x


def _truncated() -> Image:
    msg = array_to_image(FRAME.left_raw, 'rgb8')
    msg.data = bytes(msg.data)[:1000]
    return msg


def test_unmatched_stamps_are_counted(node: Any) -> None:
    image, info = _pair()
    info.header.stamp.sec = 5
    # feed the node's subscription callbacks, which go through its stamp synchroniser
    (image_cb, info_cb) = (spec.callback for spec in node.inputs)
    image.header.stamp.sec = 1
    image_cb(image)
    info_cb(info)
    matched_image, _ = _pair()
    matched_image.header.stamp.sec = 5
    image_cb(matched_image)
    assert len(node.outbox) == 2
    assert node.drops == {'sync_unmatched': 1}


def test_interpolation_changes_through_the_parameter_service(node: Any,
                                                             context: Context) -> None:
    with tuner(node, context) as tune:
        maps = Rectifier().maps(FRAME.left_camera)
        for value, flag in (('nearest', cv2.INTER_NEAREST), (2, cv2.INTER_CUBIC),
                            ('lanczos4', cv2.INTER_LANCZOS4)):
            (result,) = tune(interpolation=value)
            assert result.successful, result.reason
            node.outbox.clear()
            node.on_frame(*_pair())
            expected = cv2.remap(FRAME.left_raw, *maps, flag)
            np.testing.assert_array_equal(image_to_array(node.outbox[0][1]), expected)
        (rejected,) = tune(interpolation='bilinear')
        assert not rejected.successful
        assert 'interpolation must be one of nearest' in rejected.reason
        assert node.get_parameter('interpolation').value == 'lanczos4'
        (read_only,) = tune(queue_size=9)
        assert not read_only.successful
        assert node.get_parameter('queue_size').value == 5


def test_threads_parameter_is_applied_to_the_frame(context: Context) -> None:
    node = RectifyNode(context=context, parameter_overrides=[Parameter('threads', value=2)])
    capture(node, history=True)
    try:
        numba.set_num_threads(1)
        node.on_frame(*_pair())
        assert numba.get_num_threads() == min(2, numba.config.NUMBA_NUM_THREADS)
        assert cv2.getNumThreads() == 2
        expected = Rectifier().rectify(FRAME.left_raw, FRAME.left_camera)
        np.testing.assert_array_equal(image_to_array(node.outbox[0][1]), expected)
    finally:
        node.destroy_node()


def test_bad_startup_parameter_is_a_clear_error(ros_env: dict[str, str]) -> None:
    result = subprocess.run(
        [sys.executable, '-m', 'depth_nodes.nodes.scripts', 'rectify', '--ros-args',
         '-p', 'interpolation:=bilinear'],
        capture_output=True, text=True, env=ros_env, timeout=120, check=False)
    assert result.returncode == 1
    assert 'RectifyNode: error: /rectify: interpolation=' in result.stderr
    assert 'Traceback' not in result.stderr


def test_node_runs_live_over_dds(context: Context) -> None:
    live = RectifyNode(context=context, namespace='/cam')
    peer = rclpy.create_node('camera', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(live)
    executor.add_node(peer)
    got: list[Image] = []
    peer.create_subscription(Image, '/cam/image_rect', got.append, 10)
    pub_image = peer.create_publisher(Image, '/cam/image', 10)
    pub_info = peer.create_publisher(CameraInfo, '/cam/camera_info', 10)
    try:
        deadline = time.monotonic() + 30
        while not got and time.monotonic() < deadline:
            image, info = _pair()
            pub_image.publish(image)
            pub_info.publish(info)
            executor.spin_once(timeout_sec=0.1)
        assert got, 'no rectified image within 30 s'
        expected = cv2.cvtColor(Rectifier().rectify(FRAME.left_raw, FRAME.left_camera),
                                cv2.COLOR_RGB2GRAY)
        np.testing.assert_array_equal(image_to_array(got[0]), expected)
    finally:
        executor.shutdown()
        live.destroy_node()
        peer.destroy_node()


@pytest.fixture
def compressed_node(context: Context) -> Any:
    n = RectifyNode(context=context,
                    parameter_overrides=[Parameter('image_transport', value='compressed')])
    capture(n, history=True)
    yield n
    n.destroy_node()


def _stamped(msg: Any, sec: int) -> Any:
    msg.header.stamp.sec = sec
    return msg


def test_compressed_transport_subscribes_image_compressed_and_matches_raw(
        compressed_node: Any) -> None:
    """image_transport: compressed reads sensor_msgs/CompressedImage on image/compressed;
    a PNG gives the very output of the raw image, a damaged JPEG is one counted frame."""
    from sensor_msgs.msg import CompressedImage

    from depth_nodes.ros.transport import compress_image

    node = compressed_node
    image_spec, info_spec = node.inputs
    assert image_spec.topic == '/image/compressed'
    assert image_spec.msg_type is CompressedImage
    info = _pair()[1]
    png = compress_image(FRAME.left_raw, 'rgb8', codec='png')
    image_spec.callback(_stamped(png, 1))
    info_spec.callback(_stamped(info, 1))
    # image_transport stores colour as BGR: the rectified colour image is bgr8
    expected = Rectifier().rectify(FRAME.left_raw[:, :, ::-1].copy(), FRAME.left_camera)
    assert [t for t, _ in node.outbox] == ['/image_rect_color', '/image_rect']
    assert node.outbox[0][1].encoding == 'bgr8'
    np.testing.assert_array_equal(image_to_array(node.outbox[0][1]), expected)
    jpeg = compress_image(FRAME.left_raw, 'rgb8', codec='jpeg')
    jpeg.data = bytes(jpeg.data)[:200]
    for sec, msg in ((2, jpeg), (3, compress_image(FRAME.left_raw, 'rgb8', codec='png'))):
        image_spec.callback(_stamped(msg, sec))
        info_spec.callback(_stamped(_pair()[1], sec))
    assert node.drops == {'decode_failed': 1}  # once: not also as an unmatched frame
    assert len(node.outbox) == 4
    foreign = CompressedImage(format='rgb8; h264 compressed rgb8', data=bytes(png.data))
    image_spec.callback(_stamped(foreign, 4))
    info_spec.callback(_stamped(_pair()[1], 4))
    assert node.drops == {'decode_failed': 1, 'unsupported_format': 1}


def test_an_unknown_image_transport_is_refused_at_start_up(context: Context) -> None:
    from depth_nodes.errors import ConfigError

    with pytest.raises(ConfigError, match=r"image_transport='theora' rejected: must be one of "
                                          r'raw, compressed, compressedDepth'):
        RectifyNode(context=context,
                    parameter_overrides=[Parameter('image_transport', value='theora')])


def test_frame_id_override_leaves_the_input_alone(context: Context) -> None:
    """`frame_id` renames the outputs' frame (a driver's frame names that do not fit the
    robot's TF tree); the input message keeps its own."""
    node = RectifyNode(context=context,
                       parameter_overrides=[Parameter('frame_id', value='cam_optical')])
    outbox: list[Any] = []
    node.sink = lambda topic, msg: outbox.append(msg)
    try:
        image, info = _pair()
        image.header.frame_id = 'driver_frame'
        image.header.stamp.sec = 12
        node.on_frame(image, info)
        assert [m.header.frame_id for m in outbox] == ['cam_optical', 'cam_optical']
        assert all(m.header.stamp.sec == 12 for m in outbox)
        assert image.header.frame_id == 'driver_frame'
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('encoding', 'wanted', 'work'), [
    ('rgb8', ('/image_rect', '/image_rect_color'), {'rectify': 1, 'to_gray': 1}),
    ('rgb8', ('/image_rect_color',), {'rectify': 1}),
    ('rgb8', ('/image_rect',), {'rectify': 1, 'to_gray': 1}),
    ('rgb8', (), {}),
    ('mono8', ('/image_rect',), {'rectify': 1}),
    ('mono8', ('/image_rect_color',), {}),  # a mono image has no colour output
])
def test_only_the_outputs_wanted_are_computed(node: Any, monkeypatch: pytest.MonkeyPatch,
                                              encoding: str, wanted: tuple[str, ...],
                                              work: dict[str, int]) -> None:
    image = FRAME.left_raw if encoding == 'rgb8' else FRAME.left_raw[:, :, 0]
    node.on_frame(*_pair(image, encoding))
    everything = list(node.outbox)
    node.outbox.clear()
    rectified = count_calls(monkeypatch, node.rectifier, 'rectify')
    grey = count_calls(monkeypatch, rectify, 'to_gray')
    want_only(monkeypatch, *wanted)
    node.on_frame(*_pair(image, encoding))
    assert node.outbox == [(topic, msg) for topic, msg in everything if topic in wanted]
    assert rectified + grey == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if work else 1)
