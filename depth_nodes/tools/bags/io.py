"""rosbag2 reading and writing through the `rosbags` library, with rclpy message objects.

``rosbag2_py`` is not on PyPI, so bags are read and written with rosbags while messages
are (de)serialised by rclpy itself. Messages therefore travel as the exact CDR bytes a live
graph would carry, and the same node classes can process them offline.
"""

from __future__ import annotations

import contextlib
import importlib
import shutil
import struct
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    Reader,
    StoragePlugin,
    Writer,
)
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import BagError, yaml_problem
from depth_nodes.tools.bags.chunks import chunks_on_a_thread, set_chunk_compression_level

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


def header_stamp(cdr: bytes) -> int:
    """The header stamp (ns) of a serialised message whose first field is a
    std_msgs/Header (every image, disparity and cloud type): read from the CDR bytes, after
    the 4-byte encapsulation header whose second byte says the byte order.

    Raises:
        BagError: Too few bytes to hold a header stamp.
    """
    order = '<' if len(cdr) > 1 and cdr[1] & 1 else '>'
    if len(cdr) < 12:
        raise BagError('a message too short to hold a header stamp')
    sec, nanosec = struct.unpack_from(f'{order}iI', cdr, 4)
    return int(sec) * NS_PER_S + int(nanosec)


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

    def check(self) -> None:
        """Check that the bytes are a message of its type, all of them (rosbags'
        deserialiser: about 0.06 ms for a 640x480 image), without making an rclpy message.

        Raises:
            BagError: They are not (another type's message, damaged bytes).
        """
        if self.msgtype not in _TYPESTORE.types:
            self.deserialize()  # rclpy: what does not parse at all is found
            return
        try:
            _TYPESTORE.deserialize_cdr(self.data, self.msgtype)
        except Exception as exc:  # rosbags: SerdeError on a size mismatch, struct errors
            raise BagError(f'the message on {self.topic} at t={self.timestamp} is not a '
                           f'{self.msgtype}: {_one_line(exc)}') from None

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
        cut = (f'; a recording cut off (killed, a full disk, a power loss)? '
               f'`depth-nodes reindex {self.path}` recovers it'
               if self.path.is_dir() and any(self.path.glob('*.mcap')) else '')
        if not (self.path / 'metadata.yaml').is_file():
            raise BagError(f'not a rosbag2 bag (no metadata.yaml): {self.path}{cut}')
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:
            raise BagError(f'cannot open bag {self.path}: {_one_line(exc)}{cut}') from None
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

    Chunks are compressed and written on a thread of their own
    (:class:`~depth_nodes.tools.bags.chunks.ChunkThread`). A write that fails raises
    :class:`BagError` in one line, at that call or (for a chunk the thread was writing) at
    the next one, or at :meth:`close`. A recording calls :meth:`flush` often, so that a
    SIGKILL or a power loss takes at most the last second with it.
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
            set_chunk_compression_level(self._writer, compression_level)
        self._chunks = chunks_on_a_thread(self._writer)
        self._last_sync = time.monotonic()

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a key/value string in the bag's metadata (e.g. the generator's seed)."""
        self._writer.set_custom_data(key, value)

    def add_topic(self, topic: str, msgtype: str, *, qos: Sequence[Any] = (),
                  msgdef: str | None = None) -> Any:
        """Register ``topic`` (done by its first :meth:`write` otherwise); returns its
        connection.

        Args:
            topic: The topic.
            msgtype: Its type, ``pkg/msg/Name``.
            qos: The QoS profiles its publishers offered (rosbags ``Qos`` tuples).
            msgdef: The type's definition (ros2msg, dependencies appended as rosbag2
                writes them), for a type the Jazzy typestore does not know.

        Raises:
            BagError: The topic has another type already, or the type is unknown (and
                ``msgdef`` does not define it).
        """
        conn = self._connections.get(topic)
        if conn is not None:
            if conn.msgtype != msgtype:
                raise BagError(f'topic {topic} has type {conn.msgtype}; cannot write a '
                               f'{msgtype}')
            return conn
        typestore = _TYPESTORE
        if msgtype not in typestore.types:
            try:
                typestore = get_typestore(Stores.ROS2_JAZZY)
                typestore.register(get_types_from_msg(msgdef or '', msgtype))
                typestore.generate_msgdef(msgtype, ros_version=2)
            except Exception:  # rosbags' parser: no definition, or not a valid one
                raise BagError(f'message type {msgtype} (topic {topic}) is unknown to '
                               'rosbags') from None
        conn = self._writer.add_connection(topic, msgtype, typestore=typestore,
                                           offered_qos_profiles=list(qos))
        self._connections[topic] = conn
        return conn

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
        conn = self.add_topic(topic, msgtype, qos=qos)
        try:
            self._writer.write(conn, timestamp, data)
        except OSError as exc:  # a full disk, now or when an earlier chunk was written
            self._fail(exc)
        if self._chunks is not None:
            self._chunks.wrote()
        self.counts[topic] += 1

    def flush(self, max_age: float = 0.0, *, wait: bool = False) -> None:
        """Make what was written outlive this process and the machine: close the chunk
        being filled once its first message is ``max_age`` seconds old, and have the file
        flushed and fsynced (on the chunk thread, after the chunks closed before) when a
        chunk was closed since the last time and that was ``max_age`` seconds ago or more.

        Called every few tens of milliseconds, a message is on the disk at most about
        ``2 * max_age`` seconds (plus the disk's latency) after it was written; what is on
        the disk of a bag cut off there is recovered by
        :func:`~depth_nodes.tools.bags.recover.reindex_bag`. With ``wait``, return once
        it is there.

        Raises:
            BagError: A chunk could not be written (a full disk).
        """
        chunks = self._chunks
        if chunks is None or self._closed or self._failed:
            return
        now = time.monotonic()
        try:
            if chunks.chunk_started is not None and now - chunks.chunk_started >= max_age:
                chunks.hand_over()
            if chunks.unsynced and now - self._last_sync >= max_age:
                chunks.sync()
                self._last_sync = now
            if wait:
                chunks.drain()
        except OSError as exc:
            self._fail(exc)

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



def remove_bag(path: str | Path) -> None:
    """Delete a bag folder written here (one holding metadata.yaml or nothing else)."""
    path = Path(path)
    if path.is_dir() and ((path / 'metadata.yaml').is_file() or not any(path.iterdir())):
        _remove_tree(path)


def _remove_tree(path: Path) -> None:
    shutil.rmtree(path)
