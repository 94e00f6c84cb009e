"""The offline bag harness: routing, chaining, copying, drops, parameters and bad input."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import run_cli
from ros_helpers import header
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.graph.description import GraphConfig, NodeSpec, load_graph_config
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.process import process_bag

pytestmark = pytest.mark.slow

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
RAW = '/stereo/left/image_raw'
GRAPH = """
graph:
  name: test
  nodes:
    - {name: invert, plugin: 'harness_nodes:InvertNode', namespace: /stereo/left,
       remappings: {image: image_raw}}
    - {name: restore, plugin: 'harness_nodes:RestoreNode', namespace: /stereo/left}
"""


def _left(i: int) -> Header:
    """The header of frame ``i``: left camera, 100 + i seconds."""
    return header((100 + i) * 10**9, 'left')


def _frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    return [rng.integers(0, 256, (6, 8), dtype=np.uint8) for _ in range(n)]


def _input_bag(path: Path, frames: list[np.ndarray], bad_at: int | None = None) -> None:
    with BagWriter(path) as writer:
        for i, pixels in enumerate(frames):
            stamp = (100 + i) * 1_000_000_000
            if i == bad_at:
                writer.write(RAW, array_to_image(np.dstack([pixels] * 3), 'rgb8', _left(i)),
                             stamp)
            else:
                writer.write(RAW, array_to_image(pixels, 'mono8', _left(i)), stamp)
            writer.write('/stereo/left/info_gt', CameraInfo(), stamp)


def _decoded(bag: Path, topic: str) -> list[tuple[int, np.ndarray]]:
    """Read images back with the rosbags deserialiser (not the code that wrote them)."""
    out = []
    with BagReader(bag) as reader:
        for m in reader.messages([topic]):
            msg = TYPESTORE.deserialize_cdr(m.data, m.msgtype)
            out.append((m.timestamp, np.asarray(msg.data).reshape(msg.height, msg.width)))
    return out


@pytest.fixture
def graph(tmp_path: Path) -> GraphConfig:
    path = tmp_path / 'graph.yaml'
    path.write_text(GRAPH)
    return load_graph_config(path)


def test_outputs_are_correct_chained_and_counted(tmp_path: Path, graph: GraphConfig,
                                                 ros_env: dict[str, str]) -> None:
    frames = _frames(5)
    _input_bag(tmp_path / 'in', frames, bad_at=2)
    report = process_bag(tmp_path / 'in', tmp_path / 'out', config=graph)

    inverted = _decoded(tmp_path / 'out', '/stereo/left/image_inverted')
    restored = _decoded(tmp_path / 'out', '/stereo/left/image_restored')
    good = [i for i in range(5) if i != 2]
    assert [t for t, _ in inverted] == [(100 + i) * 1_000_000_000 for i in good]
    for (_, inv), (_, back), i in zip(inverted, restored, good, strict=True):
        np.testing.assert_array_equal(inv, 255 - frames[i])
        np.testing.assert_array_equal(back, frames[i])
    # inputs (and ground truth) are copied through untouched
    with BagReader(tmp_path / 'out') as reader:
        assert reader.counts[RAW] == 5
        assert reader.counts['/stereo/left/info_gt'] == 5
    assert report.nodes == ['/stereo/left/invert', '/stereo/left/restore']
    assert report.consumed[RAW] == 5
    assert report.published == {'/stereo/left/image_inverted': 4,
                                '/stereo/left/image_restored': 4}
    assert report.drops['/stereo/left/invert'] == {'unsupported_encoding': 1}
    text = report.format()
    assert 'unsupported_encoding' in text
    assert 'dropped: 1' in text


def test_params_file_reaches_the_node(tmp_path: Path, graph: GraphConfig,
                                      ros_env: dict[str, str]) -> None:
    frames = [np.full((4, 4), 100, np.uint8)]
    _input_bag(tmp_path / 'in', frames)
    params = tmp_path / 'params.yaml'
    params.write_text('stereo/left/invert:\n  ros__parameters: {offset: 7}\n')
    process_bag(tmp_path / 'in', tmp_path / 'out', config=graph, params_file=params)
    ((_, inv),) = _decoded(tmp_path / 'out', '/stereo/left/image_inverted')
    assert (inv == 255 - 100 + 7).all()


def test_wrong_topic_type_is_a_clear_error(tmp_path: Path, ros_env: dict[str, str]) -> None:
    with BagWriter(tmp_path / 'in') as writer:
        writer.write(RAW, CameraInfo(), 1)
    config = GraphConfig('t', [NodeSpec('invert', 'harness_nodes:InvertNode', '/stereo/left',
                                        remappings={'image': 'image_raw'})])
    with pytest.raises(BagError, match=r'image_raw .* has type sensor_msgs/msg/CameraInfo, '
                                       'but a node subscribes to it as sensor_msgs/msg/Image'):
        process_bag(tmp_path / 'in', tmp_path / 'out', config=config)


def test_cli_runs_the_graph_and_prints_counts(tmp_path: Path, ros_env: dict[str, str]) -> None:
    _input_bag(tmp_path / 'in', _frames(3), bad_at=1)
    (tmp_path / 'g.yaml').write_text(GRAPH)
    result = run_cli(['process', str(tmp_path / 'in'), str(tmp_path / 'out'),
                      '--config', str(tmp_path / 'g.yaml')], env=ros_env)
    assert result.returncode == 0, result.stderr
    assert '/stereo/left/image_restored' in result.stdout
    assert 'unsupported_encoding' in result.stdout
    again = run_cli(['process', str(tmp_path / 'in'), str(tmp_path / 'out'),
                     '--config', str(tmp_path / 'g.yaml')], env=ros_env)
    assert again.returncode == 1
    assert again.stderr.strip().splitlines() == [
        f'depth-nodes process: error: output bag exists already: {tmp_path / "out"} '
        '(use --force)']


def test_output_cannot_be_the_input(tmp_path: Path, graph: GraphConfig) -> None:
    _input_bag(tmp_path / 'in', _frames(1))
    with pytest.raises(BagError, match='is the input bag'):
        process_bag(tmp_path / 'in', tmp_path / 'in', config=graph, overwrite=True)
    with BagReader(tmp_path / 'in') as reader:
        assert reader.counts[RAW] == 1


@pytest.mark.parametrize(('make', 'message'), [
    (lambda p: None, 'bag not found'),
    (lambda p: p.mkdir(), 'no metadata.yaml'),
])
def test_cli_bad_input_bag_is_one_line(tmp_path: Path, ros_env: dict[str, str], make,
                                       message: str) -> None:
    make(tmp_path / 'in')
    result = run_cli(['process', str(tmp_path / 'in'), str(tmp_path / 'out')], env=ros_env)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert message in lines[0]
    assert 'Traceback' not in result.stderr


def _flip(bag: Path, count: int = 64) -> None:
    """Flip ``count`` bytes in the middle of the bag's storage file (its message data)."""
    mcap = next(bag.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    middle = len(data) // 2
    for i in range(count):
        data[middle + i] ^= 0xFF
    mcap.write_bytes(bytes(data))


def test_damage_to_a_written_bag_is_found_when_it_is_read(tmp_path: Path,
                                                          graph: GraphConfig,
                                                          ros_env: dict[str, str]) -> None:
    """64 flipped bytes in a bag `process` wrote went unnoticed by process, play and eval
    (the MCAP chunks carried no CRC): now every reader says the bag is corrupt, and
    `process` leaves no partial output behind."""
    _input_bag(tmp_path / 'in', _frames(400))
    process_bag(tmp_path / 'in', tmp_path / 'out', config=graph)
    _flip(tmp_path / 'out')
    with BagReader(tmp_path / 'out') as reader, pytest.raises(
            BagError, match='Chunk checksum mismatch'):
        list(reader.messages())
    with pytest.raises(BagError, match=r'checksum mismatch; .*again not written'):
        process_bag(tmp_path / 'out', tmp_path / 'again', config=graph)
    assert not (tmp_path / 'again').exists()
    result = run_cli(['play', str(tmp_path / 'out')], env=ros_env)  # eval: the same reader
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert 'corrupt bag' in line


def test_a_run_that_produces_nothing_is_an_error(tmp_path: Path, graph: GraphConfig,
                                                 ros_env: dict[str, str]) -> None:
    """A bag whose topics no node takes (another namespace, say) used to exit 0 with
    '(nothing published)'; an empty bag too."""
    with BagWriter(tmp_path / 'elsewhere') as writer:
        writer.write('/camera/left/image_raw', array_to_image(_frames(1)[0], 'mono8',
                                                              _left(0)), 10**11)
    (tmp_path / 'g.yaml').write_text(GRAPH)
    result = run_cli(['process', str(tmp_path / 'elsewhere'), str(tmp_path / 'out'),
                      '--config', str(tmp_path / 'g.yaml')], env=ros_env)
    assert result.returncode == 1
    assert 'the graph published nothing' in result.stderr
    assert 'is subscribed but neither in the bag nor published' in result.stdout
    assert not (tmp_path / 'out').exists()
    with BagWriter(tmp_path / 'empty'):
        pass
    for args in (['process', str(tmp_path / 'empty'), str(tmp_path / 'out')],
                 ['play', str(tmp_path / 'empty')]):
        result = run_cli(args, env=ros_env)
        assert result.returncode == 1
        assert 'holds no messages' in result.stderr


class _FullDiskAt(BagWriter):
    """A writer whose disk fills up when the graph publishes ``topic`` the ``n``-th time."""

    def __init__(self, *args: Any, topic: str, n: int, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.topic, self.left = topic, n

    def write(self, topic: str, *args: Any, **kwargs: Any) -> None:
        if topic == self.topic:
            self.left -= 1
            if self.left == 0:
                self._fail(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))
        super().write(topic, *args, **kwargs)


@pytest.mark.parametrize('topic', ['/stereo/left/image_restored', RAW])
def test_a_full_disk_ends_the_run_in_one_line_with_no_output(
        tmp_path: Path, graph: GraphConfig, topic: str, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str]) -> None:
    """The disk filling up while a node publishes (the write happens inside the node's
    callback, whose guard used to take it for a failure of the frame: a traceback per
    node, then a traceback of the whole command) or while an input is copied: one error
    line, and no half-written bag left behind."""
    import depth_nodes.tools.bags.process as process

    _input_bag(tmp_path / 'in', _frames(20))
    monkeypatch.setattr(process, 'BagWriter',
                        lambda *a, **k: _FullDiskAt(*a, topic=topic, n=7, **k))
    with pytest.raises(BagError) as raised:
        process_bag(tmp_path / 'in', tmp_path / 'out', config=graph)
    assert str(raised.value) == (f'cannot write the bag {tmp_path / "out"}: No space left on '
                                 f'device; {tmp_path / "out"} not written')
    assert not (tmp_path / 'out').exists()
    err = capfd.readouterr().err
    assert 'Traceback' not in err
    assert 'internal_error' not in err


STATEFUL = """
graph:
  name: stateful
  nodes:
    - {name: invert, plugin: 'harness_nodes:InvertNode', namespace: /stereo/left,
       remappings: {image: image_raw}}
    - {name: running_mean, plugin: 'harness_nodes:RunningMeanNode', namespace: /stereo/left,
       remappings: {image: image_inverted}}
"""


def test_a_node_that_keeps_state_is_refused_on_several_workers(
        tmp_path: Path, ros_env: dict[str, str]) -> None:
    """A worker that starts mid-bag would lack what such a node gathered: `--workers N` and
    `--ray` stop before anything runs, naming the node; one worker runs the graph."""
    frames = _frames(4)
    _input_bag(tmp_path / 'in', frames)
    (tmp_path / 'g.yaml').write_text(STATEFUL)
    config = load_graph_config(tmp_path / 'g.yaml')
    for options, how in (({'workers': 2}, '--workers 2'), ({'ray': True}, '--ray')):
        with pytest.raises(ConfigError) as raised:
            process_bag(tmp_path / 'in', tmp_path / 'out', config=config, **options)
        assert str(raised.value) == (
            f'{how}: node /stereo/left/running_mean keeps state from frame to frame, which a '
            'bag split between workers would lose; use one worker (--workers 1, without '
            '--ray)')
        assert not (tmp_path / 'out').exists()
    shown = run_cli(['process', str(tmp_path / 'in'), str(tmp_path / 'out'), '--config',
                     str(tmp_path / 'g.yaml'), '--workers', '3'], env=ros_env)
    assert shown.returncode == 1
    assert shown.stderr.strip().splitlines() == [
        'depth-nodes process: error: --workers 3: node /stereo/left/running_mean keeps state '
        'from frame to frame, which a bag split between workers would lose; use one worker '
        '(--workers 1, without --ray)']
    report = process_bag(tmp_path / 'in', tmp_path / 'out', config=config)
    means = _decoded(tmp_path / 'out', '/stereo/left/image_mean')
    assert len(means) == report.published['/stereo/left/image_mean'] == len(frames)
    inverted = np.cumsum([255 - f.astype(np.float64) for f in frames], axis=0)
    expected = np.rint(inverted / np.arange(1, len(frames) + 1)[:, None, None]).astype(np.uint8)
    for (_, got), want in zip(means, expected, strict=True):
        np.testing.assert_array_equal(got, want)
