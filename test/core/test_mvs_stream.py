"""The multi-view stream's choice of source views: a keyframe turned more than
``max_view_angle_deg`` from a frame is not swept against it (its surfaces look too
foreshortened to match), and a frame left without a source is a ``no_baseline`` NoDepth
that says why."""

from __future__ import annotations

import numpy as np

from depth_nodes.core.mvs.matcher import MvsParams
from depth_nodes.core.mvs.stream import Frame, MvsStream, NoDepth, StreamDepth, StreamParams
from depth_nodes.sim.sequence import SequenceConfig, simulate_sequence


def _outputs(max_angle: float) -> list[tuple[StreamDepth | NoDepth, np.ndarray]]:
    config = SequenceConfig(motion='orbit', width=160, height=120, n_frames=2, orbit_deg=6.0)
    stream = MvsStream(MvsParams(min_depth=0.9, max_depth=8.0, planes=32),
                       StreamParams(max_view_angle_deg=max_angle))
    outputs = []
    for view in simulate_sequence(config):
        angle = view.pose.angle_to(stream.keyframes[-1].pose) if stream.keyframes else 0.0
        assert abs(angle - (6.0 if view.index else 0.0)) < 0.01  # the orbit's step
        out = stream.process(Frame(view.image, view.intrinsics, view.pose, view.stamp_ns))
        assert out is not None
        outputs.append((out, view.depth))
    return outputs


def test_a_source_turned_too_far_is_not_used() -> None:
    (first, _), (second, _) = _outputs(max_angle=5.0)
    assert isinstance(first, NoDepth)
    assert first.reason == 'no_baseline'
    assert isinstance(second, NoDepth)
    assert second.reason == 'no_baseline'
    assert 'turned at most 5 degrees' in second.detail


def test_a_source_within_the_angle_is_swept_against() -> None:
    _, (second, truth) = _outputs(max_angle=10.0)
    assert isinstance(second, StreamDepth)
    ok = np.isfinite(second.depth) & np.isfinite(truth)
    assert ok.mean() > 0.5  # measured 0.68
    relative = np.abs(second.depth[ok] - truth[ok]) / truth[ok]
    assert np.median(relative) < 0.05  # measured 3.6 % (one frame, one source)


def test_a_rig_and_its_keyframes_never_exceed_the_sweeps_sixteen_views() -> None:
    # 17 cameras: the reference and 16 others, plus a keyframe from the step before and
    # max_sources 16: the rig's views come first and the keyframes fill what is left (none)
    config = SequenceConfig(motion='rig', width=48, height=32, n_frames=2, rig_cameras=17,
                            rig_baseline_m=0.01)
    stream = MvsStream(MvsParams(min_depth=0.9, max_depth=8.0, planes=8),
                       StreamParams(max_sources=16))
    views = list(simulate_sequence(config))
    outputs = []
    for step in (0, 1):
        rig = [Frame(v.image, v.intrinsics, v.pose, v.stamp_ns) for v in views
               if v.index == step]
        outputs.append(stream.process(rig[0], rig[1:]))
    assert all(isinstance(out, StreamDepth) for out in outputs)
    assert len(stream.keyframes) >= 1  # the second step had a keyframe to add, and no room
