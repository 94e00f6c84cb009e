"""Reading an MCAP file from its start, record by record, without its summary: what is
left of a recording cut off by a SIGKILL, a full disk or a power loss.

A complete MCAP file ends with a summary and a footer, which rosbags needs to open it; a
cut one has neither. :func:`scan_mcap` walks the data section instead (the MCAP
specification's record layout: an opcode byte, a uint64 length, the content) and yields
the schemas, channels and messages of every complete record, inside chunks too, until
the data ends or stops being MCAP:

* a chunk is used when it is whole and its CRC (when it has one) matches its records;
  a whole chunk that is damaged (CRC, size, compression) is skipped and counted, and the
  scan goes on after it;
* the chunk the file ends inside (cut while it was written) gives the messages whose
  records are complete in what can be decompressed of it: no CRC covers them, as none
  covers a message record outside a chunk;
* the scan stops at the data-end record (a complete file), at the end of the file, or
  at a record that cannot be one (a zero or unknown opcode: the zeros a power loss leaves
  past the last write, or garbage).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from lz4.frame import LZ4FrameDecompressor  # type: ignore[import-untyped]

try:  # zstd is in the standard library from Python 3.14; rosbags needs the backport before
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:
    from backports import zstd  # type: ignore[import-not-found,no-redef,unused-ignore]

from depth_nodes.errors import BagError

MAGIC = b'\x89MCAP0\r\n'
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = 0x02, 0x03, 0x04, \
    0x05, 0x06, 0x0F
#: Opcodes of the MCAP specification (0x01 header ... 0x0F data end).
KNOWN_OPCODES = range(0x01, 0x10)
#: Bytes of compressed data decompressed at a time from a cut chunk.
_PIECE = 1 << 16


@dataclass(frozen=True)
class Schema:
    """An MCAP schema record: a message type and its definition."""

    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    """An MCAP channel record: a topic, its schema and its metadata (rosbag2 keeps the
    offered QoS profiles there)."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class Message:
    """An MCAP message record (rosbag2's timestamp is its log time)."""

    channel_id: int
    log_time: int
    data: bytes


@dataclass
class ScanEnd:
    """How far a scan got.

    Attributes:
        offset: Bytes of the file read as complete records (the rest is lost).
        size: The file's size.
        reason: Why the scan stopped, in words.
        complete: The data section ended with its data-end record: nothing was cut.
        chunks: Whole chunks read.
        damaged: Whole chunks skipped as damaged (CRC, size, compression).
        cut_chunk_messages: Messages taken from the chunk the file ends inside.
    """

    offset: int
    size: int
    reason: str = ''
    complete: bool = False
    chunks: int = 0
    damaged: int = 0
    cut_chunk_messages: int = 0


Record = Schema | Channel | Message


class _Cursor:
    """Reads little-endian MCAP fields from bytes; IndexError / struct.error past the
    end."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data, self.at = memoryview(data), 0

    def take(self, size: int) -> bytes:
        if size < 0 or self.at + size > len(self.data):
            raise struct.error(f'{size} bytes wanted at {self.at} of {len(self.data)}')
        out = bytes(self.data[self.at:self.at + size])
        self.at += size
        return out

    def uint(self, size: int) -> int:
        return int.from_bytes(self.take(size), 'little')

    def string(self) -> str:
        return self.take(self.uint(4)).decode()


def _record(op: int, content: bytes | memoryview) -> Record | None:
    """A schema, channel or message record's content parsed (None for other records)."""
    cur = _Cursor(content)
    if op == OP_SCHEMA:
        return Schema(cur.uint(2), cur.string(), cur.string(), cur.take(cur.uint(4)))
    if op == OP_CHANNEL:
        ident, schema, topic, encoding = cur.uint(2), cur.uint(2), cur.string(), cur.string()
        meta, end = {}, cur.uint(4)
        end += cur.at
        while cur.at < end:
            key = cur.string()
            meta[key] = cur.string()
        return Channel(ident, schema, topic, encoding, meta)
    if op == OP_MESSAGE:
        channel, _, log_time, _ = cur.uint(2), cur.uint(4), cur.uint(8), cur.uint(8)
        return Message(channel, log_time, bytes(cur.data[cur.at:]))
    return None


def _records(data: bytes | memoryview) -> Iterator[Record]:
    """The schema, channel and message records of a chunk's records, complete ones only
    (the end of cut data, or a record too short to be one, ends them)."""
    at = 0
    while at + 9 <= len(data):
        op = data[at]
        length = int.from_bytes(data[at + 1:at + 9], 'little')
        if op not in KNOWN_OPCODES or at + 9 + length > len(data):
            return
        try:
            record = _record(op, data[at + 9:at + 9 + length])
        except (struct.error, UnicodeDecodeError):
            return
        if record is not None:
            yield record
        at += 9 + length


def _decompress(data: bytes, compression: str) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        return bytes(zstd.decompress(data))
    if compression == 'lz4':
        return bytes(LZ4FrameDecompressor().decompress(data))
    raise ValueError(f'unknown compression {compression!r}')


def _decompress_prefix(data: bytes, compression: str) -> bytes:
    """As much of a cut compressed stream as decodes, in pieces until it fails."""
    if compression == '':
        return data
    decoder = zstd.ZstdDecompressor() if compression == 'zstd' else (
        LZ4FrameDecompressor() if compression == 'lz4' else None)
    if decoder is None:
        return b''
    out = bytearray()
    for at in range(0, len(data), _PIECE):
        try:
            out += decoder.decompress(data[at:at + _PIECE])
        except Exception:  # the damaged or garbage end of the stream: what came before
            break
    return bytes(out)


def _chunk(content: bytes, end: ScanEnd, *, cut: bool) -> list[Record]:
    """The records of a chunk record's content (``cut``: the file ended inside it)."""
    cur = _Cursor(content)
    try:
        cur.take(16)  # message start and end time
        size, crc = cur.uint(8), cur.uint(4)
        compression = cur.string()
        wanted = cur.uint(8)
        compressed = cur.take(min(wanted, len(content) - cur.at) if cut else wanted)
    except (struct.error, UnicodeDecodeError):
        if not cut:
            end.damaged += 1
        return []
    if cut:
        records = list(_records(_decompress_prefix(compressed, compression)[:size]))
        end.cut_chunk_messages = sum(isinstance(r, Message) for r in records)
        return records
    try:
        raw = _decompress(compressed, compression)
    except Exception:  # damaged compressed data, an unknown compression
        raw = b''
    if len(raw) != size or (crc and zlib.crc32(raw) != crc):
        end.damaged += 1
        return []
    end.chunks += 1
    return list(_records(raw))


def scan_mcap(path: Path) -> Iterator[Record | ScanEnd]:
    """The schemas, channels and messages of an MCAP file, complete or cut off, in file
    order; last a :class:`ScanEnd` (see the module docstring).

    Raises:
        BagError: The file cannot be read, or is not an MCAP file at all.
    """
    try:
        with path.open('rb') as f:
            size = path.stat().st_size
            head = f.read(len(MAGIC))
            if head == MAGIC:
                yield from _scan(f, size)
            elif MAGIC.startswith(head):  # cut before its first record: nothing in it
                yield ScanEnd(len(head), size, 'the end of the file, before any record')
            else:
                raise BagError(f'{path} is not an MCAP file (no MCAP magic at its start)')
    except OSError as exc:
        raise BagError(f'cannot read {path}: {exc.strerror or exc}') from None


def _scan(f: BinaryIO, size: int) -> Iterator[Record | ScanEnd]:
    end = ScanEnd(len(MAGIC), size)
    while True:
        at = f.tell()
        head = f.read(9)
        if len(head) < 9:
            end.reason = 'the end of the file' if not head else 'a record cut at its start'
            break
        op, length = head[0], int.from_bytes(head[1:], 'little')
        if op in (OP_DATA_END, OP_FOOTER):
            end.offset, end.reason, end.complete = at, 'the end of the data', True
            break
        if op not in KNOWN_OPCODES:
            end.reason = f'bytes that are no MCAP record (opcode {op:#04x})'
            break
        if at + 9 + length > size:
            if op == OP_CHUNK:
                yield from _chunk(f.read(), end, cut=True)
            end.reason = f'a record cut off (opcode {op:#04x}, {size - at} of ' \
                         f'{9 + length} bytes)'
            break
        content = f.read(length)
        end.offset = at + 9 + length
        if op == OP_CHUNK:
            yield from _chunk(content, end, cut=False)
        else:
            try:
                record = _record(op, content)
            except (struct.error, UnicodeDecodeError):
                record = None
            if record is not None:
                yield record
    yield end
