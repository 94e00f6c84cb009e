"""`depth-nodes reindex`: a bag cut off anywhere (a SIGKILL, a full disk, a power loss
mid-write) gives back every message of its whole chunks, bit for bit, as a bag that
BagReader and rosbags read; built here with the Writer and cut at random offsets (fixed
seeds) and at the edges that matter."""

from __future__ import annotations

import random
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo

from depth_nodes.errors import BagError
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.recover import CUT_SUFFIX, reindex_bag

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
Stored = tuple[str, int, bytes]  # topic, timestamp, bytes


def _write(bag: Path, *, frames: int = 40, compress: bool = True) -> list[Stored]:
    """A recording of images (noise: they do not compress) and camera_infos, its chunks
    closed by size and by flushes; the messages as stored, in order."""
    rng = np.random.default_rng(7)
    with BagWriter(bag, keep_partial=True, compress=compress) as writer:
        for i in range(frames):
            size = int(rng.integers(40, 160))
            image = array_to_image(rng.integers(0, 256, (size, 400), dtype=np.uint8), 'mono8')
            image.header.stamp.sec = i
            writer.write('/cam/image_raw', image, 10**9 + i * 10**8)
            writer.write('/cam/camera_info', CameraInfo(width=i), 10**9 + i * 10**8 + 1)
            if i % 3 == 2:
                writer.flush()
    with BagReader(bag) as reader:
        return [(m.topic, m.timestamp, m.data) for m in reader.messages()]


def _chunk_ends(bag: Path) -> list[tuple[int, int]]:
    """(end offset, last timestamp) of each chunk, from the complete file's summary
    (rosbags' reader)."""
    storage = McapReader(bag / f'{bag.name}.mcap')
    storage.open()
    try:
        return [(c.chunk_start_offset + c.chunk_length, c.message_end_time)
                for c in storage.chunks]
    finally:
        storage.close()


def _cut(source: Path, folder: Path, size: int, *, zeros: int = 0) -> Path:
    """The bag's MCAP file cut after ``size`` bytes (then ``zeros`` zero bytes, as a power
    loss leaves past the last write), alone in ``folder``: no metadata.yaml."""
    folder.mkdir(parents=True)
    data = (source / f'{source.name}.mcap').read_bytes()[:size]
    (folder / f'{folder.name}.mcap').write_bytes(data + bytes(zeros))
    return folder


def _stored(bag: Path) -> list[Stored]:
    with BagReader(bag) as reader:
        ours = [(m.topic, m.timestamp, m.data) for m in reader.messages()]
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:  # rosbags reads it too
        theirs = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
        for connection, _, data in reader.messages():
            reader.deserialize(data, connection.msgtype)
    assert ours == theirs
    return ours


@pytest.fixture(scope='module')
def original(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Stored]]:
    bag = tmp_path_factory.mktemp('original') / 'rec'
    return bag, _write(bag)


def _expected(original: tuple[Path, list[Stored]], size: int) -> list[Stored]:
    """The messages of the chunks that end within the first ``size`` bytes."""
    bag, messages = original
    whole = [t for end, t in _chunk_ends(bag) if end <= size]
    return [m for m in messages if whole and m[1] <= max(whole)]


def _check(original: tuple[Path, list[Stored]], size: int, recovered: list[Stored]) -> None:
    messages = original[1]
    expected = _expected(original, size)
    assert len(recovered) >= len(expected)
    # and whatever came from the chunk it was cut inside is what was written there
    assert recovered == messages[:len(recovered)]


def test_the_original_has_many_chunks(original: tuple[Path, list[Stored]]) -> None:
    ends = _chunk_ends(original[0])
    assert len(ends) >= 12
    assert len(original[1]) == 80


@pytest.mark.parametrize('seed', range(12))
def test_a_bag_cut_at_a_random_offset_gives_back_every_whole_chunk(
        tmp_path: Path, original: tuple[Path, list[Stored]], seed: int) -> None:
    full = (original[0] / 'rec.mcap').stat().st_size
    size = random.Random(seed).randrange(200, full)
    bag = _cut(original[0], tmp_path / 'rec', size)
    with pytest.raises(BagError, match=r'depth-nodes reindex .*rec` recovers it'):
        BagReader(bag)
    result = reindex_bag(bag)
    recovered = _stored(bag)
    _check(original, size, recovered)
    assert sum(result.counts.values()) == len(recovered)
    assert result.kept == [bag / f'rec.mcap{CUT_SUFFIX}']
    assert (bag / f'rec.mcap{CUT_SUFFIX}').stat().st_size == size  # kept as it was
    assert reindex_bag(bag).complete_already  # and now it opens


def test_cut_at_each_edge_of_a_chunk(tmp_path: Path,
                                     original: tuple[Path, list[Stored]]) -> None:
    """Exactly at a chunk's end, one byte short of it, one past it (its message index
    begins), and past every chunk with the summary missing."""
    ends = [end for end, _ in _chunk_ends(original[0])]
    for k, size in enumerate([ends[3], ends[3] - 1, ends[3] + 1, ends[-1] + 40]):
        bag = _cut(original[0], tmp_path / f'cut{k}', size)
        reindex_bag(bag)
        recovered = _stored(bag)
        _check(original, size, recovered)
        if k != 1:
            assert len(recovered) == len(_expected(original, size))
    assert len(recovered) == len(original[1])


def test_zeros_after_the_cut_are_no_messages(tmp_path: Path,
                                             original: tuple[Path, list[Stored]]) -> None:
    """A power loss can leave the file longer than what reached the disk, zero-filled."""
    size = _chunk_ends(original[0])[5][0] + 300
    bag = _cut(original[0], tmp_path / 'rec', size, zeros=8192)
    result = reindex_bag(bag)
    _check(original, size, _stored(bag))
    (_, end), = result.scans
    assert 'no MCAP record (opcode 0x00)' in end.reason or 'cut off' in end.reason


def test_a_damaged_chunk_is_skipped_and_the_rest_recovered(
        tmp_path: Path, original: tuple[Path, list[Stored]]) -> None:
    """A whole chunk whose bytes changed (its CRC no longer holds) is left out, counted;
    the chunks after it come back."""
    bag = tmp_path / 'rec'
    shutil.copytree(original[0], bag)
    (bag / 'metadata.yaml').unlink()
    data = bytearray((bag / 'rec.mcap').read_bytes())
    ends = _chunk_ends(original[0])
    data[ends[4][0] - 10] ^= 0xFF  # inside chunk 5's compressed records
    (bag / 'rec.mcap').write_bytes(bytes(data))
    result = reindex_bag(bag)
    (_, end), = result.scans
    assert end.damaged == 1
    assert end.complete
    lost = {m for m in original[1] if ends[3][1] < m[1] <= ends[4][1]}
    assert lost
    assert _stored(bag) == [m for m in original[1] if m not in lost]


def test_a_cut_uncompressed_chunk_gives_its_complete_records(tmp_path: Path) -> None:
    """Chunks stored without compression: the chunk the file is cut inside gives the
    messages whose records are complete, as they are."""
    bag = tmp_path / 'plain' / 'rec'
    messages = _write(bag, frames=12, compress=False)
    size = _chunk_ends(bag)[3][0] - 200  # near the end of chunk 4's records
    cut = _cut(bag, tmp_path / 'cut' / 'rec', size)
    result = reindex_bag(cut)
    recovered = _stored(cut)
    assert result.scans[0][1].cut_chunk_messages >= 2
    assert len(recovered) == len(_expected((bag, messages), size)) + (
        result.scans[0][1].cut_chunk_messages)
    assert recovered == messages[:len(recovered)]


def _record(op: int, *fields: bytes) -> bytes:
    content = b''.join(fields)
    return bytes([op]) + struct.pack('<Q', len(content)) + content


def _string(text: str) -> bytes:
    return struct.pack('<I', len(text)) + text.encode()


def test_a_record_too_short_to_be_a_message_ends_its_chunk(tmp_path: Path) -> None:
    """An MCAP file made by hand: a chunk whose second message record is 5 bytes long
    (a message's fields take 22): the first message comes back, the rest of the chunk
    cannot be trusted and does not."""
    definition = TYPESTORE.generate_msgdef('std_msgs/msg/String', ros_version=2)[0]
    message = TYPESTORE.serialize_cdr(TYPESTORE.types['std_msgs/msg/String'](data='hi'),
                                      'std_msgs/msg/String')
    records = b''.join([
        _record(0x03, struct.pack('<H', 1), _string('std_msgs/msg/String'),
                _string('ros2msg'), _string(definition)),
        _record(0x04, struct.pack('<HH', 1, 1), _string('/chatter'), _string('cdr'),
                struct.pack('<I', 0)),
        _record(0x05, struct.pack('<HIQQ', 1, 0, 5, 5), bytes(message)),
        _record(0x05, b'\x01\x00\x00\x00\x00'),
        _record(0x05, struct.pack('<HIQQ', 1, 0, 6, 6), bytes(message))])
    chunk = _record(0x06, struct.pack('<QQQI', 5, 6, len(records), 0), _string(''),
                    struct.pack('<Q', len(records)), records)
    bag = tmp_path / 'rec'
    bag.mkdir()
    (bag / 'rec.mcap').write_bytes(b'\x89MCAP0\r\n' + _record(0x01, _string('ros2'),
                                                                   _string('by hand'))
                                   + chunk + _record(0x0F, struct.pack('<I', 0)))
    result = reindex_bag(bag)
    assert result.counts == {'/chatter': 1}
    assert _stored(bag) == [('/chatter', 5, bytes(message))]


def test_reindex_into_another_folder_leaves_the_bag_as_it_is(
        tmp_path: Path, original: tuple[Path, list[Stored]]) -> None:
    size = _chunk_ends(original[0])[6][0]
    bag = _cut(original[0], tmp_path / 'rec', size)
    before = sorted(p.name for p in bag.iterdir())
    result = reindex_bag(bag, tmp_path / 'out')
    assert result.bag == tmp_path / 'out'
    assert sorted(p.name for p in bag.iterdir()) == before
    _check(original, size, _stored(tmp_path / 'out'))
    with pytest.raises(BagError, match='exists already'):
        reindex_bag(bag, tmp_path / 'out')
    reindex_bag(bag, tmp_path / 'out', overwrite=True)


def test_qos_and_types_are_kept(tmp_path: Path, original: tuple[Path, list[Stored]]) -> None:
    bag = _cut(original[0], tmp_path / 'rec', _chunk_ends(original[0])[-1][0])
    reindex_bag(bag)
    with BagReader(bag) as reader, BagReader(original[0]) as before:
        assert reader.topics == before.topics
        assert reader.qos == before.qos
        assert reader.counts == before.counts


@pytest.mark.parametrize(('make', 'message'), [
    (lambda p: None, 'bag not found'),
    (lambda p: p.mkdir(), 'no MCAP file in'),
    (lambda p: (p.mkdir(), (p / 'rec.db3').write_bytes(b'x')), 'sqlite3 bag survives'),
    (lambda p: (p.mkdir(), (p / 'rec.mcap').write_bytes(b'not an mcap file')),
     'is not an MCAP file'),
    (lambda p: (p.mkdir(), (p / 'rec.mcap').write_bytes(b'\x89MCAP0\r\n\x01\x00')),
     'no complete message in'),
    (lambda p: (p.mkdir(), (p / 'rec.mcap').write_bytes(b'')),  # killed before a flush
     r'no complete message in .*before any record'),
])
def test_what_cannot_be_recovered_is_one_error(tmp_path: Path, make: object,
                                               message: str) -> None:
    bag = tmp_path / 'rec'
    make(bag)  # type: ignore[operator]
    with pytest.raises(BagError, match=message):
        reindex_bag(bag)
    if bag.is_dir():
        assert [p.name for p in bag.iterdir() if p.name != 'rec.db3'] in (
            [], ['rec.mcap'])  # nothing written, nothing renamed
    assert not list(tmp_path.glob('.rec.reindex-*'))


@pytest.mark.slow
def test_the_command(tmp_path: Path, original: tuple[Path, list[Stored]]) -> None:
    size = _chunk_ends(original[0])[8][0] + 1000
    bag = _cut(original[0], tmp_path / 'rec', size)
    result = run_cli(['reindex', str(bag)])
    assert result.returncode == 0, result.stderr
    count = len(_stored(bag))
    assert result.stdout.startswith(f'recovered {count} messages on 2 topics into {bag}\n')
    assert 'rec.mcap: 9 whole chunk(s), cut off: read up to a record cut off' in result.stdout
    assert f'the cut file is kept as {bag}/rec.mcap.cut' in result.stdout
    again = run_cli(['reindex', str(bag)])
    assert again.stdout.strip() == f'{bag} is complete (it opens as it is): nothing to recover'
    missing = run_cli(['reindex', str(tmp_path / 'nope')])
    assert missing.returncode == 1
    assert missing.stderr.strip() == (f'depth-nodes reindex: error: bag not found: '
                                      f'{tmp_path / "nope"}')


def test_struct_of_a_chunk_record_is_what_the_scan_reads(
        original: tuple[Path, list[Stored]]) -> None:
    """The MCAP layout the scan relies on, read from a file rosbags wrote: magic, header
    record, then chunk records whose CRC is set."""
    data = (original[0] / 'rec.mcap').read_bytes()
    assert data[:8] == b'\x89MCAP0\r\n'
    assert data[8] == 0x01
    (length,) = struct.unpack_from('<Q', data, 9)
    assert data[17 + length] == 0x06  # the first chunk follows the header
