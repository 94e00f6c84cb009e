"""The point_cloud node: clouds and depth images checked against the simulator's ground
truth, read back with independent readers (numpy structured dtypes built by hand here, and
the rosbags CDR deserialiser), layouts, masks, live parameters and every drop reason.

Tolerance: with ground-truth disparity the cloud's points equal the ground-truth 3-D points
to a relative 1e-5 of Z (float32 precision).
"""

from __future__ import annotations

from typing import Any

import cv2
import numba
import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from ros_helpers import capture, header, tuner
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header

from depth_nodes.errors import ConfigError
from depth_nodes.nodes import point_cloud
from depth_nodes.nodes.point_cloud import PointCloudNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from harness_nodes import Listener, count_calls, want_only

pytestmark = pytest.mark.ros

CONFIG = StereoSimConfig(width=160, height=120, n_frames=1, seed=6, right_cx_offset=3.5,
                         colour=True, distortion_scale=0.0, rotation_deg=0.0)
FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))
H, W = FRAME.disparity_gt.shape
RTOL = 1e-5
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _header() -> Header:
    return header(1234 * 10**9 + 5678, 'left_optical')


def _disparity(disparity: np.ndarray | None = None) -> Any:
    d = FRAME.disparity_gt if disparity is None else disparity
    return build_disparity(d, _header(), focal=FRAME.left_camera.fx, baseline=0.12,
                           min_disparity=-4.0, max_disparity=64.0, delta_d=0.0)


def _inputs(changes: dict[Any, Any] | None = None) -> dict[str, Any]:
    """Keyword arguments of on_frame; ``changes`` maps (name, field) -> value."""
    changes = dict(changes or {})
    rgb = FRAME.left_rect_gt
    msgs = {'disparity_msg': _disparity(), 'left_info': model_to_camera_info(FRAME.left_camera),
            'right_info': model_to_camera_info(FRAME.right_camera),
            'image': array_to_image(rgb, 'rgb8')}
    for (name, field), value in changes.items():
        target = msgs[name]
        for part in field.split('.')[:-1]:
            target = getattr(target, part)
        setattr(target, field.split('.')[-1], value)
    return msgs


def _cloud_dtype(fields: list[tuple[str, int]], step: int) -> np.dtype[Any]:
    return np.dtype({'names': [n for n, _ in fields], 'formats': ['<f4'] * len(fields),
                     'offsets': [o for _, o in fields], 'itemsize': step})


def _read(msg: Any, fields: list[tuple[str, int]], step: int) -> np.ndarray:
    """Independent reader: the raw bytes through a structured dtype written out here."""
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        (n, o, 7, 1) for n, o in fields]
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (H, W, step, step * W)
    assert msg.is_dense is False
    assert msg.is_bigendian is False
    return np.frombuffer(bytes(msg.data), _cloud_dtype(fields, step)).reshape(H, W)


def _gt_points() -> np.ndarray:
    cam = FRAME.left_camera
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    z = FRAME.depth_gt.astype(np.float64)
    return np.dstack([(u - cam.cx) * z / cam.fx, (v - cam.cy) * z / cam.fy, z])


def _make(context: Context, **params: Any) -> Any:
    n = PointCloudNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])
    capture(n)
    return n


@pytest.fixture
def node(context: Context) -> Any:
    n = _make(context)
    yield n
    n.destroy_node()


XYZ_RGB_PADDED = [('x', 0), ('y', 4), ('z', 8), ('rgb', 16)]


def test_gt_disparity_gives_gt_points_and_colours(node: Any) -> None:
    node.on_frame(**_inputs())
    assert node.drops == {}
    cloud = node.outbox['/points2']
    assert cloud.header.frame_id == 'left_optical'
    assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == (1234, 5678)
    points = _read(cloud, XYZ_RGB_PADDED, 32)
    xyz = np.dstack([points['x'], points['y'], points['z']]).astype(np.float64)
    z = FRAME.depth_gt.astype(np.float64)
    assert np.isfinite(xyz).all()
    assert (np.abs(xyz[..., 2] - z) / z).max() < RTOL
    assert (np.linalg.norm(xyz - _gt_points(), axis=-1) / z).max() < RTOL
    packed = points['rgb'].view('<u4')
    rgb = FRAME.left_rect_gt.astype(np.uint32)
    np.testing.assert_array_equal(packed, rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2])
    depth = node.outbox['/depth']
    assert (depth.encoding, depth.step, depth.header.frame_id) == ('32FC1', 4 * W,
                                                                  'left_optical')
    np.testing.assert_array_equal(np.frombuffer(bytes(depth.data), '<f4').reshape(H, W),
                                  points['z'])


def test_threads_parameter_is_applied_to_the_frame(context: Context) -> None:
    node = _make(context, threads=2)
    try:
        numba.set_num_threads(1)
        node.on_frame(**_inputs())
        assert numba.get_num_threads() == min(2, numba.config.NUMBA_NUM_THREADS)
        assert cv2.getNumThreads() == 2
        assert set(node.outbox) == {'/points2', '/depth'}
    finally:
        node.destroy_node()


def test_rosbags_deserialiser_reads_the_same_cloud(node: Any) -> None:
    node.on_frame(**_inputs())
    msg = TYPESTORE.deserialize_cdr(serialize_message(node.outbox['/points2']),
                                    'sensor_msgs/msg/PointCloud2')
    assert [(f.name, f.offset) for f in msg.fields] == XYZ_RGB_PADDED
    assert (msg.height, msg.width, msg.point_step, msg.is_dense) == (H, W, 32, False)
    raw = np.asarray(msg.data).reshape(H, W, 32)
    z = raw[..., 8:12].copy().view('<f4')[..., 0]
    assert (np.abs(z - FRAME.depth_gt) / FRAME.depth_gt).max() < RTOL


@pytest.mark.parametrize(('use_color', 'avoid_padding', 'fields', 'step'), [
    (True, False, XYZ_RGB_PADDED, 32),
    (True, True, [('x', 0), ('y', 4), ('z', 8), ('rgb', 12)], 16),
    (False, False, [('x', 0), ('y', 4), ('z', 8)], 16),
    (False, True, [('x', 0), ('y', 4), ('z', 8)], 12),
])
def test_layouts(context: Context, use_color: bool, avoid_padding: bool,
                 fields: list[tuple[str, int]], step: int) -> None:
    n = _make(context, use_color=use_color, avoid_point_cloud_padding=avoid_padding)
    try:
        args = _inputs()
        if not use_color:
            del args['image']
        n.on_frame(**args)
        points = _read(n.outbox['/points2'], fields, step)
        assert (np.abs(points['z'] - FRAME.depth_gt) / FRAME.depth_gt).max() < RTOL
        assert len(n.outbox['/points2'].data) == H * W * step
    finally:
        n.destroy_node()


@pytest.mark.parametrize('encoding', ['mono8', 'rgb8', 'bgr8', 'rgba8', 'bgra8', 'mono16'])
def test_rgb_packing_per_encoding(node: Any, encoding: str) -> None:
    rgb = FRAME.left_rect_gt
    grey = rgb[..., 1]
    alpha = np.full((H, W, 1), 77, np.uint8)
    arrays = {'mono8': grey, 'rgb8': rgb, 'bgr8': rgb[..., ::-1],
              'rgba8': np.dstack([rgb, alpha]), 'bgra8': np.dstack([rgb[..., ::-1], alpha]),
              'mono16': grey.astype(np.uint16) * 257}
    expected = np.dstack([grey] * 3) if encoding.startswith('mono') else rgb
    node.on_frame(**_inputs({('image', 'encoding'): encoding}) | {
        'image': array_to_image(np.ascontiguousarray(arrays[encoding]), encoding)})
    packed = _read(node.outbox['/points2'], XYZ_RGB_PADDED, 32)['rgb'].view('<u4')
    e = expected.astype(np.uint32)
    np.testing.assert_array_equal(packed, e[..., 0] << 16 | e[..., 1] << 8 | e[..., 2])


def test_depth_16uc1_in_millimetres(context: Context) -> None:
    n = _make(context, depth_encoding='16UC1', max_range=float(np.quantile(FRAME.depth_gt,
                                                                          0.5)))
    try:
        n.on_frame(**_inputs())
        depth = n.outbox['/depth']
        assert (depth.encoding, depth.step) == ('16UC1', 2 * W)
        mm = np.frombuffer(bytes(depth.data), '<u2').reshape(H, W)
        z = n.params.values['max_range']
        kept = FRAME.depth_gt <= z * (1 - 1e-6)
        # within 1 mm: a depth 1e-5 relative off can round across a half millimetre
        expected = np.rint(FRAME.depth_gt[kept].astype(np.float64) * 1000)
        assert np.abs(mm[kept] - expected).max() <= 1
        assert (mm[kept] == expected).mean() > 0.99
        assert (mm[FRAME.depth_gt > z * (1 + 1e-6)] == 0).all()
        assert 0.4 < (mm > 0).mean() < 0.6
    finally:
        n.destroy_node()


def test_ranges_confidence_and_extra_fields(context: Context) -> None:
    lo, hi = (float(q) for q in np.quantile(FRAME.depth_gt, [0.1, 0.9]))
    n = _make(context, use_confidence=True, min_range=lo, max_range=hi, min_confidence=0.4,
              extra_fields='confidence, depth_std', disparity_std=0.5)
    conf = np.random.default_rng(2).random((H, W)).astype(np.float32)
    try:
        n.on_frame(**_inputs(), confidence=array_to_image(conf, '32FC1'))
        fields = [*XYZ_RGB_PADDED, ('confidence', 20), ('depth_std', 24)]
        points = _read(n.outbox['/points2'], fields, 32)
        z = FRAME.depth_gt
        inside = (z >= lo * (1 + 1e-6)) & (z <= hi * (1 - 1e-6))
        outside = (z < lo * (1 - 1e-6)) | (z > hi * (1 + 1e-6))
        kept = np.isfinite(points['z'])
        assert kept[inside & (conf >= 0.4)].all()
        assert not kept[outside | (conf < 0.4)].any()
        assert np.isnan(points['x'][~kept]).all()
        assert np.isnan(points['y'][~kept]).all()
        np.testing.assert_array_equal(points['confidence'], conf)
        fb = FRAME.left_camera.fx * 0.12
        np.testing.assert_allclose(points['depth_std'][kept], z[kept] ** 2 / fb * 0.5,
                                   rtol=RTOL)
        assert np.isnan(points['depth_std'][~kept]).all()
        depth = np.frombuffer(bytes(n.outbox['/depth'].data), '<f4').reshape(H, W)
        np.testing.assert_array_equal(np.isnan(depth), ~kept)
    finally:
        n.destroy_node()


def test_synchroniser_inputs_follow_use_color_and_use_confidence(context: Context) -> None:
    n = _make(context, use_color=False, use_confidence=True)
    try:
        assert [spec.topic for spec in n.inputs] == [
            '/disparity', '/left/camera_info', '/right/camera_info', '/confidence']
        args = _inputs()
        conf = array_to_image(np.ones((H, W), np.float32), '32FC1', args['disparity_msg'].header)
        for info in (args['left_info'], args['right_info']):
            info.header = args['disparity_msg'].header
        msgs = [args['disparity_msg'], args['left_info'], args['right_info'], conf]
        for spec, msg in zip(n.inputs, msgs, strict=True):
            spec.callback(msg)
        assert set(n.outbox) == {'/points2', '/depth'}
        assert [f.name for f in n.outbox['/points2'].fields] == ['x', 'y', 'z']
    finally:
        n.destroy_node()
    n = _make(context)
    try:
        assert [spec.topic for spec in n.inputs] == [
            '/disparity', '/left/camera_info', '/right/camera_info', '/left/image_rect_color']
    finally:
        n.destroy_node()


def test_inconsistent_start_up_parameters_are_refused(context: Context) -> None:
    with pytest.raises(ConfigError, match='min_confidence needs use_confidence'):
        PointCloudNode(context=context, parameter_overrides=[
            Parameter('min_confidence', value=0.5)])
    with pytest.raises(ConfigError, match='unknown field'):
        PointCloudNode(context=context, parameter_overrides=[
            Parameter('extra_fields', value='intensity')])


@pytest.mark.parametrize(('changes', 'reason'), [
    ({('disparity_msg', 'image.encoding'): '16UC1'}, 'disparity_encoding'),
    ({('disparity_msg', 'image.step'): 10}, 'malformed_image'),
    ({('left_info', 'k'): [0.0] * 9}, 'uncalibrated'),
    ({('right_info', 'p'): [100.0, 0, 80, 5.0, 0, 100, 60, 0, 0, 0, 1, 0]},
     'bad_calibration'),
    ({('left_info', 'width'): 320, ('right_info', 'width'): 320}, 'size_mismatch'),
    ({('image', 'width'): 80, ('image', 'step'): 240}, 'size_mismatch'),
    ({('image', 'encoding'): '32FC1'}, 'unsupported_encoding'),
    ({('image', 'encoding'): 'yuv420'}, 'unsupported_encoding'),
    ({('image', 'step'): 10}, 'malformed_image'),
])
def test_bad_input_is_a_counted_drop(node: Any, changes: dict[Any, Any], reason: str) -> None:
    node.on_frame(**_inputs(changes))
    assert node.outbox == {}
    assert node.drops == {reason: 1}
    node.on_frame(**_inputs())
    assert '/points2' in node.outbox


@pytest.mark.parametrize(('array', 'encoding', 'reason'), [
    (np.ones((H, W), np.uint8), 'mono8', 'unsupported_encoding'),
    (np.ones((H, W - 1), np.float32), '32FC1', 'size_mismatch'),
    (None, '32FC1', 'malformed_image'),
])
def test_bad_confidence_is_a_counted_drop(context: Context, array: Any, encoding: str,
                                          reason: str) -> None:
    n = _make(context, use_confidence=True)
    try:
        conf = array_to_image(np.ones((H, W), np.float32) if array is None else array,
                              encoding)
        if array is None:
            conf.data = bytes(10)
        n.on_frame(**_inputs(), confidence=conf)
        assert n.outbox == {}
        assert n.drops == {reason: 1}
    finally:
        n.destroy_node()


def test_missing_camera_info_is_counted(node: Any) -> None:
    callbacks = [spec.callback for spec in node.inputs]
    for i in range(7):  # disparity and image only: the queue (5) overflows
        args = _inputs()
        args['disparity_msg'].header.stamp.sec = i
        args['image'].header.stamp.sec = i
        callbacks[0](args['disparity_msg'])
        callbacks[3](args['image'])
    assert node.outbox == {}
    assert node.drops['sync_queue_full'] >= 2


def test_parameters_change_live_and_bad_values_are_rejected(node: Any,
                                                            context: Context) -> None:
    with tuner(node, context) as tune:
        results = tune(avoid_point_cloud_padding=True, depth_encoding='16UC1',
                       extra_fields='depth_std', max_range=3.0)
        assert all(r.successful for r in results), [r.reason for r in results]
        node.on_frame(**_inputs())
        points = _read(node.outbox['/points2'], [('x', 0), ('y', 4), ('z', 8), ('rgb', 12),
                                                 ('depth_std', 16)], 20)
        assert np.nanmax(points['z']) <= 3.0
        assert node.outbox['/depth'].encoding == '16UC1'
        for values, reason in [
            ({'extra_fields': 'confidence'}, 'extra field confidence needs use_confidence'),
            ({'extra_fields': 'depth_std,depth_std'}, 'a field is listed twice'),
            ({'extra_fields': 'intensity'}, 'unknown field(s) intensity'),
            ({'min_range': 4.0}, 'max_range (3.0) must be >= min_range (4.0)'),
            ({'depth_encoding': 'mono16'}, 'must be one of 32FC1, 16UC1'),
            ({'min_confidence': 0.5}, 'min_confidence needs use_confidence'),
            ({'use_color': False}, 'read-only'),
            ({'queue_size': 9}, 'read-only'),
        ]:
            (result,) = tune(**values)
            assert not result.successful, values
            assert reason in result.reason, (values, result.reason)
        assert node.params.values['extra_fields'] == 'depth_std'
        assert node.params.values['min_range'] == 0.0


@pytest.mark.slow  # a benchmark: 5 s
def test_bench_reports_times_and_sizes(ros_env: dict[str, str]) -> None:
    from depth_nodes.tools.bench.nodes import bench_point_cloud

    bench = bench_point_cloud(1)
    assert (bench.width, bench.height, bench.point_step) == (640, 480, 32)
    assert bench.cloud_bytes == 640 * 480 * 32
    assert bench.depth_bytes == 640 * 480 * 4
    text = bench.format()
    assert 'node / SGM' in text
    assert '9.83 MB (32 bytes x 307200 points)' in text


def test_compressed_colour_and_its_hostile_forms(context: Context) -> None:
    """image_transport: compressed colours the cloud from left/image_rect_color/compressed
    (PNG: the raw image's colours exactly); a damaged JPEG or a foreign format is one
    counted drop of its kind."""
    from sensor_msgs.msg import CompressedImage

    from depth_nodes.ros.transport import compress_image

    n = _make(context, image_transport='compressed')
    try:
        assert '/left/image_rect_color/compressed' in [s.topic for s in n.inputs]
        raw = _make(context)
        raw.on_frame(**_inputs())
        png = compress_image(FRAME.left_rect_gt, 'rgb8', codec='png')
        n.on_frame(**{**_inputs(), 'image': png})
        assert n.drops == {}
        assert bytes(n.outbox['/points2'].data) == bytes(raw.outbox['/points2'].data)
        raw.destroy_node()
        damaged = compress_image(FRAME.left_rect_gt, 'rgb8', codec='jpeg')
        damaged.data = bytes(damaged.data)[:100]
        n.on_frame(**{**_inputs(), 'image': damaged})
        foreign = CompressedImage(format='rgb8; webp compressed rgb8', data=bytes(png.data))
        n.on_frame(**{**_inputs(), 'image': foreign})
        assert n.drops == {'decode_failed': 1, 'unsupported_format': 1}
    finally:
        n.destroy_node()


@pytest.mark.parametrize(('wanted', 'work'), [
    (('/points2', '/depth'), {'reproject_disparity': 1, 'to_rgb8': 1, 'build_pointcloud': 1}),
    (('/points2',), {'reproject_disparity': 1, 'to_rgb8': 1, 'build_pointcloud': 1}),
    (('/depth',), {'reproject_disparity': 1}),  # no colour read, no cloud built
    ((), {}),  # skipped before anything is read
])
def test_only_the_outputs_wanted_are_computed(node: Any, monkeypatch: pytest.MonkeyPatch,
                                              wanted: tuple[str, ...],
                                              work: dict[str, int]) -> None:
    node.on_frame(**_inputs())
    everything = dict(node.outbox)
    node.outbox.clear()
    calls = count_calls(monkeypatch, point_cloud, 'reproject_disparity', 'to_rgb8',
                        'build_pointcloud')
    want_only(monkeypatch, *wanted)
    node.on_frame(**_inputs())
    assert node.outbox == {topic: everything[topic] for topic in wanted}
    assert calls == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if wanted else 1)


def test_the_depth_alone_needs_no_colour(node: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    want_only(monkeypatch, '/depth')
    node.on_frame(**_inputs({('image', 'encoding'): '32FC1'}))  # unusable as colour
    assert set(node.outbox) == {'/depth'}
    assert node.drops == {}
    want_only(monkeypatch, '/depth', '/points2')
    node.on_frame(**_inputs({('image', 'encoding'): '32FC1'}))
    assert node.drops == {'unsupported_encoding': 1}


def test_live_a_subscriber_on_depth_gets_depth_and_no_cloud_is_built(
        context: Context) -> None:
    node = PointCloudNode(context=context)
    listener = Listener(context)
    try:
        depth = listener.subscribe(node.pub_depth, Image)
        node.on_frame(**_inputs())
        listener.wait(depth, 1)
        assert (node.pub_depth.count, node.pub_points.count) == (1, 0)
        points = listener.subscribe(node.pub_points, PointCloud2)
        node.on_frame(**_inputs())
        listener.wait(points, 1)
        listener.wait(depth, 2)
        z = _read(points[0], XYZ_RGB_PADDED, 32)['z']
        for msg in depth:
            np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), '<f4').reshape(H, W),
                                          z)
        assert node.drops == {}
    finally:
        listener.close()
        node.destroy_node()
