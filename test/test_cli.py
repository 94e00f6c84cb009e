"""Every subcommand answers bad input with one line on stderr and exit status 1."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo

from conftest import run_cli
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bagio import BagWriter


def _good_bag(path: Path) -> None:
    with BagWriter(path) as writer:
        for i in range(20):
            writer.write('/stereo/left/image_raw',
                         array_to_image(np.full((8, 8), i, np.uint8), 'mono8'), i)


def _missing(path: Path) -> None:
    """No bag at all."""


def _bad_metadata(path: Path) -> None:
    _good_bag(path)
    (path / 'metadata.yaml').write_text(': : not yaml [')


def _truncated(path: Path) -> None:
    _good_bag(path)
    mcap = next(path.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:300])


def _wrong_type(path: Path) -> None:
    with BagWriter(path) as writer:
        writer.write('/stereo/left/disparity_gt', CameraInfo(), 1)


BROKEN: dict[str, Callable[[Path], None]] = {
    'missing': _missing, 'bad_metadata': _bad_metadata, 'truncated': _truncated,
}
COMMANDS = {
    'process': lambda bag, out: ['process', str(bag), str(out)],
    'eval': lambda bag, out: ['eval', str(bag)],
    'play': lambda bag, out: ['play', str(bag), '--rate', '100'],
}


@pytest.mark.parametrize('damage', sorted(BROKEN))
@pytest.mark.parametrize('command', sorted(COMMANDS))
def test_broken_bags(tmp_path: Path, ros_env: dict[str, str], command: str, damage: str) -> None:
    bag = tmp_path / 'bag'
    BROKEN[damage](bag)
    result = run_cli(COMMANDS[command](bag, tmp_path / 'out'), env=ros_env)
    assert result.returncode == 1, result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f'depth-nodes {command}: error: ')
    assert str(bag) in lines[0]


def test_ground_truth_topic_of_the_wrong_type(tmp_path: Path) -> None:
    _wrong_type(tmp_path / 'bag')
    result = run_cli(['eval', str(tmp_path / 'bag')])
    assert result.returncode == 1
    assert 'has no ground-truth topic' in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_bad_graph_config_and_params(tmp_path: Path, ros_env: dict[str, str]) -> None:
    _good_bag(tmp_path / 'bag')
    (tmp_path / 'g.yaml').write_text('graph: {nodes: [{name: a, plugin: nope}]}')
    result = run_cli(['process', str(tmp_path / 'bag'), str(tmp_path / 'out'),
                      '--config', str(tmp_path / 'g.yaml')], env=ros_env)
    assert result.returncode == 1
    assert "unknown node plugin 'nope'" in result.stderr
    result = run_cli(['process', str(tmp_path / 'bag'), str(tmp_path / 'out2'),
                      '--params', str(tmp_path / 'missing.yaml')], env=ros_env)
    assert result.returncode == 1
    assert 'parameter file not found' in result.stderr
    assert 'Traceback' not in result.stderr


def test_usage_errors_exit_2() -> None:
    result = run_cli(['frobnicate'])
    assert result.returncode == 2
    assert 'invalid choice' in result.stderr


@pytest.mark.parametrize(('args', 'message'), [
    (['pipeline', '--config', 'missing.yaml'], 'graph config not found: missing.yaml'),
    (['pipeline', '--config', '{tmp}/g.yaml'], "unknown node plugin 'nope'"),
    (['pipeline', '--config', '{tmp}/empty.yaml'], 'has no nodes'),
    (['pipeline', '--threads', '0'], '--threads must be at least 1, got 0'),
    (['pipeline', '--params', '{tmp}/typo.yaml'],
     'node /stereo/sgm_stereo (sgm_stereo) has no parameter P3'),
    (['eval', 'x', '--ros-args', '-p', 'a:=1'], '--ros-args is only accepted by pipeline'),
    (['bench'], 'bench needs a stage'),
    (['play', 'x', '--delay', '-1'], '--delay must be >= 0, got -1.0'),
])
def test_pipeline_and_live_usage_errors(tmp_path: Path, ros_env: dict[str, str],
                                        args: list[str], message: str) -> None:
    (tmp_path / 'g.yaml').write_text('graph: {nodes: [{name: a, plugin: nope}]}')
    (tmp_path / 'empty.yaml').write_text('graph: {name: e, nodes: []}')
    (tmp_path / 'typo.yaml').write_text('sgm_stereo:\n  ros__parameters: {P3: 1.0}\n')
    _good_bag(tmp_path / 'x')
    result = run_cli([a.format(tmp=tmp_path) for a in args], env=ros_env)
    assert result.returncode == 1, result.stderr
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
