"""What a spawned worker process of `process` sets up first, before it imports anything
else: its numba threads (``NUMBA_NUM_THREADS`` is read when numba is imported, which the
graph's modules do), its heap, its signals.

Standard library only: a spawned worker imports this module to run :func:`init_worker`
(the pool's initializer) before its first job imports the graph.
"""

from __future__ import annotations

import ctypes
import os
import signal

#: glibc's mallopt parameters, and the values a worker sets (see :func:`keep_heap`).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_HEAP_KEEP = 1 << 30
_MMAP_FROM = 256 << 20


def keep_heap() -> None:
    """Let the worker reuse its heap for the frames' large buffers instead of mapping and
    unmapping them: glibc maps blocks of a few MB and returns the memory at once, and the
    page faults of the next frame's buffers cost a worker a tenth of its time here (see
    docs/speed.md, "Offline processing"). No-op off glibc."""
    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_FROM)
        libc.mallopt(_M_TRIM_THRESHOLD, _HEAP_KEEP)
    except (OSError, AttributeError):
        pass


def init_worker(threads: int) -> None:
    """A spawned worker: its share of the cores, a heap kept for reuse, and signals left
    to the main process, which stops the workers itself. SIGTERM too: sent to the whole
    process group (`timeout`, `kill -- -PGID`, a service manager stopping its unit), it
    killed the workers under the main process, which then failed with a traceback instead
    of closing the output with what was done."""
    os.environ['NUMBA_NUM_THREADS'] = str(threads)
    keep_heap()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
