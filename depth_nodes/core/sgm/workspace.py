"""The matcher's buffers, allocated for one frame size and reused across frames.

Both searches hold the same :class:`FrameBuffers` (census images, bands, path rings,
outputs), built by :func:`frame_buffers`; each adds its volumes and its workers' scratch:

* the full search (:class:`FullWorkspace`): whole-frame volumes when they fit
  ``memory_mb`` (:func:`whole_volumes`), else a few bands in flight, one slot each;
* the coarse search's second pass (:class:`RangedWorkspace`): the flat volumes of the
  pixels' windows (``ranged.py``), grown to the largest frame's windows.

:class:`Workspaces` keeps them between frames and counts every allocation (a new frame
size, other settings that change the volumes, flat volumes that grow). The thread count is
not part of what is kept: a frame on more threads only adds the scratch of the extra
workers (``bench sgm --busy`` alternates two and one; reallocating the 118 MB of a VGA
frame's volumes on every such call cost more than the match itself under contention).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.sgm import ranged
from depth_nodes.core.sgm.aggregate import (
    SENTINEL,
    SINGLE_PASS,
    VERTICAL_DIRECTIONS,
    new_line_buffers,
    p2_table,
)
from depth_nodes.core.sgm.bands import (
    CACHED_BAND_BYTES,
    CELL_BYTES,
    MIN_BAND_ROWS,
    MIN_BANDS,
    Band,
    band_layout,
    band_rows,
)
from depth_nodes.core.sgm.census import Census, census_dtype
from depth_nodes.core.sgm.params import SgmParams

U8 = NDArray[np.uint8]
U16 = NDArray[np.uint16]
I64 = NDArray[np.int64]
F32 = NDArray[np.float32]
#: The ring buffers of :func:`~depth_nodes.core.sgm.aggregate.sweep_down`: three L rows
#: and the ring of their minima.
Rings = tuple[tuple[U16, U16, U16], U16]

#: Bands in flight the automatic band height is sized for (a downward sweep and two
#: selections: two threads never wait for a free band). Each thread beyond two adds one.
SIZED_SLOTS = 3
#: Rows below a band whose costs a worker holds at once while its upward paths go
#: through them (they are never all held: see ``schedule.FullFrame``).
OVERLAP_CHUNK = 8


def whole_volumes(params: SgmParams, h: int, w: int) -> bool:
    """Whether an (h, w) frame is matched with whole-frame volumes (exact; the downward
    and upward paths as two chains of bands running at once) rather than bands in flight
    whose upward paths start ``band_overlap`` rows below them (memory bounded): when the
    volumes (3 bytes a cell) fit ``memory_mb``, or the overlap reaches the image bottom
    anyway. Single-pass path counts need no whole volume."""
    p = params
    if p.paths in SINGLE_PASS:
        return False
    return p.band_overlap >= h or CELL_BYTES * h * w * p.disparity_range <= p.memory_mb * 1e6


def frame_bands(params: SgmParams, h: int, w: int) -> list[Band]:
    """The bands of an (h, w) frame with ``params`` (independent of the thread count, so
    every thread count gives the same result)."""
    p = params
    if whole_volumes(p, h, w):
        return band_layout(h, min(h, p.band_rows or -(-h // MIN_BANDS)), 0)
    overlap = 0 if p.paths in SINGLE_PASS else p.band_overlap
    rows = p.band_rows or band_rows(h, w, p.disparity_range, memory_mb=p.memory_mb,
                                    slots=SIZED_SLOTS, overlap=overlap)
    if p.paths in SINGLE_PASS and not p.band_rows:  # exact with any bands: cache-sized
        cached = int(CACHED_BAND_BYTES // (w * p.disparity_range * CELL_BYTES))
        rows = min(rows, max(MIN_BAND_ROWS, cached))
    return band_layout(h, min(rows, h), overlap)


@dataclass
class FrameBuffers:
    """What both searches hold for one frame size.

    Attributes:
        census: The (H, W) census images of the left and (mirrored) right image.
        bands: The frame's bands of rows.
        dxs: The vertical directions' horizontal steps (``aggregate.VERTICAL_DIRECTIONS``).
        dys: Their vertical steps.
        down: The downward chain's ring buffers.
        up: The upward chain's (None where no chain runs upward).
        disparity: (H, W) float32 left disparity (output).
        disparity_right: (H, W) float32 right-view disparity (output).
        ratio: (H, W) float32 cost ratio (output).
    """

    census: tuple[Census, Census]
    bands: list[Band]
    dxs: I64
    dys: I64
    down: Rings
    up: Rings | None
    disparity: F32
    disparity_right: F32
    ratio: F32


def frame_buffers(params: SgmParams, h: int, w: int, bands: list[Band], *,
                  upward: bool) -> FrameBuffers:
    """The buffers both searches share, for an (h, w) frame cut into ``bands``; the
    upward chain's rings with ``upward``."""
    n = params.disparity_range
    dirs = VERTICAL_DIRECTIONS[params.paths]
    census = census_dtype((params.census_height, params.census_width))
    return FrameBuffers(
        census=(np.empty((h, w), census), np.empty((h, w), census)), bands=bands,
        dxs=np.array([d[0] for d in dirs], np.int64),
        dys=np.array([d[1] for d in dirs], np.int64),
        down=new_line_buffers(len(dirs), w, n),
        up=new_line_buffers(len(dirs), w, n) if upward else None,
        disparity=np.empty((h, w), np.float32), disparity_right=np.empty((h, w), np.float32),
        ratio=np.empty((h, w), np.float32))


@dataclass
class FullScratch:
    """One worker's scratch in the full search (``select.band_select``'s and more).

    Attributes:
        rings: The upward paths' ring buffers of the bands in flight.
        total: (W, D) uint16 row of the total.
        ltr: (2, W, D) uint16 left-to-right paths of two rows.
        rtl: (2, W, D) uint16 right-to-left paths of two rows.
        lines: (4, D + 2) uint16 path lines, SENTINEL at both ends.
        keys: (W,) uint32 the right view's candidates.
        sample: (1, W, D) uint8 one row of costs for the border statistic.
        below: (OVERLAP_CHUNK or fewer, W, D) uint8 costs of the rows below a band.
    """

    rings: Rings
    total: U16
    ltr: U16
    rtl: U16
    lines: U16
    keys: NDArray[np.uint32]
    sample: U8
    below: U8


@dataclass
class FullWorkspace:
    """The full search's buffers.

    Attributes:
        frame: The buffers both searches share.
        whole: Whole-frame volumes (one slot) rather than bands in flight.
        cost: The cost volume of each slot, (rows, W, D) uint8.
        partial: The downward (with whole volumes also the upward) sum of each slot,
            (rows, W, D) uint16.
        workers: Each worker's scratch.
    """

    frame: FrameBuffers
    whole: bool
    cost: list[U8]
    partial: list[U16]
    workers: list[FullScratch]


@dataclass
class RangedScratch:
    """One worker's scratch in the coarse search's second pass (``ranged.ranged_select``).

    Attributes:
        total: (W, D) uint16 row of the total, a pixel's window in its first entries.
        ltr: (W, D) uint16 left-to-right path.
        rtl: (W, D) uint16 right-to-left path.
        lines: (2, D + 2) uint16 path lines.
        keys: (W,) uint32 the right view's candidates.
    """

    total: U16
    ltr: U16
    rtl: U16
    lines: U16
    keys: NDArray[np.uint32]


@dataclass
class RangedWorkspace:
    """The buffers of the coarse search's second pass.

    Attributes:
        frame: The buffers both searches share.
        cost: The windows' flat cost volume, uint8.
        partial: The windows' flat sum of the vertical paths, uint16.
        workers: Each worker's scratch.
    """

    frame: FrameBuffers
    cost: U8
    partial: U16
    workers: list[RangedScratch]


def path_lines(count: int, n: int) -> U16:
    """``count`` path lines of D + 2 entries, SENTINEL at both ends (``band_select``)."""
    lines = np.empty((count, n + 2), np.uint16)
    lines[:, 0] = lines[:, -1] = SENTINEL
    return lines


def nbytes(value: Any) -> int:
    """Bytes of the arrays in ``value`` (arrays, lists and tuples of them, workspaces)."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (list, tuple)):
        return sum(nbytes(v) for v in value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return sum(nbytes(getattr(value, f.name)) for f in dataclasses.fields(value))
    return 0


class Workspaces:
    """The buffers one matcher keeps between frames (see the module notes).

    Attributes:
        allocations: How many times volumes were allocated.
        full: The full search's buffers, once it ran.
        ranged: The coarse search's second pass's, once it ran.
        total: The (H, W, D) aggregated volume a test asked to keep.
    """

    def __init__(self) -> None:
        self.allocations = 0
        self.full: FullWorkspace | None = None
        self.ranged: RangedWorkspace | None = None
        self.total = np.empty((0, 0, 0), np.uint16)
        self._full_key: tuple[object, ...] = ()
        self._ranged_key: tuple[object, ...] = ()
        self._table_key: tuple[object, ...] = ()
        self._table = p2_table(0, 0, 0.0)

    @property
    def nbytes(self) -> int:
        """Bytes of every buffer kept."""
        return nbytes(self.full) + nbytes(self.ranged) + nbytes(self.total)

    def p2_table(self, params: SgmParams) -> I64:
        """The adaptive-P2 table of ``params`` (``aggregate.p2_table``), kept while they
        do not change it."""
        key = (params.P1, params.P2, params.p2_adaptive_scale)
        if key != self._table_key:
            self._table = p2_table(*key)
            self._table_key = key
        return self._table

    def total_volume(self, h: int, w: int, n: int) -> U16:
        """An (h, w, n) uint16 volume for the aggregated total (tests)."""
        if self.total.shape != (h, w, n):
            self.total = np.empty((h, w, n), np.uint16)
        return self.total

    def for_full(self, params: SgmParams, h: int, w: int, threads: int) -> FullWorkspace:
        """The full search's buffers for an (h, w) frame on ``threads`` threads."""
        p = params
        n = p.disparity_range
        bands = frame_bands(p, h, w)
        whole = whole_volumes(p, h, w)
        slots = 1 if whole else min(len(bands), max(SIZED_SLOTS, threads + 1))
        rows = h if whole else max(b.rows for b in bands)
        chunk = min(OVERLAP_CHUNK, max(b.reach - b.rows for b in bands)) if not whole else 0
        census = census_dtype((p.census_height, p.census_width))
        key = (h, w, n, p.paths, census, tuple(bands), whole, slots)
        if key != self._full_key or self.full is None:
            self.full = FullWorkspace(
                frame=frame_buffers(p, h, w, bands, upward=whole), whole=whole,
                cost=[np.empty((rows, w, n), np.uint8) for _ in range(slots)],
                partial=[np.empty((rows, w, n), np.uint16) for _ in range(slots)],
                workers=[])
            self._full_key = key
            self.allocations += 1
        workers = self.full.workers
        while len(workers) < threads:
            workers.append(FullScratch(
                rings=new_line_buffers(len(VERTICAL_DIRECTIONS[p.paths]), w, n),
                total=np.empty((w, n), np.uint16), ltr=np.empty((2, w, n), np.uint16),
                rtl=np.empty((2, w, n), np.uint16), lines=path_lines(4, n),
                keys=np.empty(w, np.uint32), sample=np.empty((1, w, n), np.uint8),
                below=np.empty((chunk, w, n), np.uint8)))
        return self.full

    def for_ranged(self, params: SgmParams, h: int, w: int, threads: int,
                   cells: int) -> RangedWorkspace:
        """The coarse search's second-pass buffers for an (h, w) frame whose windows hold
        ``cells`` cells; the flat volumes grow to the largest frame's windows (by a
        quarter more, so that they seldom grow again, but never past ``memory_mb``)."""
        p = params
        n = p.disparity_range
        census = census_dtype((p.census_height, p.census_width))
        key = (h, w, n, p.paths, census)
        if key != self._ranged_key or self.ranged is None:
            bands = band_layout(h, -(-h // MIN_BANDS), 0)
            self.ranged = RangedWorkspace(
                frame=frame_buffers(p, h, w, bands, upward=True),
                cost=np.empty(0, np.uint8), partial=np.empty(0, np.uint16), workers=[])
            self._ranged_key = key
            self.allocations += 1
        ws = self.ranged
        while len(ws.workers) < threads:
            ws.workers.append(RangedScratch(
                total=np.empty((w, n), np.uint16), ltr=np.empty((w, n), np.uint16),
                rtl=np.empty((w, n), np.uint16), lines=np.empty((2, n + 2), np.uint16),
                keys=np.empty(w, np.uint32)))
        if ws.cost.size < cells:
            grown = max(cells, min(cells + cells // 4,
                                   int(p.memory_mb * 1e6) // ranged.CELL_BYTES))
            # let the old volumes go before the new ones are allocated
            ws.cost, ws.partial = np.empty(0, np.uint8), np.empty(0, np.uint16)
            ws.cost = np.empty(grown, np.uint8)
            ws.partial = np.empty(grown, np.uint16)
            self.allocations += 1
        return ws
