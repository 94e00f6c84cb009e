"""The composed pipeline (`depth-nodes pipeline`) live, reconfigured while frames flow.

The whole stereo graph runs in one process started as a user would; this test publishes
frames into it over DDS, one at a time, and between two frames changes matcher and
point-cloud parameters with `depth-nodes param set`. Each published disparity is compared
with the matcher run here on the rectified images the graph published, with the
parameters that must have applied: the old ones up to the change, the new ones from the
next frame on. An invalid value is refused with its reason and changes nothing.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from helpers import REPO, interrupt, run_cli
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.graph.description import load_graph_config
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.tools.live.processes import StereoFeeder, StereoFrame, load_stereo_frames

pytestmark = [pytest.mark.ros, pytest.mark.slow]

WATCH = ['/stereo/left/image_rect', '/stereo/right/image_rect', '/stereo/disparity',
         '/stereo/points2']
SGM = '/stereo/sgm_stereo'
#: The shipped graph's matcher: SgmParams' defaults but for its path count.
SHIPPED_PATHS = next(n for n in load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml').nodes
                     if n.plugin == 'sgm_stereo').parameters['paths']


class _Live:
    def __init__(self, feeder: StereoFeeder, frames: list[StereoFrame],
                 pipeline: subprocess.Popen[str], env: dict[str, str], log: Path) -> None:
        self.feeder = feeder
        self.frames = frames
        self.pipeline = pipeline
        self.env = env
        self.log = log
        self.clients: dict[str, Any] = {}
        self.spinner: threading.Thread
        self.stamp = 10 * 1_000_000_000

    def frame(self, index: int, timeout: float = 120) -> int:
        """Publish frame ``index`` and wait for all its outputs; returns its stamp.
        A frame lost on the way (none should be) is published again, newer."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.stamp += 200_000_000
            self.feeder.publish(self.frames[index % len(self.frames)], self.stamp)
            retry = time.monotonic() + 5
            while time.monotonic() < retry:
                assert self.pipeline.poll() is None, self.log.read_text()
                assert self.spinner.is_alive(), 'the test\'s executor thread died'
                if self.feeder.complete(self.stamp):
                    return self.stamp
                time.sleep(0.02)
        arrived = {t: sorted(a)[-3:] for t, a in self.feeder.arrived.items()}
        raise AssertionError(f'no complete output within {timeout} s (last stamp '
                             f'{self.stamp}; latest arrivals {arrived}); the pipeline '
                             f'printed:\n{self.log.read_text()[-4000:]}')

    def param(self, *args: str) -> subprocess.CompletedProcess[str]:
        """`depth-nodes param ARGS`, as a user types it."""
        return run_cli(['param', *args], env=self.env, timeout=120)

    def set(self, node: str, **values: Any) -> list[Any]:
        """Set parameters through the node's set_parameters service from this process
        (what `param set` does, without starting a process per value).

        Clients are kept: destroying one while the executor thread waits on it can break
        that thread."""
        if node not in self.clients:
            self.clients[node] = self.feeder.node.create_client(SetParameters,
                                                                f'{node}/set_parameters')
        client = self.clients[node]
        assert client.wait_for_service(timeout_sec=30)
        request = SetParameters.Request(parameters=[
            Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        future = client.call_async(request)
        deadline = time.monotonic() + 30
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert future.done(), f'{node}/set_parameters did not answer'
        return list(future.result().results)

    def disparity(self, stamp: int) -> Any:
        return read_disparity(self.feeder.message('/stereo/disparity', stamp, DisparityImage))

    def expected(self, stamp: int, **params: Any) -> np.ndarray:
        """The matcher run here on the graph's own rectified images of ``stamp``."""
        left, right = (image_to_array(self.feeder.message(f'/stereo/{side}/image_rect',
                                                          stamp, Image))
                       for side in ('left', 'right'))
        return SgmMatcher(SgmParams(**{'paths': SHIPPED_PATHS, **params})).match(
            left, right).disparity

    def cloud_z(self, stamp: int) -> np.ndarray:
        cloud = read_pointcloud(self.feeder.message('/stereo/points2', stamp, PointCloud2))
        z = np.asarray(cloud['z'], np.float64)
        return z[np.isfinite(z)]


@pytest.fixture(scope='module')
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[_Live]:
    from helpers import next_domain

    patch = pytest.MonkeyPatch()
    patch.setenv('ROS_DOMAIN_ID', str(next_domain()))
    patch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    patch.delenv('ROS_STATIC_PEERS', raising=False)
    env = dict(os.environ)
    log = tmp_path_factory.mktemp('live') / 'pipeline.log'
    with log.open('w') as stream:
        pipeline = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'pipeline', '--config',
             str(REPO / 'config' / 'stereo_pipeline.yaml')],
            stdout=stream, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
    context = Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node('live_graph_test', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    feeder = StereoFeeder(node, '/stereo', WATCH, keep_data=True)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + 120
        while not feeder.graph_ready():
            assert pipeline.poll() is None, log.read_text()
            assert time.monotonic() < deadline, 'the composed graph did not connect'
            time.sleep(0.05)
        state = _Live(feeder, load_stereo_frames(REPO / 'bags' / 'stereo_vga'), pipeline, env,
                      log)
        state.spinner = spinner
        state.frame(0, timeout=300)  # warm-up: numba may compile on a fresh clone
        yield state
    finally:
        interrupt(pipeline)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        spinner.join(timeout=5)
        patch.undo()


def _same(got: np.ndarray, want: np.ndarray) -> None:
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got[~np.isnan(got)], want[~np.isnan(want)])


def test_matcher_parameters_apply_from_the_next_frame(live: _Live) -> None:
    before = live.frame(1)
    changed = live.param('set', SGM, 'P2', '400')
    assert changed.returncode == 0, changed.stderr
    assert changed.stdout.strip() == 'Set parameter successful'
    results = live.set(SGM, disparity_range=96, uniqueness_ratio=5.0)
    assert all(r.successful for r in results), results
    after = live.frame(1)
    old, new = live.disparity(before), live.disparity(after)
    assert (old.min_disparity, old.max_disparity) == (0, 127)
    assert (new.min_disparity, new.max_disparity) == (0, 95)
    _same(old.disparity, live.expected(before))
    _same(new.disparity, live.expected(after, P2=400, disparity_range=96, uniqueness_ratio=5))
    # the change is visible in the output itself, not only in the metadata
    assert np.nanmax(new.disparity) <= 95
    assert np.isnan(new.disparity).sum() != np.isnan(old.disparity).sum()
    results = live.set(SGM, P2=220.0, disparity_range=128, uniqueness_ratio=10.0)
    assert all(r.successful for r in results), results
    restored = live.frame(1)
    _same(live.disparity(restored).disparity, live.expected(restored))


def test_an_invalid_value_is_refused_and_changes_nothing(live: _Live) -> None:
    refused = live.param('set', SGM, 'P1', '500')  # above P2 (220)
    assert refused.returncode == 1
    assert 'Setting parameter failed: SGM parameter P2=220: must be >= P1 (500)' in refused.stderr
    assert live.param('get', SGM, 'P1').stdout.strip() == 'Double value is: 18.0'
    (out_of_range,) = live.set(SGM, disparity_range=0)
    assert not out_of_range.successful
    assert 'out of range' in out_of_range.reason
    stamp = live.frame(0)
    _same(live.disparity(stamp).disparity, live.expected(stamp))


def test_point_cloud_parameters_apply_from_the_next_frame(live: _Live) -> None:
    before = live.frame(0)
    z = live.cloud_z(before)
    limit = float(np.median(z))
    (result,) = live.set('/stereo/point_cloud', max_range=round(limit, 3))
    assert result.successful, result.reason
    after = live.frame(0)
    (result,) = live.set('/stereo/point_cloud', max_range=0.0)
    assert result.successful, result.reason
    z_after = live.cloud_z(after)
    assert z.max() > limit
    assert z_after.max() <= round(limit, 3) + 1e-6
    # same images, same disparity: exactly the points within the limit are kept
    assert z_after.size == int((z <= round(limit, 3)).sum())
