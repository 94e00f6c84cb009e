"""The sgm_stereo node: counted drops for bad input, live parameter changes, both backends."""

from __future__ import annotations

import threading
from typing import Any

import numba
import numpy as np
import pytest
from helpers import Lazy
from rclpy.context import Context
from rclpy.parameter import Parameter
from ros_helpers import capture, tuner

from depth_nodes.core.opencv_stereo import opencv_sgbm
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.errors import ConfigError
from depth_nodes.nodes import sgm_stereo
from depth_nodes.nodes.sgm_stereo import SgmStereoNode, opencv_settings, sgm_params
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim import StereoSimConfig, simulate_stereo
from harness_nodes import count_calls, want_only

pytestmark = pytest.mark.ros

CONFIG = StereoSimConfig(width=160, height=120, n_frames=1, seed=6, distortion_scale=0.0,
                         rotation_deg=0.0, noise_sigma=1.0)
FRAME = Lazy(lambda: next(simulate_stereo(CONFIG)))



@pytest.fixture
def node(context: Context) -> Any:
    n = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48)])
    capture(n)
    yield n
    n.destroy_node()


def _inputs(changes: dict[Any, Any] | None = None) -> list[Any]:
    changes = dict(changes or {})
    left = changes.pop('left', FRAME.left_rect_gt)
    right = changes.pop('right', FRAME.right_rect_gt)
    msgs = [array_to_image(left, changes.pop('left_encoding', 'mono8')),
            model_to_camera_info(FRAME.left_camera),
            array_to_image(right, changes.pop('right_encoding', 'mono8')),
            model_to_camera_info(FRAME.right_camera)]
    for (index, field), value in changes.items():
        setattr(msgs[index], field, value)
    return msgs


def test_good_frame_publishes_three_outputs(node: Any) -> None:
    node.on_frame(*_inputs())
    assert set(node.outbox) == {'/disparity', '/disparity_right', '/cost_ratio'}
    frame = read_disparity(node.outbox['/disparity'])
    expected = SgmMatcher(sgm_params(node.params.values)).match(FRAME.left_rect_gt,
                                                               FRAME.right_rect_gt)
    np.testing.assert_array_equal(frame.disparity, expected.disparity)
    good = np.abs(frame.disparity - FRAME.disparity_gt) < 2
    assert good.mean() > 0.75
    assert node.drops == {}


@pytest.mark.parametrize(('changes', 'reason'), [
    ({'right': FRAME.right_rect_gt[:, :150]}, 'size_mismatch'),
    ({'right': FRAME.right_rect_gt.astype(np.uint16) * 257, 'right_encoding': 'mono16'},
     'encoding_mismatch'),
    ({'left': FRAME.left_rect_gt.astype(np.float32), 'left_encoding': '32FC1',
      'right': FRAME.right_rect_gt.astype(np.float32), 'right_encoding': '32FC1'},
     'unsupported_encoding'),
    ({(1, 'k'): [0.0] * 9}, 'uncalibrated'),
    ({(3, 'p'): [100.0, 0, 80, 5.0, 0, 100, 60, 0, 0, 0, 1, 0]}, 'bad_calibration'),
    ({(1, 'width'): 320, (3, 'width'): 320}, 'camera_info_mismatch'),
    ({(0, 'step'): 10}, 'malformed_image'),
])
def test_bad_input_is_a_counted_drop(node: Any, changes: dict[Any, Any], reason: str) -> None:
    node.on_frame(*_inputs(changes))
    assert node.outbox == {}
    assert node.drops == {reason: 1}
    node.on_frame(*_inputs())
    assert '/disparity' in node.outbox


class _Recorder:
    """Stands in for an rclpy publisher: notes what would have gone out (any thread)."""

    def __init__(self, topic: str, log: list[tuple[str, Any]]) -> None:
        self.topic, self.log = topic, log

    def publish(self, msg: Any) -> None:
        self.log.append((self.topic, msg))

    def get_subscription_count(self) -> int:
        return 1  # somebody listens: the output is wanted


def test_parallel_frames_publish_every_frame_in_stamp_order(context: Context) -> None:
    """Two frames matched at once on worker threads: each frame's three outputs equal the
    frame-by-frame matcher's, and they go out in the order the frames came."""
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('parallel_frames', value=2),
        Parameter('threads', value=1)])
    log: list[tuple[str, Any]] = []
    for out in node.outputs.values():
        out._publisher = _Recorder(out.topic, log)  # live path (no sink), no DDS
    shifted = np.roll(FRAME.right_rect_gt, 3, axis=1)  # a second, different frame
    try:
        for i in range(6):
            msgs = _inputs({'right': shifted} if i % 2 else None)
            for msg in msgs:
                msg.header.stamp.sec = 100 + i
            node.on_frame(*msgs)
        node._workers.drain()
        assert node.drops == {}
        values = {kv.key: kv.value for kv in node.diagnostics().values}
        assert values['frames processed'] == '6'
    finally:
        node.destroy_node()
    matcher = SgmMatcher(sgm_params(node.params.values))
    expected = [matcher.match(FRAME.left_rect_gt, FRAME.right_rect_gt).disparity.copy(),
                matcher.match(FRAME.left_rect_gt, shifted).disparity.copy()]
    for topic in ('/disparity', '/disparity_right', '/cost_ratio'):
        stamps = [m.header.stamp.sec for t, m in log if t == topic]
        assert stamps == list(range(100, 106)), topic
    disparities = [m for t, m in log if t == '/disparity']
    for i, msg in enumerate(disparities):
        np.testing.assert_array_equal(read_disparity(msg).disparity, expected[i % 2])


def test_a_failing_match_in_parallel_mode_is_a_counted_drop(context: Context,
                                                            monkeypatch: Any) -> None:
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('parallel_frames', value=2)])
    log: list[tuple[str, Any]] = []
    for out in node.outputs.values():
        out._publisher = _Recorder(out.topic, log)
    calls = 0
    lock = threading.Lock()  # the workers call match at the same time
    real = SgmMatcher.match

    def flaky(self: SgmMatcher, *args: Any, **kwargs: Any) -> Any:
        nonlocal calls
        with lock:
            calls += 1
            fail = calls == 2
        if fail:
            raise MemoryError('no room for the buffers')
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SgmMatcher, 'match', flaky)
    try:
        for i in range(3):
            msgs = _inputs()
            for msg in msgs:
                msg.header.stamp.sec = 200 + i
            node.on_frame(*msgs)
        node._workers.drain()
    finally:
        node.destroy_node()
    assert node.drops == {'match_failed': 1}
    assert len([m for t, m in log if t == '/disparity']) == 2


def test_range_wider_than_the_image(context: Context) -> None:
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=200)])
    node.sink = lambda topic, msg: None
    try:
        node.on_frame(*_inputs())
        assert node.drops == {'range_too_wide': 1}
    finally:
        node.destroy_node()


def test_missing_camera_info_is_counted(node: Any) -> None:
    callbacks = [spec.callback for spec in node.inputs]
    for i in range(7):  # images only: sets never complete, the queue (5) overflows
        left, _, right, _ = _inputs()
        for msg in (left, right):
            msg.header.stamp.sec = i
        callbacks[0](left)
        callbacks[2](right)
    assert node.outbox == {}
    assert node.drops['sync_queue_full'] >= 2


def test_parameters_change_live_and_bad_values_are_rejected(node: Any,
                                                            context: Context) -> None:
    with tuner(node, context) as tune:
        node.on_frame(*_inputs())
        before = read_disparity(node.outbox['/disparity']).disparity.copy()
        (result,) = tune(P2=900.0)
        assert result.successful, result.reason
        node.on_frame(*_inputs())
        after = read_disparity(node.outbox['/disparity']).disparity
        assert not np.array_equal(before, after, equal_nan=True)
        expected = SgmMatcher(sgm_params(node.params.values)).match(FRAME.left_rect_gt,
                                                                   FRAME.right_rect_gt)
        np.testing.assert_array_equal(after, expected.disparity)
        (rejected,) = tune(P1=1000.0)
        assert not rejected.successful
        assert 'SGM parameter P2=900: must be >= P1 (1000)' in rejected.reason
        (rejected,) = tune(paths=6)
        assert not rejected.successful
        assert 'must be one of 4, 5, 8, 16' in rejected.reason
        (accepted,) = tune(disparity_range=50)  # any range for census_sgm
        assert accepted.successful
        (rejected,) = tune(stereo_algorithm=1)
        assert not rejected.successful
        assert ('disparity_range (50) must be a multiple of 16 with OpenCV StereoSGBM'
                in rejected.reason)
        assert node.params.values['P2'] == 900.0
        assert node.params.values['stereo_algorithm'] == 2
        results = tune(disparity_range=64, uniqueness_ratio=5.0, threads=1)
        assert all(r.successful for r in results)
        node.on_frame(*_inputs())
        assert node.outbox['/disparity'].max_disparity == 63.0
        assert numba.get_num_threads() == 1  # the kernels of this frame ran on one thread
        one_thread = read_disparity(node.outbox['/disparity']).disparity.copy()
        (result,) = tune(threads=0)
        assert result.successful
        node.on_frame(*_inputs())
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
        np.testing.assert_array_equal(read_disparity(node.outbox['/disparity']).disparity,
                                      one_thread)
        (result,) = tune(paths=5)  # one pass: the matcher's single-pass mode from now on
        assert result.successful
        node.on_frame(*_inputs())
        single = SgmMatcher(sgm_params(node.params.values)).match(FRAME.left_rect_gt,
                                                                 FRAME.right_rect_gt)
        assert single.disparity.shape == one_thread.shape
        np.testing.assert_array_equal(read_disparity(node.outbox['/disparity']).disparity,
                                      single.disparity)
        assert not np.array_equal(single.disparity, one_thread, equal_nan=True)


def test_the_checks_of_the_raw_output_are_parameters(node: Any, context: Context) -> None:
    """The raw output's own checks (left-right, speckles, border extrapolation, brightness
    matching) reach the matcher from the node's parameters: each change gives the core's
    output for the new values, and switching them all off keeps every pixel."""
    with tuner(node, context) as tune:
        node.on_frame(*_inputs())
        checked = read_disparity(node.outbox['/disparity']).disparity.copy()
        results = tune(disp12_max_diff=-1, speckle_size=0, uniqueness_ratio=0.0,
                       border_cost=3.5, border_extrapolation=1.0)
        assert all(r.successful for r in results), results
        node.on_frame(*_inputs())
        loose = read_disparity(node.outbox['/disparity']).disparity.copy()
        assert np.isfinite(loose).all()  # no check left: every pixel has a disparity
        assert np.isnan(checked).sum() > 0
        for change in ({'border_cost': 0.0}, {'match_brightness': False},
                       {'disp12_max_diff': 1, 'speckle_size': 50, 'speckle_range': 1}):
            results = tune(**change)
            assert all(r.successful for r in results), results
            node.on_frame(*_inputs())
            want = SgmMatcher(sgm_params(node.params.values)).match(FRAME.left_rect_gt,
                                                                   FRAME.right_rect_gt)
            np.testing.assert_array_equal(read_disparity(node.outbox['/disparity']).disparity,
                                          want.disparity)
        (rejected,) = tune(border_extrapolation=1.5)
        assert not rejected.successful
        assert 'out of range' in rejected.reason


def test_opencv_sgbm_matches_stereosgbm(context: Context) -> None:
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('stereo_algorithm', value=1), Parameter('disparity_range', value=48)])
    outbox: dict[str, Any] = {}
    node.sink = lambda topic, msg: outbox.__setitem__(topic, msg)
    try:
        node.on_frame(*_inputs())
        assert set(outbox) == {'/disparity', '/disparity_right', '/cost_ratio'}
        got = read_disparity(outbox['/disparity'])
        expected = opencv_sgbm(FRAME.left_rect_gt, FRAME.right_rect_gt,
                               opencv_settings(node.params.values), disparity_range=48)
        np.testing.assert_array_equal(got.disparity, expected)
        assert got.delta_d == pytest.approx(1 / 16)
        # the right view: the mirrored pair, so x_left = x_right + d where both agree
        right = read_disparity(outbox['/disparity_right']).disparity
        mirrored = opencv_sgbm(FRAME.right_rect_gt[:, ::-1].copy(),
                               FRAME.left_rect_gt[:, ::-1].copy(),
                               opencv_settings(node.params.values), disparity_range=48)
        np.testing.assert_array_equal(right, mirrored[:, ::-1])
        ys, xs = np.nonzero(np.isfinite(expected))
        xr = np.rint(xs - expected[ys, xs]).astype(int)
        inside = (xr >= 0) & np.isfinite(right[ys, np.clip(xr, 0, None)])
        agree = np.abs(right[ys[inside], xr[inside]] - expected[ys[inside], xs[inside]]) <= 1
        assert agree.mean() > 0.8
        assert np.isnan(image_to_array(outbox['/cost_ratio'])).all()
        outbox.clear()
        node.set_parameters([Parameter('right_view', value=False)])
        node.on_frame(*_inputs())
        assert set(outbox) == {'/disparity'}  # as stereo_image_proc
    finally:
        node.destroy_node()


def test_compressed_and_bayer_inputs_match_the_raw_grey_pair(context: Context) -> None:
    """image_transport: compressed takes CompressedImage on left|right/image_rect/compressed;
    lossless PNG gives the raw pair's disparity bit for bit."""
    from depth_nodes.ros.transport import compress_image

    n = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('image_transport', value='compressed')])
    capture(n)
    try:
        assert [spec.topic for spec in n.inputs] == [
            '/left/image_rect/compressed', '/left/camera_info', '/right/image_rect/compressed',
            '/right/camera_info']
        msgs = _inputs()
        msgs[0] = compress_image(FRAME.left_rect_gt, 'mono8', codec='png')
        msgs[2] = compress_image(FRAME.right_rect_gt, 'mono8', codec='png')
        n.on_frame(*msgs)
        expected = SgmMatcher(sgm_params(n.params.values)).match(FRAME.left_rect_gt,
                                                                  FRAME.right_rect_gt)
        np.testing.assert_array_equal(read_disparity(n.outbox['/disparity']).disparity,
                                      expected.disparity)
        assert n.drops == {}
    finally:
        n.destroy_node()


def test_hostile_compressed_and_bayer_inputs_are_counted(context: Context) -> None:
    from sensor_msgs.msg import CompressedImage

    from depth_nodes.ros.transport import compress_image

    n = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('image_transport', value='compressed')])
    capture(n)
    try:
        good = compress_image(FRAME.right_rect_gt, 'mono8', codec='png')
        damaged = compress_image(FRAME.left_rect_gt, 'mono8', codec='jpeg')
        damaged.data = bytes(damaged.data)[:50]
        odd_bayer = compress_image(np.zeros((120, 159), np.uint8), 'bayer_rggb8', codec='png')
        for left, reason in ((damaged, 'decode_failed'), (odd_bayer, 'malformed_image'),
                             (CompressedImage(format='mono8; h264 compressed mono8',
                                              data=bytes(good.data)), 'unsupported_format')):
            msgs = _inputs()
            msgs[0], msgs[2] = left, good
            n.on_frame(*msgs)
            assert n.drops[reason] == 1, n.drops
        assert n.outbox == {}
    finally:
        n.destroy_node()


def test_a_census_rule_is_the_same_in_the_core_and_in_the_node(node: Any,
                                                                 context: Context) -> None:
    """The node's census parameters come from SgmParams' settings: the same description,
    and a value the core refuses is refused on set with the core's reason; P2's limit
    follows the number of paths (4 paths take up to 16128, 8 only 7936)."""
    from dataclasses import replace

    from depth_nodes.core.settings import rules
    from depth_nodes.core.sgm import SgmParams
    from depth_nodes.errors import ArgumentError
    from depth_nodes.nodes.sgm_stereo import CENSUS_ONLY
    from depth_nodes.ros.params import ParamSpec

    described = {p.name: p.description for p in node.params._specs.values()
                 if isinstance(p, ParamSpec)}
    for name, _, rule in rules(SgmParams):
        if name in CENSUS_ONLY:
            assert described[name] == 'census SGM: ' + rule.description
    with tuner(node, context) as tune:
        for name, bad in (('census_width', 6), ('intensity_cost', 'sad'),
                          ('subpixel', 'cubic')):
            (rejected,) = tune(**{name: bad})
            assert not rejected.successful
            with pytest.raises(ArgumentError, match=name) as core:
                replace(SgmParams(), **{name: bad}).validate()
            reason = str(core.value).split(': ', 1)[1]
            assert rejected.reason == f'{name}={bad!r} rejected: {reason}'
        assert all(r.successful for r in tune(paths=4, P2=16000.0))
        (rejected,) = tune(paths=8)
        assert not rejected.successful
        assert 'SGM parameter P2=16000: must be <= 7936 with 8 paths' in rejected.reason
        assert all(r.successful for r in tune(P2=7936.0, paths=8))


def test_offline_the_cores_of_parallel_frames_go_to_the_one_frame(context: Context,
                                                                 monkeypatch: Any) -> None:
    """The offline harness (a sink: `process`) matches frame by frame, so with threads: 1,
    parallel_frames: 2 (the shipped graph) the matcher ran on one thread and left a core to
    the bag writer alone; it now matches each frame on 2, with the same output."""
    seen: list[int] = []
    real = SgmMatcher.match

    def spy(self: SgmMatcher, *args: Any, **kwargs: Any) -> Any:
        seen.append(numba.get_num_threads())
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SgmMatcher, 'match', spy)
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('parallel_frames', value=2),
        Parameter('threads', value=1)])
    capture(node)
    try:
        node.on_frame(*_inputs())
    finally:
        node.destroy_node()
    assert seen == [min(2, numba.config.NUMBA_NUM_THREADS)]  # (clamped to the cores)
    numba.set_num_threads(1)
    expected = real(SgmMatcher(sgm_params(node.params.values)), FRAME.left_rect_gt,
                    FRAME.right_rect_gt)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    np.testing.assert_array_equal(read_disparity(node.outbox['/disparity']).disparity,
                                  expected.disparity)


@pytest.mark.parametrize(('wanted', 'work'), [
    (('/disparity', '/disparity_right', '/cost_ratio'),
     {'match': 1, 'build_disparity': 2, 'array_to_image': 1}),
    (('/disparity',), {'match': 1, 'build_disparity': 1}),
    (('/cost_ratio',), {'match': 1, 'array_to_image': 1}),  # the matcher gives all three
    ((), {}),
])
def test_census_builds_only_the_outputs_wanted(node: Any, monkeypatch: pytest.MonkeyPatch,
                                               wanted: tuple[str, ...],
                                               work: dict[str, int]) -> None:
    node.on_frame(*_inputs())
    everything = dict(node.outbox)
    node.outbox.clear()
    matched = count_calls(monkeypatch, SgmMatcher, 'match')
    built = count_calls(monkeypatch, sgm_stereo, 'build_disparity', 'array_to_image')
    want_only(monkeypatch, *wanted)
    node.on_frame(*_inputs())
    assert node.outbox == {topic: everything[topic] for topic in wanted}
    assert matched + built == work
    assert node.drops == {}
    assert node.accounting.skipped == (0 if wanted else 1)


@pytest.mark.parametrize(('right_view', 'wanted', 'matches'), [
    (True, ('/disparity', '/disparity_right', '/cost_ratio'), 2),
    (True, ('/disparity',), 1),
    (True, ('/disparity_right',), 1),  # the mirrored pair only
    (True, ('/cost_ratio',), 0),  # all NaN: OpenCV has no matching cost
    (False, ('/disparity_right', '/cost_ratio'), 0),  # never published: skipped
])
def test_opencv_matches_only_the_views_wanted(context: Context,
                                              monkeypatch: pytest.MonkeyPatch,
                                              right_view: bool, wanted: tuple[str, ...],
                                              matches: int) -> None:
    node = capture(SgmStereoNode(context=context, parameter_overrides=[
        Parameter('stereo_algorithm', value=1), Parameter('disparity_range', value=48),
        Parameter('right_view', value=right_view)]))
    try:
        node.on_frame(*_inputs())
        everything = dict(node.outbox)
        node.outbox.clear()
        calls = count_calls(monkeypatch, sgm_stereo, 'opencv_disparity')
        want_only(monkeypatch, *wanted)
        node.on_frame(*_inputs())
        published = {topic: everything[topic] for topic in wanted if topic in everything}
        assert node.outbox == published
        assert calls['opencv_disparity'] == matches
        assert node.drops == {}
        assert node.accounting.skipped == (0 if published else 1)
    finally:
        node.destroy_node()


def test_parallel_frames_decide_what_is_wanted_before_the_work(
        context: Context, monkeypatch: pytest.MonkeyPatch) -> None:
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('parallel_frames', value=2),
        Parameter('threads', value=1)])
    log: list[tuple[str, Any]] = []
    for out in node.outputs.values():
        out._publisher = _Recorder(out.topic, log)  # live path (no sink), no DDS
    built = count_calls(monkeypatch, sgm_stereo, 'build_disparity', 'array_to_image')
    want_only(monkeypatch, '/disparity_right')
    try:
        for i in range(4):
            msgs = _inputs()
            for msg in msgs:
                msg.header.stamp.sec = 100 + i
            node.on_frame(*msgs)
        want_only(monkeypatch)  # nobody now: the frames in flight still publish
        node._workers.drain()
    finally:
        node.destroy_node()
    assert [(topic, msg.header.stamp.sec) for topic, msg in log] == [
        ('/disparity_right', 100 + i) for i in range(4)]
    assert built == {'build_disparity': 4}
    assert node.drops == {}


def test_the_learned_cost_runs_in_the_node_as_in_the_core(context: Context) -> None:
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48),
        Parameter('matching_cost', value='census+learned')])
    capture(node)
    try:
        node.on_frame(*_inputs())
        expected = SgmMatcher(sgm_params(node.params.values)).match(FRAME.left_rect_gt,
                                                                   FRAME.right_rect_gt)
        assert sgm_params(node.params.values).matching_cost == 'census+learned'
        frame = read_disparity(node.outbox['/disparity'])
        np.testing.assert_array_equal(frame.disparity, expected.disparity)
        assert (np.abs(frame.disparity - FRAME.disparity_gt) < 2).mean() > 0.75
        assert node.drops == {}
    finally:
        node.destroy_node()


def test_unreadable_learned_weights_are_a_counted_drop(context: Context,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       tmp_path: Any) -> None:
    from depth_nodes.core.learned import network

    monkeypatch.setattr(network, 'SHIPPED', tmp_path / 'gone.npz')
    network.shipped_features.cache_clear()
    node = SgmStereoNode(context=context, parameter_overrides=[
        Parameter('disparity_range', value=48), Parameter('matching_cost', value='learned')])
    capture(node)
    try:
        node.on_frame(*_inputs())
        assert node.outbox == {}
        assert node.drops == {'no_weights': 1}
    finally:
        node.destroy_node()
        network.shipped_features.cache_clear()


def test_learned_weights_read_another_network_and_an_unreadable_file_is_refused(
        context: Context, tmp_path: Any) -> None:
    """learned_weights: a file train-cost wrote (here the shipped one, copied) gives the
    same disparity as the shipped weights; a file it cannot read is refused at start-up
    and when set, with the reason, and the node keeps its weights."""
    import shutil

    from depth_nodes.core.learned.network import SHIPPED

    copy = tmp_path / 'mine.npz'
    shutil.copy(SHIPPED, copy)
    (tmp_path / 'broken.npz').write_bytes(b'not an npz')
    common = [Parameter('disparity_range', value=48),
              Parameter('matching_cost', value='census+learned')]
    with pytest.raises(ConfigError, match='learned_weights: cannot read feature weights'):
        SgmStereoNode(context=context, parameter_overrides=[
            *common, Parameter('learned_weights', value=str(tmp_path / 'missing.npz'))])
    node = SgmStereoNode(context=context, parameter_overrides=[
        *common, Parameter('learned_weights', value=str(copy))])
    capture(node)
    try:
        node.on_frame(*_inputs())
        expected = SgmMatcher(SgmParams(disparity_range=48, matching_cost='census+learned',
                                        learned_weights=str(copy))).match(
            FRAME.left_rect_gt, FRAME.right_rect_gt)
        np.testing.assert_array_equal(read_disparity(node.outbox['/disparity']).disparity,
                                      expected.disparity)
        refused = node.set_parameters([Parameter('learned_weights',
                                                 value=str(tmp_path / 'broken.npz'))])[0]
        assert not refused.successful
        assert 'cannot read feature weights' in refused.reason
        assert node.params.values['learned_weights'] == str(copy)
    finally:
        node.destroy_node()
