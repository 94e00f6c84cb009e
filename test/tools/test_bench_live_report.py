"""What `depth-nodes bench --live` prints, from given figures (the run itself is a
benchmark, timed by hand, never by a test)."""

from __future__ import annotations

from depth_nodes.graph.description import GraphConfig, NodeSpec
from depth_nodes.tools.bench.live import LiveBench, LiveRun, opencv_graph, opencv_mode


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
            'paths': 5, 'stereo_algorithm': 1, 'sgbm_mode': mode, 'right_view': False,
            'correlation_window_size': 5, 'P1': 200.0, 'P2': 800.0, 'uniqueness_ratio': 10.0,
            'prefilter_cap': 63, 'disp12_max_diff': 1, 'speckle_size': 100,
            'speckle_range': 2}
