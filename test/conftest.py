"""Fixtures shared by every test folder. Helpers are plain modules beside this file
(helpers.py without ROS, ros_helpers.py with rclpy); rclpy is imported only by the fixtures
that start a ROS context, so the core tests run without ROS installed."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers import REAL_PAIRS, REPO, STEREO_RANGES, import_real_pair, isolated, next_domain

from depth_nodes.ros.dds import use_large_message_profile

# This process publishes 640x480 images into live graphs too (the live-graph and campaign
# tests' feeders), so it takes the same Fast DDS profile as every depth_nodes process,
# before any rclpy.init. Without it, its 512 KiB default shared-memory segment holds one
# 300 KB image at a time and best-effort readers lose what does not fit (README, "QoS,
# middleware and time"); the likeliest cause of a CI run in which the composed pipeline
# got this process's camera_info but none of its images for 120 s.
use_large_message_profile()


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """Environment of an isolated ROS graph, applied to this process and returned for
    subprocesses: a fresh ROS_DOMAIN_ID, localhost-only discovery, the test nodes importable.
    """
    env = isolated(dict(os.environ), next_domain())
    for name in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE'):
        monkeypatch.setenv(name, env[name])
    monkeypatch.delenv('ROS_STATIC_PEERS', raising=False)
    return env


@pytest.fixture
def context(ros_env: dict[str, str]) -> Iterator[Any]:
    """An initialised rclpy context on the test's own ROS_DOMAIN_ID."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(args=[], context=ctx)
    yield ctx
    rclpy.shutdown(context=ctx)


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


def _replay(tmp_path_factory: pytest.TempPathFactory, bags: dict[str, tuple[Any, int]],
            sgm: dict[str, Any]) -> dict[str, tuple[Path, Any]]:
    """Each bag of ``bags`` (``{name: (bag or a function making it in a folder, disparity
    window)}``) through config/stereo_pipeline.yaml (rectify -> sgm_stereo -> cross_check
    -> point_cloud), the SGM node's parameters overridden by ``sgm``, scored by eval:
    ``{name: (output bag, EvalReport)}``."""
    from depth_nodes.graph.description import load_graph_config
    from depth_nodes.tools.bags.process import process_bag
    from depth_nodes.tools.evaluation.evaluate import evaluate_bag

    config = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    out = {}
    for name, (source, disparities) in bags.items():
        folder = tmp_path_factory.mktemp(name)
        bag = source(folder / 'in') if callable(source) else source
        params = folder / 'params.yaml'
        values = ', '.join(f'{k}: {v}' for k, v in {**sgm, 'disparity_range': disparities}.items())
        params.write_text(f'sgm_stereo:\n  ros__parameters: {{{values}}}\n')
        report = process_bag(bag, folder / 'out', config=config, params_file=params)
        assert sum(sum(c.values()) for c in report.drops.values()) == 0, report.format()
        out[name] = (folder / 'out', evaluate_bag(folder / 'out'))
    return out


#: The bundled stereo bags, each with its disparity window.
BUNDLED = {name: (REPO / 'bags' / name, n) for name, n in STEREO_RANGES.items()}
#: The real pairs of test/data, imported on use, all searched with 64 disparities.
REAL = {name: (lambda out, name=name: import_real_pair(name, out), 64) for name in REAL_PAIRS}


@pytest.fixture(scope='session')
def stereo_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Any]]:
    """The bundled bags through the shipped stereo graph as it is (5 paths). Shared by the
    accuracy tests."""
    return _replay(tmp_path_factory, BUNDLED, {})


@pytest.fixture(scope='session')
def stereo_reports_8_paths(tmp_path_factory: pytest.TempPathFactory
                           ) -> dict[str, tuple[Path, Any]]:
    """The same with ``paths: 8``, the most accurate setting the README also reports."""
    return _replay(tmp_path_factory, BUNDLED, {'paths': 8})


@pytest.fixture(scope='session')
def real_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Any]]:
    """Teddy and Cones through the shipped graph (5 paths), scored by eval."""
    return _replay(tmp_path_factory, REAL, {})


@pytest.fixture(scope='session')
def real_reports_8_paths(tmp_path_factory: pytest.TempPathFactory
                         ) -> dict[str, tuple[Path, Any]]:
    """The same with ``paths: 8``."""
    return _replay(tmp_path_factory, REAL, {'paths': 8})
