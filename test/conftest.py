"""Shared fixtures: every test graph gets its own ROS_DOMAIN_ID, discovery stays local."""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from depth_nodes.ros.dds import use_large_message_profile

REPO = Path(__file__).resolve().parents[1]
TEST_DIR = Path(__file__).resolve().parent

# This process publishes 640x480 images into live graphs too (the live-graph and campaign
# tests' feeders), so it takes the same Fast DDS profile as every depth_nodes process,
# before any rclpy.init. Without it, its 512 KiB default shared-memory segment holds one
# 300 KB image at a time and best-effort readers lose what does not fit (README, "QoS,
# middleware and time"); the likeliest cause of a CI run in which the composed pipeline
# got this process's camera_info but none of its images for 120 s.
use_large_message_profile()

# Domain IDs 1..100 are valid everywhere; start at a pid-dependent offset so that two test
# sessions running at once are unlikely to share one, and never reuse one within a session.
_DOMAINS = itertools.cycle([1 + (os.getpid() + i) % 100 for i in range(100)])


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment of an isolated ROS graph, applied to this process and returned for
    subprocesses: a fresh ROS_DOMAIN_ID, localhost-only discovery, the test nodes importable.
    """
    domain = str(next(_DOMAINS))
    monkeypatch.setenv('ROS_DOMAIN_ID', domain)
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.delenv('ROS_STATIC_PEERS', raising=False)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(TEST_DIR), env.get('PYTHONPATH')]))
    return env


#: Seconds a node process may take to start (imports, numba cache) before a fixture gives up.
START_TIMEOUT = 120.0


def graph_env() -> dict[str, str]:
    """Environment of a fresh isolated graph (as ros_env, but not tied to one test): its
    own ROS_DOMAIN_ID, localhost-only discovery, the test nodes importable."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(next(_DOMAINS))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(TEST_DIR), env.get('PYTHONPATH')]))
    return env


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


@pytest.fixture
def context(ros_env: dict[str, str]) -> Iterator[Context]:
    """An initialised rclpy context on the test's own ROS_DOMAIN_ID."""
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    yield ctx
    rclpy.shutdown(context=ctx)


def set_parameters(peer: Any, executor: Any, node: str, **values: Any) -> list[SetParametersResult]:
    """Set parameters of ``node`` through its standard set_parameters service, as
    `ros2 param set` does, spinning ``executor`` until the answer arrives."""
    client = peer.create_client(SetParameters, f'{node}/set_parameters')
    assert client.wait_for_service(timeout_sec=30)
    request = SetParameters.Request()
    request.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    future = client.call_async(request)
    executor.spin_until_future_complete(future, timeout_sec=30)
    assert future.done(), f'{node}/set_parameters did not answer'
    return list(future.result().results)


@contextlib.contextmanager
def tuner(node: Any, context: Context) -> Iterator[Callable[..., list[SetParametersResult]]]:
    """A peer node and executor around ``node``; yields ``tune(**values)``, which sets
    ``node``'s parameters through its set_parameters service (see :func:`set_parameters`)."""
    peer = rclpy.create_node('tuner', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    try:
        yield lambda **values: set_parameters(peer, executor,
                                              node.get_fully_qualified_name(), **values)
    finally:
        executor.shutdown()
        peer.destroy_node()


#: Disparity window per bundled stereo bag: 128 at 640 px, 64 on the 320 px ones (OpenCV is
#: always given the same window as ours).
STEREO_RANGES = {'stereo_vga': 128, 'stereo_qvga_color': 64, 'stereo_qvga_fisheye': 64}


@pytest.fixture(autouse=True)
def thread_settings() -> Iterator[None]:
    """Restore this thread's numba threads and OpenCV's after every test: a node's frame
    sets them (its `threads` parameter), and later tests must not inherit that."""
    import cv2
    import numba

    numba_threads, cv2_threads = numba.get_num_threads(), cv2.getNumThreads()
    yield
    numba.set_num_threads(numba_threads)
    cv2.setNumThreads(cv2_threads)


def _replay_bundled(tmp_path_factory: pytest.TempPathFactory,
                    sgm: dict[str, int]) -> dict[str, tuple[Path, Any]]:
    """Every bundled stereo bag through config/stereo_pipeline.yaml (rectify -> sgm_stereo
    -> cross_check -> point_cloud), the SGM node's parameters overridden by ``sgm`` and its
    disparity window set per bag, scored by eval: ``{bag: (output bag, EvalReport)}``."""
    from depth_nodes.graph.description import load_graph_config
    from depth_nodes.tools.bags.process import process_bag
    from depth_nodes.tools.evaluation.evaluate import evaluate_bag

    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    out = {}
    for name, disparities in STEREO_RANGES.items():
        folder = tmp_path_factory.mktemp(name)
        params = folder / 'params.yaml'
        values = ', '.join(f'{k}: {v}' for k, v in {**sgm, 'disparity_range': disparities}.items())
        params.write_text(f'sgm_stereo:\n  ros__parameters: {{{values}}}\n')
        report = process_bag(REPO / 'bags' / name, folder / 'out', config=config,
                             params_file=params)
        assert sum(sum(c.values()) for c in report.drops.values()) == 0, report.format()
        out[name] = (folder / 'out', evaluate_bag(folder / 'out'))
    return out


@pytest.fixture(scope='session')
def stereo_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Any]]:
    """The bundled bags through the shipped stereo graph as it is (5 paths). Shared by the
    accuracy tests."""
    return _replay_bundled(tmp_path_factory, {})


@pytest.fixture(scope='session')
def stereo_reports_8_paths(tmp_path_factory: pytest.TempPathFactory
                           ) -> dict[str, tuple[Path, Any]]:
    """The same with ``paths: 8``, the most accurate setting the README also reports."""
    return _replay_bundled(tmp_path_factory, {'paths': 8})


#: The real pairs of test/data (Middlebury 2003, quarter size; README there), all searched
#: with 64 disparities.
REAL_PAIRS = ('teddy', 'cones')
REAL_DATA = TEST_DIR / 'data' / 'middlebury2003'


def import_real_pair(name: str, out: Path) -> Path:
    """Import a pair of test/data as a bag (colour images, ground truth of both views)."""
    from depth_nodes.tools.bags.pairs import PairSource, import_pair

    folder = REAL_DATA / name
    import_pair(PairSource(folder / 'im2.png', folder / 'im6.png',
                           ground_truth=folder / 'disp2.pgm', gt_scale=4.0,
                           ground_truth_right=folder / 'disp6.pgm'), out)
    return out


def _replay_real(tmp_path_factory: pytest.TempPathFactory,
                 sgm: dict[str, Any]) -> dict[str, tuple[Path, Any]]:
    """Every real pair through the shipped stereo graph with a 64-disparity window (and
    ``sgm`` overriding the matcher's parameters), scored by eval."""
    from depth_nodes.graph.description import load_graph_config
    from depth_nodes.tools.bags.process import process_bag
    from depth_nodes.tools.evaluation.evaluate import evaluate_bag

    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    out = {}
    for name in REAL_PAIRS:
        folder = tmp_path_factory.mktemp(name)
        bag = import_real_pair(name, folder / 'in')
        params = folder / 'params.yaml'
        values = ', '.join(f'{k}: {v}' for k, v in {**sgm, 'disparity_range': 64}.items())
        params.write_text(f'sgm_stereo:\n  ros__parameters: {{{values}}}\n')
        report = process_bag(bag, folder / 'out', config=config, params_file=params)
        assert sum(sum(c.values()) for c in report.drops.values()) == 0, report.format()
        out[name] = (folder / 'out', evaluate_bag(folder / 'out'))
    return out


@pytest.fixture(scope='session')
def real_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Any]]:
    """Teddy and Cones through the shipped graph (5 paths), scored by eval."""
    return _replay_real(tmp_path_factory, {})


@pytest.fixture(scope='session')
def real_reports_8_paths(tmp_path_factory: pytest.TempPathFactory
                         ) -> dict[str, tuple[Path, Any]]:
    """The same with ``paths: 8``."""
    return _replay_real(tmp_path_factory, {'paths': 8})
