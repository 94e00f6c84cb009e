"""`depth-nodes bench multiview`: the plane sweep of the multiview_stereo node, beside the
stereo matcher on the same number of pixels x labels, measured in the same run.

On views of the simulator's sideways sequence (the reference and ``sources`` views before
it), per frame: the whole sweep (costs of every view, SGM over the planes, refinement,
standard deviation; the sources' census images computed in the call), the cost kernel
alone on one thread, a frame of the stream as the node runs it (the sweep against
``sources`` keyframes whose census images it keeps, the check against them, the filter),
and the census SGM stereo matcher on a pair of
the same size with as many disparities as planes and the same paths. Memory: the
matcher's buffers at several plane counts with bounded bands (``memory_mb``): they stay
about constant. With ``busy``, everything again with that many cores kept busy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numba
import numpy as np

from depth_nodes.core.mvs.matcher import MultiViewMatcher, MvsParams, SourceView
from depth_nodes.core.mvs.stream import Frame, MvsStream, StreamDepth, StreamParams
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.sim.sequence import SequenceConfig, SequenceView, simulate_sequence
from depth_nodes.tools.bench.sgm import busy_loops
from depth_nodes.tools.bench.timing import median_ms

#: Plane counts of the memory line (bounded bands).
MEMORY_PLANES = (64, 128, 256)


@dataclass
class MultiviewBench:
    """Per-frame times of the plane sweep beside the stereo matcher."""

    width: int
    height: int
    planes: int
    sources: int
    paths: int
    threads: int
    repeats: int
    sweep_ms: float
    cost_ms: float
    stream_ms: float
    #: Keyframes the stream's frame was swept against.
    stream_sources: int
    stereo_ms: float
    #: Matcher buffers (MB) by plane count, with ``memory_mb`` bands.
    memory_mb: dict[int, float]
    busy: int = 0
    busy_ms: dict[str, float] | None = None

    def format(self) -> str:
        """The printed report."""
        cells = self.width * self.height * self.planes
        lines = [
            f'multiview: {self.width}x{self.height}, {self.planes} planes, {self.sources} '
            f'source views, {self.paths} paths, {self.threads} threads, median of '
            f'{self.repeats} interleaved rounds on the sideways sequence',
            f'  plane sweep (costs, SGM, refinement)     {self.sweep_ms:8.1f} ms',
            f'    its cost kernel alone, one thread     {self.cost_ms:8.1f} ms   '
            f'{cells * self.sources / self.cost_ms / 1e6:5.2f} G view-plane costs/s',
            f'  a frame of the stream (sweep, check, filter) {self.stream_ms:5.1f} ms   '
            f'({self.stream_sources} keyframes)',
            f'  census SGM stereo, {self.planes} disparities     {self.stereo_ms:8.1f} ms   '
            f'sweep / stereo = {self.sweep_ms / self.stereo_ms:5.2f}',
            '  matcher buffers with bands (memory_mb 25): ' + ', '.join(
                f'{planes} planes {mb:.0f} MB' for planes, mb in self.memory_mb.items()),
        ]
        if self.busy_ms:
            lines.append(f'  with {self.busy} busy core(s): sweep {self.busy_ms["sweep"]:.1f} '
                         f'ms ({self.busy_ms["sweep"] / self.sweep_ms:.2f}x), stream '
                         f'{self.busy_ms["stream"]:.1f} ms, stereo '
                         f'{self.busy_ms["stereo"]:.1f} ms')
        return '\n'.join(lines)


def _views(width: int, height: int, count: int) -> list[SequenceView]:
    config = SequenceConfig(motion='sideways', width=width, height=height, n_frames=count,
                            step_m=0.03 * 320 / width)
    return list(simulate_sequence(config))


def bench_multiview(*, size: tuple[int, int] = (320, 240), planes: int = 64, sources: int = 4,
                    paths: int = 8, repeats: int = 10, busy: int = 0) -> MultiviewBench:
    """Time the sweep, its cost kernel, a stream frame and the stereo matcher."""
    w, h = size
    views = _views(w, h, 2 * sources + 1)
    reference, earlier = views[-1], views[:-1:2]
    params = MvsParams(min_depth=0.9, max_depth=8.0, planes=planes, paths=paths)
    matcher = MultiViewMatcher(params)
    srcs = [SourceView(v.image, v.intrinsics, reference.pose.relative_to(v.pose))
            for v in earlier]
    inputs = matcher.match(reference.image, reference.intrinsics, srcs).inputs
    volume = np.empty(inputs.shape, np.uint8)
    # every view a keyframe, so that the stream's frame too is swept against `sources`
    stream = MvsStream(params, StreamParams(max_sources=sources, keyframe_baseline=0.0))
    for view in views[:-1]:
        stream.process(Frame(view.image, view.intrinsics, view.pose, view.stamp_ns))
    # the timed frames add no keyframe (the same reference again would evict the others)
    stream.set_params(params, StreamParams(max_sources=sources, keyframe_baseline=10.0,
                                           keyframe_angle_deg=180.0))
    stream_sources = len(stream.sources_for(Frame(reference.image, reference.intrinsics,
                                                  reference.pose, reference.stamp_ns)))
    stereo = SgmMatcher(SgmParams(disparity_range=planes, paths=paths))
    left, right = views[-2].image, views[-1].image  # the camera moves to +x
    threads = numba.get_num_threads()

    def cost_one_thread() -> None:
        numba.set_num_threads(1)
        try:
            inputs.rows(0, volume)
        finally:
            numba.set_num_threads(threads)

    def stream_frame() -> None:
        # the same reference again: a stream frame with its keyframes and filter state
        stream.reset_filter()  # the same work every round
        out = stream.process(Frame(reference.image, reference.intrinsics, reference.pose,
                                   reference.stamp_ns))
        if not isinstance(out, StreamDepth):
            raise RuntimeError(f'the timed stream frame gave no depth: {out}')

    fns = {'sweep': lambda: matcher.match(reference.image, reference.intrinsics, srcs),
           'cost': cost_one_thread, 'stream': stream_frame,
           'stereo': lambda: stereo.match(left, right)}
    ms = median_ms(fns, repeats, settle=0.05)
    memory = {}
    for count in MEMORY_PLANES:
        if count >= w:
            continue
        bounded = MultiViewMatcher(replace(params, planes=count, memory_mb=25.0))
        bounded.match(reference.image, reference.intrinsics, srcs)
        memory[count] = bounded.workspace_bytes / 1e6
    busy_ms = None
    if busy:
        loops = busy_loops(busy)
        try:
            time.sleep(0.5)
            busy_ms = median_ms({k: fns[k] for k in ('sweep', 'stream', 'stereo')}, repeats,
                                settle=0.05)
        finally:
            for loop in loops:
                loop.kill()
                loop.wait()
    return MultiviewBench(w, h, planes, len(srcs), paths, threads, repeats, ms['sweep'],
                          ms['cost'], ms['stream'], stream_sources, ms['stereo'], memory,
                          busy, busy_ms)
