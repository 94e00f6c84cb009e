"""`depth-nodes eval BAG` picks the scorer by what the bag holds (tools/evaluation/kinds.py):
each kind's bag gives through `eval` the report its scorer (and its old command, now an
alias) gives; an option of another kind, and a bag of no kind, are one-line errors."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import REPO, run_cli
from std_msgs.msg import Header

from depth_nodes.graph.description import load_graph_config
from depth_nodes.ros.disparity import build_disparity
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim import StereoSimConfig
from depth_nodes.sim.projector import ProjectorSimConfig
from depth_nodes.sim.sequence import SequenceConfig
from depth_nodes.sim.tof import ToFSimConfig
from depth_nodes.tools.bags import depth_filter, generate, multiview, structured_light, tof
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.bags.views import VIEWS_KEY
from depth_nodes.tools.cli import build_parser
from depth_nodes.tools.evaluation.depth_filter_stages import compare, read_sequence
from depth_nodes.tools.evaluation.evaluate import evaluate_bag
from depth_nodes.tools.evaluation.kinds import (
    DEPTH_FILTER,
    FUSION,
    KINDS,
    MULTIVIEW,
    STEREO,
    STRUCTURED_LIGHT,
    TOF,
    VIEWS,
    Kind,
    bag_kind,
)
from depth_nodes.tools.evaluation.multiview import evaluate_multiview_bag
from depth_nodes.tools.evaluation.structured_light import evaluate_structured_light_bag
from depth_nodes.tools.evaluation.tof import evaluate_tof_bag

GT = '/stereo/left/disparity_gt'


def _tagged(path: Path, key: str | None, *, disparity_gt: bool = False) -> Path:
    """A bag of one small image, with ``key`` in its metadata (None: none) and, if asked, a
    stereo ground-truth topic."""
    with BagWriter(path) as writer:
        if key is not None:
            writer.set_custom_data(key, '{}')
        writer.write('/cam/image', array_to_image(np.zeros((4, 5), np.uint8), 'mono8',
                                                   Header()), 1)
        if disparity_gt:
            writer.write(GT, build_disparity(np.ones((4, 5), np.float32), Header(), focal=1.0,
                                             baseline=1.0, min_disparity=0.0,
                                             max_disparity=1.0, delta_d=0.0), 1)
    return path


#: The kinds told by their metadata (a fused bag is told by its mesh topic's type).
TAGGED = [kind for kind in KINDS if kind is not FUSION]


@pytest.mark.parametrize('kind', TAGGED, ids=[k.name for k in TAGGED])
def test_the_metadata_tells_the_kind(tmp_path: Path, kind: Kind) -> None:
    assert bag_kind(_tagged(tmp_path / 'bag', kind.key)) is kind


def test_a_mesh_topic_tells_a_fused_bag_whatever_the_metadata(tmp_path: Path) -> None:
    from depth_nodes.ros.serialized import marker_array
    path = tmp_path / 'fused'
    with BagWriter(path) as writer:
        writer.set_custom_data(generate.CONFIG_KEY, '{}')
        mesh = marker_array((0, 1), 'map', 'mesh', [], (1.0, 1.0, 1.0, 1.0))
        writer.write('/mesh', mesh.data, 1, msgtype=mesh.msgtype)
    assert bag_kind(path) is FUSION


def test_the_keys_are_those_the_bags_are_written_with() -> None:
    assert [k.key for k in (MULTIVIEW, VIEWS, STRUCTURED_LIGHT, TOF, DEPTH_FILTER, STEREO)] == [
        multiview.CONFIG_KEY, VIEWS_KEY, structured_light.CONFIG_KEY, tof.CONFIG_KEY,
        depth_filter.CONFIG_KEY, generate.CONFIG_KEY]
    assert len({k.key for k in KINDS}) == len({k.name for k in KINDS}) == len(KINDS)


def test_a_stereo_ground_truth_alone_is_stereo_and_metadata_comes_first(tmp_path: Path) -> None:
    assert bag_kind(_tagged(tmp_path / 'pair', None, disparity_gt=True)) is STEREO
    # a multi-view rig's bag holds the stereo pair's ground truth too
    rig = _tagged(tmp_path / 'rig', multiview.CONFIG_KEY, disparity_gt=True)
    assert bag_kind(rig) is MULTIVIEW
    assert bag_kind(_tagged(tmp_path / 'none', None)) is None


def test_a_bag_of_no_kind_is_a_one_line_error_saying_what_was_looked_for(
        tmp_path: Path) -> None:
    bag = _tagged(tmp_path / 'bag', 'somebody.else')
    done = run_cli(['eval', str(bag)])
    assert done.returncode == 1
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f'depth-nodes eval: error: {bag} has no ground truth to score '
                           'against: cannot tell its kind (looked for a stereo ground truth, '
                           '…/left/disparity_gt of type stereo_msgs/msg/DisparityImage, and '
                           'the metadata of a generated or imported bag, ')
    for kind in TAGGED:
        assert f'{kind.key}: {kind.name}' in line
    assert f'a mesh ({FUSION.key})' in line
    assert line.endswith('--previews DIR draws its disparity, depth and confidence instead')
    drawn = run_cli(['eval', str(bag), '--previews', str(tmp_path / 'png'), '--threshold',
                     '3'])
    assert drawn.returncode == 1
    (line,) = drawn.stderr.strip().splitlines()
    assert line == (f'depth-nodes eval: error: --threshold does not apply to {bag}: it has no '
                    'ground truth to score, and is only drawn')
    assert not (tmp_path / 'png').exists()  # made for the run, gone with its failure


@pytest.mark.parametrize(('key', 'option', 'message'), [
    (tof.CONFIG_KEY, ['--librealsense'],
     '--librealsense does not apply to {bag}, a time-of-flight bag (it applies to '
     'depth-filter bags)'),
    (structured_light.CONFIG_KEY, ['--threshold', '3'],
     '--threshold does not apply to {bag}, a structured-light bag (it applies to stereo '
     'bags)'),
    (generate.CONFIG_KEY, ['--skip', '2'],
     '--skip does not apply to {bag}, a stereo bag (it applies to multi-view and depth-filter '
     'bags)'),
    (depth_filter.CONFIG_KEY, ['--no-opencv'],
     '--no-opencv does not apply to {bag}, a depth-filter bag (it applies to '
     'structured-light bags)'),
])
def test_an_option_of_another_kind_is_a_one_line_error_naming_the_kind(
        tmp_path: Path, key: str, option: list[str], message: str) -> None:
    bag = _tagged(tmp_path / 'bag', key)
    done = run_cli(['eval', str(bag), *option])
    assert done.returncode == 1
    (line,) = done.stderr.strip().splitlines()
    assert line == f'depth-nodes eval: error: {message.format(bag=bag)}'


def test_a_previews_folder_that_cannot_be_is_refused_before_the_scoring(tmp_path: Path) -> None:
    bag = _tagged(tmp_path / 'bag', depth_filter.CONFIG_KEY)  # no depth: scoring would fail
    (tmp_path / 'file').write_text('')
    done = run_cli(['eval', str(bag), '--previews', str(tmp_path / 'file' / 'png')])
    assert done.returncode == 1
    (line,) = done.stderr.strip().splitlines()
    assert line == (f'depth-nodes eval: error: cannot write previews to '
                    f'{tmp_path / "file" / "png"}: {tmp_path / "file"} is a file')
    done = run_cli(['eval', str(bag), '--previews', str(tmp_path / 'png')])
    (line,) = done.stderr.strip().splitlines()
    assert 'topic /camera/depth/image_rect_raw is not in' in line
    assert not (tmp_path / 'png').exists()  # made for the run, gone with its failure


def test_the_aliases_say_so_and_take_their_kind_s_options_only() -> None:
    for name, kind in (('eval-sl', STRUCTURED_LIGHT), ('eval-tof', TOF),
                       ('eval-depth-filter', DEPTH_FILTER)):
        shown = run_cli([name, '--help'])
        assert shown.returncode == 0
        text = ' '.join(shown.stdout.split())
        assert f'An alias of `depth-nodes eval` for {kind.what}' in text
        assert 'eval tells the kind by itself' in text
        assert '--threshold' not in text
    refused = run_cli(['eval-tof', 'x', '--librealsense'])
    assert refused.returncode == 1
    assert 'depth-nodes eval-tof: error: unrecognized arguments: --librealsense' in \
        refused.stderr


def test_each_kind_s_defaults_are_its_own() -> None:
    parser = build_parser(['eval-depth-filter', 'eval-sl'])
    args = parser.parse_args(['eval-depth-filter', 'bag'])
    assert (args.skip, args.persistence, args.librealsense) == (3, 3, False)
    args = parser.parse_args(['eval-sl', 'bag'])
    assert not args.no_opencv
    assert not hasattr(args, 'skip')
    args = build_parser(['eval']).parse_args(['eval', 'bag'])
    assert args.skip is None
    assert args.threshold is None


# ----------------------------------------------------------------- each kind's report
def _output(words: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """What the command prints (its run, as main calls it, in this process)."""
    args = build_parser([words[0]]).parse_args(words)
    capsys.readouterr()
    assert args.run(args) == 0
    return capsys.readouterr().out


@pytest.fixture
def no_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every timing in a report 0 ms, so two reports of one bag are the same text."""
    monkeypatch.setattr(time, 'perf_counter', lambda: 0.0)


@pytest.mark.slow
def test_a_stereo_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = StereoSimConfig(width=160, height=120, n_frames=1, seed=3)
    generate.write_stereo_bag(tmp_path / 'bag', config)
    shown = _output(['eval', str(tmp_path / 'bag'), '--threshold', '3'], capsys)
    report = evaluate_bag(tmp_path / 'bag', threshold=3.0)
    assert shown == report.format() + '\n'
    assert report.threshold == 3.0
    assert report.frames == 1
    assert 'opencv' in shown


SL_SMALL = structured_light.StructuredLightBagConfig(
    sim=ProjectorSimConfig(width=96, height=72, focal_px=84.0, projector_width=96,
                           projector_height=72, projector_focal_px=75.0, seed=5),
    steps=4, period=8.0, sequences=1, speckle_frames=1)


@pytest.mark.slow
@pytest.mark.usefixtures('no_clock')
def test_a_structured_light_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    structured_light.write_structured_light_bag(tmp_path / 'bag', SL_SMALL)
    shown = _output(['eval', str(tmp_path / 'bag')], capsys)
    assert shown == _output(['eval-sl', str(tmp_path / 'bag')], capsys)
    report = evaluate_structured_light_bag(tmp_path / 'bag')
    assert shown == report.format() + '\n'
    assert shown.startswith(f'bag {tmp_path / "bag"}: 1 sequence(s) of '
                            f'{SL_SMALL.pattern_set.count} frames, 96x72')
    phase = next(r for r in report.rows if r.method.startswith('phase'))
    assert phase.decoded is not None
    assert phase.decoded > 0.9
    without = _output(['eval', str(tmp_path / 'bag'), '--no-opencv'], capsys)
    assert without == _output(['eval-sl', str(tmp_path / 'bag'), '--no-opencv'], capsys)
    assert 'opencv GrayCodePattern' in without
    assert 'unavailable' in without


@pytest.mark.slow
def test_a_time_of_flight_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    small = ToFSimConfig(width=96, height=72, focal_px=75.0, supersample=2, emitter_step=8,
                         n_frames=2, seed=9)
    tof.write_tof_bag(tmp_path / 'bag', small)
    process_bag(tmp_path / 'bag', tmp_path / 'out',
                config=load_graph_config(REPO / 'config' / 'tof_pipeline.yaml'))
    shown = _output(['eval', str(tmp_path / 'out')], capsys)
    assert shown == _output(['eval-tof', str(tmp_path / 'out')], capsys)
    report = evaluate_tof_bag(tmp_path / 'out')
    assert shown == report.format() + '\n'
    assert len(report.frames) == 2
    assert all(frame.median_rel < 0.01 for frame in report.frames)
    # the generated bag has no depth yet: the same error through either command
    for command in ('eval', 'eval-tof'):
        done = run_cli([command, str(tmp_path / 'bag')])
        assert done.returncode == 1
        (line,) = done.stderr.strip().splitlines()
        assert line.startswith(f'depth-nodes {command}: error: topic /tof/depth/image_rect '
                               'is not in')


@pytest.mark.slow
@pytest.mark.usefixtures('no_clock')
def test_a_depth_filter_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    small = dataclasses.replace(depth_filter.PRESETS['depth_moving_camera'], width=160,
                                height=120, n_frames=6, supersample=2)
    depth_filter.write_depth_bag(tmp_path / 'bag', small)
    shown = _output(['eval', str(tmp_path / 'bag'), '--skip', '2'], capsys)
    assert shown == _output(['eval-depth-filter', str(tmp_path / 'bag'), '--skip', '2'],
                            capsys)
    assert shown == compare(read_sequence(tmp_path / 'bag'), librealsense=False, skip=2,
                            persistence=3) + '\n'
    assert 'chain (defaults)' in shown
    assert 'input (the camera)' in shown


def _with_perfect_depth(bag: Path, out: Path) -> int:
    """``bag`` copied to ``out`` with a /mvs/depth that is the truth and a /mvs/sigma of 1 mm:
    a processed bag whose multi-view node was exact. Returns the depth images written."""
    count = 0
    with BagReader(bag) as reader, BagWriter(out) as writer:
        for key, value in reader.custom_data.items():
            writer.set_custom_data(key, value)
        for m in reader.messages():
            msg = m.deserialize()
            writer.write(m.topic, msg, m.timestamp)
            if m.topic == '/mvs/depth_gt':
                writer.write('/mvs/depth', msg, m.timestamp)
                sigma = np.full((msg.height, msg.width), 0.001, np.float32)
                writer.write('/mvs/sigma', array_to_image(sigma, '32FC1', msg.header),
                             m.timestamp)
                count += 1
    return count


@pytest.mark.slow
def test_a_multiview_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = SequenceConfig(motion='sideways', n_frames=4, width=64, height=48)
    multiview.write_sequence_bag(tmp_path / 'bag', config)
    assert _with_perfect_depth(tmp_path / 'bag', tmp_path / 'out') == 4
    shown = _output(['eval', str(tmp_path / 'out'), '--skip', '1'], capsys)
    report = evaluate_multiview_bag(tmp_path / 'out', skip=1)
    assert shown == report.format() + '\n'
    summary = report.summary()
    assert summary.median_rel == 0.0
    assert summary.within_1 == summary.within_2 == summary.coverage == 1.0
    assert summary.within_sigma == 1.0
    assert 'from frame 1 on: median |dZ|/Z 0.00 % (target <= 1 %), within 2 % 100.0 %' in shown
    # its maps drawn too: the depth and the truth of each frame
    drawn = _output(['eval', str(tmp_path / 'out'), '--previews', str(tmp_path / 'png'),
                     '--preview-frames', '2'], capsys)
    assert drawn.startswith(evaluate_multiview_bag(tmp_path / 'out').format())
    assert drawn.endswith(f'2 previews written to {tmp_path / "png"}\n')
    names = sorted(p.name for p in (tmp_path / 'png').glob('*.png'))
    assert len(names) == 2  # a sheet a frame: the depth and the truth in one row
    assert all(n.endswith('_sheet.png') for n in names)
    with BagReader(tmp_path / 'out') as reader:
        truth = image_to_array(next(reader.messages(['/mvs/depth_gt'])).deserialize())
    assert np.isfinite(truth).mean() > 0.5  # the scores above are over real pixels
    refused = run_cli(['eval', str(tmp_path / 'out'), '--skip', '-1'])
    (line,) = refused.stderr.strip().splitlines()
    assert line == 'depth-nodes eval: error: --skip must be >= 0, got -1'
