"""One frame's match as a graph of tasks for :func:`~depth_nodes.core.sgm.bands.run_tasks`.

:class:`FullFrame` is the full search's (every disparity at every pixel), over a
:class:`~depth_nodes.core.sgm.workspace.FullWorkspace`; :class:`RangedFrame` the coarse
search's second pass (each pixel's window, ``ranged.py``), over a
:class:`~depth_nodes.core.sgm.workspace.RangedWorkspace`. Each task is one band's step
(its costs, a sweep, its selection) run by whichever thread is free; the dependencies
keep the result independent of the thread count, bit for bit.

Both also take the out-of-image cost (``border_cost`` x the frame's mean best cost,
``border.py``) from every :data:`BORDER_ROW_STEP`-th row before the cells that need it
are aggregated.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.sgm import ranged
from depth_nodes.core.sgm.aggregate import SINGLE_PASS, sweep_down
from depth_nodes.core.sgm.bands import Task
from depth_nodes.core.sgm.border import (
    best_cost_sum,
    fill_outside,
    full_range_columns,
    mean_best_count,
    sampled_best_cost_sum,
)
from depth_nodes.core.sgm.cost import CostInputs, CostRows
from depth_nodes.core.sgm.learned_cost import LearnedCosts
from depth_nodes.core.sgm.params import SgmParams
from depth_nodes.core.sgm.select import SUBPIXEL_MODES, band_select
from depth_nodes.core.sgm.workspace import FullWorkspace, RangedWorkspace

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
#: A task's work: ``run(worker)``, the worker's index picking its scratch.
Run = Callable[[int], None]

#: Row step of the frame statistic behind ``border_cost`` (:func:`border.mean_best_cost`).
BORDER_ROW_STEP = 4


def border_cost(params: SgmParams, total: float, h: int, w: int) -> int:
    """The out-of-image cost: ``border_cost`` times the frame's mean best cost, from the
    sum ``total`` of the best costs of the sampled rows (1 .. 254)."""
    count = mean_best_count(h, w, params.disparity_range, params.min_disparity,
                            BORDER_ROW_STEP)
    return min(254, max(1, round(params.border_cost * total / count)))


class FullFrame:
    """One match of the full search as tasks.

    First the border statistic (two halves of its sampled rows, then their sum). Whole
    volumes: per band its costs, its downward sweep (a chain from the top: each continues
    the paths of the band above), its upward sweep (a chain from the bottom) and, once both
    have passed it, its selection. Bands in flight: per band its costs and downward sweep
    (the chain), then its selection with its own upward paths; a band's buffers are reused
    once the selection that last held them is done.

    Args:
        params: The settings.
        ws: The buffers (outputs included).
        inputs: The frame's cost inputs.
        image: (H, W) float32 left image (adaptive P2).
        table: The adaptive-P2 table of ``params``.
        total: (H, W, D) uint16 volume for the aggregated total, used with ``keep_total``.
        keep_total: Write the aggregated total into ``total`` (tests).
        threads: Threads the tasks will run on.
    """

    def __init__(self, params: SgmParams, ws: FullWorkspace, inputs: CostRows, image: F32,
                 table: I64, total: NDArray[np.uint16], keep_total: bool,
                 threads: int) -> None:
        self.p = params
        self.ws = ws
        self.inputs = inputs
        self.image = image
        self.table = table
        self.total = total
        self.keep_total = keep_total
        self.extrapolate = params.border_cost > 0
        #: The out-of-image cost this frame used (0: none, extrapolation off).
        self.border_cost = 0
        self.samples = [0.0, 0.0]
        # on one thread with whole volumes the border statistic is taken from the stored
        # costs once they are all there (the same rows, so the same value) instead of from
        # rows computed again for it: 4 % of a frame's work saved; with more threads the
        # sampled rows come first, so that the chains can start on the first bands' costs
        self.from_volume = ws.whole and self.extrapolate and threads == 1
        self.h, self.w = image.shape
        bands = len(ws.frame.bands)
        self.band_locks = [threading.Lock() for _ in range(bands)]
        self.swept = [False] * bands

    def tasks(self) -> list[Task]:
        """The frame's tasks, dependencies first."""
        tasks: list[Task] = []
        if self.extrapolate and not self.from_volume:
            ys = range(0, self.h, BORDER_ROW_STEP)
            half = (len(ys) + 1) // 2
            tasks += [Task(self._sample(part, rows))
                      for part, rows in enumerate((ys[:half], ys[half:]))]
            tasks.append(Task(lambda worker: self._border(), [0, 1]))
        border = [len(tasks) - 1] if tasks else []
        bands = len(self.ws.frame.bands)
        if self.ws.whole:
            # costs from both ends inwards, the two chains meeting in the middle
            cost = [len(tasks) + k for k in range(bands)]
            tasks += [Task(self._cost(k), border, 2 * min(k, bands - 1 - k))
                      for k in range(bands)]
            if self.from_volume:  # every band's costs, then the statistic and the fill
                tasks.append(Task(lambda worker: self._border_from_volume(), cost))
                cost = [len(tasks) - 1] * bands
            down = [len(tasks) + k for k in range(bands)]
            tasks += [Task(self._sweep(k, upward=False), [cost[k], *down[k - 1:k]], 2 * k + 1)
                      for k in range(bands)]
            up = [len(tasks) + bands - 1 - k for k in range(bands)]  # added bottom first
            tasks += [Task(self._sweep(k, upward=True), [cost[k], *up[k + 1:k + 2]],
                           2 * (bands - 1 - k) + 1) for k in reversed(range(bands))]
            tasks += [Task(self._select(k), [down[k], up[k]], 2 * bands + k)
                      for k in range(bands)]
            return tasks
        # per band its costs, its downward sweep (the chain) and its selection; the costs
        # are a task of their own, so that a free thread makes the next bands' costs
        # while the chain sweeps (into a slot whose last selection is done): the chain is
        # then the sweeps alone
        first_band = len(tasks)
        slots = len(self.ws.cost)
        for k in range(bands):
            cost_k = first_band + 3 * k
            after = list(border)
            if k >= slots:
                after.append(cost_k - 3 * slots + 2)  # the selection that last used the slot
            tasks.append(Task(self._band_cost(k), after, priority=1))
            tasks.append(Task(self._down(k), [cost_k, *([cost_k - 2] if k else [])],
                              priority=0))
            tasks.append(Task(self._select(k), [cost_k + 1], priority=2))
        return tasks

    def _border(self) -> None:
        """Set :attr:`border_cost` from the sampled rows."""
        self.border_cost = border_cost(self.p, sum(self.samples), self.h, self.w)

    def _cost(self, k: int) -> Run:
        """Whole volumes: the cost of band k (a slice of the frame's volume)."""
        def run(worker: int) -> None:
            band = self.ws.frame.bands[k]
            cost = self.inputs.rows(band.y0, self.ws.cost[0][band.y0:band.y0 + band.rows])
            if self.extrapolate and not self.from_volume:
                fill_outside(cost, self.p.min_disparity, self.border_cost)
        return run

    def _border_from_volume(self) -> None:
        """:meth:`_border` from the stored volume's rows, then its out-of-image cells."""
        volume = self.ws.cost[0]
        x_lo, x_hi = full_range_columns(self.w, self.p.disparity_range, self.p.min_disparity)
        total = float(best_cost_sum(volume, x_lo, x_hi, BORDER_ROW_STEP))
        self.border_cost = border_cost(self.p, total, self.h, self.w)
        fill_outside(volume, self.p.min_disparity, self.border_cost)

    def _sweep(self, k: int, *, upward: bool) -> Run:
        """Whole volumes: one chain's paths through band k, into the frame's partial sum
        (the chain that comes second adds to the first one's; never both at once)."""
        def run(worker: int) -> None:
            p, ws, frame = self.p, self.ws, self.ws.frame
            band = frame.bands[k]
            rows = slice(band.y0, band.y0 + band.rows)
            rings = frame.up if upward else frame.down
            assert rings is not None  # whole volumes hold both chains' rings
            (lb0, lb1, lb2), mbuf = rings
            with self.band_locks[k]:
                sweep_down(ws.cost[0][rows], self.image, band.y0, band.rows, frame.dxs,
                           frame.dys, int(p.P1), int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                           ws.partial[0][rows], upward, self.swept[k])
                self.swept[k] = True
        return run

    def _sample(self, part: int, ys: range) -> Run:
        def run(worker: int) -> None:
            # border_cost > 0 (the only case that samples) is a stereo pair's costs
            assert isinstance(self.inputs, (CostInputs, LearnedCosts))
            self.samples[part] = sampled_best_cost_sum(self.inputs, ys,
                                                       self.ws.workers[worker].sample)
        return run

    def _band_cost(self, k: int) -> Run:
        """Bands in flight: the costs of band k, into its slot."""
        def run(worker: int) -> None:
            ws = self.ws
            band = ws.frame.bands[k]
            cost = self.inputs.rows(band.y0, ws.cost[k % len(ws.cost)][:band.rows])
            if self.extrapolate:
                fill_outside(cost, self.p.min_disparity, self.border_cost)
        return run

    def _down(self, k: int) -> Run:
        """Bands in flight: the downward sweep of band k, continuing band k - 1's paths."""
        def run(worker: int) -> None:
            p, ws, frame = self.p, self.ws, self.ws.frame
            band = frame.bands[k]
            slot = k % len(ws.cost)
            cost = ws.cost[slot][:band.rows]
            (lb0, lb1, lb2), mbuf = frame.down
            sweep_down(cost, self.image, band.y0, band.rows, frame.dxs, frame.dys, int(p.P1),
                       int(p.P2), self.table, lb0, lb1, lb2, mbuf, ws.partial[slot])
        return run

    def _select(self, k: int) -> Run:
        def run(worker: int) -> None:
            p, ws, frame = self.p, self.ws, self.ws.frame
            band = frame.bands[k]
            if ws.whole:  # both vertical sums are in the partial: horizontals and select
                rows = slice(band.y0, band.y0 + band.rows)
                cost, partial, upward = ws.cost[0][rows], ws.partial[0][rows], False
            else:
                slot = k % len(ws.cost)
                cost, partial = ws.cost[slot][:band.rows], ws.partial[slot]
                upward = p.paths not in SINGLE_PASS
            scratch = ws.workers[worker]
            (lb0, lb1, lb2), mbuf = scratch.rings

            def select(cost: Any, y0: int, rows: int, ring0: int) -> None:
                band_select(cost, self.image, partial, y0, rows, frame.dxs, frame.dys,
                            int(p.P1), int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                            int(p.min_disparity), float(p.uniqueness_ratio),
                            SUBPIXEL_MODES[p.subpixel], scratch.total, scratch.ltr,
                            scratch.rtl, scratch.keys, frame.disparity,
                            frame.disparity_right, frame.ratio, self.total, self.keep_total,
                            upward, self.extrapolate, ring0, scratch.lines)

            swept = 0
            if upward and band.reach > band.rows:  # the rows below, a few at a time,
                # bottom up: their paths only
                below = scratch.below
                for end in range(band.y0 + band.reach, band.y0 + band.rows, -len(below)):
                    start = max(band.y0 + band.rows, end - len(below))
                    part = self.inputs.rows(start, below[:end - start])
                    if self.extrapolate:
                        fill_outside(part, p.min_disparity, self.border_cost)
                    select(part, start, 0, swept)
                    swept += end - start
            select(cost, band.y0, band.rows, swept)
        return run


class RangedFrame:
    """One coarse-to-fine match as tasks (``ranged.py``): the whole-volume order of
    :class:`FullFrame` on the windows' flat volumes. Per band its costs; once every band's
    are there, the border statistic (its rows' minima over the windows) and the
    out-of-image cells; then the downward chain from the top and the upward one from the
    bottom (none with a single-pass path count), and each band's selection once both
    have passed it.

    Args:
        params: The settings.
        ws: The buffers (outputs included).
        inputs: The frame's cost inputs.
        image: (H, W) float32 left image (adaptive P2).
        table: The adaptive-P2 table of ``params``.
        lo: (H, W) int32 first disparity index of each pixel's window.
        wid: (H, W) int32 width of each pixel's window.
        base: (H W + 1,) int64 where each pixel's cells start (``ranged.flat_offsets``).
    """

    def __init__(self, params: SgmParams, ws: RangedWorkspace, inputs: CostInputs,
                 image: F32, table: I64, lo: I32, wid: I32, base: I64) -> None:
        self.p = params
        self.ws = ws
        self.inputs = inputs
        self.image = image
        self.table = table
        self.lo, self.wid, self.base = lo, wid, base
        self.extrapolate = params.border_cost > 0
        #: The out-of-image cost this frame used (0: none, extrapolation off).
        self.border_cost = 0
        self.h, self.w = image.shape
        bands = len(ws.frame.bands)
        self.band_locks = [threading.Lock() for _ in range(bands)]
        self.swept = [False] * bands

    def tasks(self) -> list[Task]:
        """The frame's tasks, dependencies first."""
        bands = len(self.ws.frame.bands)
        tasks = [Task(self._cost(k), (), 2 * min(k, bands - 1 - k)) for k in range(bands)]
        cost = list(range(bands))
        if self.extrapolate:
            tasks.append(Task(lambda worker: self._border(), cost))
            cost = [bands] * bands
        down = [len(tasks) + k for k in range(bands)]
        tasks += [Task(self._sweep(k, upward=False), [cost[k], *down[k - 1:k]], 2 * k + 1)
                  for k in range(bands)]
        up: list[int] = []
        if self.p.paths not in SINGLE_PASS:
            up = [len(tasks) + bands - 1 - k for k in range(bands)]  # added bottom first
            tasks += [Task(self._sweep(k, upward=True), [cost[k], *up[k + 1:k + 2]],
                           2 * (bands - 1 - k) + 1) for k in reversed(range(bands))]
        tasks += [Task(self._select(k), [down[k], *up[k:k + 1]], 2 * bands + k)
                  for k in range(bands)]
        return tasks

    def _cost(self, k: int) -> Run:
        def run(worker: int) -> None:
            band = self.ws.frame.bands[k]
            ranged.ranged_costs(self.inputs, band.y0, band.rows, self.lo, self.wid,
                                self.base, self.ws.cost)
        return run

    def _border(self) -> None:
        """:class:`FullFrame`'s border statistic from the windows' costs, then the
        out-of-image cells of every window set to it."""
        p = self.p
        n, h, w = p.disparity_range, self.h, self.w
        x_lo, x_hi = full_range_columns(w, n, p.min_disparity)
        total = ranged.ranged_best_cost_sum(self.ws.cost, self.lo, self.wid, self.base,
                                            x_lo, x_hi, BORDER_ROW_STEP)
        self.border_cost = border_cost(p, total, h, w)
        ranged.ranged_fill_outside(self.ws.cost, self.lo, self.wid, self.base, 0, h,
                                   p.min_disparity, n, self.border_cost)

    def _sweep(self, k: int, *, upward: bool) -> Run:
        def run(worker: int) -> None:
            p, ws, frame = self.p, self.ws, self.ws.frame
            band = frame.bands[k]
            rings = frame.up if upward else frame.down
            assert rings is not None  # the ranged workspace holds both chains' rings
            (lb0, lb1, lb2), mbuf = rings
            with self.band_locks[k]:
                ranged.ranged_sweep(ws.cost, self.base, self.lo, self.wid, self.image,
                                    band.y0, band.rows, frame.dxs, frame.dys, int(p.P1),
                                    int(p.P2), self.table, lb0, lb1, lb2, mbuf,
                                    ws.partial, upward, self.swept[k])
                self.swept[k] = True
        return run

    def _select(self, k: int) -> Run:
        def run(worker: int) -> None:
            p, ws, frame = self.p, self.ws, self.ws.frame
            band = frame.bands[k]
            s = ws.workers[worker]
            ranged.ranged_select(ws.cost, self.base, self.lo, self.wid, self.image,
                                 ws.partial, band.y0, band.rows, int(p.P1), int(p.P2),
                                 self.table, int(p.disparity_range), int(p.min_disparity),
                                 float(p.uniqueness_ratio), SUBPIXEL_MODES[p.subpixel],
                                 s.total, s.ltr, s.rtl, s.lines, s.keys, frame.disparity,
                                 frame.disparity_right, frame.ratio, self.extrapolate)
        return run
