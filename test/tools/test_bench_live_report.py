"""What `depth-nodes bench live` prints, from given figures and arrival times (the run
itself is a benchmark, timed by hand, never by a test)."""

from __future__ import annotations

import pytest

from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import GraphConfig, NodeSpec, load_graph_config
from depth_nodes.tools.bench.live import (
    CHECKED,
    DISPARITY,
    LEFT_RECT,
    OPENCV_STAGES,
    OURS_STAGES,
    POINTS,
    REPO,
    RIGHT_RECT,
    LiveBench,
    LiveRun,
    bench_live,
    latencies,
    opencv_graph,
    opencv_mode,
    watched,
)


def _run(received: int, fps: float) -> LiveRun:
    return LiveRun('ours', 10.0, 50, received, fps,
                   {'sgm_stereo': (150.0, 180.0)}, {'/stereo/sgm_stereo': 94.0,
                                                    '/stereo/point_cloud': 15.0},
                   {'/stereo/point_cloud': 3}, {'/stereo/sgm_stereo': 155.7}, 10.4)


def test_report_gives_load_processing_time_and_the_bench_process() -> None:
    text = _run(37, 6.33).format()
    assert '50 frames sent at 10 Hz, 37 point clouds back (13 lost), sustained 6.33 Hz' in text
    assert 'sgm_stereo 94%, point_cloud 15%; total 109% of 200%' in text
    assert 'this bench process (publisher, subscribers) 10%' in text
    assert 'processing per frame (ms, from /diagnostics): sgm_stereo 155.7' in text
    assert 'drops reported on /diagnostics: /stereo/point_cloud 3' in text


def test_target_is_met_only_with_every_frame_back_at_the_rate() -> None:
    assert 'target 10 Hz with nothing lost: NOT met' in LiveBench(_run(37, 6.33), None).format()
    assert 'target 10 Hz with nothing lost: NOT met' in LiveBench(_run(49, 9.9), None).format()
    assert 'target 10 Hz with nothing lost: met' in LiveBench(_run(50, 9.9), None).format()


def test_header_names_the_paths_and_opencv_runs_the_matching_mode() -> None:
    assert '128 disparities, 5 paths,' in LiveBench(_run(50, 9.9), None, paths=5).format()
    assert '128 disparities, 8 paths,' in LiveBench(_run(50, 9.9), None).format()
    assert [opencv_mode(p) for p in (4, 5, 8, 16)] == ['MODE_SGBM', 'MODE_SGBM', 'MODE_HH',
                                                        'MODE_HH']
    config = GraphConfig('stereo', [
        NodeSpec('sgm_stereo', 'sgm_stereo', '/stereo', {'paths': 5}, {}),
        NodeSpec('cross_check', 'cross_check', '/stereo', {}, {})])
    for paths, mode in ((5, 0), (8, 1)):
        graph = opencv_graph(config, paths)
        assert [n.plugin for n in graph.nodes] == ['sgm_stereo']  # no cross-check
        assert graph.nodes[0].parameters == {
            'paths': 5, 'disparity_range': 128, 'stereo_algorithm': 1, 'sgbm_mode': mode,
            'right_view': False, 'correlation_window_size': 5, 'P1': 200.0, 'P2': 800.0,
            'uniqueness_ratio': 10.0, 'prefilter_cap': 63, 'disp12_max_diff': 1,
            'speckle_size': 100, 'speckle_range': 2}


def test_opencv_searches_the_same_disparity_range_as_ours() -> None:
    # the shipped graph leaves disparity_range to the census node's default (128); with
    # stereo_algorithm 1 the node would take stereo_image_proc's 64: half OpenCV's work
    shipped = load_graph_config(REPO / 'config' / 'stereo_pipeline.yaml')
    ours = next(n for n in shipped.nodes if n.plugin == 'sgm_stereo')
    assert 'disparity_range' not in ours.parameters
    theirs = next(n for n in opencv_graph(shipped, 5).nodes if n.plugin == 'sgm_stereo')
    assert theirs.parameters['disparity_range'] == 128
    ranged = GraphConfig('stereo', [NodeSpec('sgm_stereo', 'sgm_stereo', '/stereo',
                                             {'disparity_range': 64}, {})])
    assert opencv_graph(ranged).nodes[0].parameters['disparity_range'] == 64


def test_the_bench_watches_every_stage_or_points2_only() -> None:
    assert watched(OURS_STAGES, 'all') == sorted([LEFT_RECT, RIGHT_RECT, DISPARITY, CHECKED,
                                                  POINTS])
    assert watched(OPENCV_STAGES, 'all') == sorted([LEFT_RECT, RIGHT_RECT, DISPARITY, POINTS])
    assert watched(OURS_STAGES, 'points2') == watched(OPENCV_STAGES, 'points2') == [POINTS]


def _arrivals(frame: int) -> dict[str, float]:
    """Times (s) a frame's outputs arrive: published at ``frame``, each stage 10 ms (frame
    0) or 20 ms (the others) after the one before; the right image 2 ms after the left."""
    step = 0.01 if frame == 0 else 0.02
    start = float(frame)
    return {LEFT_RECT: start + step, RIGHT_RECT: start + step + 0.002,
            DISPARITY: start + 2 * step + 0.002, CHECKED: start + 3 * step + 0.002,
            POINTS: start + 4 * step + 0.002}


def _feed(watch: list[str], frames: int = 3, lost: int | None = None
          ) -> tuple[dict[int, float], dict[str, dict[int, float]]]:
    sent = {s: float(s) for s in range(frames)}
    arrived: dict[str, dict[int, float]] = {t: {} for t in watch}
    for s in range(frames):
        for topic, when in _arrivals(s).items():
            if topic in arrived and not (s == lost and topic == POINTS):
                arrived[topic][s] = when
    return sent, arrived


def test_every_stage_has_a_latency_when_every_output_is_watched() -> None:
    sent, arrived = _feed(watched(OURS_STAGES, 'all'))
    got = latencies(OURS_STAGES, sent, arrived, [0, 1, 2])
    assert list(got) == ['rectify', 'sgm_stereo', 'cross_check', 'point_cloud', 'end to end']
    # median of (10, 20, 20) ms and the 95th percentile (the largest of three)
    assert got['rectify'] == pytest.approx((22.0, 22.0))  # both images: the later one
    assert got['sgm_stereo'] == pytest.approx((20.0, 20.0))  # from the later input
    assert got['end to end'] == pytest.approx((82.0, 82.0))
    first = latencies(OURS_STAGES, sent, arrived, [0])
    assert first['cross_check'] == pytest.approx((10.0, 10.0))


def test_watching_points2_gives_the_end_to_end_latency_only() -> None:
    sent, arrived = _feed(watched(OURS_STAGES, 'points2'), frames=4, lost=3)
    got = latencies(OURS_STAGES, sent, arrived, [0, 1, 2, 3])
    assert got == {'end to end': pytest.approx((82.0, 82.0))}  # the lost frame left out
    assert latencies(OURS_STAGES, sent, arrived, [3]) == {}
    text = LiveBench(LiveRun('ours', 10.0, 4, 3, 9.5, got, {'/stereo/sgm_stereo': 90.0}),
                     None, watch='points2').format()
    assert 'the bench subscribed to points2 only (latency: raw frame published -> points2)' \
        in text.splitlines()[0]
    assert '4 frames sent at 10 Hz, 3 point clouds back (1 lost)' in text
    assert 'latency end to end             median    82.0 ms   p95    82.0 ms' in text
    assert 'latency rectify' not in text
    assert 'subscribed to points2' not in LiveBench(_run(50, 9.9), None).format()


def test_an_unknown_watch_is_refused_before_anything_starts() -> None:
    with pytest.raises(ConfigError, match="--watch must be one of all, points2, got 'depth'"):
        bench_live(watch='depth')  # type: ignore[arg-type]
