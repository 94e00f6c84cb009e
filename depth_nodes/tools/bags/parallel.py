"""`process` on several workers: the bag cut into time segments, each run by a fresh copy of
the graph in another process (spawned, or a Ray actor), the results stitched back into the
output the one-worker run writes, byte for byte.

A graph holds state from one message to the next: synchronisers wait for partners, the
structured-light node gathers a sequence, camera_info caches hold the last calibration. A
copy of the graph that starts in the middle of the bag starts without that state, so its
first outputs may differ. Two things make the stitched result exact:

* **Hand-over at a common idle point.** Every worker records after which messages its graph
  held nothing (no message waiting in a synchroniser or a sequence: ``holds_input``) once
  every dense input has delivered a message since it started. The worker of segment k runs
  on past its end until it has seen :data:`HANDOVER_POINTS` idle points in the next segment.
  The output takes segment k's results up to the first message after which both workers'
  graphs were idle, and the next worker's from there on: from a point where both hold
  nothing and have seen the same latest message on every input, they compute the same thing.
* **Primed sparse inputs.** A topic with at most :data:`SPARSE_MESSAGES` messages in the
  whole bag (a camera_info recorded once, latched) is fed to a worker first with its last
  message before the segment, as the one-worker run would hold it.

When no common idle point exists (a graph that never empties, e.g. a sequence longer than
the hand-over), the run stops with an error that says to use one worker rather than write
something else than one worker would. The main process checks every message the workers
report against its own reading of the bag, so a different message order cannot go unnoticed.

Workers are spawned, never forked: numba's thread-safe layer (OpenMP here) is not fork-safe.
"""

from __future__ import annotations

import logging
import mmap
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from depth_nodes.errors import BagError, DepthNodesError

#: Idle points a worker records past its segment's end, for the hand-over.
HANDOVER_POINTS = 2
#: A topic with at most this many messages in the bag is primed (see the module notes).
SPARSE_MESSAGES = 4
#: Segments per worker: enough that workers finish together, few enough that the
#: hand-over (about two frames per segment) and each segment's start cost little.
SEGMENTS_PER_WORKER = 4
#: Causes of the outputs and drops that come after the last message (``finish_stream``).
END = -1


@dataclass(frozen=True)
class Segment:
    """The messages with timestamps in ``[start_ns, stop_ns)``; ``stop_ns`` None: to the end."""

    index: int
    start_ns: int | None
    stop_ns: int | None

    @property
    def last(self) -> bool:
        return self.stop_ns is None


@dataclass(frozen=True)
class SegmentJob:
    """What a worker needs: the bag, the graph with its parameters, the segment."""

    in_bag: str
    config: Any  # GraphConfig
    params: dict[str, dict[str, Any]]
    segment: Segment
    #: Consumed topics to prime, and the dense ones that must have delivered a message
    #: before an idle point counts.
    sparse: tuple[str, ...]
    dense: tuple[str, ...]
    #: Folder for the outputs' bytes (workers on this machine); None: in the result.
    spill_dir: str | None = None


@dataclass
class SegmentResult:
    """A worker's outputs, drops and idle points, by the local index of the message (from
    the segment's start) that caused them."""

    index: int
    #: (topic, timestamp) of each message handled, in order.
    seen: list[tuple[str, int]] = field(default_factory=list)
    #: Local index of the first message past the segment's end (``len(seen)`` if none).
    own_end: int = 0
    idle: set[int] = field(default_factory=set)
    #: (topic, msgtype, CDR bytes, or their (offset, length) in ``spill``).
    outputs: dict[int, list[tuple[str, str, bytes | tuple[int, int]]]] = field(
        default_factory=dict)
    drops: dict[int, list[tuple[str, str, int]]] = field(default_factory=dict)
    #: The file holding the outputs' bytes, when the job gave a folder.
    spill: str | None = None


def segments(start_ns: int, end_ns: int, count: int) -> list[Segment]:
    """``count`` segments of equal duration covering ``[start_ns, end_ns]``.

    (Measured on the 200-frame VGA bag with two workers: a short first and last segment,
    or a big first one, were slower; so was nothing gained by running the workers nicer
    than the main process.)
    """
    span = end_ns - start_ns + 1
    count = max(1, min(count, span))
    cuts = [start_ns + span * k // count for k in range(1, count)]
    bounds: list[int | None] = [None, *cuts, None]
    return [Segment(k, bounds[k], bounds[k + 1]) for k in range(count)]


def run_segment(job: SegmentJob) -> SegmentResult:
    """Run the graph over one segment (in a worker process or actor)."""
    _worker_environment()
    import rclpy
    from rclpy.context import Context
    from rclpy.impl.logging_severity import LoggingSeverity

    from depth_nodes.graph.description import create_nodes
    from depth_nodes.tools.bags.io import BagReader, message_type_name, serialize
    from depth_nodes.tools.bags.process import routes_of

    result = SegmentResult(job.segment.index)
    segment = job.segment
    spill = None
    if job.spill_dir is not None:  # bytes through a file: no pickling of the clouds
        result.spill = spill_path(job)
        # a file an earlier segment used is written over, not truncated (claim_spill);
        # closed in the finally below
        mode = 'r+b' if os.path.exists(result.spill) else 'wb'
        spill = open(result.spill, mode)  # noqa: SIM115
    context = Context()
    rclpy.init(args=[], context=context)
    nodes: list[Any] = []
    try:
        with BagReader(job.in_bag) as reader:
            nodes = create_nodes(job.config, job.params, context=context)
            for node in nodes:  # warnings about the discarded start would mislead: the
                # report's drop table counts what the stitched output lost
                node.get_logger().set_level(LoggingSeverity.ERROR)
            routes, produced = routes_of(nodes)
            cause = [END]
            keep = [False]
            failed: list[BagError] = []

            def sink(topic: str, msg: Any) -> None:
                # a node's publish calls this: a spill write that fails (a full disk) ends
                # the segment below, instead of being taken by the node for its own failure
                if failed:
                    return
                if keep[0]:
                    msgtype = message_type_name(msg)
                    data: bytes | tuple[int, int] = serialize(msg, msgtype)
                    if spill is not None:
                        try:
                            data = (spill.tell(), spill.write(data))
                        except OSError as exc:
                            failed.append(BagError(
                                f"cannot write a worker's outputs to {job.spill_dir}: "
                                f'{exc.strerror or exc}'))
                            return
                    result.outputs.setdefault(cause[0], []).append((topic, msgtype, data))
                for spec_in in routes.get(topic, ()):
                    spec_in.callback(msg)

            for node in nodes:
                node.sink = sink

            def feed(bag_msg: Any) -> None:
                subscribers = routes.get(bag_msg.topic)
                if subscribers and bag_msg.topic not in produced:
                    msg = bag_msg.deserialize()
                    for spec_in in subscribers:
                        spec_in.callback(msg)

            if segment.start_ns is not None:  # what a one-worker run would hold already
                for topic in job.sparse:
                    latest = None
                    for bag_msg in reader.messages([topic], stop=segment.start_ns):
                        latest = bag_msg
                    if latest is not None:
                        feed(latest)
            before = _drop_counts(nodes)
            keep[0] = True
            waiting = set(job.dense)
            handover = 0
            result.own_end = -1
            for local, bag_msg in enumerate(reader.messages(start=segment.start_ns)):
                past = segment.stop_ns is not None and bag_msg.timestamp >= segment.stop_ns
                if past and result.own_end < 0:
                    result.own_end = local
                result.seen.append((bag_msg.topic, bag_msg.timestamp))
                cause[0] = local
                feed(bag_msg)
                if failed:
                    raise failed[0]
                waiting.discard(bag_msg.topic)
                after = _drop_counts(nodes)
                delta = [(n, r, c - before.get((n, r), 0)) for (n, r), c in after.items()
                         if c != before.get((n, r), 0)]
                if delta:
                    result.drops[local] = delta
                before = after
                if not waiting and not any(node.holds_input() for node in nodes):
                    result.idle.add(local)
                    if past:
                        handover += 1
                        if handover >= HANDOVER_POINTS:
                            break
            else:  # the end of the bag (the last segment, or a hand-over that ran
                # into it): what the graph still holds can never complete
                cause[0] = END
                for node in nodes:
                    node.finish_stream()
                if failed:
                    raise failed[0]
                after = _drop_counts(nodes)
                result.drops[END] = [(n, r, c - before.get((n, r), 0))
                                     for (n, r), c in after.items()
                                     if c != before.get((n, r), 0)]
            if result.own_end < 0:
                result.own_end = len(result.seen)
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.shutdown(context=context)
        if spill is not None:
            spill.close()
    return result


def _worker_environment() -> None:
    """A worker routes its messages in-process: its participant discovers no other one and
    has no shared-memory transport, whatever the caller's environment says.

    * Discovery: with the caller's LOCALHOST (as in the tests) the workers' participants
      found each other, and one worker once hung for good at its end: Fast DDS's
      set_listener spinning while a discovery thread (a participant that went away) waited
      on the lock it held.
    * Shared memory: a participant's 64 MiB segment, a file in /dev/shm, is removed only
      when it exits cleanly; each worker killed when a run was stopped (SIGINT, SIGTERM) or
      failed left 70 MB behind, for good. The package's own large-message profile is
      dropped for the worker (a profile of the user's is kept) and the builtin transports
      are UDP only (with discovery off, localhost mode would add shared memory back).

    Set before the worker's first participant.
    """
    from depth_nodes.ros.dds import PROFILE, PROFILE_VARIABLES

    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    os.environ.pop('ROS_STATIC_PEERS', None)
    for name in PROFILE_VARIABLES:
        if os.environ.get(name) == str(PROFILE):
            del os.environ[name]
    os.environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'


def _drop_counts(nodes: list[Any]) -> dict[tuple[str, str], int]:
    return {(node.get_fully_qualified_name(), reason): count
            for node in nodes for reason, count in node.drops.items()}


@dataclass
class Stitched:
    """One message of the output, in order: the input message at ``index`` (global), then
    what the graph published because of it."""

    index: int
    #: (topic, timestamp) the worker read there.
    seen: tuple[str, int] | None
    outputs: list[tuple[str, str, bytes]]
    drops: list[tuple[str, str, int]]


def stitch(results: Iterator[SegmentResult]) -> Iterator[Stitched]:
    """The segments' results as one stream, in the order of the bag (see the module notes).

    A segment whose worker never reached a point where the previous worker's graph was
    idle (a sequence longer than the segment) is dropped: the previous worker, which runs on
    until its graph empties, covered it.

    Raises:
        BagError: Two consecutive segments have no common idle point.
    """
    current = next(results, None)
    if current is None:
        return
    offset = 0  # global index of current's local 0
    begin = 0  # current's first local index to use
    start = current.own_end  # global index of the next result's local 0
    for following in results:
        common = sorted(g for g in (i + offset for i in current.idle)
                        if g >= start and g - start in following.idle)
        if not common:
            covered = offset + len(current.seen)
            if covered >= start + len(following.seen):  # current outlived it: skip it
                _discard(following)
                start += following.own_end
                continue
            _discard(following)
            raise BagError(
                'cannot split this bag between workers: the graph never empties near '
                f'message {start} (a sequence or queue spans the cut); use --workers 1')
        yield from _emit(current, offset, begin, common[0] + 1 - offset)
        begin = common[0] + 1 - start
        offset, current = start, following
        start = offset + current.own_end
    yield from _emit(current, offset, begin, len(current.seen), final=True)


def spill_path(job: SegmentJob) -> str:
    """The file a local worker writes the outputs' bytes of ``job`` to."""
    assert job.spill_dir is not None
    return os.path.join(job.spill_dir, f'segment-{job.segment.index}')


#: Name prefix of a spill file whose segment was written out, kept for the next segment.
_FREE = 'free-'


def claim_spill(job: SegmentJob) -> None:
    """Give ``job`` the spill file of a segment already written out, if one is free.

    Writing over a file's pages costs a tenth of writing new ones (500 MB: 0.1 s against
    1.56 s of system time on this machine's ext4, 0.32 s on tmpfs): with a new file per
    segment, two workers spent about 10 s more in the kernel than one worker on the
    200-frame VGA bag, mostly copying into fresh page-cache pages. The main process renames
    files, so nothing else touches them meanwhile.
    """
    if job.spill_dir is None:
        return
    free = sorted(f for f in os.listdir(job.spill_dir) if f.startswith(_FREE))
    if free:
        os.rename(os.path.join(job.spill_dir, free[0]), spill_path(job))


def _release(path: str | None) -> None:
    """Mark a segment's spill file free for the next segment (:func:`claim_spill`)."""
    if path and os.path.exists(path):
        head, tail = os.path.split(path)
        os.rename(path, os.path.join(head, _FREE + tail))


def _discard(result: SegmentResult) -> None:
    _release(result.spill)


def _emit(result: SegmentResult, offset: int, begin: int, end: int, *,
          final: bool = False) -> Iterator[Stitched]:
    """Messages ``[begin, end)`` of ``result`` (and its end-of-stream outputs if
    ``final``), the outputs' bytes read back from its spill file, which is freed after."""
    spill = open(result.spill, 'rb') if result.spill else None  # noqa: SIM115
    view = mmap.mmap(spill.fileno(), 0, access=mmap.ACCESS_READ) if spill and \
        os.fstat(spill.fileno()).st_size else None

    def resolved(outputs: list[tuple[str, str, bytes | tuple[int, int]]]
                 ) -> list[tuple[str, str, bytes]]:
        out = []
        for topic, msgtype, data in outputs:
            if isinstance(data, tuple):
                assert view is not None
                data = view[data[0]:data[0] + data[1]]
            out.append((topic, msgtype, data))
        return out

    try:
        for local in range(begin, end):
            yield Stitched(offset + local, result.seen[local],
                           resolved(result.outputs.get(local, [])), result.drops.get(local, []))
        if final and (END in result.outputs or END in result.drops):
            yield Stitched(END, None, resolved(result.outputs.get(END, [])),
                           result.drops.get(END, []))
    finally:
        if view is not None:
            view.close()
        if spill is not None:
            spill.close()
            _release(spill.name)


class Engine:
    """Runs segment jobs on workers; results come back in the order of the jobs."""

    workers = 1
    #: Workers may run on other machines (outputs come back in the results, not files).
    remote = False

    def map(self, jobs: list[SegmentJob], stop: Callable[[], bool]) -> Iterator[SegmentResult]:
        raise NotImplementedError

    def close(self) -> None:
        """Stop the workers."""


#: glibc's mallopt parameters, and the values a worker sets (see :func:`_keep_heap`).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_HEAP_KEEP = 1 << 30
_MMAP_FROM = 256 << 20


def _keep_heap() -> None:
    """Let the worker reuse its heap for the frames' large buffers instead of mapping and
    unmapping them: glibc maps blocks of a few MB and returns the memory at once, and the
    page faults of the next frame's buffers cost a worker a tenth of its time here (see
    docs/speed.md, "Offline processing"). No-op off glibc."""
    import ctypes

    try:
        libc = ctypes.CDLL(None)
        libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_FROM)
        libc.mallopt(_M_TRIM_THRESHOLD, _HEAP_KEEP)
    except (OSError, AttributeError):
        pass


def _init_worker(threads: int) -> None:
    """A spawned worker: its share of the cores, a heap kept for reuse, and signals left
    to the main process, which stops the workers itself. SIGTERM too: sent to the whole
    process group (`timeout`, `kill -- -PGID`, a service manager stopping its unit), it
    killed the workers under the main process, which then failed with a traceback instead
    of closing the output with what was done."""
    import signal

    os.environ['NUMBA_NUM_THREADS'] = str(threads)
    _keep_heap()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


class LocalEngine(Engine):
    """Spawned worker processes on this machine (they keep the compiled kernels loaded
    from one segment to the next)."""

    def __init__(self, workers: int) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        cores = os.cpu_count() or 1
        self.workers = workers
        self._futures: list[Any] = []
        self._pool = ProcessPoolExecutor(
            workers, mp_context=multiprocessing.get_context('spawn'),
            initializer=_init_worker, initargs=(max(1, cores // workers),))

    def map(self, jobs: list[SegmentJob], stop: Callable[[], bool]) -> Iterator[SegmentResult]:
        from concurrent.futures import Future
        from concurrent.futures.process import BrokenProcessPool

        pending: list[Future[SegmentResult]] = []
        queue = list(jobs)
        while queue or pending:
            try:
                while queue and len(pending) < self.workers + 1 and not stop():
                    claim_spill(queue[0])
                    pending.append(self._pool.submit(run_segment, queue.pop(0)))
                    self._futures.append(pending[-1])
                if not pending:
                    return
                future = pending.pop(0)
                while True:
                    try:
                        result = future.result(timeout=0.2)
                        break
                    except TimeoutError:
                        if stop():
                            return
            except BrokenProcessPool:
                if stop():  # stopped while a worker went away: the run ends as asked
                    return
                raise BagError('a worker process ended abruptly (killed, or out of '
                               'memory?); try fewer --workers') from None
            yield result

    def close(self) -> None:
        """Stop the workers: at once if a segment is still running (an interrupted run),
        else after they exited cleanly."""
        processes = list((getattr(self._pool, '_processes', None) or {}).values())
        if any(not future.done() for future in self._futures):
            for process in processes:  # a segment in progress is abandoned
                if process.is_alive():
                    process.kill()  # (workers ignore SIGTERM: _init_worker)
        self._pool.shutdown(wait=True, cancel_futures=True)


class RayEngine(Engine):
    """Ray actors, one per worker, each holding a warm interpreter: a local cluster
    started here, or an existing one at ``address``. Every machine of a cluster needs this
    package installed and the bag at the same path."""

    def __init__(self, workers: int, address: str | None) -> None:
        try:
            import ray
        except ImportError:
            raise DepthNodesError('--ray needs the ray package: pip install ray (or the '
                                  "package's cluster extra)") from None
        self._ray = ray
        self.workers = workers
        self.remote = address is not None
        if address is not None:
            _check_reachable(address)
        logging.getLogger('ray').setLevel(logging.ERROR)  # its start-up notices
        try:
            if address is None:
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                         configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
        except Exception as exc:  # unreachable address, version mismatch, ...
            raise DepthNodesError(f'cannot start or reach the Ray cluster'
                                  f'{" at " + address if address else ""}: '
                                  f'{" ".join(str(exc).split())}') from None
        cores = os.cpu_count() or 1
        env = {'NUMBA_NUM_THREADS': str(max(1, cores // workers)),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'}
        actor = ray.remote(num_cpus=1)(_SegmentActor)
        self._actors: list[Any] = [actor.options(runtime_env={'env_vars': env}).remote()
                                   for _ in range(workers)]

    def map(self, jobs: list[SegmentJob], stop: Callable[[], bool]) -> Iterator[SegmentResult]:
        ray = self._ray
        free = list(self._actors)
        busy: dict[Any, Any] = {}  # result ref -> its actor, while it runs
        pending: list[Any] = []  # result refs in the order of the jobs
        queue = list(jobs)
        while queue or pending:
            # results wait in the object store: at most two per worker ahead of the output
            while queue and free and len(pending) < 2 * self.workers and not stop():
                actor = free.pop(0)
                claim_spill(queue[0])
                ref = actor.run.remote(queue.pop(0))
                busy[ref] = actor
                pending.append(ref)
            if not pending:
                return
            ready, _ = ray.wait(list(busy), num_returns=1, timeout=0.2) if busy else ([], [])
            for ref in ready:
                free.append(busy.pop(ref))
            if pending[0] in busy:
                if stop():
                    return
                continue
            try:
                result = ray.get(pending.pop(0))
            except ray.exceptions.RayTaskError as exc:
                raise exc.as_instanceof_cause() from None
            yield result

    def close(self) -> None:
        self._ray.shutdown()


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail in a few seconds, in one line, when nothing listens at a Ray cluster's
    ``host:port`` (Ray itself retries for minutes); ``auto`` and addresses without a port
    are left to Ray.

    Raises:
        DepthNodesError: The address is not reachable.
    """
    import socket

    hostport = address.split('://', 1)[-1].rstrip('/')
    host, sep, port = hostport.rpartition(':')
    if not sep or not port.isdigit():
        return
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as exc:
        raise DepthNodesError(f'--ray-address {address}: nothing answers there '
                              f'({exc.strerror or exc}); start the cluster with `ray start '
                              '--head` or give its address') from None


class _SegmentActor:
    """A Ray actor around :func:`run_segment`."""

    def __init__(self) -> None:
        _keep_heap()

    def run(self, job: SegmentJob) -> SegmentResult:
        return run_segment(job)
