"""Where the segments of `process` on several workers run: spawned processes on this
machine (:class:`LocalEngine`) or Ray actors (:class:`RayEngine`), on a local cluster or an
existing one. Results come back in the order of the jobs.

Workers are spawned, never forked: numba's thread-safe layer (OpenMP here) is not fork-safe.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import socket
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from depth_nodes.errors import BagError, DepthNodesError
from depth_nodes.tools.bags.segments import SegmentJob, SegmentResult, claim_spill, run_segment
from depth_nodes.tools.bags.worker_setup import init_worker, keep_heap


class Engine:
    """Runs segment jobs on workers; results come back in the order of the jobs."""

    workers = 1
    #: Workers may run on other machines (outputs come back in the results, not files).
    remote = False

    def map(self, jobs: list[SegmentJob], stop: Callable[[], bool]) -> Iterator[SegmentResult]:
        raise NotImplementedError

    def close(self) -> None:
        """Stop the workers."""


class LocalEngine(Engine):
    """Spawned worker processes on this machine (they keep the compiled kernels loaded
    from one segment to the next)."""

    def __init__(self, workers: int) -> None:
        cores = os.cpu_count() or 1
        self.workers = workers
        self._futures: list[Any] = []
        self._pool = ProcessPoolExecutor(
            workers, mp_context=multiprocessing.get_context('spawn'),
            initializer=init_worker, initargs=(max(1, cores // workers),))

    def map(self, jobs: list[SegmentJob], stop: Callable[[], bool]) -> Iterator[SegmentResult]:
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
                    process.kill()  # (workers ignore SIGTERM: init_worker)
        self._pool.shutdown(wait=True, cancel_futures=True)


class RayEngine(Engine):
    """Ray actors, one per worker, each holding a warm interpreter: a local cluster
    started here, or an existing one at ``address``. Every machine of a cluster needs this
    package installed and the bag at the same path."""

    def __init__(self, workers: int, address: str | None) -> None:
        try:  # an optional dependency (the cluster extra), imported when asked for
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
        keep_heap()

    def run(self, job: SegmentJob) -> SegmentResult:
        return run_segment(job)
