"""`depth-nodes bench sgm`: the census SGM matcher beside OpenCV's StereoSGBM (MODE_HH and
MODE_SGBM), measured in the same run on the bundled pair.

Times are medians over interleaved rounds after one warm-up round; besides them: the
matcher's buffers, the peak memory of a fresh process matching one frame, the cold start,
what bounds the path recurrence, and (``busy``) the times with cores taken by other
processes.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numba
import numpy as np

from depth_nodes.core.opencv_stereo import TUNED_HH, TUNED_SGBM, opencv_sgbm
from depth_nodes.core.rectify import rectify_image
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.aggregate import new_line_buffers, p2_table, sweep_down
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bench.timing import median_ms

#: The bundled pair the matcher is timed on.
BUNDLED_PAIR = Path(__file__).resolve().parents[3] / 'bags' / 'stereo_vga'


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
    #: Ours with ``matching_cost`` learned and census+learned (ms; 0: not run).
    learned_ms: dict[str, float] = field(default_factory=dict)

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
        for cost, ms in self.learned_ms.items():
            lines.insert(4, f'  SGM, {cost + " cost":<22}{ms:8.1f} ms   ours / MODE_SGBM = '
                         f'{ms / self.sgbm_ms:5.2f}   (matching_cost {cost}: '
                         f'{ms / self.ours_ms:4.2f} x census)')
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
    first: dict[str, Any] = {}
    with BagReader(BUNDLED_PAIR) as reader:
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
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(count)]


def kernel_limits(width: int = 640, height: int = 480,
                  disparities: int = 128) -> dict[str, float]:
    """Is the path recurrence bound by memory bandwidth or by arithmetic? The downward
    sweep (3 directions, one thread) over a whole random volume of this size, the same
    number of rows swept from one 8-row band again and again (3.5 MB with its path rows at
    640x480x128: in the caches, not DRAM), and a plain memory copy for the bandwidth the
    machine offers one thread."""
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


def _timed_match(matcher: SgmMatcher, left: Any, right: Any) -> Any:
    """What :func:`median_ms` times: one match of the pair."""
    return lambda: matcher.match(left, right)


def bench_sgm(*, repeats: int = 10, disparities: int = 128, paths: int = 8,
              size: tuple[int, int] = (640, 480), busy: int = 0, memory: bool = True,
              cold_start: bool = True) -> SgmBench:
    """Time census SGM against OpenCV MODE_HH and MODE_SGBM on the same pair; with
    ``busy``, again with that many cores kept busy by other processes."""
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

    learned = {cost: SgmMatcher(SgmParams(disparity_range=disparities, paths=paths,
                                          matching_cost=cost))
               for cost in ('learned', 'census+learned')}
    fns = {
        'ours': lambda: matcher.match(left, right),
        'coarse': lambda: coarse.match(left, right),
        **{cost: _timed_match(m, left, right) for cost, m in learned.items()},
        'hh': lambda: opencv_sgbm(left, right, TUNED_HH, disparity_range=disparities),
        'sgbm': lambda: opencv_sgbm(left, right, TUNED_SGBM, disparity_range=disparities),
    }
    ms = median_ms(fns, repeats, settle=0.05)
    busy_ms = None
    if busy:
        loops = busy_loops(busy)
        try:
            time.sleep(0.5)  # let them take their cores
            contended = {k: f for k, f in fns.items() if k not in ('coarse', *learned)}
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
                    coarse.fallbacks, {cost: ms[cost] for cost in learned})
