"""Helpers shared by the tests, without ROS: the repository's paths, isolated graph
environments for subprocesses, the CLI as a user runs it, the real pairs of test/data.

``pytest.ini`` puts this folder on ``sys.path``, so any test imports ``from helpers
import ...`` (fixtures live in the conftest files)."""

from __future__ import annotations

import fcntl
import itertools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, TypeVar

from depth_nodes.core.jit import JIT_ENABLED

T = TypeVar('T')

REPO = Path(__file__).resolve().parents[1]
TEST_DIR = Path(__file__).resolve().parent

#: Seconds a node process may take to start (imports, numba cache) before a test gives up.
START_TIMEOUT = 120.0

#: Disparity window per bundled stereo bag: 128 at 640 px, 64 on the 320 px ones (OpenCV is
#: always given the same window as ours).
STEREO_RANGES = {'stereo_vga': 128, 'stereo_qvga_color': 64, 'stereo_qvga_fisheye': 64}

#: The real pairs of test/data (Middlebury 2003, quarter size; README there), all searched
#: with 64 disparities.
REAL_PAIRS = ('teddy', 'cones')
REAL_DATA = TEST_DIR / 'data' / 'middlebury2003'


def _domains() -> list[int]:
    """This process's ROS_DOMAIN_IDs: 1..100, split between the workers of a parallel run
    (pytest-xdist) so that two workers never share one, each worker's share started at a
    pid-dependent offset so that two test sessions running at once are unlikely to share
    one either. Not above 101: Fast DDS's ports for a higher domain fall in Linux's
    ephemeral range (32768 - 60999), where another socket may hold one (ROS 2's "About
    Domain ID")."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    count = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    span = 100 // max(count, 1)
    base = 1 + int(worker.removeprefix('gw') or 0) * span
    return [base + (os.getpid() + i) % span for i in range(span)]


_DOMAINS = itertools.cycle(_domains())


def next_domain() -> str:
    """The next ROS_DOMAIN_ID of this worker's share, in turn: one comes round again after
    as many graphs as the share holds (50 on two workers), long after its graph stopped."""
    return str(next(_DOMAINS))


#: Where Fast DDS keeps its shared-memory segments and ports.
SHM = Path('/dev/shm')


def fast_dds_files() -> set[str]:
    """Fast DDS's files in /dev/shm: segments, ports, their lock files and mutexes."""
    if not SHM.is_dir():
        return set()
    return {p.name for p in SHM.iterdir() if p.name.startswith(('fastrtps_', 'sem.fastrtps_'))}


def _held(name: str) -> bool:
    """Whether a live process holds segment or port ``name``: Fast DDS keeps an flock on
    ``<name>_el`` for as long as the segment's owner lives."""
    try:
        fd = os.open(SHM / f'{name}_el', os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


def orphaned(names: set[str]) -> set[str]:
    """The segments and ports among ``names`` that no live process holds: what a process
    that died without cleaning up leaves behind. Segments of processes that are still
    running (another test worker's, say) are not counted; one seen without its lock file
    is looked at again a moment later, as its owner may be creating or removing it."""
    def unheld() -> set[str]:
        return {n for n in names if n.startswith('fastrtps_') and
                not n.endswith(('_el', '_sl')) and (SHM / n).exists() and not _held(n)}

    first = unheld()
    if first:
        time.sleep(0.5)
    return first & unheld()


def held_by(pid: int) -> set[str]:
    """The Fast DDS segments and ports that process ``pid`` holds (its flocks in
    /proc/locks on their ``_el`` files)."""
    inodes = set()
    with open('/proc/locks') as locks:
        for line in locks:
            fields = line.split()  # 1: FLOCK ADVISORY WRITE <pid> <dev>:<inode> 0 EOF
            if len(fields) > 5 and fields[1] == 'FLOCK' and fields[4] == str(pid):
                inodes.add(int(fields[5].rsplit(':', 1)[1]))
    return {p.name.removesuffix('_el') for p in SHM.glob('fastrtps_*_el')
            if p.stat().st_ino in inodes} if SHM.is_dir() else set()


def isolated(env: dict[str, str], domain: str) -> dict[str, str]:
    """``env`` for an isolated ROS graph: ``domain``, localhost-only discovery, no static
    peers, and this folder importable (the test nodes of harness_nodes.py)."""
    env = dict(env)
    env['ROS_DOMAIN_ID'] = domain
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(TEST_DIR), env.get('PYTHONPATH')]))
    return env


def graph_env() -> dict[str, str]:
    """Environment of a fresh isolated graph, for subprocesses (not tied to one test)."""
    return isolated(dict(os.environ), next_domain())


def run_cli(args: list[str], env: dict[str, str] | None = None,
            timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run `depth-nodes ARGS` in a subprocess, as a user would."""
    return subprocess.run(
        [sys.executable, '-m', 'depth_nodes.tools.cli', *args],
        capture_output=True, text=True, env=env, timeout=timeout, cwd=REPO, check=False,
    )


def interrupt(proc: subprocess.Popen[Any], timeout: float = 30) -> str:
    """Stop a node process with Ctrl-C, as a user does, and return what it printed (when
    its output is a pipe). A clean shutdown removes the process's Fast DDS shared-memory
    segment; one still running after ``timeout`` seconds is killed (exit status -9), which
    leaves its 64 MiB segment in /dev/shm."""
    proc.send_signal(signal.SIGINT)
    try:
        output, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        output, _ = proc.communicate()
    return output or ''


def import_real_pair(name: str, out: Path) -> Path:
    """Import a pair of test/data as a bag (colour images, ground truth of both views)."""
    from depth_nodes.tools.bags.pairs import PairSource, import_pair

    folder = REAL_DATA / name
    import_pair(PairSource(folder / 'im2.png', folder / 'im6.png',
                           ground_truth=folder / 'disp2.pgm', gt_scale=4.0,
                           ground_truth_right=folder / 'disp6.pgm'), out)
    return out


class Lazy:
    """A module's test data (a simulated frame, a match) made on first use and kept for the
    session: collecting or deselecting the module's tests costs nothing.

    ``FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))``; then ``FRAME.left_raw``.
    """

    def __init__(self, make: Any) -> None:
        self._make = make
        self._value: Any = None

    def __getattr__(self, name: str) -> Any:
        if name.startswith('_'):  # pytest's collection probes module attributes
            # (``_mock_name``, ``__wrapped__``): no reason to make the data
            raise AttributeError(name)
        if self._value is None:
            self._value = self._make()
        return getattr(self._value, name)


#: The numba kernels run as plain Python: ``NUMBA_DISABLE_JIT=1``, under which the tests
#: marked ``kernels`` run again (test/packaging/test_kernels_without_jit.py), about a
#: thousand times slower than compiled.
JIT_OFF = not JIT_ENABLED


def kernel_size(compiled: T, interpreted: T) -> T:
    """What drives a kernel test's time (an image size, a disparity range, the cases of a
    parametrisation): ``compiled`` as usual, the smaller ``interpreted`` with the JIT off,
    so that the plain-Python run of the kernels stays short."""
    return interpreted if JIT_OFF else compiled


#: The structured-light node's plugin name.
SL_PLUGIN = 'depth_nodes.nodes.structured_light:StructuredLightNode'


def small_sl_graph(bag: Path) -> Any:
    """The structured-light graph for the small simulated bags of the tests (4 phase
    steps, period 8, and the speckle node with the bag's reference): a GraphConfig,
    imported here so that this module stays free of ROS."""
    from depth_nodes.graph.description import GraphConfig, NodeSpec
    from depth_nodes.tools.bags.structured_light import REFERENCE_FILE

    return GraphConfig('sl', [
        NodeSpec('structured_light', SL_PLUGIN, '/sl', {'phase_steps': 4, 'phase_period': 8.0},
                 {'image': 'image_raw'}),
        NodeSpec('speckle', SL_PLUGIN, '/sl/speckle',
                 {'mode': 'speckle', 'speckle_reference': str(bag / REFERENCE_FILE),
                  'speckle_window': 9},
                 {'image': 'image_raw', 'projector/camera_info': '/sl/projector/camera_info'}),
    ])


def interrupt_once_written(args: list[str], path: Path, *, settle: float = 0.0,
                           timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run `depth-nodes ARGS`, send it Ctrl-C (SIGINT) once ``path`` exists (and ``settle``
    seconds more), and return what it printed and its exit code; fails when ``path`` never
    appears."""
    proc = subprocess.Popen([sys.executable, '-m', 'depth_nodes.tools.cli', *args], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + timeout
        while not path.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert path.exists(), proc.stderr.read() if proc.stderr else ''
        time.sleep(settle)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
