"""Several frames processed at once on worker threads, published in the order they came.

A node whose per-frame work is one long kernel that releases the GIL (the SGM matcher) can
keep two cores busy with two frames at a time, without the fine-grained synchronisation
that splitting one frame across threads needs. :class:`OrderedWorkers` runs each frame's
``compute`` on a worker and its ``publish`` once every frame submitted before it has
published (or failed), so subscribers see the stamps in order. :meth:`OrderedWorkers.submit`
blocks while ``count`` frames are in flight: the node's input queue then fills, exactly as
when the node works one frame at a time, and the middleware drops what does not fit.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from typing import Any, TypeVar

import cv2
import numba

from depth_nodes.errors import ArgumentError

T = TypeVar('T')


class OrderedWorkers:
    """Up to ``count`` frames in flight on worker threads; results published in order.

    Args:
        count: Frames processed at once (>= 1).
        on_error: Called with the exception of a frame whose ``compute`` or ``publish``
            raised, in that frame's turn (the frames after it still publish).
        name: Prefix of the worker threads' names.
    """

    def __init__(self, count: int, on_error: Callable[[BaseException], None], *,
                 name: str = 'frame') -> None:
        if count < 1:
            raise ArgumentError(f'count must be at least 1, got {count}')
        self.count = count
        self._on_error = on_error
        self._pool = ThreadPoolExecutor(max_workers=count, thread_name_prefix=name)
        self._in_flight: list[Future[None]] = []
        self._previous = threading.Event()
        self._previous.set()

    def submit(self, compute: Callable[[], T], publish: Callable[[T], None]) -> None:
        """Run ``compute()`` on a worker, then ``publish(result)`` in submission order.

        Blocks until fewer than ``count`` frames are in flight. Call from one thread (the
        node's callback).
        """
        self._in_flight = [f for f in self._in_flight if not f.done()]
        while len(self._in_flight) >= self.count:
            wait(self._in_flight, return_when=FIRST_COMPLETED)
            self._in_flight = [f for f in self._in_flight if not f.done()]
        before, mine = self._previous, threading.Event()
        self._previous = mine

        def run() -> None:
            result: Any = None
            failure: BaseException | None = None
            try:
                result = compute()
            except Exception as exc:  # reported in this frame's turn, below
                failure = exc
            before.wait()
            try:
                if failure is None:
                    publish(result)
                else:
                    self._on_error(failure)
            except Exception as exc:
                self._on_error(exc)
            finally:
                mine.set()

        self._in_flight.append(self._pool.submit(run))

    @property
    def in_flight(self) -> int:
        """Frames submitted and not yet published."""
        return sum(not f.done() for f in self._in_flight)

    def drain(self) -> None:
        """Wait until every submitted frame has published (or failed)."""
        wait(self._in_flight)
        self._in_flight = []

    def shutdown(self) -> None:
        """Finish the frames in flight and stop the worker threads."""
        self.drain()
        self._pool.shutdown(wait=True)


def use_threads(threads: int) -> None:
    """Run the calling thread's numba kernels and OpenCV calls on ``threads`` threads (0:
    every core).

    numba's setting belongs to the calling thread, so a node applies it in the thread that
    runs its kernels, once per frame. OpenCV's is process-wide (nodes composed into one
    process share it) and is only changed when it differs, since changing it rebuilds
    OpenCV's thread pool. More threads than cores are clamped to the cores (``threads:
    1024`` once made a composed process start over 1,000 OpenCV threads).
    """
    cores = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    numba.set_num_threads(min(threads, cores) if threads else cores)
    cpus = cv2.getNumberOfCPUs()
    wanted = min(threads, cpus) if threads else cpus
    if cv2.getNumThreads() != wanted:
        cv2.setNumThreads(wanted)
