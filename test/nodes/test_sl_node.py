"""The structured-light node: correct depth from a sequence; every broken sequence and bad
input is a counted, logged drop, after which the next sequence decodes; live parameters."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, header

from depth_nodes.core.structured_light import (
    PatternSet,
    ProjectorGeometry,
    generate_patterns,
    speckle_pattern,
)
from depth_nodes.core.structured_light.reconstruct import reconstruct
from depth_nodes.errors import ConfigError
from depth_nodes.nodes import structured_light
from depth_nodes.nodes.structured_light import StructuredLightNode
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.pointcloud import read_pointcloud
from depth_nodes.sim.projector import ProjectorCameraSim, ProjectorSimConfig, reference_plane_scene
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

SIM = ProjectorSimConfig(width=96, height=72, focal_px=84.0, projector_width=96,
                         projector_height=72, projector_focal_px=75.0, seed=4)
PS = PatternSet('phase', 96, 72, steps=4, period=8.0)
PARAMS = {'mode': 'phase', 'phase_steps': 4, 'phase_period': 8.0}
_SIM = ProjectorCameraSim(SIM)
CAPTURE = Lazy(lambda: _SIM.capture(generate_patterns(PS)))
N = PS.count



def _make(context: Context, **params: Any) -> Any:
    overrides = [Parameter(k, value=v) for k, v in {**PARAMS, **params}.items()]
    node = StructuredLightNode(context=context, parameter_overrides=overrides)
    capture(node, history=True)
    node.cb = {spec.topic: spec.callback for spec in node.inputs}
    return node


@pytest.fixture
def node(context: Context) -> Any:
    n = _make(context)
    yield n
    n.destroy_node()


def _send(node: Any, stamp: int, image: np.ndarray, tag: str | None, *,
          projector: bool = True, tag_first: bool = False) -> None:
    h = header(stamp)
    if projector:
        node.cb['/projector/camera_info'](model_to_camera_info(CAPTURE.projector, h))
    if tag is not None and tag_first:
        node.cb['/pattern'](header(stamp, tag))
    node.cb['/image'](array_to_image(image, 'mono8', h))
    node.cb['/camera_info'](model_to_camera_info(CAPTURE.camera, h))
    if tag is not None and not tag_first:
        node.cb['/pattern'](header(stamp, tag))


def _sequence(node: Any, seq: int, *, start: int = 0, order: list[int] | None = None,
              **kwargs: Any) -> None:
    for k, index in enumerate(order if order is not None else range(N)):
        stamp = 10**9 * (seq + 1) + start + 10**6 * k
        _send(node, stamp, CAPTURE.images[index], f'{seq}:{index}/{N}',
              tag_first=bool(k % 2), **kwargs)


def _outputs(node: Any) -> dict[str, Any]:
    return dict(node.outbox)


def test_sequence_gives_depth_points_and_confidence(node: Any) -> None:
    _sequence(node, 0)
    out = _outputs(node)
    assert sorted(out) == ['/confidence', '/depth', '/points2']
    assert node.drops == {}
    depth = image_to_array(out['/depth'])
    geometry = ProjectorGeometry.from_models(CAPTURE.camera, CAPTURE.projector)
    expected = reconstruct(CAPTURE.images, PS, geometry, depth_min=0.2, depth_max=5.0)
    np.testing.assert_array_equal(depth, expected.depth)
    lit = CAPTURE.shadow == 0
    assert np.isfinite(depth[lit]).mean() > 0.97
    # 96 px wide: dZ = Z^2 / (f_p b) du is 0.3 m per projector pixel at 1.5 m
    assert np.nanmedian(np.abs(depth - CAPTURE.depth)) < 0.03
    assert out['/depth'].header.stamp.sec == 1  # the first frame's stamp
    assert out['/depth'].header.frame_id == 'cam'
    cloud = read_pointcloud(out['/points2'])
    np.testing.assert_allclose(cloud['z'], depth, equal_nan=True)
    conf = image_to_array(out['/confidence'])
    assert conf.min() >= 0
    assert conf.max() <= 1
    assert (conf[np.isnan(depth)] == 0).all()


@pytest.mark.parametrize(('order', 'reasons'), [
    ([i for i in range(N) if i != 5], {'sequence_missing_frame': 1, 'sequence_resync': N - 7}),
    ([*range(6), 5, *range(6, N)], {'sequence_repeated_frame': 1, 'sequence_resync': N - 6}),
    ([0, 1, 3, 2, *range(4, N)], {'sequence_missing_frame': 1, 'sequence_resync': N - 3}),
])
def test_broken_sequence_is_dropped_and_the_next_decodes(node: Any, order: list[int],
                                                         reasons: dict[str, int]) -> None:
    _sequence(node, 0, order=order)
    assert node.outbox == []
    assert node.drops == reasons
    _sequence(node, 1)
    assert len(node.outbox) == 3


def test_frames_delivered_out_of_stamp_order(node: Any) -> None:
    stamps = [10**9 + 10**6 * k for k in range(N)]
    order = [0, 1, 3, 2, *range(4, N)]
    for k in order:
        _send(node, stamps[k], CAPTURE.images[k], f'0:{k}/{N}')
    assert node.outbox == []
    assert node.drops['stamp_out_of_order'] == 2  # the image and its camera_info
    assert node.drops['sequence_missing_frame'] == 1
    _sequence(node, 1)
    assert len(node.outbox) == 3


def test_sequence_without_projector_info(node: Any) -> None:
    _sequence(node, 0, projector=False)
    assert node.outbox == []
    assert node.drops == {'no_projector_info': 1}


def test_projector_info_after_the_first_frame_is_fine(node: Any) -> None:
    _send(node, 10**9, CAPTURE.images[0], f'0:0/{N}', projector=False)
    for k in range(1, N):
        _send(node, 10**9 + 10**6 * k, CAPTURE.images[k], f'0:{k}/{N}')
    assert len(node.outbox) == 3


def test_count_mismatch(context: Context) -> None:
    node = _make(context, phase_steps=5)
    try:
        _sequence(node, 0)
        assert node.outbox == []
        assert node.drops == {'pattern_count_mismatch': 1, 'sequence_resync': N - 1}
    finally:
        node.destroy_node()


def test_bad_and_missing_tags(node: Any) -> None:
    _send(node, 10**9, CAPTURE.images[0], 'cam_optical_frame')
    assert node.drops == {'bad_pattern_tag': 1}
    for k in range(6):  # queue_size 5: the sixth untagged frame evicts the first
        _send(node, 2 * 10**9 + k, CAPTURE.images[0], None)
    assert node.drops['pattern_tag_missing'] == 1


def test_tags_without_images_are_counted(node: Any) -> None:
    """A projector driver publishing tags for images that never come: up to twice the
    queue waits, the rest is pattern_tag_unmatched, and what waits at the end of the
    stream is counted too."""
    for k in range(12):  # queue_size 5: ten tags wait, the 11th and 12th evict two
        node.cb['/pattern'](header(10**9 + k, f'0:0/{N}'))
    assert node.drops == {'pattern_tag_unmatched': 2}
    node.finish_stream()
    assert node.drops == {'pattern_tag_unmatched': 12}


def test_a_pattern_set_that_does_not_fit_the_projector_is_dropped(context: Context) -> None:
    """A phase period longer than the projector is wide (a 64 px projector here): the
    parameters are valid, the set built from them is not: bad_pattern_set, no output."""
    node = _make(context, phase_period=100.0)
    try:
        h = header(10**9)
        small = model_to_camera_info(CAPTURE.projector, h)
        small.width, small.height = 64, 48
        node.cb['/projector/camera_info'](small)
        node.cb['/image'](array_to_image(CAPTURE.images[0], 'mono8', h))
        node.cb['/camera_info'](model_to_camera_info(CAPTURE.camera, h))
        node.cb['/pattern'](header(10**9, f'0:0/{N}'))
        assert node.outbox == []
        assert node.drops == {'bad_pattern_set': 1}
    finally:
        node.destroy_node()


def test_unsupported_encoding(node: Any) -> None:
    h = header(10**9)
    msg = array_to_image(CAPTURE.images[0], 'mono8', h)
    msg.encoding = 'yuv420'
    node.cb['/projector/camera_info'](model_to_camera_info(CAPTURE.projector, h))
    node.cb['/image'](msg)
    node.cb['/camera_info'](model_to_camera_info(CAPTURE.camera, h))
    node.cb['/pattern'](header(10**9, f'0:0/{N}'))
    assert node.drops == {'unsupported_encoding': 1}


def test_mode_change_mid_sequence_drops_it(node: Any) -> None:
    for k in range(3):
        _send(node, 10**9 + k, CAPTURE.images[k], f'0:{k}/{N}')
    assert node.set_parameters([Parameter('phase_period', value=12.0)])[0].successful
    _send(node, 10**9 + 3, CAPTURE.images[3], f'0:3/{N}')
    assert node.drops['sequence_incomplete'] == 1


@pytest.mark.parametrize(('name', 'value', 'reason'), [
    ('depth_min', 9.0, 'depth_min (9.0) must be smaller than depth_max (5.0)'),
    ('mode', 'moire', "mode='moire' rejected: must be one of gray, phase, opencv, speckle"),
    ('axes', 'rows', "axes='rows' rejected: must be one of columns, both"),
    ('speckle_window', 10, 'speckle_window=10 rejected: must be odd'),
    ('epipolar_tolerance', -1.0, 'Parameter epipolar_tolerance out of range'),
])
def test_invalid_parameters_are_rejected_with_a_reason(node: Any, name: str, value: Any,
                                                       reason: str) -> None:
    result = node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert reason in result.reason


def test_invalid_startup_parameter(context: Context) -> None:
    with pytest.raises(ConfigError, match="mode='moire' rejected"):
        _make(context, mode='moire')


# ------------------------------------------------------------------ speckle

@pytest.fixture(scope='module')
def speckle_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, Path]:
    dots = speckle_pattern(96, 72, seed=4, density=0.2)[None]
    ref_sim = ProjectorCameraSim(dataclasses.replace(SIM, defocus_sigma=0.5),
                                 reference_plane_scene(1.0))
    path = tmp_path_factory.mktemp('ref') / 'reference.png'
    cv2.imwrite(str(path), ref_sim.render(dots, noise_sigma=0.5)[0])
    image = ProjectorCameraSim(dataclasses.replace(SIM, defocus_sigma=0.5)).render(dots)[0]
    return image, path


def _speckle(node: Any, image: np.ndarray, stamp: int = 10**9) -> None:
    _send(node, stamp, image, None)


def test_speckle_depth(context: Context, speckle_files: tuple[np.ndarray, Path]) -> None:
    image, path = speckle_files
    node = _make(context, mode='speckle', speckle_reference=str(path), speckle_window=9)
    try:
        _speckle(node, image)
        depth = image_to_array(_outputs(node)['/depth'])
        lit = CAPTURE.shadow == 0
        err = np.abs(depth - CAPTURE.depth)[lit & np.isfinite(depth)]
        assert np.isfinite(depth[lit]).mean() > 0.7
        assert np.median(err) < 0.02
    finally:
        node.destroy_node()


@pytest.mark.parametrize(('reference', 'message'), [
    ('', 'speckle mode needs the speckle_reference parameter'),
    ('/nonexistent/ref.png', "cannot read speckle_reference '/nonexistent/ref.png': "
                             'No such file or directory'),
    ('TEXT', 'is not a one-channel image file OpenCV can read'),
    ('SMALL', 'is 10x8; images are 96x72'),
])
def test_bad_speckle_reference_is_a_counted_drop(context: Context, tmp_path: Path,
                                                 caplog: pytest.LogCaptureFixture,
                                                 reference: str, message: str) -> None:
    if reference == 'TEXT':
        reference = str(tmp_path / 'notes.png')
        Path(reference).write_text('not an image')
    elif reference == 'SMALL':
        reference = str(tmp_path / 'small.png')
        cv2.imwrite(reference, np.zeros((8, 10), np.uint8))
    node = _make(context, mode='speckle', speckle_reference=reference)
    try:
        details: list[str] = []
        node.drop = lambda reason, detail: details.append(f'{reason}: {detail}')
        _speckle(node, CAPTURE.images[0])
        assert node.outbox == []
        assert len(details) == 1
        assert details[0].startswith('speckle_reference: ')
        assert message in details[0]
    finally:
        node.destroy_node()


def _data(outbox: list[tuple[str, Any]]) -> list[tuple[str, bytes]]:
    return [(topic, bytes(msg.data)) for topic, msg in outbox]


@pytest.mark.parametrize(('wanted', 'work'), [
    (('/depth', '/points2', '/confidence'), {'reconstruct': 1, 'points_on_rays': 1}),
    (('/depth',), {'reconstruct': 1}),
    (('/points2',), {'reconstruct': 1, 'points_on_rays': 1}),
    ((), {}),
])
def test_a_sequence_is_decoded_only_for_the_outputs_wanted(
        node: Any, monkeypatch: pytest.MonkeyPatch, wanted: tuple[str, ...],
        work: dict[str, int]) -> None:
    _sequence(node, 0)
    everything = _data(node.outbox)
    node.outbox.clear()
    calls = count_calls(monkeypatch, structured_light, 'reconstruct', 'points_on_rays')
    want_only(monkeypatch, *wanted)
    _sequence(node, 1)
    assert _data(node.outbox) == [(topic, data) for topic, data in everything
                                  if topic in wanted]
    assert calls == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if wanted else 1)


def test_a_sequence_gathered_while_nobody_listened_is_decoded_for_a_later_subscriber(
        node: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    want_only(monkeypatch)
    _sequence(node, 0, order=list(range(N - 1)))
    want_only(monkeypatch, '/depth')
    _sequence(node, 0, start=10**6 * (N - 1), order=[N - 1])
    assert [topic for topic, _ in node.outbox] == ['/depth']
    assert node.drops == {}
    assert node.accounting.skipped == 0


def test_a_speckle_image_nobody_wants_is_not_matched(
        context: Context, speckle_files: tuple[np.ndarray, Path],
        monkeypatch: pytest.MonkeyPatch) -> None:
    image, path = speckle_files
    node = _make(context, mode='speckle', speckle_reference=str(path), speckle_window=9)
    try:
        calls = count_calls(monkeypatch, structured_light, 'speckle_depth')
        want_only(monkeypatch)
        _speckle(node, image)
        assert (node.outbox, calls, node.drops) == ([], {}, {})
        assert node.accounting.skipped == 1
        want_only(monkeypatch, '/confidence')
        _speckle(node, image, stamp=2 * 10**9)
        assert [topic for topic, _ in node.outbox] == ['/confidence']
        assert calls == {'speckle_depth': 1}
    finally:
        node.destroy_node()
