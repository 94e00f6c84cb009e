"""The cross_check node: outputs equal the core's, message conventions, counted drops,
live parameters, and the accuracy targets on the bundled bags (rectify -> sgm_stereo ->
cross_check through the bag harness, scored by `depth-nodes eval`)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import cv2
import numba
import numpy as np
import pytest
from helpers import STEREO_RANGES, Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, tuner
from targets import assert_confidence_ranks_errors

from depth_nodes.core.cross_check import (
    MISMATCH,
    OCCLUDED,
    OUTSIDE,
    VALID,
    cross_check,
    left_right_check,
)
from depth_nodes.core.metrics import sparsification_auc
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.errors import ConfigError
from depth_nodes.nodes import cross_check as cross_check_node
from depth_nodes.nodes.cross_check import CrossCheckNode
from depth_nodes.ros.disparity import build_disparity, read_disparity
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.evaluate import EvalReport
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

CONFIG = StereoSimConfig(width=160, height=120, n_frames=1, seed=6, distortion_scale=0.0,
                         rotation_deg=0.0, noise_sigma=1.0)
FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))
MATCH = Lazy(lambda: SgmMatcher(SgmParams(disparity_range=48)).match(FRAME.left_rect_gt,
                                                                      FRAME.right_rect_gt))
COMMON = {'focal': 100.0, 'baseline': 0.1, 'min_disparity': 0.0, 'max_disparity': 47.0,
          'delta_d': 1 / 32, 'valid_window': (0, 0, 160, 120)}


@pytest.fixture
def node(context: Context) -> Any:
    n = CrossCheckNode(context=context)
    capture(n)
    yield n
    n.destroy_node()


def _inputs(left: Any = None, right: Any = None, ratio: Any = None,
            ratio_encoding: str = '32FC1', **right_common: Any) -> list[Any]:
    left_msg = build_disparity(MATCH.disparity if left is None else left, None, **COMMON)
    left_msg.header.stamp.sec = 7
    left_msg.header.frame_id = 'left_optical'
    right_msg = build_disparity(MATCH.disparity_right if right is None else right, None,
                                **{**COMMON, **right_common})
    right_msg.header = copy.deepcopy(left_msg.header)
    cost = array_to_image(MATCH.cost_ratio if ratio is None else ratio, ratio_encoding,
                          copy.deepcopy(left_msg.header))
    return [left_msg, right_msg, cost]


def test_good_frame_equals_the_core(node: Any) -> None:
    node.on_frame(*_inputs())
    assert set(node.outbox) == {'/disparity_checked', '/confidence'}
    assert node.drops == {}
    expected = cross_check(MATCH.disparity, MATCH.disparity_right, MATCH.cost_ratio)
    msg = node.outbox['/disparity_checked']
    checked = read_disparity(msg)
    np.testing.assert_array_equal(checked.disparity, expected.disparity)
    conf_msg = node.outbox['/confidence']
    np.testing.assert_array_equal(image_to_array(conf_msg), expected.confidence)
    # conventions: the input's geometry and window, the DisparityImage invalid rule
    assert (msg.f, msg.t, msg.min_disparity, msg.max_disparity) == (100.0, 0.1, 0.0, 47.0)
    assert msg.delta_d == pytest.approx(1 / 32)
    assert checked.valid_window == (0, 0, 160, 120)
    raw = image_to_array(msg.image)
    invalid = np.isnan(checked.disparity)
    assert invalid.sum() > np.isnan(MATCH.disparity).sum()  # the check removed pixels
    assert (raw[invalid] < msg.min_disparity).all()
    for out in (msg, msg.image, conf_msg):
        assert out.header.stamp.sec == 7
        assert out.header.frame_id == 'left_optical'
    assert conf_msg.encoding == '32FC1'
    assert (conf_msg.height, conf_msg.width) == (120, 160)
    conf = image_to_array(conf_msg)
    assert conf.min() >= 0
    assert conf.max() <= 1
    assert (conf[invalid] == 0).all()
    # the checked pixels are better than the ones the check removed
    truth = FRAME.disparity_gt
    kept = ~invalid
    removed = invalid & np.isfinite(MATCH.disparity)
    bad_kept = (np.abs(checked.disparity[kept] - truth[kept]) > 2).mean()
    bad_removed = (np.abs(MATCH.disparity[removed] - truth[removed]) > 2).mean()
    assert bad_kept < 0.5 * bad_removed


def _bad(data: Any, field: str, value: Any) -> Any:
    setattr(data, field, value)
    return data


@pytest.mark.parametrize(('make', 'reason'), [
    (lambda: _inputs(right=MATCH.disparity_right[:, :150], valid_window=None),
     'size_mismatch'),
    (lambda: _inputs(ratio=MATCH.cost_ratio[:100]), 'size_mismatch'),
    (lambda: _inputs(ratio=(MATCH.cost_ratio * 255).astype(np.uint8), ratio_encoding='mono8'),
     'unsupported_encoding'),
    (lambda: [_bad(_inputs()[0], 'image', array_to_image(np.zeros((120, 160), np.uint16),
                                                         '16UC1')), *_inputs()[1:]],
     'disparity_encoding'),
    (lambda: [_inputs()[0], _bad(_inputs()[1], 'image', array_to_image(
        np.zeros((120, 160), np.uint8), 'mono8')), _inputs()[2]], 'disparity_encoding'),
    (lambda: [_inputs()[0], *_inputs()[1:2], _bad(_inputs()[2], 'step', 10)],
     'malformed_image'),
    (lambda: _inputs(max_disparity=63.0), 'range_mismatch'),
])
def test_bad_input_is_a_counted_drop(node: Any, make: Any, reason: str) -> None:
    node.on_frame(*make())
    assert node.outbox == {}
    assert node.drops == {reason: 1}
    node.on_frame(*_inputs())
    assert '/confidence' in node.outbox


def test_malformed_disparity_is_a_counted_drop(node: Any) -> None:
    msgs = _inputs()
    msgs[0].image.step = 10
    node.on_frame(*msgs)
    assert node.outbox == {}
    assert node.drops == {'malformed_image': 1}


def test_stamps_that_never_match_are_counted(node: Any) -> None:
    callbacks = [spec.callback for spec in node.inputs]
    assert [spec.topic for spec in node.inputs] == ['/disparity', '/disparity_right',
                                                    '/cost_ratio']
    for i in range(8):  # the cost ratio arrives with other stamps: no set ever completes
        left, right, ratio = _inputs()
        for msg, sec in ((left, i), (right, i), (ratio, 100 + i)):
            msg.header.stamp.sec = sec
        callbacks[0](left)
        callbacks[1](right)
        callbacks[2](ratio)
    assert node.outbox == {}
    assert node.drops['sync_queue_full'] >= 3
    for callback, msg in zip(callbacks, _inputs(), strict=True):  # a later, complete set
        msg.header.stamp.sec = 200
        callback(msg)
    assert set(node.outbox) == {'/disparity_checked', '/confidence'}


def test_parameters_change_live_and_bad_values_are_rejected(node: Any,
                                                            context: Context) -> None:
    with tuner(node, context) as tune:
        node.on_frame(*_inputs())
        before = read_disparity(node.outbox['/disparity_checked']).disparity
        results = tune(disp12_max_diff=3,
                                 speckle_size=0, fill_holes=True, confidence_window=3)
        assert all(r.successful for r in results), results
        node.on_frame(*_inputs())
        after = read_disparity(node.outbox['/disparity_checked']).disparity
        expected = cross_check(MATCH.disparity, MATCH.disparity_right, MATCH.cost_ratio,
                               disp12_max_diff=3, speckle_size=0, fill=True,
                               confidence_window=3)
        np.testing.assert_array_equal(after, expected.disparity)
        assert np.isfinite(after).sum() > np.isfinite(before).sum()
        for name, value, reason in [
                ('confidence_window', 4, 'must be odd'),
                ('disp12_max_diff', 100.0, 'must be in [-1, 64]'),
                ('disp12_max_diff', 'one', 'must be a number'),
                ('speckle_range', -1, 'must be in [0, 64]')]:
            (result,) = tune(**{name: value})
            assert not result.successful
            assert reason in result.reason, result.reason
        (result,) = tune(queue_size=9)
        assert not result.successful  # read-only
        assert node.params.values['confidence_window'] == 3
        assert node.params.values['disp12_max_diff'] == 3


def test_threads_parameter_applies_from_the_next_frame(node: Any, context: Context) -> None:
    with tuner(node, context) as tune:
        node.on_frame(*_inputs())
        assert (numba.get_num_threads(), cv2.getNumThreads()) == (1, 1)  # the default
        one_thread = read_disparity(node.outbox['/disparity_checked']).disparity
        (result,) = tune(threads=0)
        assert result.successful, result.reason
        node.on_frame(*_inputs())
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
        assert cv2.getNumThreads() == cv2.getNumberOfCPUs()
        every_core = read_disparity(node.outbox['/disparity_checked']).disparity
        np.testing.assert_array_equal(every_core, one_thread)
        (result,) = tune(threads=-1)
        assert not result.successful
        assert node.params.values['threads'] == 0


def test_bad_start_up_value_is_an_error(context: Context) -> None:
    with pytest.raises(ConfigError, match='confidence_window=8 rejected: must be odd'):
        CrossCheckNode(context=context, parameter_overrides=[
            Parameter('confidence_window', value=8)])


# -- accuracy on the bundled bags ---------------------------------------------------------

CHECKED, RAW = '/stereo/disparity_checked', '/stereo/disparity'


@pytest.mark.parametrize('bag', sorted(STEREO_RANGES))
def test_confidence_on_the_bundled_bags(stereo_reports: dict[str, tuple[Path, EvalReport]],
                                        bag: str) -> None:
    """The shipped graph's confidence ranks the errors (``targets``), and eval's figure is
    the one computed here from the bag: the AUC over the raw matcher's pixels, ranking the
    raw matcher's errors by the confidence the checked output carries."""
    path, report = stereo_reports[bag]
    assert_confidence_ranks_errors(report, own_limit=5.0)
    checked = report.row(CHECKED)
    assert report.row(RAW).auc_ratio is None  # the confidence belongs to the checked output
    conf, raw, gt = [], [], []
    with BagReader(path) as reader:
        msgs: dict[str, dict[int, Any]] = {}
        for m in reader.messages(['/stereo/confidence', RAW, '/stereo/left/disparity_gt']):
            msg = m.deserialize()
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            msgs.setdefault(m.topic, {})[stamp] = msg
    for stamp, gt_msg in sorted(msgs['/stereo/left/disparity_gt'].items()):
        gt.append(read_disparity(gt_msg).disparity)
        raw.append(read_disparity(msgs[RAW][stamp]).disparity)
        conf.append(image_to_array(msgs['/stereo/confidence'][stamp]))
    g, r = np.concatenate(gt), np.concatenate(raw)
    scores = sparsification_auc(np.concatenate(conf), np.abs(r - g),
                                valid_mask=np.isfinite(g) & np.isfinite(r))
    assert scores.ratio == pytest.approx(checked.auc_ratio)
    with BagReader(path) as reader:
        out = next(m for m in reader.messages([CHECKED])).deserialize()
    assert np.isfinite(read_disparity(out).disparity).all()  # the shipped output is dense


def test_disp12_max_diff_zero_is_one_and_minus_one_is_off(context: Context) -> None:
    """stereo_image_proc's default 0 (which also reaches this node through a `/**` entry)
    checks at 1 px, as OpenCV's StereoSGBM reads it; -1 keeps every pixel with a partner,
    whatever the two views say."""
    def run(value: int) -> np.ndarray:
        node = CrossCheckNode(context=context, parameter_overrides=[
            Parameter('disp12_max_diff', value=value), Parameter('speckle_size', value=0)])
        capture(node)
        try:
            node.on_frame(*_inputs())
            return read_disparity(node.outbox['/disparity_checked']).disparity.copy()
        finally:
            node.destroy_node()

    np.testing.assert_array_equal(run(0), run(1))
    kept = run(-1)
    lr = left_right_check(MATCH.disparity, MATCH.disparity_right, max_diff=1.0)
    with_partner = np.isin(lr.labels, (VALID, MISMATCH, OUTSIDE)) | (
        (lr.labels == OCCLUDED) & np.isfinite(lr.difference))
    np.testing.assert_array_equal(np.isfinite(kept), with_partner)
    assert (lr.labels == MISMATCH).any()  # there was something to drop


def test_a_set_still_incomplete_when_the_stream_ends_is_counted(node: Any) -> None:
    """The offline harness ends the stream: the frame still waiting for its partners is
    one stream_ended drop, not lost silently."""
    left, right, _ = _inputs()
    callbacks = {spec.topic: spec.callback for spec in node.inputs}
    callbacks['/disparity'](left)
    callbacks['/disparity_right'](right)
    assert node.drops == {}
    node.finish_stream()
    assert node.drops == {'stream_ended': 1}
    assert node.outbox == {}



@pytest.mark.parametrize(('wanted', 'work'), [
    (('/disparity_checked', '/confidence'),
     {'cross_check': 1, 'build_disparity': 1, 'array_to_image': 1}),
    (('/disparity_checked',), {'cross_check': 1, 'build_disparity': 1}),
    (('/confidence',), {'cross_check': 1, 'array_to_image': 1}),
    ((), {}),
])
def test_only_the_outputs_wanted_are_built(node: Any, monkeypatch: pytest.MonkeyPatch,
                                           wanted: tuple[str, ...],
                                           work: dict[str, int]) -> None:
    node.on_frame(*_inputs())
    everything = dict(node.outbox)
    node.outbox.clear()
    calls = count_calls(monkeypatch, cross_check_node, 'cross_check', 'build_disparity',
                        'array_to_image')
    want_only(monkeypatch, *wanted)
    node.on_frame(*_inputs())
    assert node.outbox == {topic: everything[topic] for topic in wanted}
    assert calls == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if wanted else 1)


def test_the_learned_confidence_is_the_cores(context: Context) -> None:
    from depth_nodes.core.learned.confidence import shipped_confidence

    node = CrossCheckNode(context=context, parameter_overrides=[
        Parameter('confidence_model', value='learned')])
    capture(node)
    try:
        node.on_frame(*_inputs())
        expected = cross_check(MATCH.disparity, MATCH.disparity_right, MATCH.cost_ratio,
                               model=shipped_confidence())
        np.testing.assert_array_equal(image_to_array(node.outbox['/confidence']),
                                      expected.confidence)
        assert node.drops == {}
    finally:
        node.destroy_node()


def test_unreadable_confidence_weights_are_a_counted_drop(context: Context,
                                                          monkeypatch: pytest.MonkeyPatch,
                                                          tmp_path: Path) -> None:
    from depth_nodes.core.learned import confidence

    monkeypatch.setattr(confidence, 'SHIPPED', tmp_path / 'gone.npz')
    confidence.shipped_confidence.cache_clear()
    node = CrossCheckNode(context=context, parameter_overrides=[
        Parameter('confidence_model', value='learned')])
    capture(node)
    try:
        node.on_frame(*_inputs())
        assert node.outbox == {}
        assert node.drops == {'no_weights': 1}
    finally:
        node.destroy_node()
        confidence.shipped_confidence.cache_clear()


def test_confidence_weights_read_another_model_and_an_unreadable_file_is_refused(
        context: Context, tmp_path: Path) -> None:
    import shutil

    from depth_nodes.core.learned.confidence import SHIPPED, ConfidenceModel

    copy = tmp_path / 'mine.npz'
    shutil.copy(SHIPPED, copy)
    learned = Parameter('confidence_model', value='learned')
    with pytest.raises(ConfigError, match='confidence_weights: cannot read confidence'):
        CrossCheckNode(context=context, parameter_overrides=[
            learned, Parameter('confidence_weights', value=str(tmp_path / 'missing.npz'))])
    node = CrossCheckNode(context=context, parameter_overrides=[
        learned, Parameter('confidence_weights', value=str(copy))])
    capture(node)
    try:
        node.on_frame(*_inputs())
        expected = cross_check(MATCH.disparity, MATCH.disparity_right, MATCH.cost_ratio,
                               model=ConfidenceModel.load(copy))
        np.testing.assert_array_equal(image_to_array(node.outbox['/confidence']),
                                      expected.confidence)
        refused = node.set_parameters([Parameter('confidence_weights',
                                                 value=str(tmp_path / 'x.npz'))])[0]
        assert not refused.successful
        assert 'cannot read confidence' in refused.reason
    finally:
        node.destroy_node()
