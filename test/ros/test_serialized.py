"""Messages written straight to CDR (depth_nodes.ros.serialized) against rclpy's own
serialisation: the bytes a MarkerArray writer produces deserialise to the message meant,
and are the bytes rclpy (with rosbags zeroing the padding) gives for it; the reader reads
any MarkerArray back, from rclpy or from the writer."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from depth_nodes.ros.serialized import (
    ADD,
    DELETE,
    DELETEALL,
    TRIANGLE_LIST,
    Serialized,
    marker_array,
    read_marker_array,
)
from depth_nodes.tools.bags.io import serialize


def _triangles(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-5, 5, (3 * n, 3)).astype(np.float32)


def test_a_marker_array_written_here_is_the_one_rclpy_writes() -> None:
    first, second = _triangles(40), _triangles(1, seed=1)
    message = marker_array((12, 345), 'odom', 'tsdf_mesh', [(7, first), (9, None), (3, second)],
                           (0.8, 0.7, 0.6, 1.0), delete_all=True)
    assert isinstance(message, Serialized)
    assert message.msgtype == 'visualization_msgs/msg/MarkerArray'
    decoded = message.message()
    assert [(m.id, m.action) for m in decoded.markers] == [(0, DELETEALL), (7, ADD),
                                                           (9, DELETE), (3, ADD)]
    marker = decoded.markers[1]
    assert marker.type == TRIANGLE_LIST
    assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (12, 345)
    assert marker.header.frame_id == 'odom'
    assert marker.ns == 'tsdf_mesh'
    assert marker.pose.orientation.w == 1.0
    assert (marker.scale.x, marker.scale.y, marker.scale.z) == (1.0, 1.0, 1.0)
    assert marker.color.g == pytest.approx(0.7)
    np.testing.assert_array_equal([[p.x, p.y, p.z] for p in marker.points], first)
    assert serialize(decoded) == message.data


def test_the_reader_reads_any_marker_array_back() -> None:
    marker = Marker(ns='other', id=4, type=TRIANGLE_LIST, action=ADD, text='words',
                    points=[Point(x=1.0, y=2.0, z=3.0)] * 3,
                    colors=[ColorRGBA(r=1.0, g=0.5, b=0.25, a=1.0)] * 3)
    marker.header.frame_id = 'map'
    marker.pose.position.x, marker.pose.orientation.w = 2.0, 1.0
    markers = read_marker_array(serialize(MarkerArray(markers=[marker, marker])))
    assert len(markers) == 2
    assert (markers[1].namespace, markers[1].id, markers[1].action) == ('other', 4, ADD)
    np.testing.assert_array_equal(markers[1].points, [[1.0, 2.0, 3.0]] * 3)
    np.testing.assert_array_equal(markers[1].colors, [[1.0, 0.5, 0.25, 1.0]] * 3)
    assert markers[1].pose[0] == 2.0
    written = read_marker_array(marker_array((0, 0), 'f', 'n', [(5, _triangles(2))],
                                             (1, 1, 1, 1)).data)
    np.testing.assert_array_equal(written[0].points, _triangles(2))
    with pytest.raises(ValueError, match='ends before'):
        read_marker_array(serialize(MarkerArray(markers=[marker]))[:60])
    with pytest.raises(ValueError, match='little-endian'):
        read_marker_array(b'\x00\x00\x00\x00')
