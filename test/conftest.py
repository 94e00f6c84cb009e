"""Shared fixtures: every test graph gets its own ROS_DOMAIN_ID, discovery stays local."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.parameter import Parameter

REPO = Path(__file__).resolve().parents[1]
TEST_DIR = Path(__file__).resolve().parent

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


def run_cli(args: list[str], env: dict[str, str] | None = None,
            timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run `depth-nodes ARGS` in a subprocess, as a user would."""
    return subprocess.run(
        [sys.executable, '-m', 'depth_nodes.tools.cli', *args],
        capture_output=True, text=True, env=env, timeout=timeout, cwd=REPO, check=False,
    )


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
