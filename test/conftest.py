"""Shared fixtures: every test graph gets its own ROS_DOMAIN_ID, discovery stays local."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

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
