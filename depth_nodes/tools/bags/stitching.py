"""The workers' results stitched into one stream, in the order of the bag: each segment's
outputs up to the first message after which both its graph and the next segment's were idle,
the next segment's from there on (:mod:`depth_nodes.tools.bags.parallel` explains why that
is exact).
"""

from __future__ import annotations

import mmap
import os
from collections.abc import Iterator
from dataclasses import dataclass

from depth_nodes.errors import BagError
from depth_nodes.tools.bags.segments import END, SegmentResult, release_spill


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


def _discard(result: SegmentResult) -> None:
    release_spill(result.spill)


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
            release_spill(spill.name)
