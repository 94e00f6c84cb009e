"""Bands of rows: how the matcher bounds its memory and shares two cores with other work.

The matcher cuts the image into bands of rows and schedules each band's steps as tasks
with dependencies (:func:`run_tasks`); each thread takes whichever task is ready. When
the frame's volumes fit the memory budget, the downward paths run as one chain of bands
from the top and the upward ones as another from the bottom, at once, and a band is
selected once both have passed it (exact). Otherwise only a few bands are held: per band
the costs and the downward sweep (continuing the band above: exact), then the upward
paths from ``overlap`` rows below the band's end (their start is the only approximation),
the horizontal paths and the selection. :func:`band_rows` sizes those bands so that
memory stays the same whatever the disparity range. No thread ever waits at a per-row barrier for a
thread the operating system has descheduled: with one core taken by another process the
matcher slows down in proportion to the CPU it gets, instead of stalling at every row.
The bands depend only on the image and the settings, never on the thread count, so every
thread count gives the same result bit for bit.
"""

from __future__ import annotations

import contextlib
import heapq
import os
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba

# The band kernels are numba parallel functions (ONE_THREAD_GUFUNC in aggregate.py) that
# several threads run at once: that needs a thread-safe threading layer (OpenMP or TBB;
# numba's own workqueue aborts on concurrent launches). The user's explicit choice wins.
if 'NUMBA_THREADING_LAYER' not in os.environ:
    numba.config.THREADING_LAYER = 'threadsafe'  # type: ignore[attr-defined]

#: Bands an image is cut into at least (when memory allows fewer, larger ones are not
#: used: the selection of several bands must be able to run while the chain goes on).
MIN_BANDS = 8
#: Rows of a band at least (fewer would spend most of the time on the overlap).
MIN_BAND_ROWS = 16
#: Cell bytes of a band in flight: 1 of cost, 2 of the downward sum.
CELL_BYTES = 3
#: Largest band (its costs and downward sum) of a single-pass path count: small enough to
#: stay in the caches between its sweep and its selection. 5 paths at 640x480 / 128 ran
#: 6 - 7 % faster on one and on two threads with 20-row bands than with 60-row ones, 1280x720
#: / 256 9 % with 16-row bands than with 54 (the output does not depend on the bands).
CACHED_BAND_BYTES = 5e6


@dataclass(frozen=True)
class Band:
    """Rows ``y0`` .. ``y0 + rows - 1``, whose upward paths start at row ``y0 + reach - 1``
    (``reach - rows`` rows of context below the band)."""

    y0: int
    rows: int
    reach: int


def band_rows(height: int, width: int, disparities: int, *, memory_mb: float,
              slots: int, overlap: int) -> int:
    """Rows per band: an eighth of the image at most, and few enough that ``slots`` bands
    in flight (their costs and downward sums) fit ``memory_mb`` with ``overlap`` rows of
    one byte a cell to spare per band.

    The spare share is what the costs of the rows below a band took when its upward paths
    read them from the band's buffer; they now pass a few rows at a time
    (``workspace.OVERLAP_CHUNK``). Sizing the bands as tall as the whole budget allows was
    measured to raise the peak at 1920x1080 / 256 disparities from 409 to 455 MB (the
    matcher's other buffers grow with the disparity range too), so the share stays spare.
    """
    row_bytes = width * disparities * CELL_BYTES
    budget = memory_mb * 1e6 / slots
    by_memory = int((budget - overlap * width * disparities) // row_bytes)
    by_count = -(-height // MIN_BANDS)
    return max(MIN_BAND_ROWS, min(by_count, by_memory))


def band_layout(height: int, rows: int, overlap: int) -> list[Band]:
    """The bands of ``rows`` rows covering ``height`` (the last one shorter), each reaching
    ``overlap`` rows below its end or to the image bottom."""
    return [Band(y0, min(rows, height - y0), min(height, y0 + rows + overlap) - y0)
            for y0 in range(0, height, rows)]


@dataclass
class Task:
    """A unit of work: ``run(worker)`` once every task in ``after`` has finished. Lower
    ``priority`` runs first among the ready tasks (ties: the order given)."""

    run: Callable[[int], None]
    after: Sequence[int] = ()
    priority: int = 0


def worker_cpus(threads: int, allowed: set[int]) -> list[int]:
    """The CPU each of ``threads`` workers runs on while they match a frame, when the
    workers are exactly as many as the CPUs ``allowed`` (the calling thread's set): one
    each. Otherwise none: no pinning.

    With a core taken by another process, three threads share two cores, and Linux woke
    a worker that had waited for a task on its waker's core: both workers then often
    shared one core for a whole frame while the other process had the other one to itself
    (the matcher got 104 - 128 % of a core from run to run). Pinned, the two workers
    always run on both cores. ``depth-nodes bench sgm --busy 1`` (8 paths, two threads;
    three runs each, in turn, 2026-11-26): contended 90.7 - 95.4 ms, 1.35 - 1.40x the quiet
    time, against 110.5 - 117.5 ms (1.58 - 1.72x) unpinned; quiet frames do not change.

    Fewer workers than CPUs are left to the scheduler: pinned to the first CPUs of the
    set, two matchers in two processes (two cameras) would share those CPUs while the
    others idled. The caller's own affinity is restored after the frame, and a set
    restricted by the user (``taskset``, a cpuset) is only ever narrowed within itself.
    The price: a pinned worker cannot move off a core that a real-time thread holds; its
    current task waits, while the other worker takes every task still to come.
    """
    if threads < 2 or len(allowed) != threads:
        return []
    return sorted(allowed)


def _set_cpus(cpus: set[int]) -> None:
    """The calling thread's CPU affinity, if the system allows it (a sandbox may refuse
    ``sched_setaffinity``, a CPU may have gone offline): pinning is an optimisation, never
    a reason for a frame to fail."""
    with contextlib.suppress(OSError):
        os.sched_setaffinity(0, cpus)


def run_tasks(tasks: Sequence[Task], threads: int) -> None:
    """Run ``tasks`` on ``threads`` threads (the calling one included), each taking the
    ready task of lowest priority. ``run`` receives the worker's index, 0 .. threads - 1,
    for per-worker scratch. The first exception stops the work and is raised here once
    every running task has returned.

    Raises:
        ValueError: A dependency refers to a later task (or itself): no cycle can form.
    """
    n = len(tasks)
    waiting = [len(t.after) for t in tasks]
    dependents: list[list[int]] = [[] for _ in range(n)]
    for i, task in enumerate(tasks):
        for j in task.after:
            if not 0 <= j < i:
                raise ValueError(f'task {i} depends on task {j}: dependencies must come first')
            dependents[j].append(i)
    ready = [(t.priority, i) for i, t in enumerate(tasks) if not t.after]
    heapq.heapify(ready)
    lock = threading.Condition()
    state = {'finished': 0}
    errors: list[BaseException] = []

    own_cpus = os.sched_getaffinity(0) if hasattr(os, 'sched_getaffinity') else set()
    cpus = worker_cpus(threads, own_cpus)

    def work(worker: int) -> None:
        numba.set_num_threads(1)  # each task is one thread's (ONE_THREAD_GUFUNC)
        if cpus:
            _set_cpus({cpus[worker]})
        while True:
            with lock:
                while not ready and not errors and state['finished'] < n:
                    lock.wait()
                if errors or state['finished'] >= n:
                    return
                _, i = heapq.heappop(ready)
            try:
                tasks[i].run(worker)
            except BaseException as error:  # handed to the caller below
                with lock:
                    errors.append(error)
                    lock.notify_all()
                return
            with lock:
                state['finished'] += 1
                for j in dependents[i]:
                    waiting[j] -= 1
                    if waiting[j] == 0:
                        heapq.heappush(ready, (tasks[j].priority, j))
                lock.notify_all()

    helpers = [threading.Thread(target=work, args=(k,), name=f'sgm-band-{k}', daemon=True)
               for k in range(1, max(1, min(threads, n)))]
    for thread in helpers:
        thread.start()
    own_threads = numba.get_num_threads()
    try:
        work(0)
    except BaseException as error:  # e.g. Ctrl-C while waiting: stop the helpers too
        with lock:
            errors.append(error)
            lock.notify_all()
        raise
    finally:
        numba.set_num_threads(own_threads)
        if cpus:
            _set_cpus(own_cpus)
        for thread in helpers:
            thread.join()
    if errors:
        raise errors[0]
