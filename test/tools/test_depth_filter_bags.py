"""Depth-camera bags for the depth filter: written, run through the shipped depth_filter
graph offline, scored by eval (beside librealsense's filters; its alias eval-depth-filter
refuses another kind of bag), timed by bench depth_filter; and the line that adds the node
to the shipped stereo and ToF graphs."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from helpers import REPO, run_cli

from depth_nodes.errors import BagError
from depth_nodes.graph.description import load_graph_config
from depth_nodes.sim.depth_sequence import DepthSequenceConfig
from depth_nodes.sim.tof import ToFSimConfig
from depth_nodes.tools.bags.depth_filter import PRESETS, config_from_metadata, write_depth_bag
from depth_nodes.tools.bags.generate import PRESETS as STEREO_PRESETS
from depth_nodes.tools.bags.generate import write_stereo_bag
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.bags.tof import write_tof_bag
from depth_nodes.tools.evaluation.depth_filter_stages import compare, read_sequence

pytestmark = pytest.mark.slow

SMALL = dataclasses.replace(PRESETS['depth_moving_camera'], width=160, height=120,
                            n_frames=6, supersample=2)
PIPELINE = REPO / 'config' / 'depth_filter_pipeline.yaml'


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('depth') / 'bag'
    assert write_depth_bag(path, SMALL) == 6 * 5
    return path


def test_topics_and_metadata(small_bag: Path) -> None:
    with BagReader(small_bag) as reader:
        assert reader.counts['/camera/depth/image_rect_raw'] == 6
        assert reader.counts['/camera/odom'] == 6
        assert config_from_metadata(reader.custom_data, small_bag) == SMALL
        depth = next(reader.messages(['/camera/depth/image_rect_raw'])).deserialize()
    assert (depth.encoding, depth.width, depth.height) == ('16UC1', 160, 120)
    with pytest.raises(BagError, match='not a depth-filter bag'):
        config_from_metadata({}, small_bag)


def test_the_shipped_graph_filters_a_bag_as_the_core_does(small_bag: Path,
                                                          tmp_path: Path) -> None:
    report = process_bag(small_bag, tmp_path / 'out', config=load_graph_config(PIPELINE))
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    for topic in ('image_rect', 'camera_info', 'filled', 'sigma', 'points'):
        assert report.published[f'/camera/filtered/{topic}'] == 6
    seq = read_sequence(tmp_path / 'out')
    assert seq.filtered is not None
    assert seq.filtered.filled is not None
    table = compare(seq, librealsense=True, skip=2, persistence=3)
    rows = {line.split('  ')[0]: line for line in table.splitlines()}
    node = [float(v) for v in re.findall(r'([-\d.]+) %', rows['depth_filter node (bag)'])]
    camera = [float(v) for v in re.findall(r'([-\d.]+) %', rows['input (the camera)'])]
    assert node[0] < camera[0] / 3  # median error
    assert 'librealsense' in table
    assert 'chain (defaults)' in table


def _with_the_line(config: Path, tmp_path: Path) -> Path:
    text = config.read_text()
    line = re.search(r'^(\s*)# (- \{name: depth_filter.*)$', text, re.MULTILINE)
    assert line is not None, f'{config.name}: no depth_filter line to uncomment'
    path = tmp_path / config.name
    path.write_text(text.replace(line.group(0), line.group(1) + line.group(2)))
    return path


def test_one_line_adds_the_filter_to_the_tof_graph(tmp_path: Path) -> None:
    bag = tmp_path / 'tof'
    write_tof_bag(bag, ToFSimConfig(width=96, height=72, focal_px=75.0, supersample=2,
                                    emitter_step=8, n_frames=3, seed=9))
    config = load_graph_config(_with_the_line(REPO / 'config' / 'tof_pipeline.yaml',
                                              tmp_path))
    report = process_bag(bag, tmp_path / 'out', config=config)
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    assert report.published['/tof/filtered/image_rect'] == 3
    assert report.published['/tof/filtered/sigma'] == 3  # from the tof node's confidence


def test_one_line_adds_the_filter_to_the_stereo_graph(tmp_path: Path) -> None:
    bag = tmp_path / 'stereo'
    small = dataclasses.replace(STEREO_PRESETS['stereo_qvga_color'], n_frames=2)
    write_stereo_bag(bag, small)
    config = load_graph_config(_with_the_line(REPO / 'config' / 'stereo_pipeline.yaml',
                                              tmp_path))
    report = process_bag(bag, tmp_path / 'out', config=config)
    assert report.published['/stereo/filtered/image_rect'] == \
        report.published['/stereo/depth'] == 2


def test_eval_and_bench_from_the_command_line(small_bag: Path) -> None:
    out = run_cli(['eval', str(small_bag), '--skip', '2'])
    assert out.returncode == 0, out.stderr
    assert 'chain (defaults)' in out.stdout
    assert 'input (the camera)' in out.stdout
    bench = run_cli(['bench', 'depth_filter', '--frames', '3', '--size', '160x120'])
    assert bench.returncode == 0, bench.stderr
    assert 'librealsense' in bench.stdout
    assert 'node frame callback' in bench.stdout
    times = [float(v) for v in re.findall(r'chain\s+([\d.]+) ms', bench.stdout)]
    assert len(times) == 2
    assert all(t > 0 for t in times)


def test_a_stereo_bag_is_not_a_depth_bag(tmp_path: Path) -> None:
    bag = tmp_path / 'stereo'
    write_stereo_bag(bag, dataclasses.replace(STEREO_PRESETS['stereo_qvga_color'],
                                              n_frames=1))
    result = run_cli(['eval-depth-filter', str(bag)])
    assert result.returncode != 0
    assert 'not a depth-filter bag' in result.stderr
    assert 'Traceback' not in result.stderr


def test_the_simulated_noise_is_what_the_node_is_told() -> None:
    config = DepthSequenceConfig()
    depth = np.array([1.0, 4.0], np.float32)
    np.testing.assert_allclose(config.sigma(depth), depth ** 2 * 0.1 / (256 * 0.08),
                               rtol=1e-6)
