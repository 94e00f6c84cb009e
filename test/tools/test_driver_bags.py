"""Bags laid out the way camera drivers record them (`depth-nodes convert`: compressed
images, Bayer mosaics, the driver's namespace) go through the shipped graph with one option,
and their disparity is as accurate as from the raw images within what the compression
costs. Also the graph renaming and remapping rules behind `--namespace`, `--left`,
`--right`, `--image` and `--ros-args -r`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import REPO, run_cli
from rclpy.context import Context
from sensor_msgs.msg import CompressedImage

from depth_nodes.graph.description import create_nodes, load_graph_config, rename_cameras
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.tools.bags.convert import ConvertOptions, convert_bag
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.evaluation.evaluate import evaluate_bag
from depth_nodes.tools.live.pipeline import compose_remappings, user_remappings

pytestmark = pytest.mark.slow

STEREO = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
RAW = '/stereo/disparity'


def _disparities(bag: Path, topic: str) -> list[np.ndarray]:
    with BagReader(bag) as reader:
        return [read_disparity(m.deserialize()).disparity for m in reader.messages([topic])]


def _driver_bag(tmp_path: Path, source: str, **options: Any) -> Path:
    out = tmp_path / 'driver'
    convert_bag(REPO / 'bags' / source, out, ConvertOptions(namespace='/camera', **options))
    return out


def test_png_compressed_bag_under_another_namespace_gives_the_raw_result(
        tmp_path: Path, stereo_reports: dict[str, tuple[Path, Any]]) -> None:
    """Lossless PNG: the same disparity, bit for bit, as the bundled raw bag."""
    bag = _driver_bag(tmp_path, 'stereo_vga', codec='png')
    with BagReader(bag) as reader:
        assert reader.topics['/camera/left/image_raw/compressed'] == \
            'sensor_msgs/msg/CompressedImage'
        assert '/camera/left/image_raw' not in reader.topics
    report = process_bag(bag, tmp_path / 'out', config=rename_cameras(STEREO,
                                                                      namespace='/camera'))
    assert report.transports == {'/camera/left/rectify_left': 'compressed',
                                 '/camera/right/rectify_right': 'compressed'}
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    ours = _disparities(tmp_path / 'out', '/camera/disparity')
    raw = _disparities(stereo_reports['stereo_vga'][0], RAW)
    assert len(ours) == len(raw) == 2
    for a, b in zip(ours, raw, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(('source', 'options', 'slack'), [
    ('stereo_vga', {'codec': 'jpeg', 'quality': 90}, 0.05),
    ('stereo_qvga_color', {'codec': 'jpeg', 'quality': 90, 'bayer': 'rggb'}, 0.15),
])
def test_jpeg_and_bayer_cost_little_accuracy(
        tmp_path: Path, stereo_reports: dict[str, tuple[Path, Any]], source: str,
        options: dict[str, Any], slack: float) -> None:
    """JPEG (quality 90) and a Bayer mosaic demosaiced by the rectifier: dense bad-2 within
    ``slack`` (relative) of the raw images' (measured: JPEG 90 on stereo_vga +0.4 %; Bayer
    RGGB + JPEG 90 on stereo_qvga_color +10 %; README "Compressed and Bayer input")."""
    bag = _driver_bag(tmp_path, source, **options)
    params = tmp_path / 'params.yaml'
    params.write_text(f'sgm_stereo:\n  ros__parameters: {{disparity_range: '
                      f'{128 if source == "stereo_vga" else 64}}}\n')
    report = process_bag(bag, tmp_path / 'out', params_file=params,
                         config=rename_cameras(STEREO, namespace='/camera'))
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    ours = evaluate_bag(tmp_path / "out", baselines=False).row('/camera/disparity')
    raw = stereo_reports[source][1].row(RAW)
    assert ours.frames == raw.frames
    assert ours.bad_dense <= raw.bad_dense * (1 + slack), (ours.bad_dense, raw.bad_dense)
    assert ours.density >= raw.density - 0.02


def test_a_bag_under_another_namespace_is_an_error_that_names_it(tmp_path: Path) -> None:
    bag = _driver_bag(tmp_path, 'stereo_vga', codec='jpeg')
    result = run_cli(['process', str(bag), str(tmp_path / 'out')])
    assert result.returncode == 1
    assert result.stderr.count('\n') == 1, result.stderr
    assert ('error: the graph published nothing: its inputs /stereo/left/camera_info, '
            '/stereo/left/image_raw, /stereo/right/camera_info, /stereo/right/image_raw are '
            'not in the bag; try --namespace /camera') in result.stderr
    assert not (tmp_path / 'out').exists()
    ok = run_cli(['process', str(bag), str(tmp_path / 'out'), '--namespace', '/camera'])
    assert ok.returncode == 0, ok.stderr
    assert '/camera/points2' in ok.stdout
    assert 'reads its images with image_transport compressed' in ok.stdout


def test_side_and_image_names_follow_a_driver(context: Context) -> None:
    """A RealSense-like layout: /cam/infra1/image_rect_raw, /cam/infra2/..."""
    config = rename_cameras(STEREO, namespace='/cam', left='infra1', right='infra2',
                            image='image_rect_raw')
    sgm = next(spec for spec in config.nodes if spec.name == 'sgm_stereo')
    # a node at the root that read a raw image would follow both renames at once
    assert sgm.remappings['left/image_raw'] == 'infra1/image_rect_raw'
    assert sgm.remappings['right/camera_info'] == 'infra2/camera_info'
    nodes = create_nodes(config, context=context)
    try:
        topics = {n.get_fully_qualified_name(): sorted(s.topic for s in n.inputs)
                  for n in nodes}
        outputs = {n.get_fully_qualified_name(): sorted(n.outputs) for n in nodes}
    finally:
        for node in nodes:
            node.destroy_node()
    assert topics['/cam/infra1/rectify_left'] == ['/cam/infra1/camera_info',
                                                  '/cam/infra1/image_rect_raw']
    assert outputs['/cam/infra1/rectify_left'] == ['/cam/infra1/image_rect',
                                                   '/cam/infra1/image_rect_color']
    assert topics['/cam/sgm_stereo'] == ['/cam/infra1/camera_info', '/cam/infra1/image_rect',
                                         '/cam/infra2/camera_info', '/cam/infra2/image_rect']
    assert '/cam/infra1/image_rect' in topics['/cam/point_cloud']  # its own remap followed


def test_a_parameter_file_for_the_graphs_own_names_follows_the_rename() -> None:
    """config/disparity_64.yaml addresses /stereo/sgm_stereo: with --namespace /camera it
    still reaches the moved node (a run that silently kept 128 disparities otherwise)."""
    from depth_nodes.graph.description import load_params_file, parameters_for, unmatched_entries

    config = rename_cameras(STEREO, namespace='/camera')
    params = load_params_file(REPO / 'config' / 'disparity_64.yaml')
    sgm = next(n for n in config.nodes if n.name == 'sgm_stereo')
    assert sgm.fully_qualified_name == '/camera/sgm_stereo'
    assert parameters_for(sgm, params)['disparity_range'] == 64
    assert unmatched_entries(config, params) == []


def test_bad_camera_names_are_refused() -> None:
    from depth_nodes.errors import ConfigError

    with pytest.raises(ConfigError, match="--namespace 'camera' must be absolute"):
        rename_cameras(STEREO, namespace='camera')
    with pytest.raises(ConfigError, match="--left 'in fra' is not a ROS name"):
        rename_cameras(STEREO, left='in fra')


def test_user_remappings_apply_after_the_graphs_own(context: Context) -> None:
    """`pipeline --ros-args -r /stereo/left/image_raw:=/camera/left/image_raw`: the
    rectifier's own `image:=image_raw` used to win, so only camera_info followed."""
    rules = user_remappings(['--ros-args', '-r', '/stereo/left/image_raw:=/camera/left/image_raw',
                             '--remap', 'rectify_right:image:=/x', '--log-level', 'info'])
    assert rules == [('/stereo/left/image_raw', '/camera/left/image_raw')]
    config = compose_remappings(STEREO, rules)
    nodes = create_nodes(config, context=context)
    try:
        left = next(n for n in nodes if n.get_name() == 'rectify_left')
        right = next(n for n in nodes if n.get_name() == 'rectify_right')
        assert left.inputs[0].topic == '/camera/left/image_raw'
        assert right.inputs[0].topic == '/stereo/right/image_raw'
    finally:
        for node in nodes:
            node.destroy_node()


def test_parameter_file_entries_matching_no_node_are_reported(tmp_path: Path) -> None:
    params = tmp_path / 'params.yaml'
    params.write_text('sgm_stero:\n  ros__parameters: {P2: 300.0}\n'
                      'disparity_node:\n  ros__parameters: {uniqueness_ratio: 12.0}\n')
    report = process_bag(REPO / 'bags' / 'stereo_qvga_color', tmp_path / 'out',
                         params_file=params, config=STEREO)
    assert report.unmatched_params == ['sgm_stero']  # disparity_node: the matcher's alias
    said = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'cli'),
                    '--params', str(params)])
    assert said.returncode == 0, said.stderr
    assert ("depth-nodes process: warning: parameter file entry 'sgm_stero' matches no node "
            'of the graph (did you mean sgm_stereo?)') in said.stderr  # at once, on stderr
    assert 'sgm_stero' not in said.stdout


def test_compressed_messages_in_the_output_bag_are_readable(tmp_path: Path) -> None:
    bag = _driver_bag(tmp_path, 'stereo_qvga_color', codec='jpeg', bayer='gbrg')
    with BagReader(bag) as reader:
        msg = next(m.deserialize() for m in reader.messages(
            ['/camera/left/image_raw/compressed']))
    assert isinstance(msg, CompressedImage)
    assert msg.format == 'bayer_gbrg8; jpeg compressed '


@pytest.mark.ros
def test_the_live_pipeline_takes_a_driver_bag_with_one_option(tmp_path: Path) -> None:
    """`depth-nodes pipeline --namespace /camera --image-transport compressed`, fed by
    `play` of a JPEG bag under /camera: the disparity comes out under /camera."""
    import signal
    import subprocess
    import sys

    from helpers import graph_env

    bag = _driver_bag(tmp_path, 'stereo_vga', codec='jpeg')
    env = graph_env()
    pipeline = subprocess.Popen(
        [sys.executable, '-m', 'depth_nodes.tools.cli', 'pipeline', '--namespace', '/camera',
         '--image-transport', 'compressed'], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env=env, cwd=REPO)
    try:
        echo = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'topic', 'echo',
             '/camera/disparity', '--count', '2', '--timeout', '120'],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
        player = subprocess.Popen(
            [sys.executable, '-m', 'depth_nodes.tools.cli', 'play', str(bag), '--loop',
             '--wait-for-subscribers', '120', '--delay', '1', '--topics',
             *(f'/camera/{side}/{name}' for side in ('left', 'right')
               for name in ('image_raw/compressed', 'camera_info'))],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
        out, err = echo.communicate(timeout=300)
        player.send_signal(signal.SIGINT)
        player.communicate(timeout=30)
        assert echo.returncode == 0, err
        lines = [line for line in out.splitlines() if line.startswith('DisparityImage')]
        assert len(lines) == 2, out
        assert all('640x480' in line and "frame 'left_camera_optical_frame'" in line
                   for line in lines)
    finally:
        pipeline.send_signal(signal.SIGINT)
        pipe_out, pipe_err = pipeline.communicate(timeout=60)
    assert pipeline.returncode == 0, pipe_err
    assert 'pipeline stereo: 5 nodes up (/camera/left/rectify_left' in pipe_out


def test_the_hint_names_what_would_feed_the_graph(tmp_path: Path) -> None:
    """A raw transport forced on a compressed bag, and a RealSense-like layout (infra1,
    infra2, image_rect_raw): the error says the options that work."""
    from depth_nodes.tools.bags.io import BagWriter

    bag = _driver_bag(tmp_path, 'stereo_qvga_color', codec='jpeg')
    forced = run_cli(['process', str(bag), str(tmp_path / 'o1'), '--namespace', '/camera',
                      '--image-transport', 'raw'])
    assert forced.returncode == 1
    assert 'try --image-transport compressed' in forced.stderr
    with BagReader(bag) as reader, BagWriter(tmp_path / 'rs') as writer:
        for m in reader.messages():
            topic = (m.topic.replace('/camera/left/', '/rs/infra1/')
                     .replace('/camera/right/', '/rs/infra2/')
                     .replace('image_raw', 'image_rect_raw'))
            writer.write(topic, m.data, m.timestamp, m.msgtype)
    hint = '--namespace /rs --left infra1 --right infra2 --image image_rect_raw'
    realsense = run_cli(['process', str(tmp_path / 'rs'), str(tmp_path / 'o2')])
    assert f'try {hint};' in realsense.stderr
    ok = run_cli(['process', str(tmp_path / 'rs'), str(tmp_path / 'o3'), *hint.split(),
                  '--params', str(REPO / 'config' / 'disparity_64.yaml')])
    assert ok.returncode == 0, ok.stderr
    assert '/rs/points2' in ok.stdout


def test_a_full_disk_under_convert_is_one_line_naming_the_output(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The output's own error, without the input bag's path in front of it (which read as
    if the input were at fault), and no half-written output."""
    import errno
    import os

    import depth_nodes.tools.bags.convert as convert
    from depth_nodes.errors import BagError
    from depth_nodes.tools.bags.io import BagWriter

    class FullDisk(BagWriter):
        def write(self, *args: Any, **kwargs: Any) -> None:
            if sum(self.counts.values()) == 5:
                self._fail(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))
            super().write(*args, **kwargs)

    monkeypatch.setattr(convert, 'BagWriter', FullDisk)
    out = tmp_path / 'out'
    with pytest.raises(BagError) as raised:
        convert_bag(REPO / 'bags' / 'stereo_vga', out, ConvertOptions(namespace='/camera'))
    assert str(raised.value) == (f'cannot write the bag {out}: No space left on device; '
                                 f'{out} not written')
    assert not out.exists()
