"""Bag reading/writing through rosbags, including deliberately broken bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.errors import BagError
from depth_nodes.tools.bags.io import BagReader, BagWriter, message_class, message_type_name

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _image(value: int, stamp_s: int = 1) -> Image:
    msg = Image()
    msg.header.stamp.sec = stamp_s
    msg.header.frame_id = 'cam'
    msg.height, msg.width, msg.step, msg.encoding = 2, 3, 3, 'mono8'
    msg.data = bytes([value] * 6)
    return msg


def _write_bag(path: Path, n: int = 3) -> None:
    with BagWriter(path) as writer:
        writer.set_custom_data('origin', 'test')
        for i in range(n):
            writer.write('/cam/image', _image(i, stamp_s=i), 1_000 + i)
            writer.write('/cam/info', CameraInfo(), 1_000 + i)


def test_round_trip_is_byte_exact_and_readable_by_rosbags(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    _write_bag(bag)
    assert (bag / 'metadata.yaml').is_file()
    assert (bag / 'bag.mcap').is_file()
    with BagReader(bag) as reader:
        assert reader.topics == {'/cam/image': 'sensor_msgs/msg/Image',
                                 '/cam/info': 'sensor_msgs/msg/CameraInfo'}
        assert reader.counts == {'/cam/image': 3, '/cam/info': 3}
        assert reader.custom_data == {'origin': 'test'}
        msgs = list(reader.messages(['/cam/image']))
    assert [m.timestamp for m in msgs] == [1000, 1001, 1002]
    for i, bag_msg in enumerate(msgs):
        # (CDR alignment padding is not guaranteed to be zeroed, so compare by length)
        assert len(bag_msg.data) == len(serialize_message(_image(i, stamp_s=i)))
        # an independent reader: the rosbags CDR deserialiser
        decoded = TYPESTORE.deserialize_cdr(bag_msg.data, bag_msg.msgtype)
        assert decoded.header.stamp.sec == i
        np.testing.assert_array_equal(decoded.data, np.full(6, i, np.uint8))
        assert bytes(bag_msg.deserialize().data) == bytes([i] * 6)


def test_message_type_names() -> None:
    assert message_type_name(Image) == 'sensor_msgs/msg/Image'
    assert message_type_name(Image()) == 'sensor_msgs/msg/Image'
    assert message_class('sensor_msgs/msg/CameraInfo') is CameraInfo
    with pytest.raises(BagError, match='not a ROS 2 message type name'):
        message_class('sensor_msgs/Image')
    with pytest.raises(BagError, match='no_such_msgs/msg/Thing is not installed'):
        message_class('no_such_msgs/msg/Thing')


def test_missing_bag(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='bag not found'):
        BagReader(tmp_path / 'nope')


def test_folder_without_metadata(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r'no metadata\.yaml'):
        BagReader(tmp_path)


def test_corrupt_metadata(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    _write_bag(bag)
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [this is not it')
    with pytest.raises(BagError, match='cannot open bag'):
        BagReader(bag)


def test_truncated_storage(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    _write_bag(bag)
    data = (bag / 'bag.mcap').read_bytes()
    (bag / 'bag.mcap').write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r'(cannot open|corrupt) bag'):
        list(BagReader(bag).messages())


def test_garbage_message_bytes(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    with BagWriter(bag) as writer:
        writer.write('/x', b'\x00\x01\x00\x00\xff', 5, 'sensor_msgs/msg/Image')
    with BagReader(bag) as reader:
        (bag_msg,) = reader.messages()
        with pytest.raises(BagError, match='cannot deserialise a sensor_msgs/msg/Image'):
            bag_msg.deserialize()


def test_unknown_topic_and_wrong_type(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    _write_bag(bag)
    with BagReader(bag) as reader:
        with pytest.raises(BagError, match=r'/nope is not in .*topics: /cam/image, /cam/info'):
            list(reader.messages(['/nope']))
        with pytest.raises(BagError, match='has type sensor_msgs/msg/Image, expected'):
            reader.require('/cam/image', 'stereo_msgs/msg/DisparityImage')


def test_writer_refuses_to_overwrite_and_mixing_types(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    _write_bag(bag)
    with pytest.raises(BagError, match='exists already'):
        BagWriter(bag)
    with BagWriter(bag, overwrite=True) as writer:
        writer.write('/t', _image(1), 1)
        with pytest.raises(BagError, match='has type sensor_msgs/msg/Image; cannot write'):
            writer.write('/t', CameraInfo(), 2)
        with pytest.raises(BagError, match='needs its message type'):
            writer.write('/u', b'\x00', 3)
    not_a_bag = tmp_path / 'precious'
    not_a_bag.mkdir()
    (not_a_bag / 'thesis.txt').write_text('keep me')
    with pytest.raises(BagError, match='not a bag folder'):
        BagWriter(not_a_bag, overwrite=True)
    assert (not_a_bag / 'thesis.txt').exists()
