"""OrderedWorkers: frames computed at once on worker threads, published in their order."""

from __future__ import annotations

import threading
from typing import Any

import cv2
import numba
import pytest

from depth_nodes.ros.workers import OrderedWorkers, use_threads

#: Generous bound on a wait for an event another thread sets at once (not a timing
#: assertion: a test only fails on it if the event never comes).
WAIT_S = 30.0


def test_a_later_frame_that_finishes_first_still_publishes_second() -> None:
    published: list[str] = []
    errors: list[BaseException] = []
    second_done = threading.Event()
    workers = OrderedWorkers(2, errors.append)

    def first() -> str:
        assert second_done.wait(WAIT_S)  # finishes only after the second has computed
        return 'first'

    def second() -> str:
        second_done.set()
        return 'second'

    workers.submit(first, published.append)
    workers.submit(second, published.append)
    workers.shutdown()
    assert published == ['first', 'second']
    assert errors == []


def test_no_more_than_count_frames_are_computed_at_once() -> None:
    lock = threading.Lock()
    running, most = 0, 0

    def compute(i: int) -> int:
        nonlocal running, most
        with lock:
            running += 1
            most = max(most, running)
        barrier.wait(WAIT_S)  # the two of a pair meet: both run at once
        with lock:
            running -= 1
        return i

    barrier = threading.Barrier(2)
    published: list[int] = []
    workers = OrderedWorkers(2, pytest.fail)
    for i in range(10):
        workers.submit(lambda i=i: compute(i), published.append)
        assert workers.in_flight <= 2
    workers.shutdown()
    assert published == list(range(10))
    assert most == 2


def test_a_failing_frame_is_reported_in_its_turn_and_the_rest_publish() -> None:
    events: list[Any] = []

    def boom() -> int:
        raise RuntimeError('matcher failed')

    def bad_publish(value: int) -> None:
        raise ValueError(f'cannot publish {value}')

    workers = OrderedWorkers(3, lambda exc: events.append(repr(exc)))
    workers.submit(lambda: 1, events.append)
    workers.submit(boom, events.append)
    workers.submit(lambda: 3, bad_publish)
    workers.submit(lambda: 4, events.append)
    workers.shutdown()
    assert events == [1, "RuntimeError('matcher failed')", "ValueError('cannot publish 3')", 4]


def test_count_must_be_positive() -> None:
    with pytest.raises(ValueError, match='at least 1'):
        OrderedWorkers(0, print)


def test_use_threads_sets_numba_for_the_calling_thread_and_opencv_for_the_process() -> None:
    cores = numba.config.NUMBA_NUM_THREADS
    use_threads(1)
    assert (numba.get_num_threads(), cv2.getNumThreads()) == (1, 1)
    seen: list[int] = []
    other = threading.Thread(target=lambda: seen.append(numba.get_num_threads()))
    other.start()
    other.join()
    assert seen == [cores]  # numba's setting belongs to the thread that made it
    use_threads(0)
    assert (numba.get_num_threads(), cv2.getNumThreads()) == (cores, cv2.getNumberOfCPUs())
    use_threads(cores + 5)  # more than numba started with: as many as it has
    assert numba.get_num_threads() == cores
    assert cv2.getNumThreads() == cv2.getNumberOfCPUs()  # OpenCV clamped too
