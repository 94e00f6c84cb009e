"""Every subcommand answers bad input with one line on stderr and exit status 1."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli
from sensor_msgs.msg import CameraInfo

from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagWriter

pytestmark = pytest.mark.slow


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
    assert 'has no ground truth to score against: cannot tell its kind (looked for a ' \
        'stereo ground truth, …/left/disparity_gt of type stereo_msgs/msg/DisparityImage' \
        in result.stderr
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


@pytest.mark.parametrize(('args', 'message'), [
    (['frobnicate'], "invalid choice: 'frobnicate'"),
    (['process'], 'the following arguments are required: in_bag, out_bag'),
    (['eval', 'x', '--threshold', 'two'], "argument --threshold: invalid float value: 'two'"),
    (['bench', 'sgm', '--paths', '6'], 'argument --paths: invalid choice: 6'),
    (['eval', 'x', '--bogus'], 'depth-nodes eval: error: unrecognized arguments: --bogus'),
    (['process', 'a', 'b', '--params', 'p.yaml', '--params', 'q.yaml'],
     'depth-nodes process: error: --params given twice'),
])
def test_usage_errors_are_one_line_and_exit_1(args: list[str], message: str) -> None:
    """argparse's own errors follow the command's rule too: one line, status 1 (argparse
    prints the usage and exits 2)."""
    result = run_cli(args)
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert message in line
    assert line.startswith('depth-nodes')
    assert '--help' in line


@pytest.mark.parametrize(('args', 'message'), [
    (['pipeline', '--config', 'missing.yaml'], 'graph config not found: missing.yaml'),
    (['pipeline', '--config', '{tmp}/g.yaml'], "unknown node plugin 'nope'"),
    (['pipeline', '--config', '{tmp}/empty.yaml'], 'has no nodes'),
    (['pipeline', '--threads', '0'], '--threads must be in 1..64, got 0'),
    (['pipeline', '--threads', '1024'], '--threads must be in 1..64, got 1024'),
    (['bench', 'sgm', '--disparities', '0'], '--disparities must be in 1..639'),
    (['bench', 'sgm', '--frames', '0'], '--frames must be at least 1'),
    (['bench', 'live', '--rate', '0'], '--rate must be positive'),
    (['bench', '--live', '--rate', '0'], 'use: depth-nodes bench live'),
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


def test_commands_that_produce_nothing_fail(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """record with no message on its topics, eval with nothing to score: one line, exit 1,
    and no empty bag left behind."""
    result = run_cli(['record', str(tmp_path / 'rec'), '--topics', '/nobody/publishes',
                      '--duration', '1'], env=ros_env)
    assert result.returncode == 1
    assert 'nothing was recorded (no message on /nobody/publishes)' in result.stderr
    assert not (tmp_path / 'rec').exists()
    with BagWriter(tmp_path / 'gt_only') as writer:
        writer.write('/stereo/left/disparity_gt', build_disparity(
            np.ones((4, 5), np.float32), None, focal=1.0, baseline=1.0, min_disparity=0.0,
            max_disparity=1.0, delta_d=0.0), 1)
    result = run_cli(['eval', str(tmp_path / 'gt_only'), '--no-baseline'], env=ros_env)
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert 'nothing to score' in line


def test_the_cli_prints_an_argument_error_as_one_line() -> None:
    """A core argument error reaching the command line: its message, no traceback."""
    result = run_cli(['bench', 'sgm', '--disparities', '0'])
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith('depth-nodes bench: error: --disparities must be in 1..')
