"""What a node counts: messages received and published, frames dropped (by reason, with a
throttled warning), frames skipped because nobody subscribes, processing times; and the
last line of defence that turns an unexpected exception into a counted drop.

A node never loses a frame silently: :meth:`Accounting.drop` counts it under a short stable
reason and logs a warning naming it, at most once per :data:`DROP_LOG_PERIOD_S` per reason.
A frame skipped because no output is wanted (:meth:`Accounting.skip`) is not a drop:
nothing was lost, nobody asked; it is counted for the diagnostics only, without a warning.
Every method may be called from any thread (a node may publish from worker threads, see
:mod:`depth_nodes.ros.workers`): the counters share one lock.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

#: Seconds between two warnings for the same drop reason.
DROP_LOG_PERIOD_S = 5.0


class DropCounter(Protocol):
    """Anything frames can be dropped on (a node, its :class:`Accounting`)."""

    def drop(self, reason: str, detail: str, count: int = 1) -> None:
        """Count ``count`` frames lost for ``reason``; ``detail`` explains it."""


@dataclass
class Window:
    """Counts of one diagnostics period (replaced by a fresh one when it is published)."""

    start: float
    inputs: Counter[str] = field(default_factory=Counter)
    outputs: Counter[str] = field(default_factory=Counter)
    drops: Counter[str] = field(default_factory=Counter)
    frame_times: list[float] = field(default_factory=list)
    skipped: int = 0


class Accounting:
    """The counters of one node.

    Args:
        logger: Returns the logger to warn on (looked up at each warning, so a test may
            replace the node's ``get_logger``).
        stopping: True once the node's context is shut down: nothing is logged then, and
            an exception is the end of the run rather than an error.
    """

    def __init__(self, logger: Callable[[], Any], stopping: Callable[[], bool]) -> None:
        self._logger = logger
        self._stopping = stopping
        self.lock = threading.Lock()
        #: Frames dropped since the start, by reason.
        self.drops: Counter[str] = Counter()
        #: Messages received since the start, by resolved input topic.
        self.received: Counter[str] = Counter()
        #: Messages published since the start, by resolved output topic.
        self.published: Counter[str] = Counter()
        #: Frames skipped since the start because no output was wanted.
        self.skipped = 0
        self.window = Window(time.monotonic())
        self._last_drop_log: dict[str, float] = {}
        self._logged_errors: set[tuple[str, str]] = set()

    def count_input(self, topic: str) -> None:
        """One message received on ``topic``."""
        with self.lock:
            self.received[topic] += 1
            self.window.inputs[topic] += 1

    def count_output(self, topic: str) -> None:
        """One message published on ``topic``."""
        with self.lock:
            self.published[topic] += 1
            self.window.outputs[topic] += 1

    def record_frame_time(self, seconds: float) -> None:
        """Add one frame's processing time to the diagnostics."""
        with self.lock:
            self.window.frame_times.append(seconds)

    def skip(self) -> None:
        """One frame skipped: no output was wanted (not a drop, no warning)."""
        with self.lock:
            self.skipped += 1
            self.window.skipped += 1

    def drop(self, reason: str, detail: str, count: int = 1) -> None:
        """Count frames that produced no output, and log why (throttled per reason).

        Args:
            reason: A short stable key, e.g. ``size_mismatch``; the counter's key.
            detail: The human-readable explanation, e.g. the sizes that disagreed.
            count: How many frames were lost for this reason at once.
        """
        with self.lock:
            self.drops[reason] += count
            self.window.drops[reason] += count
            now = time.monotonic()
            last = self._last_drop_log.get(reason)
            log = (last is None or now - last >= DROP_LOG_PERIOD_S) and not self._stopping()
            if log:
                self._last_drop_log[reason] = now
        if log:
            self._logger().warning(
                f'dropped frame ({reason}, {self.drops[reason]} so far): {detail}'
            )

    def internal_error(self, exc: BaseException, where: str) -> None:
        """Count an unexpected exception as an ``internal_error`` drop; log its traceback
        the first time this type of exception happens at ``where``."""
        key = (where, type(exc).__name__)
        with self.lock:
            first = key not in self._logged_errors
            self._logged_errors.add(key)
        if first:
            self._logger().error(
                f'unexpected {type(exc).__name__} handling {where}; the frame is dropped and '
                f'the node goes on (logged once per kind):\n'
                + ''.join(traceback.format_exception(exc)).rstrip())
        self.drop('internal_error', f'{where}: {type(exc).__name__}: {exc}')

    def guarded(self, callback: Callable[..., None], *args: Any, where: str) -> None:
        """Run ``callback(*args)``; an exception it did not expect becomes a counted
        ``internal_error`` drop (see :meth:`internal_error`) instead of ending the node."""
        try:
            callback(*args)
        except Exception as exc:  # the last line of defence: the node must go on
            if self._stopping():  # a publish after Ctrl-C / SIGTERM shut the context down
                return
            self.internal_error(exc, where)

    def new_window(self, now: float) -> tuple[Window, Counter[str], Counter[str]]:
        """Start a new diagnostics period at ``now`` (monotonic seconds).

        Returns:
            The period that ends, and the totals of drops and of published messages.
        """
        with self.lock:
            window, self.window = self.window, Window(now)
            return window, Counter(self.drops), Counter(self.published)
