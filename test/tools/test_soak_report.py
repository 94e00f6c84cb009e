"""`bench soak`'s accounting and report, on hand-made diagnostics (the soak itself runs for
minutes; the README has its figures and the command)."""

from __future__ import annotations

from depth_nodes.tools.bench.soak import SoakReport, middleware_losses, timeline


def test_middleware_losses_are_outputs_minus_inputs_per_topic() -> None:
    totals = {
        '/stereo/left/rectify_left': {'output /stereo/left/image_rect total': '100',
                                      'input /stereo/left/image_raw total': '100'},
        '/stereo/sgm_stereo': {'input /stereo/left/image_rect total': '97',
                               'output /stereo/disparity total': '95'},
        '/stereo/cross_check': {'input /stereo/disparity total': '95'},
        '/stereo/other': {'input /stereo/disparity total': '90'},  # a second subscriber
    }
    assert middleware_losses(totals) == {'/stereo/left/image_rect': 3,
                                          '/stereo/disparity': 5}


def test_report_says_whether_every_lost_frame_is_accounted_for() -> None:
    report = SoakReport(duration_s=60, rate=10, composed=False, sent=600, back=596,
                        drops={'/stereo/sgm_stereo': {'sync_queue_full': 3}},
                        middleware_lost={'/stereo/left/image_rect': 1},
                        memory_mb={'/stereo/sgm_stereo': [300.0, 310.0, 305.0]},
                        answers_ms=[5.0, 7.0, 6.0])
    text = report.format()
    assert 'frames sent 600, point clouds back 596, lost 4' in text
    assert 'counted by /stereo/sgm_stereo: sync_queue_full 3' in text
    assert 'not delivered by the middleware on /stereo/left/image_rect: 1' in text
    assert 'nothing lost uncounted' in text
    assert ('first   300.0 MB  middle   310.0 MB  last   305.0 MB  max   310.0 MB  '
            'second half -5.0 MB') in text
    assert 'every 5 min: 300 305 MB' in text
    assert 'answer median 6 ms, max 7 ms, refused 0' in text
    report.back = 590  # ten lost, four accounted for
    assert 'SOME LOST UNCOUNTED' in report.format()


def test_timeline_shows_every_nth_sample_and_the_last() -> None:
    assert timeline([290.4, 291.0, 292.2, 311.6, 311.4], 2) == '290 292 311'
    assert timeline([290.4, 291.0, 292.2, 311.6], 2) == '290 292 312'
