"""The MCAP chunks of a bag being written, closed on a thread of their own, with their
CRC, and made durable on request (a recording's flushes).

rosbags' MCAP writer (``rosbags.rosbag2.storage_mcap.McapWriter``) gathers records in a
chunk and closes it past 1 MiB: compressing it, writing it with its message indexes. Here
that work moves to a thread (:class:`ChunkThread`), which also fills in the chunk's CRC
(rosbags leaves 0) and, when asked (:meth:`ChunkThread.sync`), flushes the file and
fsyncs it once the chunks before have been written. The bytes written are rosbags' own
but for the CRC. These are rosbags' private attributes (``chunk``, ``bio``, ``chunks``,
``compressor``, ``close_chunk``, ``close``); :func:`chunks_on_a_thread` checks for them.
"""

from __future__ import annotations

import functools
import os
import queue
import struct
import threading
import time
import zlib
from types import SimpleNamespace
from typing import Any

from rosbags.rosbag2 import Writer

try:  # zstd is in the standard library from Python 3.14; rosbags needs the backport before
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:
    from backports import zstd  # type: ignore[import-not-found,no-redef,unused-ignore]

from depth_nodes.errors import BagError

#: Offset of the uncompressed-data CRC in an MCAP chunk record: opcode (1), record length
#: (8), message start and end time and uncompressed size (8 each).
CHUNK_CRC_OFFSET = 1 + 8 + 24
#: Closed chunks waiting for the writing thread (each about 1 - 10 MB): the writer blocks
#: beyond that, so a slow disk or compressor bounds the memory instead of growing it.
PENDING_CHUNKS = 4
#: What the thread's queue holds besides chunks: flush and fsync the file, or stop.
_SYNC, _STOP = object(), object()


def set_chunk_compression_level(writer: Writer, level: int) -> None:
    """Swap the MCAP storage's chunk compressor for one with an explicit zstd level.

    Raises:
        BagError: This rosbags version has no compressor to swap.
    """
    storage: Any = writer.storage
    if not hasattr(storage, 'compressor'):
        raise BagError('this rosbags version does not allow a zstd level for MCAP chunks')
    storage.compressor = functools.partial(zstd.compress, level=level)


class ChunkThread:
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
        #: Monotonic time the chunk being filled got its first message (None: none yet).
        self.chunk_started: float | None = None
        #: Chunks handed over since the last :meth:`sync`.
        self.unsynced = 0
        storage.close_chunk = self.hand_over
        storage.close = self._close_storage
        self._thread = threading.Thread(target=self._run, name='mcap-chunks', daemon=True)
        self._thread.start()

    @property
    def chunk_has_messages(self) -> bool:
        """Whether the chunk being filled holds a message."""
        return bool(self._storage.chunk.msgs)

    def wrote(self) -> None:
        """A message went into the chunk being filled (the writer calls this after each):
        note when the chunk got its first one."""
        if self.chunk_started is None and self.chunk_has_messages:
            self.chunk_started = time.monotonic()

    def hand_over(self) -> None:
        """Storage's ``close_chunk``: queue the chunk, start an empty one."""
        self.check()
        storage = self._storage
        chunk = storage.chunk
        storage.chunk = type(chunk)(2**63 - 1, 0, type(chunk.bio)(), type(chunk.msgs)(list))
        self.chunk_started = None
        self.unsynced += 1
        self._queue.put(chunk)

    def sync(self) -> None:
        """Have the file flushed and fsynced once the chunks queued so far are written (on
        the thread: the caller does not wait for the disk)."""
        self.check()
        self.unsynced = 0
        self._queue.put(_SYNC)

    def drain(self) -> None:
        """Wait until everything queued so far is written (and synced, if asked); raise
        what stopped the thread, if anything did."""
        if not self._closed:
            self._queue.join()
        self.check()

    def _run(self) -> None:
        storage = self._storage
        while (item := self._queue.get()) is not _STOP:
            try:
                if self._error is not None:
                    continue  # drain: the caller sees the error
                if item is _SYNC:
                    storage.bio.flush()
                    os.fsync(storage.bio.fileno())
                else:
                    self._write(item)
            except BaseException as exc:  # handed to the writer's thread
                self._error = exc
            finally:
                self._queue.task_done()

    def _write(self, chunk: Any) -> None:
        storage = self._storage
        crc = zlib.crc32(chunk.bio.getbuffer())
        stand_in = SimpleNamespace(chunk=chunk, compressor=storage.compressor,
                                   compression=storage.compression, bio=storage.bio,
                                   chunks=storage.chunks)
        start = storage.bio.tell()
        self._close_one(stand_in)
        end = storage.bio.tell()
        storage.bio.seek(start + CHUNK_CRC_OFFSET)
        storage.bio.write(struct.pack('<I', crc))
        storage.bio.seek(end)

    def check(self) -> None:
        """Raise what stopped the thread, if anything did."""
        if self._error is not None:
            raise self._error

    def finish(self) -> None:
        """Write every queued chunk; raise what stopped the thread, if anything did."""
        if not self._closed:
            self._closed = True
            self._queue.put(_STOP)
            self._thread.join()
        self.check()

    def _close_storage(self, version: int, metadata: str) -> None:
        """Storage's ``close``: the last chunk and the queue first, then the summary."""
        if self._storage.chunk.bio.tell():
            self.hand_over()
        self.finish()
        self._original_close(version, metadata)


def chunks_on_a_thread(writer: Writer) -> ChunkThread | None:
    """Close the MCAP storage's chunks on a thread (:class:`ChunkThread`), each with its
    CRC: rosbags' reader checks a nonzero CRC against the decompressed chunk, so damage to
    a bag written here is found when it is read (flipped bytes in a bag written by `process`
    went unnoticed by `process`, `play` and `eval`). None for another storage."""
    storage: Any = writer.storage  # rosbags' MCAP storage: private attributes
    needed = ('close_chunk', 'close', 'chunk', 'bio', 'chunks', 'compressor', 'compression')
    if not all(hasattr(storage, a) for a in needed):
        return None
    return ChunkThread(storage)
