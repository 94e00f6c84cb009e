"""The layers hold: core and sim run without ROS (a user of the Python API needs no ROS
install), and so do their tests."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import REPO

pytestmark = pytest.mark.slow

#: Make rclpy (and the message packages) unimportable before anything else is imported.
WITHOUT_ROS = ("import sys\n"
               "for name in ('rclpy', 'sensor_msgs', 'stereo_msgs', 'std_msgs'):\n"
               "    sys.modules[name] = None\n")


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-c', WITHOUT_ROS + code], capture_output=True,
                          text=True, cwd=REPO, check=False, timeout=600)


def test_core_and_sim_import_without_ros() -> None:
    modules = sorted(
        '.'.join(p.relative_to(REPO).with_suffix('').parts)
        for folder in ('core', 'sim') for p in (REPO / 'depth_nodes' / folder).rglob('*.py'))
    assert len(modules) > 20
    result = _run(''.join(f'import {m}\n' for m in modules))
    assert result.returncode == 0, result.stderr


def test_the_core_and_sim_tests_run_without_ros() -> None:
    result = _run('import pytest\n'
                  "sys.exit(pytest.main(['-q', 'test/core', 'test/sim', "
                  "'-p', 'no:cacheprovider']))")
    assert result.returncode == 0, result.stdout[-2000:]
    assert ' passed' in result.stdout
