"""Stopping the `depth-nodes` commands with SIGINT (Ctrl-C) or SIGTERM (what systemd, docker
and launchers send), however they were started.

A shell starts a background job with SIGINT ignored, and Python then installs no handler
for it; SIGTERM ends a Python process at once, without cleanup. So the command line
installs handlers for both itself (:func:`install`):

* commands that write nothing (eval, bench, param) stop at once: the signal raises
  KeyboardInterrupt;
* commands that write a bag or publish (process, generate, record, play) run inside
  :func:`graceful`: the first signal only sets :data:`STOP`, which their loops check between
  two messages, so the bag is closed with everything written so far (its metadata matching
  its content); a second signal raises KeyboardInterrupt for a user who will not wait.

The node processes and `pipeline` block in rclpy's executor, which a Python handler cannot
wake: they also install rclpy's own handlers, which wake the executor and shut its context
down (``rclpy.init(signal_handler_options=SignalHandlerOptions.ALL)``).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

#: Set by the first SIGINT / SIGTERM inside :func:`graceful`.
STOP = threading.Event()
SIGNALS = (signal.SIGINT, signal.SIGTERM)
_graceful = False


def _handler(signum: int, frame: FrameType | None) -> None:
    if _graceful and not STOP.is_set():
        STOP.set()
        return
    raise KeyboardInterrupt(signal.Signals(signum).name)


def install() -> None:
    """Handle SIGINT and SIGTERM in this (main) thread, even if SIGINT was ignored."""
    for sig in SIGNALS:
        signal.signal(sig, _handler)


@contextlib.contextmanager
def graceful() -> Iterator[threading.Event]:
    """Within: the first signal sets the returned event instead of raising (see the
    module notes); a second raises KeyboardInterrupt."""
    global _graceful
    previous, _graceful = _graceful, True
    STOP.clear()
    try:
        yield STOP
    finally:
        _graceful = previous


def stop_requested() -> bool:
    """True after a SIGINT / SIGTERM inside :func:`graceful`."""
    return STOP.is_set()
