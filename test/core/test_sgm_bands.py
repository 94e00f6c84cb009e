"""The banded matcher: its task scheduler, band sizes, and the aggregated volume of the
memory-bounded mode against a reference built from the plain per-path references."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numba
import numpy as np
import pytest
from helpers import kernel_size
from reference.sgm import aggregate_path_reference, cost_volume_reference

from depth_nodes.core.sgm import SgmMatcher, SgmParams, bands, workspace
from depth_nodes.core.sgm.aggregate import VERTICAL_DIRECTIONS
from depth_nodes.core.sgm.bands import (
    CACHED_BAND_BYTES,
    CELL_BYTES,
    MIN_BAND_ROWS,
    Task,
    band_layout,
    band_rows,
    run_tasks,
    worker_cpus,
)


def _pair(h: int, w: int, shift: int = 4, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (h, w + shift)).astype(np.uint8)
    right = np.clip(wide[:, shift:].astype(int) + rng.integers(-3, 4, (h, w)), 0, 255)
    return np.ascontiguousarray(wide[:, :w]), right.astype(np.uint8)  # disparity: shift


@pytest.mark.parametrize('threads', [1, 2, 3])
def test_tasks_run_once_after_their_dependencies(threads: int) -> None:
    """A diamond-shaped graph of 40 tasks: each runs once, after every task it depends on,
    on a worker index below the thread count."""
    done: list[int] = []
    workers: set[int] = set()
    lock = threading.Lock()

    def task(i: int) -> Task:
        def run(worker: int) -> None:
            with lock:
                assert all(j in done for j in after[i]), (i, after[i], done)
                done.append(i)
                workers.add(worker)
        return Task(run, after[i], priority=i % 3)

    after = [[j for j in (i - 1, i - 7, i // 2) if 0 <= j < i] for i in range(40)]
    run_tasks([task(i) for i in range(40)], threads)
    assert sorted(done) == list(range(40))
    assert workers <= set(range(threads))


def _affinities_seen(threads: int, allowed: set[int]) -> tuple[dict[int, set[int]], set[int]]:
    """Run 12 tasks on ``threads`` workers from a thread allowed ``allowed``: the CPU set
    each worker ran its tasks with, and the caller's set afterwards."""
    seen: dict[int, set[int]] = {}
    after: list[set[int]] = []
    lock = threading.Lock()

    def run(worker: int) -> None:
        with lock:
            seen.setdefault(worker, set()).update(os.sched_getaffinity(0))
        time.sleep(0.002)  # long enough for the other worker to take tasks too

    def caller() -> None:
        os.sched_setaffinity(0, allowed)  # this thread only
        run_tasks([Task(run) for _ in range(12)], threads)
        after.append(os.sched_getaffinity(0))

    thread = threading.Thread(target=caller)
    thread.start()
    thread.join()
    return seen, after[0]


def test_workers_are_pinned_one_per_cpu_when_they_are_as_many() -> None:
    """With as many workers as allowed CPUs, each worker runs on a CPU of its own (a core
    taken by another process then slows one worker, never both), and the caller gets its
    own set back. With one thread, or fewer workers than CPUs (left to the scheduler, so
    that two matchers do not crowd onto the same CPUs), nothing is pinned."""
    assert worker_cpus(2, {3, 5}) == [3, 5]
    assert worker_cpus(4, {0, 1, 2, 3}) == [0, 1, 2, 3]
    assert worker_cpus(2, {0, 1, 2, 3}) == []  # fewer workers than CPUs
    assert worker_cpus(3, {0, 1}) == []  # more workers than CPUs
    assert worker_cpus(1, {0}) == []
    allowed = sorted(os.sched_getaffinity(0))
    seen, after = _affinities_seen(1, set(allowed))
    assert seen == {0: set(allowed)}
    assert after == set(allowed)
    seen, after = _affinities_seen(2, {allowed[0]})
    assert all(cpus == {allowed[0]} for cpus in seen.values())  # within the user's set
    assert after == {allowed[0]}
    if len(allowed) >= 2:  # on a one-CPU machine there is nothing to pin to
        two = set(allowed[:2])
        seen, after = _affinities_seen(2, two)
        assert seen  # whichever workers took tasks, each on its own CPU
        assert all(cpus == {allowed[worker]} for worker, cpus in seen.items()), seen
        assert after == two


def test_a_refused_affinity_pins_nothing_and_fails_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the system refuses ``sched_setaffinity`` (a sandbox), every task still runs
    once: pinning is an optimisation."""
    calls: list[set[int]] = []

    def refuse(pid: int, cpus: set[int]) -> None:
        calls.append(set(cpus))
        raise PermissionError(1, 'Operation not permitted')

    monkeypatch.setattr(bands.os, 'sched_getaffinity', lambda pid: {0, 1})
    monkeypatch.setattr(bands.os, 'sched_setaffinity', refuse)
    done: list[int] = []
    run_tasks([Task(lambda worker, i=i: done.append(i)) for i in range(8)], 2)
    assert sorted(done) == list(range(8))
    assert calls  # it tried


def test_the_first_error_is_raised_and_stops_the_rest() -> None:
    ran: list[int] = []

    def ok(i: int) -> Task:
        return Task(lambda worker: ran.append(i), [i - 1])

    def fail(worker: int) -> None:
        raise KeyError('band 3')

    tasks = [Task(lambda worker: ran.append(0)), ok(1), ok(2), Task(fail, [2]), ok(4), ok(5)]
    with pytest.raises(KeyError, match='band 3'):
        run_tasks(tasks, 2)
    assert ran == [0, 1, 2]  # nothing after the failed task ran


def test_a_dependency_on_a_later_task_is_refused() -> None:
    with pytest.raises(ValueError, match='dependencies must come first'):
        run_tasks([Task(lambda worker: None, [1]), Task(lambda worker: None)], 1)


def test_bands_cover_the_image_once() -> None:
    bands = band_layout(100, 16, 24)
    assert [b.y0 for b in bands] == list(range(0, 100, 16))
    assert sum(b.rows for b in bands) == 100
    assert [b.reach for b in bands[-3:]] == [100 - 64, 100 - 80, 100 - 96]  # to the bottom
    assert bands[0].reach == 16 + 24


def test_band_height_keeps_memory_constant_across_disparity_ranges() -> None:
    """HD frames: rows x disparities (the volume of a band) within 10% for 128 and 256,
    and the bands in flight within the budget."""
    sizes = {n: band_rows(1080, 1920, n, memory_mb=400, slots=3, overlap=64)
             for n in (128, 256)}
    volume = {n: rows * n for n, rows in sizes.items()}
    assert abs(volume[256] / volume[128] - 1) < 0.1
    for n, rows in sizes.items():
        in_flight = 3 * ((rows + 64) * 1920 * n + 2 * rows * 1920 * n)
        assert in_flight <= 400e6
    assert band_rows(480, 640, 128, memory_mb=160, slots=3, overlap=64) == 60  # H / 8


def _bounded_reference(cost: np.ndarray, image: np.ndarray, paths: int, p1: int, p2: int,
                       scale: float, rows: int, overlap: int) -> np.ndarray:
    """The memory-bounded matcher's total: the downward and horizontal paths over the
    whole image, the upward ones of each band started ``overlap`` rows below it."""
    h = cost.shape[0]
    down = VERTICAL_DIRECTIONS[paths]
    whole = [(1, 0), (-1, 0), *down]
    total = sum(aggregate_path_reference(cost, image, dx, dy, p1, p2, scale)
                for dx, dy in whole)
    for band in band_layout(h, rows, overlap):
        part = slice(band.y0, band.y0 + band.reach)
        up = sum(aggregate_path_reference(cost[part], image[part], -dx, -dy, p1, p2, scale)
                 for dx, dy in down)
        total[band.y0:band.y0 + band.rows] += up[:band.rows]
    return total  # type: ignore[no-any-return]


@pytest.mark.kernels
@pytest.mark.parametrize(('paths', 'scale', 'overlap'), [(8, 0.0, 3), (8, 12.0, 5),
                                                         (16, 7.5, 4), (4, 0.0, 0),
                                                         (8, 12.0, 19), (16, 0.0, 11)])
def test_bounded_bands_match_their_reference(paths: int, scale: float, overlap: int) -> None:
    """With a budget too small for whole volumes, 6-row bands whose upward paths start
    ``overlap`` rows below them: the total equals the reference of exactly that (overlaps
    of 11 and 19 rows pass below the band in pieces of OVERLAP_CHUNK = 8 rows)."""
    h, w = 29, kernel_size(31, 15)
    left, right = _pair(h, w)
    params = SgmParams(disparity_range=7, census_width=5, census_height=5, P1=5, P2=60,
                       p2_adaptive_scale=scale, paths=paths, border_cost=0.0, band_rows=6,
                       band_overlap=overlap, memory_mb=0.0)
    matcher = SgmMatcher(params)
    assert not matcher.whole_volumes(h, w)
    matcher.match(left, right, keep_total=True)
    cost = cost_volume_reference(left, right, min_disparity=0, disparity_range=7,
                                 census_window=(5, 5), intensity_weight=1,
                                 match_brightness=True)
    want = _bounded_reference(cost, left.astype(np.float32), paths, 5, 60, scale, 6, overlap)
    np.testing.assert_array_equal(matcher.total.astype(np.int64), want)


@pytest.mark.parametrize('border_cost', [0.0, 3.5])
@pytest.mark.parametrize(('paths', 'memory_mb'), [(8, 160.0), (8, 0.0), (5, 0.0)])
def test_every_thread_count_gives_the_same_result(paths: int, memory_mb: float,
                                                  border_cost: float) -> None:
    """Whole volumes (two chains meeting) and bounded bands, on one and on two threads:
    bit-identical outputs, and 5 paths in bands equal one band (single pass: exact). With
    a border cost, one thread takes its statistic from the stored volume, two from rows
    computed for it: the same value."""
    left, right = _pair(70, 90, seed=5)
    params = SgmParams(disparity_range=16, paths=paths, band_rows=9, memory_mb=memory_mb,
                       band_overlap=12, border_cost=border_cost)
    outputs = []
    border_costs = []
    before = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):  # type: ignore[attr-defined]
            numba.set_num_threads(threads)
            matcher = SgmMatcher(params)
            result = matcher.match(left, right)
            outputs.append([a.copy() for a in (result.disparity, result.disparity_right,
                                                result.cost_ratio)])
            border_costs.append(matcher.border_cost)
    finally:
        numba.set_num_threads(before)
    for got, want in zip(outputs[0], outputs[1], strict=True):
        np.testing.assert_array_equal(got, want)
    assert border_costs[0] == border_costs[1]
    assert (border_costs[0] > 0) == (border_cost > 0)
    if paths == 5:
        one = SgmMatcher(SgmParams(disparity_range=16, paths=5, band_rows=70,
                                   border_cost=border_cost)).match(left, right)
        np.testing.assert_array_equal(one.disparity, outputs[0][0])
    valid = outputs[0][0][np.isfinite(outputs[0][0])]
    assert valid.size > 0.5 * left.size
    assert np.median(valid) == 4


@pytest.mark.slow  # 28 s: VGA frames at two thread counts
@pytest.mark.parametrize('search', ['full', 'coarse'])
@pytest.mark.parametrize(('paths', 'memory_mb'), [(8, 160.0), (8, 0.0), (5, 0.0)])
def test_another_thread_count_reuses_the_volumes(paths: int, memory_mb: float,
                                                 search: str) -> None:
    """One matcher called on one, two, then one thread again (as ``bench sgm --busy``
    does): the frame's volumes are allocated once, only the second worker's scratch is
    added, and every call's output is a fresh matcher's bit for bit."""
    left, right = _pair(70, 90, seed=5)
    params = SgmParams(disparity_range=16, paths=paths, band_rows=9, memory_mb=memory_mb,
                       band_overlap=12, border_cost=3.5, disparity_search=search)
    two = min(2, numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    before = numba.get_num_threads()
    matcher = SgmMatcher(params)
    try:
        for threads in (1, two, 1, two):
            numba.set_num_threads(threads)
            got = matcher.match(left, right)
            got_arrays = [a.copy() for a in (got.disparity, got.disparity_right,
                                             got.cost_ratio)]
            want = SgmMatcher(params).match(left, right)
            for g, w in zip(got_arrays, (want.disparity, want.disparity_right,
                                         want.cost_ratio), strict=True):
                np.testing.assert_array_equal(g, w)
    finally:
        numba.set_num_threads(before)
    ranged = search == 'coarse' and matcher.fallbacks == 0  # else the windows did not fit
    assert ranged == (search == 'coarse' and memory_mb > 0)
    assert matcher.allocations == (2 if ranged else 1)  # coarse: + its flat volume
    volumes = matcher.workspaces.ranged if ranged else matcher.workspaces.full
    assert volumes is not None
    assert len(volumes.workers) == two


def test_single_pass_bands_are_cache_sized_and_change_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """5 paths cut the image into bands of at most CACHED_BAND_BYTES (never below
    MIN_BAND_ROWS rows), and the output is the one-band output bit for bit; 8 paths keep
    their bands."""
    assert SgmMatcher(SgmParams(disparity_range=128, paths=5)).bands(480, 640)[0].rows == (
        int(CACHED_BAND_BYTES // (640 * 128 * CELL_BYTES)))
    assert SgmMatcher(SgmParams(disparity_range=256, paths=5)).bands(1080, 1920)[0].rows == (
        MIN_BAND_ROWS)
    left, right = _pair(200, 90, seed=7)
    assert SgmMatcher(SgmParams(disparity_range=16, paths=5)).bands(200, 90)[0].rows == 25
    monkeypatch.setattr(workspace, 'CACHED_BAND_BYTES', 90 * 16 * CELL_BYTES * 20)
    banded = SgmMatcher(SgmParams(disparity_range=16, paths=5))
    assert [b.rows for b in banded.bands(200, 90)] == [20] * 10
    got = banded.match(left, right)
    one = SgmMatcher(SgmParams(disparity_range=16, paths=5, band_rows=200)).match(left, right)
    for a, b in zip((got.disparity, got.disparity_right, got.cost_ratio),
                    (one.disparity, one.disparity_right, one.cost_ratio), strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.isfinite(got.disparity).mean() > 0.5
    assert len(SgmMatcher(SgmParams(disparity_range=16, paths=8)).bands(200, 90)) == 8


@pytest.mark.parametrize(('given', 'expected'), [(None, 'PASSIVE'), ('ACTIVE', 'ACTIVE')])
def test_openmp_threads_sleep_between_regions_unless_the_user_says(
        given: str | None, expected: str) -> None:
    """Importing the package makes libgomp's idle threads sleep instead of spin (they took
    the cores other processes needed: docs/speed.md); a value already set is kept. It must
    hold when libgomp loads, so it is checked where libgomp loaded: in a fresh process,
    after a parallel kernel ran."""
    env = {k: v for k, v in os.environ.items() if k != 'OMP_WAIT_POLICY'}
    if given is not None:
        env['OMP_WAIT_POLICY'] = given
    code = ('import os, numpy as np\n'
            'from depth_nodes.core.sgm import SgmMatcher, SgmParams\n'
            'SgmMatcher(SgmParams(disparity_range=16)).match(*[np.zeros((20, 40), np.uint8)] * 2)\n'
            'assert any("libgomp" in line for line in open("/proc/self/maps"))\n'
            'print(os.environ["OMP_WAIT_POLICY"])\n')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == expected
