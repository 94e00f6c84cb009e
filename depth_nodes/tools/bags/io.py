"""rosbag2 reading and writing through the `rosbags` library, with rclpy message objects.

``rosbag2_py`` is not on PyPI, so bags are read and written with rosbags while messages
are (de)serialised by rclpy itself. Messages therefore travel as the exact CDR bytes a live
graph would carry, and the same node classes can process them offline.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import queue
import shutil
import struct
import threading
import zlib
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace, TracebackType
from typing import Any, Self

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    Reader,
    StoragePlugin,
    Writer,
)
from rosbags.typesys import Stores, get_typestore

try:  # zstd is in the standard library from Python 3.14; rosbags needs the backport before
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:
    from backports import zstd  # type: ignore[import-not-found,no-redef,unused-ignore]

from depth_nodes.errors import BagError, yaml_problem

_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _one_line(exc: BaseException) -> str:
    """A storage library's error in one line (its YAML errors span several)."""
    cause = exc.__cause__ or exc.__context__
    if cause is not None and hasattr(cause, 'problem'):  # a YAML error underneath
        return f'metadata.yaml is not valid YAML: {yaml_problem(cause)}'
    return ' '.join(str(exc).split()).rstrip('.')


def message_class(msgtype: str) -> type:
    """Return the rclpy message class for a type name such as ``sensor_msgs/msg/Image``.

    Raises:
        BagError: The name is malformed or the message package is not installed.
    """
    parts = msgtype.split('/')
    if len(parts) != 3 or parts[1] != 'msg':
        raise BagError(f'not a ROS 2 message type name: {msgtype!r}')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[2])  # type: ignore[no-any-return]
    except (ImportError, AttributeError):
        raise BagError(f'message type {msgtype} is not installed') from None


def serialize(msg: Any, msgtype: str | None = None) -> bytes:
    """The CDR bytes of an rclpy message, the same every time.

    rclpy's serialiser leaves the alignment padding after strings uninitialised, so the
    same message gave other bytes from run to run (two `process` runs of one bag wrote
    different files). The bytes are rewritten by rosbags' serialiser, which zeroes the
    padding: about 650 MB/s here, a few per cent of a `process` run.
    """
    msgtype = msgtype or message_type_name(msg)
    data = serialize_message(msg)
    if msgtype not in _TYPESTORE.types:
        return bytes(data)
    return bytes(_TYPESTORE.serialize_cdr(_TYPESTORE.deserialize_cdr(data, msgtype), msgtype))


def message_type_name(msg_or_class: Any) -> str:
    """Return ``pkg/msg/Name`` for an rclpy message or message class."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    return f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'


@dataclass(frozen=True)
class BagMessage:
    """One message read from a bag, still serialised."""

    topic: str
    msgtype: str
    timestamp: int
    data: bytes

    def deserialize(self) -> Any:
        """Deserialise into an rclpy message object."""
        try:
            return deserialize_message(self.data, message_class(self.msgtype))
        except BagError:
            raise
        except Exception as exc:  # rclpy raises plain Exception subclasses on bad CDR
            raise BagError(
                f'cannot deserialise a {self.msgtype} message on {self.topic} '
                f'at t={self.timestamp}: {exc}'
            ) from None


class _Closing:
    """``with`` closes it."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class BagReader(_Closing):
    """Read a rosbag2 bag (sqlite3 or MCAP, compressed or not).

    Args:
        path: The bag folder (the one holding metadata.yaml).

    Raises:
        BagError: The bag is missing, unreadable or corrupt.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f'bag not found: {self.path}')
        if not (self.path / 'metadata.yaml').is_file():
            raise BagError(f'not a rosbag2 bag (no metadata.yaml): {self.path}')
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:
            raise BagError(f'cannot open bag {self.path}: {_one_line(exc)}') from None
        self.topics: dict[str, str] = {}
        self.counts: Counter[str] = Counter()
        #: The QoS profiles each topic's publishers offered when it was recorded (rosbag2's
        #: offered_qos_profiles; empty when the bag does not say).
        self.qos: dict[str, list[Any]] = {}
        for conn in self._reader.connections:
            self.topics[conn.topic] = conn.msgtype
            self.counts[conn.topic] += conn.msgcount
            self.qos.setdefault(conn.topic, []).extend(
                getattr(conn.ext, 'offered_qos_profiles', None) or [])
        self.custom_data: dict[str, str] = dict(self._reader.storage.metadata.custom or {})

    @property
    def message_count(self) -> int:
        """Number of messages in the bag."""
        return int(self._reader.message_count)

    def require(self, topic: str, msgtype: str | None = None) -> None:
        """Check that ``topic`` exists (with type ``msgtype`` when given).

        Raises:
            BagError: The topic is missing or of another type.
        """
        if topic not in self.topics:
            known = ', '.join(sorted(self.topics)) or 'none'
            raise BagError(f'topic {topic} is not in {self.path} (topics: {known})')
        if msgtype is not None and self.topics[topic] != msgtype:
            raise BagError(
                f'topic {topic} in {self.path} has type {self.topics[topic]}, expected {msgtype}'
            )

    @property
    def time_range(self) -> tuple[int, int]:
        """Timestamps (ns) of the first and the last message."""
        return int(self._reader.start_time), int(self._reader.end_time) - 1

    def messages(self, topics: Iterable[str] | None = None, *, start: int | None = None,
                 stop: int | None = None) -> Iterator[BagMessage]:
        """Yield messages in timestamp order, optionally only those of ``topics``, and only
        those stamped in ``[start, stop)`` (ns).

        Raises:
            BagError: A requested topic is missing, or the storage is corrupt.
        """
        wanted = None if topics is None else set(topics)
        if wanted is not None:
            for topic in sorted(wanted):
                self.require(topic)
        conns = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        try:
            for conn, timestamp, data in self._reader.messages(connections=conns, start=start,
                                                               stop=stop):
                yield BagMessage(conn.topic, conn.msgtype, timestamp, bytes(data))
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f'corrupt bag {self.path}: {_one_line(exc)}') from None

    def close(self) -> None:
        """Close the bag."""
        self._reader.close()



class BagWriter(_Closing):
    """Write a rosbag2 bag in MCAP storage, zstd-compressed per chunk.

    Topics are registered on first write with the type's message definition from the
    Jazzy typestore, so ``ros2 bag info`` and other tools can read the result.

    Args:
        path: The bag folder to create; it must not exist unless ``overwrite``.
        compress: Compress the MCAP chunks with zstd.
        overwrite: Remove an existing bag folder at ``path`` first.
        compression_level: zstd level of the chunks (rosbags uses zstd's default, 3);
            the committed bags use 19, which makes float ground truth about 40% smaller.
        keep_partial: When a write fails (a full disk), leave what was written instead of
            removing the bag folder.

    Chunks are compressed and written on a thread of their own (:class:`_ChunkThread`).
    A write that fails raises :class:`BagError` in one line, at that call or (for a chunk
    the thread was writing) at the next one, or at :meth:`close`.
    """

    def __init__(self, path: str | Path, *, compress: bool = True, overwrite: bool = False,
                 compression_level: int | None = None, keep_partial: bool = False) -> None:
        self.path = Path(path)
        self.keep_partial = keep_partial
        if self.path.exists() and not self.path.is_dir():
            raise BagError(f'cannot write the bag {self.path}: it is a file, not a folder')
        if self.path.exists():
            if not overwrite:
                raise BagError(f'output bag exists already: {self.path} (use --force)')
            if not (self.path / 'metadata.yaml').is_file() and any(self.path.iterdir()):
                raise BagError(f'refusing to overwrite {self.path}: not a bag folder')
            _remove_tree(self.path)
        existing = next((a for a in self.path.parents if a.exists()), None)
        if existing is not None and not existing.is_dir():
            raise BagError(f'cannot write the bag {self.path}: {existing} is a file, not a '
                           'folder')
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = Writer(self.path, version=Writer.VERSION_LATEST,
                                  storage_plugin=StoragePlugin.MCAP)
            if compress:
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._connections: dict[str, Any] = {}
            self.counts: Counter[str] = Counter()
            self._failed = self._closed = False
            self._writer.open()
        except OSError as exc:
            raise BagError(f'cannot write the bag {self.path}: {exc.strerror or exc}'
                           f'{" (" + str(exc.filename) + ")" if exc.filename else ""}') from None
        if compress and compression_level is not None:
            _set_chunk_compression_level(self._writer, compression_level)
        self._chunks = _chunks_on_a_thread(self._writer)

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a key/value string in the bag's metadata (e.g. the generator's seed)."""
        self._writer.set_custom_data(key, value)

    def write(self, topic: str, msg: Any, timestamp: int, msgtype: str | None = None,
              qos: Sequence[Any] = ()) -> None:
        """Write one message (an rclpy message object, or CDR bytes with ``msgtype``).

        ``qos``: the QoS profiles the topic's publishers offered (rosbags ``Qos`` tuples),
        stored in the bag's metadata with the topic's first message, as rosbag2 does.
        """
        if isinstance(msg, bytes | bytearray | memoryview):
            if msgtype is None:
                raise BagError(f'writing raw bytes to {topic} needs its message type')
            data = bytes(msg)
        else:
            msgtype = msgtype or message_type_name(msg)
            data = serialize(msg, msgtype)
        conn = self._connections.get(topic)
        if conn is None:
            if msgtype not in _TYPESTORE.types:
                raise BagError(f'message type {msgtype} (topic {topic}) is unknown to rosbags')
            conn = self._writer.add_connection(topic, msgtype, typestore=_TYPESTORE,
                                               offered_qos_profiles=list(qos))
            self._connections[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f'topic {topic} has type {conn.msgtype}; cannot write a {msgtype}')
        try:
            self._writer.write(conn, timestamp, data)
        except OSError as exc:  # a full disk, now or when an earlier chunk was written
            self._fail(exc)
        self.counts[topic] += 1

    @property
    def failed(self) -> bool:
        """Whether a write failed (the bag is incomplete)."""
        return self._failed

    def _fail(self, exc: OSError) -> None:
        self._failed = True
        raise BagError(f'cannot write the bag {self.path}: {exc.strerror or exc}') from None

    def close(self) -> None:
        """Finish the bag (writes metadata.yaml). After a failed write (a full disk) only
        stop writing, and remove the incomplete bag unless it was made with
        ``keep_partial`` (a recording, which cannot be made again)."""
        if self._closed:
            return
        self._closed = True
        error = None
        if not self._failed:
            try:
                self._writer.close()
                return
            except OSError as exc:  # the summary or metadata.yaml
                error = exc
        self._abandon()
        if error is not None:
            self._fail(error)

    def _abandon(self) -> None:
        """Stop writing after a failed write; remove the incomplete bag unless
        ``keep_partial``."""
        if self._chunks is not None:
            with contextlib.suppress(Exception):
                self._chunks.finish()
        with contextlib.suppress(Exception):
            self._writer.storage.bio.close()  # type: ignore[union-attr]
        if not self.keep_partial and self.path.is_dir():
            _remove_tree(self.path)

    def discard(self) -> None:
        """Stop writing and remove the bag folder (an output that can be made again)."""
        with contextlib.suppress(BagError):
            self.close()
        if self.path.is_dir():
            _remove_tree(self.path)



def _set_chunk_compression_level(writer: Writer, level: int) -> None:
    """Swap the MCAP storage's chunk compressor for one with an explicit zstd level."""
    storage: Any = writer.storage
    if not hasattr(storage, 'compressor'):
        raise BagError('this rosbags version does not allow a zstd level for MCAP chunks')
    storage.compressor = functools.partial(zstd.compress, level=level)


#: Offset of the uncompressed-data CRC in an MCAP chunk record: opcode (1), record length
#: (8), message start and end time and uncompressed size (8 each).
_CHUNK_CRC_OFFSET = 1 + 8 + 24
#: Closed chunks waiting for the writing thread (each about 1 - 10 MB): the writer blocks
#: beyond that, so a slow disk or compressor bounds the memory instead of growing it.
PENDING_CHUNKS = 4


class _ChunkThread:
    """Closes the MCAP storage's chunks on a thread of their own: its CRC32 (which rosbags
    leaves 0, none), its zstd compression and the writing, in the order closed.

    The caller only swaps in an empty chunk and goes on: `process` on one worker spent
    about a quarter of its time compressing chunks while the graph waited (13 of 48 s on
    the 200-frame VGA bag); compression and CRC release the GIL, so they now run on the
    other core. Each chunk goes through rosbags' own ``close_chunk`` (on a stand-in that
    holds that chunk), so the bytes are the ones the synchronous writer wrote.

    A chunk that cannot be written (a full disk) stops the thread; the error is raised by
    the writer's next call (:meth:`check`), and :meth:`finish` before the summary.
    """

    def __init__(self, storage: Any) -> None:
        self._storage = storage
        self._close_one = type(storage).close_chunk
        self._queue: queue.Queue[Any] = queue.Queue(PENDING_CHUNKS)
        self._error: BaseException | None = None
        self._closed = False
        self._original_close = storage.close
        storage.close_chunk = self._hand_over
        storage.close = self._close_storage
        self._thread = threading.Thread(target=self._run, name='mcap-chunks', daemon=True)
        self._thread.start()

    def _hand_over(self) -> None:
        """Storage's ``close_chunk``: queue the chunk, start an empty one."""
        self.check()
        storage = self._storage
        chunk = storage.chunk
        storage.chunk = type(chunk)(2**63 - 1, 0, type(chunk.bio)(), type(chunk.msgs)(list))
        self._queue.put(chunk)

    def _run(self) -> None:
        storage = self._storage
        while (chunk := self._queue.get()) is not None:
            if self._error is not None:
                continue  # drain: the caller sees the error
            try:
                crc = zlib.crc32(chunk.bio.getbuffer())
                stand_in = SimpleNamespace(chunk=chunk, compressor=storage.compressor,
                                           compression=storage.compression, bio=storage.bio,
                                           chunks=storage.chunks)
                start = storage.bio.tell()
                self._close_one(stand_in)
                end = storage.bio.tell()
                storage.bio.seek(start + _CHUNK_CRC_OFFSET)
                storage.bio.write(struct.pack('<I', crc))
                storage.bio.seek(end)
            except BaseException as exc:  # handed to the writer's thread
                self._error = exc

    def check(self) -> None:
        """Raise what stopped the thread, if anything did."""
        if self._error is not None:
            raise self._error

    def finish(self) -> None:
        """Write every queued chunk; raise what stopped the thread, if anything did."""
        if not self._closed:
            self._closed = True
            self._queue.put(None)
            self._thread.join()
        self.check()

    def _close_storage(self, version: int, metadata: str) -> None:
        """Storage's ``close``: the last chunk and the queue first, then the summary."""
        if self._storage.chunk.bio.tell():
            self._hand_over()
        self.finish()
        self._original_close(version, metadata)


def _chunks_on_a_thread(writer: Writer) -> _ChunkThread | None:
    """Close the MCAP storage's chunks on a thread (:class:`_ChunkThread`), each with its
    CRC: rosbags' reader checks a nonzero CRC against the decompressed chunk, so damage to
    a bag written here is found when it is read (flipped bytes in a bag written by `process`
    went unnoticed by `process`, `play` and `eval`). None for another storage."""
    storage: Any = writer.storage  # rosbags' MCAP storage: private attributes
    needed = ('close_chunk', 'close', 'chunk', 'bio', 'chunks', 'compressor', 'compression')
    if not all(hasattr(storage, a) for a in needed):
        return None
    return _ChunkThread(storage)


def remove_bag(path: str | Path) -> None:
    """Delete a bag folder written here (one holding metadata.yaml or nothing else)."""
    path = Path(path)
    if path.is_dir() and ((path / 'metadata.yaml').is_file() or not any(path.iterdir())):
        _remove_tree(path)


def _remove_tree(path: Path) -> None:
    shutil.rmtree(path)
