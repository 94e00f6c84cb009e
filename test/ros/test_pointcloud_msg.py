"""Tests of depth_nodes.ros.pointcloud, read back independently of the module under test."""

from __future__ import annotations

import array

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from reference.pointcloud import pack_points_reference
from ros_helpers import header
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from depth_nodes.errors import MessageError
from depth_nodes.ros.image import set_message_bytes
from depth_nodes.ros.pointcloud import (
    _layout,
    build_pointcloud,
    pack_points,
    read_pointcloud,
)

H, W = 4, 6


def _header() -> Header:
    return header(3 * 10**9 + 7, 'left_optical')


def _inputs(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(H, W, 3)).astype(np.float32)
    xyz[1, 2] = np.nan
    rgb = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    rgb[0, 0] = (0x12, 0x34, 0x56)
    conf = rng.uniform(size=(H, W)).astype(np.float32)
    return xyz, rgb, conf


def _by_hand(data: bytes, offsets: dict[str, int], step: int) -> np.ndarray:
    dtype = np.dtype({'names': list(offsets), 'formats': ['<f4'] * len(offsets),
                      'offsets': list(offsets.values()), 'itemsize': step})
    return np.frombuffer(data, dtype=dtype).reshape(H, W)


LAYOUTS = [
    (False, True, {'x': 0, 'y': 4, 'z': 8}, 16),
    (False, False, {'x': 0, 'y': 4, 'z': 8}, 12),
    (True, True, {'x': 0, 'y': 4, 'z': 8, 'rgb': 16}, 32),
    (True, False, {'x': 0, 'y': 4, 'z': 8, 'rgb': 12}, 16),
]


@pytest.mark.parametrize(('use_rgb', 'pad', 'offsets', 'step'), LAYOUTS)
def test_layout_read_back_with_numpy_and_rosbags(
    use_rgb: bool, pad: bool, offsets: dict[str, int], step: int
) -> None:
    xyz, rgb, _ = _inputs()
    msg = build_pointcloud(xyz, _header(), rgb=rgb if use_rgb else None, pad=pad)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (H, W, step, step * W)
    assert not msg.is_dense
    assert not msg.is_bigendian
    assert msg.header.frame_id == 'left_optical'
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        (n, o, PointField.FLOAT32, 1) for n, o in offsets.items()]

    store = get_typestore(Stores.ROS2_JAZZY)
    bag_msg = store.deserialize_cdr(serialize_message(msg), 'sensor_msgs/msg/PointCloud2')
    assert bag_msg.point_step == step
    assert [(f.name, f.offset) for f in bag_msg.fields] == list(offsets.items())
    for data in (bytes(msg.data), bag_msg.data.tobytes()):
        assert len(data) == H * W * step
        pts = _by_hand(data, offsets, step)
        np.testing.assert_array_equal(np.stack([pts['x'], pts['y'], pts['z']], -1), xyz)
        assert np.isnan(pts['x'][1, 2])
        assert np.isnan(pts['z'][1, 2])
        if use_rgb:
            packed = np.ascontiguousarray(pts['rgb']).view(np.uint32)
            assert packed[0, 0] == 0x00123456
            r, g, b = (rgb[..., i].astype(np.uint32) for i in range(3))
            np.testing.assert_array_equal(packed, (r << 16) | (g << 8) | b)

    for m in (msg, bag_msg):
        out = read_pointcloud(m)
        assert set(out) == set(offsets)
        np.testing.assert_array_equal(np.stack([out['x'], out['y'], out['z']], -1), xyz)
        if use_rgb:
            assert out['rgb'].dtype == np.uint8
            np.testing.assert_array_equal(out['rgb'], rgb)


@pytest.mark.parametrize(
    ('use_rgb', 'pad', 'offsets', 'step'),
    [(True, True, {'rgb': 16, 'confidence': 20, 'cost': 24}, 32),
     (False, True, {'confidence': 16}, 32),
     (True, False, {'rgb': 12, 'confidence': 16, 'cost': 20}, 24)],
)
def test_extra_fields(use_rgb: bool, pad: bool, offsets: dict[str, int], step: int) -> None:
    xyz, rgb, conf = _inputs(1)
    extra = {'confidence': conf, 'cost': conf * 2}
    if not use_rgb:
        del extra['cost']
    msg = build_pointcloud(xyz, None, rgb=rgb if use_rgb else None, pad=pad,
                           extra_fields=extra)
    assert msg.point_step == step
    assert [(f.name, f.offset) for f in msg.fields][3:] == list(offsets.items())
    pts = _by_hand(bytes(msg.data), {'x': 0, **offsets}, step)
    np.testing.assert_array_equal(pts['confidence'], conf)
    out = read_pointcloud(msg)
    for name, values in extra.items():
        np.testing.assert_array_equal(out[name], values)


def test_build_rejects_bad_shapes() -> None:
    xyz, rgb, conf = _inputs()
    with pytest.raises(MessageError, match=r'xyz must be a \(H, W, 3\) array, got shape'):
        build_pointcloud(xyz[..., :2], None)
    with pytest.raises(MessageError, match=r'rgb must be \(4, 6, 3\) uint8 like xyz, got shape '
                                           r'\(4, 6, 3\) dtype float32'):
        build_pointcloud(xyz, None, rgb=rgb.astype(np.float32))
    with pytest.raises(MessageError, match=r"extra field 'c' must have shape \(4, 6\), got "
                                           r'\(6, 4\)'):
        build_pointcloud(xyz, None, extra_fields={'c': conf.T})
    with pytest.raises(MessageError, match="extra field name 'rgb' is empty or reserved"):
        build_pointcloud(xyz, None, extra_fields={'rgb': conf})


def _cloud(fields: list[tuple[str, int, int, int]], point_step: int, height: int, width: int,
           data: bytes, big: bool = False, row_step: int | None = None) -> PointCloud2:
    msg = PointCloud2(height=height, width=width, point_step=point_step,
                      row_step=point_step * width if row_step is None else row_step,
                      is_bigendian=big)
    msg.fields = [PointField(name=n, offset=o, datatype=t, count=c) for n, o, t, c in fields]
    msg.data = data
    return msg


def test_read_generic_types_big_endian_and_row_padding() -> None:
    rng = np.random.default_rng(5)
    dtype = np.dtype({'names': ['a', 'b', 'c', 'd', 'e', 'f'],
                      'formats': ['>i2', '>u4', '>f8', 'u1', ('>f4', (2,)), 'i1'],
                      'offsets': [0, 2, 6, 14, 15, 23], 'itemsize': 24})
    pts = np.zeros((2, 3), dtype)
    for name in dtype.names:
        pts[name] = rng.integers(0, 100, size=pts[name].shape)
    rows = np.zeros((2, 3 * 24 + 8), np.uint8)
    rows[:, :72] = pts.view(np.uint8).reshape(2, 72)
    fields = [('a', 0, PointField.INT16, 1), ('b', 2, PointField.UINT32, 1),
              ('c', 6, PointField.FLOAT64, 1), ('d', 14, PointField.UINT8, 1),
              ('e', 15, PointField.FLOAT32, 2), ('f', 23, PointField.INT8, 1)]
    out = read_pointcloud(_cloud(fields, 24, 2, 3, rows.tobytes(), big=True, row_step=80))
    for name in dtype.names:
        assert out[name].dtype.isnative
        np.testing.assert_array_equal(out[name], pts[name])
    assert out['e'].shape == (2, 3, 2)


@pytest.mark.parametrize(
    ('kwargs', 'pattern'),
    [
        ({'data': bytes(10)}, 'PointCloud2 data has 10 bytes, but row_step 192 x height 4 '
                              'needs 768'),
        ({'fields': [('x', 0, 9, 1)]}, "field 'x' has unknown datatype 9"),
        ({'fields': [('x', 10, 7, 1)]}, r"field 'x' \(offset 10, 4 bytes\) does not fit in "
                                        'point_step 12'),
        ({'fields': [('x', 0, 7, 1), ('x', 4, 7, 1)]}, "field 'x' appears twice"),
        ({'row_step': 40}, 'row_step 40 is smaller than point_step 12 x width 6 = 72'),
        ({'point_step': 0}, 'point_step must be positive, got 0'),
        ({'height': 2**31, 'width': 2**31}, 'PointCloud2 data has 768 bytes'),
    ],
)
def test_read_malformed(kwargs: dict[str, object], pattern: str) -> None:
    args: dict[str, object] = {'fields': [('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1)],
                               'point_step': 12, 'height': H, 'width': W, 'data': bytes(768),
                               'row_step': 192}
    args.update(kwargs)
    if 'width' in kwargs:
        args['row_step'] = 12 * kwargs['width']  # type: ignore[operator]
    with pytest.raises(MessageError, match=pattern):
        read_pointcloud(_cloud(**args))  # type: ignore[arg-type]


def test_empty_cloud() -> None:
    msg = build_pointcloud(np.zeros((0, 5, 3), np.float32), None, rgb=np.zeros((0, 5, 3),
                                                                                 np.uint8))
    assert msg.point_step == 32
    out = read_pointcloud(msg)
    assert out['x'].shape == (0, 5)
    assert len(msg.data) == 0


@pytest.mark.parametrize('extra', [False, True])
@pytest.mark.parametrize(('use_rgb', 'pad', 'offsets', 'step'), LAYOUTS)
def test_packing_kernel_equals_numpy_reference(use_rgb: bool, pad: bool,
                                               offsets: dict[str, int], step: int,
                                               extra: bool) -> None:
    """The numba packing writes the bytes the numpy structured array does, padding zero
    included, from float32 and float64 points (cast on the way, as numpy casts)."""
    xyz, rgb, conf = _inputs(3)
    fields_extra = {'confidence': conf, 'depth_std': conf.astype(np.float64) * 2} if extra \
        else {}
    fields, layout_step = _layout(use_rgb, pad, list(fields_extra))
    assert dict(fields) == {**offsets, **dict(fields[len(offsets):])}
    for points in (xyz, xyz.astype(np.float64) * 1.1):
        got = pack_points(points, rgb if use_rgb else None, fields_extra, fields, layout_step)
        want = pack_points_reference(points, rgb if use_rgb else None, fields_extra, fields,
                                     layout_step)
        assert got.typecode == 'B'
        assert bytes(got) == want


def test_message_keeps_its_data_array() -> None:
    """The cloud's bytes go into the message as the array they were written in (no copy)."""
    xyz, rgb, _ = _inputs()
    data = array.array('B', b'\x01\x02\x03')
    msg = PointCloud2()
    set_message_bytes(msg, data)
    assert msg.data is data
    cloud = build_pointcloud(xyz, None, rgb=rgb)
    assert isinstance(cloud.data, array.array)
    assert bytes(cloud.data) in serialize_message(cloud)  # what rclpy publishes
