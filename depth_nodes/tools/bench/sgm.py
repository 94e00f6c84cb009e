"""`depth-nodes bench`: speed figures, always beside OpenCV measured in the same run.

Times are medians over repeated runs on the same synthetic frame, after one warm-up run;
OpenCV uses its default thread count (``cv2.getNumThreads()``), printed with the figures.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from depth_nodes.core.rectify import interpolation_flag
from depth_nodes.sim import StereoSimConfig, simulate_stereo


def median_ms(fns: dict[str, Callable[[], Any]], repeats: int,
              settle: float = 0.0) -> dict[str, float]:
    """Median wall time in ms of each function, over ``repeats`` interleaved rounds.

    Every round calls each function once, so a slow spell of the machine affects all of
    them alike and their ratios stay meaningful. One untimed warm-up round comes first.
    ``settle`` seconds of sleep precede each timed call: OpenCV's worker threads keep
    spinning for a moment after a call returns and would otherwise slow down whatever
    runs next on this 2-core machine.
    """
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            if settle:
                time.sleep(settle)
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: float(np.median(t) * 1e3) for name, t in times.items()}


@dataclass
class RectifyBench:
    """Per-frame times of the rectify node and of OpenCV on the same frame."""

    width: int
    height: int
    encoding: str
    interpolation: str
    repeats: int
    threads: int
    first_frame_ms: float
    node_ms: float
    remap_ms: float
    messages_ms: float
    undistort_ms: float

    def format(self) -> str:
        """The printed report."""
        return '\n'.join([
            f'rectify: {self.width}x{self.height} {self.encoding}, {self.interpolation}, '
            f'median of {self.repeats} frames, OpenCV threads {self.threads}',
            f'  first frame (builds the maps)                  {self.first_frame_ms:8.2f} ms',
            f'  node, per frame (image_rect_color + image_rect) {self.node_ms:7.2f} ms',
            f'  cv2.remap with the cached maps                 {self.remap_ms:8.2f} ms'
            f'   node / remap     = {self.node_ms / self.remap_ms:5.2f}',
            f'  node part: building the two Image messages     {self.messages_ms:8.2f} ms'
            f'   (pixels copied into rclpy messages, mono conversion included)',
            f'  cv2.undistort (no R, no P; maps every call)    {self.undistort_ms:8.2f} ms'
            f'   node / undistort = {self.node_ms / self.undistort_ms:5.2f}',
        ])


def bench_rectify(*, width: int = 640, height: int = 480, repeats: int = 200,
                  interpolation: str = 'linear') -> RectifyBench:
    """Time the rectify node's frame callback against cv2.remap and cv2.undistort."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from std_msgs.msg import Header

    from depth_nodes.nodes.rectify import RectifyNode
    from depth_nodes.ros.camera_info import model_to_camera_info
    from depth_nodes.ros.image import array_to_image

    frame = next(simulate_stereo(StereoSimConfig(width=width, height=height, n_frames=1,
                                                 colour=True, seed=21)))
    camera = frame.left_camera
    header = Header(frame_id=camera.frame_id)
    image_msg = array_to_image(frame.left_raw, 'rgb8', header)
    info_msg = model_to_camera_info(camera, header)
    context = Context()
    rclpy.init(args=[], context=context)
    # the node's threads as the caller set OpenCV's (the node applies them every frame)
    node = RectifyNode(context=context, parameter_overrides=[
        Parameter('interpolation', value=interpolation),
        Parameter('threads', value=cv2.getNumThreads())])
    try:
        published: list[str] = []
        node.sink = lambda topic, msg: published.append(topic)  # keep no pixels
        start = time.perf_counter()
        node.on_frame(image_msg, info_msg)
        first_ms = (time.perf_counter() - start) * 1e3
        if len(published) != 2:
            raise RuntimeError(f'rectify node dropped the benchmark frame: {dict(node.drops)}')
        map1, map2 = node.rectifier.maps(camera)
        flag = interpolation_flag(interpolation)
        rect = cv2.remap(frame.left_raw, map1, map2, flag)
        ms = median_ms({
            'node': lambda: node.on_frame(image_msg, info_msg),
            'remap': lambda: cv2.remap(frame.left_raw, map1, map2, flag),
            'messages': lambda: (
                array_to_image(rect, 'rgb8', header),
                array_to_image(cv2.cvtColor(rect, cv2.COLOR_RGB2GRAY), 'mono8', header)),
            'undistort': lambda: cv2.undistort(frame.left_raw, camera.K, camera.D),
        }, repeats)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
    return RectifyBench(width, height, 'rgb8', interpolation, repeats, cv2.getNumThreads(),
                        first_ms, ms['node'], ms['remap'], ms['messages'], ms['undistort'])


@dataclass
class SgmBench:
    """Per-frame time of the census SGM matcher beside OpenCV's StereoSGBM."""

    width: int
    height: int
    disparities: int
    paths: int
    repeats: int
    threads: int
    ours_ms: float
    hh_ms: float
    sgbm_ms: float
    workspace_mb: float
    #: Peak RSS (MB) of a fresh process matching one frame, by method; empty if not run.
    peak_mb: dict[str, float]
    cold_start: dict[str, float]
    #: What bounds the path recurrence (:func:`kernel_limits`); empty if not run.
    limits: dict[str, float] | None = None
    #: Busy-loop processes during the contended run (0: none run).
    busy: int = 0
    #: Times (ms) with ``busy`` cores taken: ours on ``threads`` and on one thread, OpenCV.
    busy_ms: dict[str, float] | None = None
    #: Ours with ``disparity_search: coarse`` (ms), the share of the cells it searched in
    #: its last frame, and how many frames fell back to the full search.
    coarse_ms: float = 0.0
    coarse_cells: float = 1.0
    coarse_fallbacks: int = 0

    def format(self) -> str:
        """The printed report."""
        updates = self.width * self.height * self.disparities * self.paths
        lines = [
            f'sgm: {self.width}x{self.height}, {self.disparities} disparities, {self.paths} '
            f'paths, {self.threads} threads (numba and OpenCV), median of {self.repeats} '
            'interleaved rounds on the bundled stereo_vga pair'
            + ('' if (self.width, self.height) == (640, 480) else ' (resized)'),
            f'  census SGM (this package)   {self.ours_ms:8.1f} ms   '
            f'{updates / self.ours_ms / 1e6:5.2f} G cell-path updates/s',
            f'  OpenCV MODE_HH (8 paths)    {self.hh_ms:8.1f} ms   '
            f'ours / MODE_HH   = {self.ours_ms / self.hh_ms:5.2f}',
            f'  OpenCV MODE_SGBM (5 paths)  {self.sgbm_ms:8.1f} ms   '
            f'ours / MODE_SGBM = {self.ours_ms / self.sgbm_ms:5.2f}',
            f'  matcher buffers {self.workspace_mb:.0f} MB (reused every frame)',
        ]
        if self.coarse_ms:
            how = (f'{self.coarse_fallbacks} frame(s) fell back to the full search: the '
                   'windows did not fit memory_mb' if self.coarse_fallbacks else
                   f'{100 * self.coarse_cells:.0f} % of the cells searched')
            lines.insert(4, f'  census SGM, coarse search    {self.coarse_ms:8.1f} ms   '
                         f'ours / MODE_SGBM = {self.coarse_ms / self.sgbm_ms:5.2f}   '
                         f'(disparity_search: coarse; {how})')
        if self.peak_mb:
            lines.append('  peak memory of a fresh process matching one frame (RSS): ours '
                         f'{self.peak_mb["ours"]:.0f} MB, MODE_HH {self.peak_mb["hh"]:.0f} '
                         f'MB, MODE_SGBM {self.peak_mb["sgbm"]:.0f} MB (the same imports; '
                         f'none matching: {self.peak_mb["idle"]:.0f} MB)')
        if self.limits:
            k = self.limits
            lines.append(
                '  downward sweep alone (3 paths, one thread, 640x480x128): '
                f'{k["whole_ms"]:.1f} ms, {k["volume_gbs"]:.1f} GB/s of volume read and '
                'written; the same rows as an 8-row band swept again and again (from the '
                f'caches, not DRAM): {k["cached_ms"]:.1f} ms; a plain memory copy '
                f'runs at {k["copy_gbs"]:.1f} GB/s (when the cached run is about as slow, '
                'memory bandwidth is not what bounds the sweep: docs/speed.md)')
        if self.busy_ms:
            b = self.busy_ms
            lines += [
                f'  with {self.busy} busy-loop process(es) beside it:',
                f'    census SGM, {self.threads} threads {b["ours"]:8.1f} ms   '
                f'contended / quiet = {b["ours"] / self.ours_ms:5.2f}',
                f'    census SGM, 1 thread  {b["ours_1"]:10.1f} ms   '
                f'{self.threads} threads / 1 thread = {b["ours"] / b["ours_1"]:5.2f}',
                f'    OpenCV MODE_HH        {b["hh"]:10.1f} ms   '
                f'contended / quiet = {b["hh"] / self.hh_ms:5.2f}',
                f'    OpenCV MODE_SGBM      {b["sgbm"]:10.1f} ms   '
                f'contended / quiet = {b["sgbm"] / self.sgbm_ms:5.2f}',
            ]
        if self.cold_start:
            lines.append(
                f'  cold start, warm numba cache: import {self.cold_start["import_s"]:.2f} s, '
                f'first frame {self.cold_start["first_frame_s"] * 1e3:.0f} ms, second '
                f'{self.cold_start["second_frame_s"] * 1e3:.0f} ms')
        return '\n'.join(lines)


def _bundled_pair() -> tuple[Any, Any]:
    """The first rectified pair of bags/stereo_vga (rectified with its CameraInfo)."""
    from pathlib import Path

    from depth_nodes.core.rectify import rectify_image
    from depth_nodes.ros.camera_info import camera_info_to_model
    from depth_nodes.ros.image import image_to_array
    from depth_nodes.tools.bags.io import BagReader

    bag = Path(__file__).resolve().parents[3] / 'bags' / 'stereo_vga'
    first: dict[str, Any] = {}
    with BagReader(bag) as reader:
        for m in reader.messages([f'/stereo/{s}/{k}' for s in ('left', 'right')
                                  for k in ('image_raw', 'camera_info')]):
            first.setdefault(m.topic, m.deserialize())
    return tuple(  # type: ignore[return-value]
        rectify_image(image_to_array(first[f'/stereo/{s}/image_raw']),
                      camera_info_to_model(first[f'/stereo/{s}/camera_info']))
        for s in ('left', 'right'))


_COLD_START = '''
import json, sys, time
start = time.perf_counter()
import numpy as np
from depth_nodes.core.sgm import SgmMatcher, SgmParams
imported = time.perf_counter()
rng = np.random.default_rng(0)
left = rng.integers(0, 256, (480, 640), dtype=np.uint8)
right = np.roll(left, -20, axis=1)
matcher = SgmMatcher(SgmParams(disparity_range=128))
t0 = time.perf_counter(); matcher.match(left, right); t1 = time.perf_counter()
matcher.match(left, right); t2 = time.perf_counter()
print(json.dumps({"import_s": imported - start, "first_frame_s": t1 - t0,
                  "second_frame_s": t2 - t1}))
'''


def cold_start_sgm() -> dict[str, float]:
    """Import and first-frame times of a fresh interpreter (numba cache already warm)."""
    import json
    import subprocess
    import sys

    for _ in range(2):  # the first run fills the cache if it is empty; the second is timed
        out = subprocess.run([sys.executable, '-c', _COLD_START], capture_output=True,
                             text=True, check=True).stdout
    return {k: float(v) for k, v in json.loads(out.strip().splitlines()[-1]).items()}


_PEAK = '''
import json, sys
import cv2, numba, numpy as np
from depth_nodes.core.opencv_stereo import TUNED_HH, TUNED_SGBM, opencv_sgbm
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.tools.bench.sgm import bench_pair
method, w, h, n, paths, threads = sys.argv[1], *map(int, sys.argv[2:])
cv2.setNumThreads(threads)
numba.set_num_threads(threads)
left, right = bench_pair(w, h)
if method == 'ours':
    SgmMatcher(SgmParams(disparity_range=n, paths=paths)).match(left, right)
elif method != 'idle':
    opencv_sgbm(left, right, TUNED_HH if method == 'hh' else TUNED_SGBM, disparity_range=n)
# VmHWM, not ru_maxrss: the latter carries the parent's peak across fork and exec
peak = [line for line in open('/proc/self/status') if line.startswith('VmHWM:')]
print(json.dumps(int(peak[0].split()[1]) / 1024))
'''


def peak_memory(width: int, height: int, disparities: int, paths: int,
                threads: int) -> dict[str, float]:
    """Peak RSS in MB of a fresh interpreter matching one frame, per method (and of one
    that loads the same modules and pair but matches nothing: ``idle``)."""
    import json
    import subprocess
    import sys

    peaks = {}
    for method in ('idle', 'ours', 'hh', 'sgbm'):
        out = subprocess.run([sys.executable, '-c', _PEAK, method, str(width), str(height),
                              str(disparities), str(paths), str(threads)],
                             capture_output=True, text=True, check=True).stdout
        peaks[method] = float(json.loads(out.strip().splitlines()[-1]))
    return peaks


def bench_pair(width: int = 640, height: int = 480) -> tuple[Any, Any]:
    """The bundled rectified pair, resized to ``width`` x ``height`` when that differs
    (disparities then scale with the width)."""
    left, right = _bundled_pair()
    if left.shape != (height, width):
        size = (width, height)
        left, right = (cv2.resize(img, size, interpolation=cv2.INTER_LINEAR)
                       for img in (left, right))
    return left, right


def busy_loops(count: int) -> list[Any]:
    """Start ``count`` processes that each keep a core busy (a plain loop), as other work
    on a robot's computer would; the caller terminates them."""
    import subprocess
    import sys

    return [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(count)]


def kernel_limits(width: int = 640, height: int = 480,
                  disparities: int = 128) -> dict[str, float]:
    """Is the path recurrence bound by memory bandwidth or by arithmetic? The downward
    sweep (3 directions, one thread) over a whole random volume of this size, the same
    number of rows swept from one 8-row band again and again (3.5 MB with its path rows at
    640x480x128: in the caches, not DRAM), and a plain memory copy for the bandwidth the
    machine offers one thread."""
    import numba

    from depth_nodes.core.sgm.aggregate import new_line_buffers, p2_table, sweep_down

    rng = np.random.default_rng(0)
    h, w, n = height, width, disparities
    cost = rng.integers(0, 60, (h, w, n), dtype=np.uint8)
    image = (rng.random((h, w)) * 255).astype(np.float32)
    dxs, dys = np.array([0, 1, -1]), np.array([1, 1, 1])
    table = p2_table(18, 220, 8.0)
    (lb0, lb1, lb2), mbuf = new_line_buffers(3, w, n)
    partial = np.empty_like(cost, np.uint16)
    rows = min(8, h)

    def sweep(volume: Any, out: Any, count: int, repeats: int) -> None:
        for _ in range(repeats):
            sweep_down(volume, image, 0, count, dxs, dys, 18, 220, table, lb0, lb1, lb2,
                       mbuf, out)

    source = np.ones(cost.nbytes + partial.nbytes, np.uint8)
    target = np.empty_like(source)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        ms = median_ms({
            'whole': lambda: sweep(cost, partial, h, 1),
            'cached': lambda: sweep(cost[:rows], partial[:rows], rows, h // rows),
            'copy': lambda: np.copyto(target, source),
        }, 3)
    finally:
        numba.set_num_threads(threads)
    return {'whole_ms': ms['whole'],
            'cached_ms': ms['cached'] * h / (h // rows * rows),
            'volume_gbs': (cost.nbytes + partial.nbytes) / ms['whole'] / 1e6,
            'copy_gbs': 2 * source.nbytes / ms['copy'] / 1e6}


def bench_sgm(*, repeats: int = 10, disparities: int = 128, paths: int = 8,
              size: tuple[int, int] = (640, 480), busy: int = 0, memory: bool = True,
              cold_start: bool = True) -> SgmBench:
    """Time census SGM against OpenCV MODE_HH and MODE_SGBM on the same pair; with
    ``busy``, again with that many cores kept busy by other processes."""
    import numba

    from depth_nodes.core.opencv_stereo import TUNED_HH, TUNED_SGBM, opencv_sgbm
    from depth_nodes.core.sgm import SgmMatcher, SgmParams

    w, h = size
    left, right = bench_pair(w, h)
    threads = numba.get_num_threads()
    matcher = SgmMatcher(SgmParams(disparity_range=disparities, paths=paths))
    coarse = SgmMatcher(SgmParams(disparity_range=disparities, paths=paths,
                                  disparity_search='coarse'))

    def one_thread() -> None:
        numba.set_num_threads(1)
        try:
            matcher.match(left, right)
        finally:
            numba.set_num_threads(threads)

    fns = {
        'ours': lambda: matcher.match(left, right),
        'coarse': lambda: coarse.match(left, right),
        'hh': lambda: opencv_sgbm(left, right, TUNED_HH, disparity_range=disparities),
        'sgbm': lambda: opencv_sgbm(left, right, TUNED_SGBM, disparity_range=disparities),
    }
    ms = median_ms(fns, repeats, settle=0.05)
    busy_ms = None
    if busy:
        loops = busy_loops(busy)
        try:
            time.sleep(0.5)  # let them take their cores
            contended = {k: f for k, f in fns.items() if k != 'coarse'}
            busy_ms = median_ms({**contended, 'ours_1': one_thread}, repeats, settle=0.05)
        finally:
            for loop in loops:
                loop.kill()
                loop.wait()
    return SgmBench(w, h, disparities, paths, repeats, threads, ms['ours'], ms['hh'],
                    ms['sgbm'], matcher.workspace_bytes / 1e6,
                    peak_memory(w, h, disparities, paths, threads) if memory else {},
                    cold_start_sgm() if cold_start else {},
                    kernel_limits(), busy, busy_ms, ms['coarse'], coarse.search_cells,
                    coarse.fallbacks)
