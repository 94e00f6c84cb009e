"""Bag reading/writing through rosbags, including deliberately broken bags."""

from __future__ import annotations

import errno
import io
import os
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.errors import BagError
from depth_nodes.tools.bags.io import (
    BagReader,
    BagWriter,
    message_class,
    message_type_name,
    serialize,
)

try:
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:
    from backports import zstd  # type: ignore[import-not-found,no-redef,unused-ignore]

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


def _mcap_records(data: bytes) -> list[tuple[int, int, bytes]]:
    """(opcode, offset of the content, content) of each record of an MCAP file."""
    assert data[:8] == b'\x89MCAP0\r\n'
    assert data[-8:] == b'\x89MCAP0\r\n'
    records, at = [], 8
    while at < len(data) - 8:
        opcode, length = data[at], struct.unpack_from('<Q', data, at + 1)[0]
        records.append((opcode, at + 9, data[at + 9:at + 9 + length]))
        at += 9 + length
    assert at == len(data) - 8
    return records


def _large_messages() -> list[tuple[str, Image, int]]:
    """Enough bytes for several chunks (rosbags closes one past 1 MiB), some compressible."""
    rng = np.random.default_rng(3)
    out = []
    for i in range(24):
        msg = _image(0, stamp_s=i)
        msg.height, msg.width, msg.step = 300, 1000, 1000
        pixels = rng.integers(0, 8 if i % 2 else 256, 300_000, dtype=np.uint8)
        msg.data = pixels.tobytes()
        out.append(('/cam/image', msg, 1_000 + i))
    return out


def test_chunks_closed_on_their_thread_are_the_bytes_rosbags_writes(tmp_path: Path) -> None:
    """The chunks are compressed and written on a thread of their own: the file is the one
    rosbags' own synchronous writer makes, but for the CRC of each chunk, which is that of
    the chunk's decompressed records (rosbags writes 0)."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    messages = _large_messages()
    ours, theirs = tmp_path / 'ours' / 'bag', tmp_path / 'theirs' / 'bag'
    with BagWriter(ours) as writer:
        for topic, msg, stamp in messages:
            writer.write(topic, msg, stamp)
    plain = Writer(theirs, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
    plain.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    plain.open()
    conn = plain.add_connection('/cam/image', 'sensor_msgs/msg/Image', typestore=TYPESTORE,
                                offered_qos_profiles=[])
    for _, msg, stamp in messages:
        plain.write(conn, stamp, serialize(msg))
    plain.close()
    data = bytearray((ours / 'bag.mcap').read_bytes())
    chunks = [(at, content) for opcode, at, content in _mcap_records(bytes(data))
              if opcode == 0x06]
    assert len(chunks) >= 6
    for at, content in chunks:
        (crc,) = struct.unpack_from('<I', content, 24)
        name_len = struct.unpack_from('<I', content, 28)[0]
        assert content[32:32 + name_len] == b'zstd'
        records = zstd.decompress(content[32 + name_len + 8:])
        assert crc == zlib.crc32(records) != 0
        data[at + 24:at + 28] = b'\0\0\0\0'  # as rosbags leaves it
    assert bytes(data) == (theirs / 'bag.mcap').read_bytes()
    with BagReader(ours) as reader:
        assert [(m.timestamp, m.data) for m in reader.messages()] == [
            (stamp, serialize(msg)) for _, msg, stamp in messages]


class _FullDisk(io.RawIOBase):
    """A file that takes ``room`` bytes, then fails as a full disk does."""

    def __init__(self, file: Any, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data: Any) -> int:
        size = memoryview(data).nbytes
        if self.file.tell() + size > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return int(self.file.write(data))

    def tell(self) -> int:
        return int(self.file.tell())

    def seek(self, offset: int, whence: int = 0) -> int:
        return int(self.file.seek(offset, whence))

    def close(self) -> None:
        self.file.close()


def _filling_writer(path: Path, room: int, **kwargs: Any) -> BagWriter:
    writer = BagWriter(path, **kwargs)
    storage = writer._writer.storage
    storage.bio = _FullDisk(storage.bio, room)  # type: ignore[union-attr]
    return writer


@pytest.mark.parametrize('keep_partial', [False, True])
def test_a_full_disk_is_one_error_and_no_half_bag(tmp_path: Path, keep_partial: bool) -> None:
    """A chunk the thread cannot write (a full disk) fails a later write, or the close, in
    one line; the incomplete bag is removed, or left as it is for a recording
    (keep_partial)."""
    bag = tmp_path / 'bag'
    writer = _filling_writer(bag, 2_000_000, keep_partial=keep_partial)

    def write_all() -> None:
        for topic, msg, stamp in _large_messages():
            writer.write(topic, msg, stamp)
        writer.close()

    with pytest.raises(BagError, match=r'^cannot write the bag .*bag: No space left on device$'):
        write_all()
    writer.close()  # no second error
    assert bag.exists() == keep_partial
    if keep_partial:
        assert not (bag / 'metadata.yaml').exists()
        assert 0 < (bag / 'bag.mcap').stat().st_size <= 2_000_000


def test_a_full_disk_at_the_last_chunk_fails_close(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    writer = _filling_writer(bag, 1_000)
    writer.write('/cam/info', CameraInfo(), 1)  # stays in the open chunk until close
    with pytest.raises(BagError, match='No space left on device'):
        writer.close()
    assert not bag.exists()


def test_flush_puts_a_chunk_on_the_disk_once_its_first_message_is_old_enough(
        tmp_path: Path) -> None:
    """What a recording relies on: a chunk that is not full is closed, written and fsynced
    by flush() once its first message is max_age old; the file then holds it whole."""
    bag = tmp_path / 'bag'
    writer = BagWriter(bag)
    try:
        writer.write('/cam/info', CameraInfo(width=1), 1)
        writer.flush(3600.0, wait=True)  # too young: still in the open chunk
        assert _messages_on_disk(bag / 'bag.mcap') == []
        writer.write('/cam/info', CameraInfo(width=2), 2)
        writer.flush(0.0, wait=True)
        assert _messages_on_disk(bag / 'bag.mcap') == [1, 2]
        writer.write('/cam/info', CameraInfo(width=3), 3)
        writer.flush(0.0, wait=True)
        assert _messages_on_disk(bag / 'bag.mcap') == [1, 2, 3]
    finally:
        writer.close()
    with BagReader(bag) as reader:
        assert [m.timestamp for m in reader.messages()] == [1, 2, 3]


def _messages_on_disk(path: Path) -> list[int]:
    from depth_nodes.tools.bags.mcap_scan import Message, scan_mcap

    return [r.log_time for r in scan_mcap(path) if isinstance(r, Message)]
