"""Exact-time and approximate-time message synchronisers (``message_filters`` is not on PyPI).

Both synchronisers are pure Python and know nothing about message types: a message is any
object with ``msg.header.stamp.sec`` and ``msg.header.stamp.nanosec``. Stamps are compared
as integer nanoseconds (:func:`stamp_to_ns`), so there is no floating-point rounding.

Both keep books: every message given to ``add`` is, at any moment, either part of an
emitted set, counted once in ``dropped`` under the reason it was discarded, or still held
(``queued``), so ``emitted * n_inputs + sum(dropped.values()) + queued`` equals the number
of messages added since the last :meth:`reset`. Drop reasons:

- ``'queue_full'``: evicted because a queue was full.
- ``'unmatched'``: older than the message of its input in an emitted set, so it can never
  be part of a later set.
- ``'out_of_order'``: its stamp is older than the previous message accepted on the same
  input (and so also older than anything already emitted on that input).
- ``'duplicate'``: the same stamp twice on one input; the first message is kept.
- ``'interval_too_large'``: (approximate only) no set containing it can be within
  ``max_interval``.

Besides messages, both count lost *frames* in ``lost_frames``, by the same reasons: one
per frame whatever evicted it, so a set that completes and discards three waiting sets
counts three. The exact synchroniser's frame is a stamp (its messages share it): a pending
stamp discarded counts once, however many of its messages had arrived. The approximate
synchroniser's frame is a message of input 0 (the primary input, e.g. the image of an
image + camera_info pair): messages of the other inputs discarded on their own (a camera_info
at 30 Hz beside images at 10 Hz) are counted in ``dropped`` only. A message refused as
``out_of_order`` or ``duplicate`` counts as a frame on either synchroniser (exact: it is one
message of its stamp, the stamp is not lost otherwise).

Neither class is thread-safe or re-entrant: call ``add`` from one thread (in rclpy, one
mutually exclusive callback group) and do not call ``add`` from inside the callback.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Any

from depth_nodes.core.stamps import NS_PER_S, stamp_ns
from depth_nodes.errors import SyncError

__all__ = [
    'DROP_REASONS',
    'ApproximateTimeSynchronizer',
    'ExactTimeSynchronizer',
    'stamp_to_ns',
]

#: Every key that can appear in a synchroniser's ``dropped`` counter.
DROP_REASONS = ('queue_full', 'unmatched', 'out_of_order', 'duplicate', 'interval_too_large')


def stamp_to_ns(stamp: Any) -> int:
    """Convert a ``builtin_interfaces/Time`` (or anything with ``sec``/``nanosec``) to ns.

    Args:
        stamp: Object with integer ``sec`` and ``nanosec`` (0 <= nanosec < 1e9) attributes.

    Returns:
        ``sec * 10**9 + nanosec`` as a Python int.

    Raises:
        SyncError: If the fields are missing, not integers, or ``nanosec`` is out of range.
    """
    try:
        sec = stamp.sec
        nanosec = stamp.nanosec
    except AttributeError:
        raise SyncError(f'stamp must have sec and nanosec fields, got {stamp!r}') from None
    if isinstance(sec, bool) or isinstance(nanosec, bool):
        raise SyncError(f'stamp sec/nanosec must be integers, got {sec!r}/{nanosec!r}')
    try:
        sec_i = int(sec)
        nanosec_i = int(nanosec)
    except (TypeError, ValueError):
        raise SyncError(f'stamp sec/nanosec must be integers, got {sec!r}/{nanosec!r}') from None
    if sec_i != sec or nanosec_i != nanosec:
        raise SyncError(f'stamp sec/nanosec must be integers, got {sec!r}/{nanosec!r}')
    if not 0 <= nanosec_i < NS_PER_S:
        raise SyncError(f'stamp nanosec must be in [0, 1e9), got {nanosec!r}')
    return stamp_ns(stamp)


def _msg_stamp_ns(msg: Any) -> int:
    try:
        stamp = msg.header.stamp
    except AttributeError:
        raise SyncError(f'msg must have header.stamp, got {type(msg).__name__}') from None
    return stamp_to_ns(stamp)


def _seconds_to_ns(name: str, value: float) -> int:
    """Validate a non-negative duration in seconds and convert it to ns (inf -> -1)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SyncError(f'{name} must be a number of seconds, got {value!r}')
    if math.isnan(value) or value < 0:
        raise SyncError(f'{name} must be >= 0 seconds, got {value!r}')
    if math.isinf(value):
        return -1
    return round(value * NS_PER_S)


class _SyncBase:
    """Argument checks, per-input ordering checks and the drop / emit counters."""

    def __init__(self, n_inputs: int, callback: Callable[..., None], queue_size: int) -> None:
        if isinstance(n_inputs, bool) or not isinstance(n_inputs, int) or n_inputs < 2:
            raise SyncError(f'n_inputs must be an int >= 2, got {n_inputs!r}')
        if isinstance(queue_size, bool) or not isinstance(queue_size, int) or queue_size < 1:
            raise SyncError(f'queue_size must be an int >= 1, got {queue_size!r}')
        if not callable(callback):
            raise SyncError(f'callback must be callable, got {callback!r}')
        self.n_inputs = n_inputs
        self.queue_size = queue_size
        self.callback = callback
        self.dropped: Counter[str] = Counter()
        #: Frames lost, by reason (see the module notes).
        self.lost_frames: Counter[str] = Counter()
        self.emitted = 0
        self._last_stamp: list[int | None] = [None] * n_inputs

    def add(self, index: int, msg: Any) -> None:
        """Offer ``msg`` on input ``index``; may call the callback (once with exact
        stamps, one or more times with the approximate policy).

        Args:
            index: Input number in ``[0, n_inputs)``.
            msg: Message with ``header.stamp``.

        Raises:
            SyncError: If ``index`` is out of range or ``msg`` has no valid stamp.
        """
        index = self._check_index(index)
        stamp = _msg_stamp_ns(msg)
        if self._accept(index, stamp):
            self._store(index, stamp, msg)

    def _store(self, index: int, stamp: int, msg: Any) -> None:
        raise NotImplementedError

    def _check_index(self, index: int) -> int:
        if isinstance(index, bool) or not isinstance(index, int):
            raise SyncError(f'index must be an int in [0, {self.n_inputs}), got {index!r}')
        if not 0 <= index < self.n_inputs:
            raise SyncError(f'index must be in [0, {self.n_inputs}), got {index}')
        return index

    def _accept(self, index: int, stamp: int) -> bool:
        """Enforce strictly increasing stamps per input; count the rejects."""
        last = self._last_stamp[index]
        if last is not None and stamp <= last:
            reason = 'duplicate' if stamp == last else 'out_of_order'
            self._drop(reason)
            self._lose(reason)
            return False
        self._last_stamp[index] = stamp
        return True

    def _drop(self, reason: str, count: int = 1) -> None:
        if count:  # never create zero entries, so ``dropped == {...}`` comparisons hold
            self.dropped[reason] += count

    def _lose(self, reason: str, frames: int = 1) -> None:
        if frames:
            self.lost_frames[reason] += frames

    def _reset_counters(self) -> None:
        self.dropped.clear()
        self.lost_frames.clear()
        self.emitted = 0
        self._last_stamp = [None] * self.n_inputs


class ExactTimeSynchronizer(_SyncBase):
    """Emit a set when every input has a message with the same stamp.

    Equivalent to the ``message_filters`` ExactTime policy: at most ``queue_size`` distinct
    stamps are pending (a new stamp beyond that evicts the oldest pending stamp and its
    messages); when a set completes, every pending message with an older stamp is dropped
    as ``'unmatched'``.

    Args:
        n_inputs: Number of inputs (>= 2).
        callback: Called as ``callback(msg_0, ..., msg_{n-1})`` for each complete set.
        queue_size: Maximum number of distinct pending stamps (>= 1).

    Raises:
        SyncError: On an invalid argument.
    """

    def __init__(
        self, n_inputs: int, callback: Callable[..., None], *, queue_size: int = 10
    ) -> None:
        super().__init__(n_inputs, callback, queue_size)
        # stamp (ns) -> per-input slots; insertion order is not stamp order, so use min().
        self._pending: dict[int, list[Any]] = {}

    @property
    def queued(self) -> int:
        """Number of messages currently held waiting for their set to complete."""
        return sum(sum(m is not None for m in slots) for slots in self._pending.values())

    @property
    def queued_frames(self) -> int:
        """Number of frames (stamps) currently waiting for their set to complete."""
        return len(self._pending)

    def _store(self, index: int, stamp: int, msg: Any) -> None:
        """Hold ``msg``; call the callback once if its set is complete."""
        slots = self._pending.setdefault(stamp, [None] * self.n_inputs)
        slots[index] = msg
        if len(self._pending) > self.queue_size:
            oldest = min(self._pending)  # may be the newcomer's own stamp
            self._drop('queue_full', sum(m is not None for m in self._pending.pop(oldest)))
            self._lose('queue_full')
            if oldest == stamp:
                return
        if any(m is None for m in slots):
            return
        del self._pending[stamp]
        for older in [s for s in self._pending if s < stamp]:
            self._drop('unmatched', sum(m is not None for m in self._pending.pop(older)))
            self._lose('unmatched')
        self.emitted += 1
        self.callback(*slots)

    def held(self) -> list[tuple[int, int, Any]]:
        """Every message held: ``(input index, stamp ns, message)``."""
        return [(i, stamp, m) for stamp, slots in self._pending.items()
                for i, m in enumerate(slots) if m is not None]

    def reset(self) -> None:
        """Forget all pending messages (uncounted), counters and per-input stamp history."""
        self._pending.clear()
        self._reset_counters()


class ApproximateTimeSynchronizer(_SyncBase):
    """Emit sets of messages with nearly equal stamps (the ROS ApproximateTime policy).

    Implements the ``message_filters`` ApproximateTime algorithm (written independently
    from its description): each set holds exactly one message per input, every message is
    used at most once, sets come out in time order (each input's stamps strictly increase
    from one set to the next), and a set is emitted as soon as it is provably the one with
    the smallest interval (latest stamp - earliest stamp) among all sets that could still be
    formed with it or with messages that have not arrived yet.

    How: the earliest queue head is repeatedly moved aside, which sweeps through all
    candidate sets in time order. The first admissible set fixes a *pivot* (the input
    holding its latest message); better candidates replace it while the sweep goes on. The
    candidate is published when the pivot message itself is swept past, or when the latest
    head is already so far after the pivot's stamp that any remaining set would be worse.
    When a queue runs empty, its next message is assumed to come no earlier than
    ``inter_message_lower_bound`` after its last one, which can prove optimality earlier
    (a virtual sweep that is undone if it proves nothing). Correctness assumes stamps on
    each input arrive in increasing order; messages that do not are dropped
    (``'out_of_order'`` / ``'duplicate'``).

    Differences from ``message_filters``: ``age_penalty`` defaults to 0 (upstream uses 0.1),
    so "better" means strictly smaller interval; stamps that go backwards on an input are
    dropped instead of only warned about; ``max_interval`` is in seconds. As upstream, when
    a queue overflows the candidate search restarts, and a set is not started with a
    just-overflowed input as its latest member (the dropped message might have matched
    better); the earliest head is then dropped as ``'unmatched'``.

    Args:
        n_inputs: Number of inputs (>= 2).
        callback: Called as ``callback(msg_0, ..., msg_{n-1})`` for each set.
        queue_size: Maximum messages held per input (>= 1); the oldest is dropped.
        max_interval: Largest allowed interval of a set in seconds; ``None`` for no limit.
        age_penalty: A new candidate must beat the current one by this relative margin
            (``(end - cand_end) * (1 + age_penalty) < start - cand_start``); >= 0.
        inter_message_lower_bound: Smallest possible stamp gap between consecutive
            messages of an input in seconds, one value for all inputs or one per input
            (>= 0). It lets sets out earlier; a bound larger than the real gap can emit a
            set that is not the best. 0 (the default) assumes nothing.

    Raises:
        SyncError: On an invalid argument.
    """

    def __init__(
        self,
        n_inputs: int,
        callback: Callable[..., None],
        *,
        queue_size: int = 10,
        max_interval: float | None = None,
        age_penalty: float = 0.0,
        inter_message_lower_bound: float | Sequence[float] = 0.0,
    ) -> None:
        super().__init__(n_inputs, callback, queue_size)
        self._max_ns = -1 if max_interval is None else _seconds_to_ns('max_interval', max_interval)
        if (
            isinstance(age_penalty, bool)
            or not isinstance(age_penalty, (int, float))
            or not math.isfinite(age_penalty)
            or age_penalty < 0
        ):
            raise SyncError(f'age_penalty must be a finite number >= 0, got {age_penalty!r}')
        self._age_factor = 1.0 + float(age_penalty)
        if isinstance(inter_message_lower_bound, (int, float)):
            bounds: Sequence[float] = [inter_message_lower_bound] * n_inputs
        else:
            bounds = list(inter_message_lower_bound)
        if len(bounds) != n_inputs:
            raise SyncError(
                f'inter_message_lower_bound must have n_inputs={n_inputs} values, got {len(bounds)}'
            )
        self._lower_ns = [_seconds_to_ns('inter_message_lower_bound', b) for b in bounds]
        if -1 in self._lower_ns:
            raise SyncError(f'inter_message_lower_bound must be finite, got {list(bounds)!r}')
        self._init_state()

    def _init_state(self) -> None:
        n = self.n_inputs
        self._queues: list[deque[tuple[int, Any]]] = [deque() for _ in range(n)]
        self._past: list[list[tuple[int, Any]]] = [[] for _ in range(n)]
        self._candidate: list[Any] | None = None
        self._cand_start = 0
        self._cand_end = 0
        self._pivot = -1  # -1: no candidate
        self._pivot_time = 0
        self._overflowed = [False] * n

    @property
    def queued(self) -> int:
        """Number of messages currently held (including a not yet published candidate)."""
        return sum(len(q) + len(p) for q, p in zip(self._queues, self._past, strict=True))

    @property
    def queued_frames(self) -> int:
        """Number of frames (messages of input 0) currently held."""
        return len(self._queues[0]) + len(self._past[0])

    def _drop_from(self, index: int, reason: str, count: int = 1) -> None:
        """Count ``count`` messages of input ``index`` discarded (frames if index is 0)."""
        self._drop(reason, count)
        if index == 0:
            self._lose(reason, count)

    def _store(self, index: int, stamp: int, msg: Any) -> None:
        """Queue ``msg``; call the callback for every set that is now decided."""
        queue = self._queues[index]
        queue.append((stamp, msg))
        self._process()
        if len(queue) + len(self._past[index]) > self.queue_size:
            # Abandon the candidate search, then drop the oldest message of this input.
            self._recover_all()
            queue.popleft()
            self._drop_from(index, 'queue_full')
            self._overflowed[index] = True
            self._candidate = None
            self._pivot = -1
            self._process()

    def held(self) -> list[tuple[int, int, Any]]:
        """Every message held (a candidate's too): ``(input index, stamp ns, message)``."""
        return [(i, stamp, m) for i, (q, p) in enumerate(zip(self._queues, self._past,
                                                              strict=True))
                for stamp, m in [*p, *q]]

    def reset(self) -> None:
        """Forget all held messages (uncounted), counters and per-input stamp history."""
        self._init_state()
        self._reset_counters()

    # -- the policy ---------------------------------------------------------------------

    def _later(self, end: int, start: int) -> bool:
        """True if a set spanning [start, end] is no better than the current candidate."""
        return (end - self._cand_end) * self._age_factor >= start - self._cand_start

    def _move_front_to_past(self, i: int) -> None:
        self._past[i].append(self._queues[i].popleft())

    def _recover_all(self) -> None:
        for q, past in zip(self._queues, self._past, strict=True):
            q.extendleft(reversed(past))
            past.clear()

    def _make_candidate(self, start: int, end: int) -> None:
        self._candidate = [q[0][1] for q in self._queues]
        self._cand_start = start
        self._cand_end = end
        # Messages swept past are older than the new candidate's: they can never be used.
        for i, past in enumerate(self._past):
            self._drop_from(i, 'unmatched', len(past))
            past.clear()

    def _publish(self) -> None:
        candidate = self._candidate
        assert candidate is not None
        self._candidate = None
        self._pivot = -1
        self._recover_all()
        for q in self._queues:
            q.popleft()  # after recovery the head of every queue is the candidate's message
        self.emitted += 1
        self.callback(*candidate)

    def _virtual_time(self, i: int) -> int:
        if self._queues[i]:
            return int(self._queues[i][0][0])
        # Empty queue: its next message comes no earlier than last + bound (and a message
        # before the pivot cannot matter any more).
        return max(self._past[i][-1][0] + self._lower_ns[i], self._pivot_time)

    def _process(self) -> None:
        while all(self._queues):
            heads = [q[0][0] for q in self._queues]
            start = min(heads)
            end = max(heads)
            start_i = heads.index(start)
            end_i = len(heads) - 1 - heads[::-1].index(end)
            for i in range(self.n_inputs):
                if i != end_i:
                    self._overflowed[i] = False
            if self._pivot < 0:
                if self._max_ns >= 0 and end - start > self._max_ns:
                    self._queues[start_i].popleft()
                    self._drop_from(start_i, 'interval_too_large')
                    continue
                if self._overflowed[end_i]:
                    self._queues[start_i].popleft()
                    self._drop_from(start_i, 'unmatched')
                    continue
                self._make_candidate(start, end)
                self._pivot = end_i
                self._pivot_time = end
            elif not self._later(end, start):
                self._make_candidate(start, end)
            self._move_front_to_past(start_i)

            if start_i == self._pivot or self._later(end, self._pivot_time):
                self._publish()
            elif not all(self._queues):
                self._virtual_search()

    def _virtual_search(self) -> None:
        """Sweep on with optimistic times for empty queues to try to prove optimality."""
        moved = [0] * self.n_inputs
        while True:
            times = [self._virtual_time(i) for i in range(self.n_inputs)]
            start = min(times)
            end = max(times)
            if self._later(end, self._pivot_time):
                self._publish()  # also undoes the virtual moves
                return
            if not self._later(end, start):
                # An optimistic future set could beat the candidate: wait for messages.
                for i, k in enumerate(moved):
                    for _ in range(k):
                        self._queues[i].appendleft(self._past[i].pop())
                return
            # start < pivot_time here, so the earliest input is not empty and not the pivot.
            start_i = times.index(start)
            self._move_front_to_past(start_i)
            moved[start_i] += 1
