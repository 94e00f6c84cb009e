"""Multi-view stereo against ground truth: the bundled sequences through the shipped graphs
(config/multiview_pipeline.yaml, config/multiview_rig.yaml) scored by `depth-nodes eval`,
the real Middlebury temple views scored by their agreement with each other, and pose
noise through the core.

The bundled bags are 320x240 (64 planes): the targets (median |dZ|/Z <= 1 %, 90 %
within 2 %) are met at 640x480 in part only, and not at 320x240, where a plane step is
1 - 2 % of the depth (docs/multiview.md#accuracy has the measurements). The thresholds
below are the measured figures with a margin, so that a change that loses accuracy fails:
bundled sideways sequence from frame 10 on, measured median 1.06 %, 66.5 % within 2 %,
93.4 % coverage, 62.7 % within one sigma; the rig against the stereo graph on its middle
and right cameras, measured dense bad-1 7.1 % against 14.7 %, bad-2 4.2 % against 12.1 %,
and bad-1 23.6 % against 77.4 % in the pixels the right camera does not see (6.1 % of
them).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import REPO, run_cli

from depth_nodes.core.mvs.matcher import MvsParams
from depth_nodes.core.mvs.stream import Frame, MvsStream, StreamDepth, StreamParams
from depth_nodes.graph.description import load_graph_config
from depth_nodes.sim.sequence import SequenceConfig, simulate_sequence
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.evaluation.multiview import (
    MultiviewReport,
    evaluate_multiview_bag,
    evaluate_views_bag,
)

pytestmark = pytest.mark.slow

BAGS = REPO / 'bags'
TEMPLE = REPO / 'test' / 'data' / 'middlebury_mvs' / 'templeSparseRing'
BBOX = ('-0.073568', '0.021728', '-0.012445', '0.028855', '0.181892', '0.062736')


def _process(bag: Path, out: Path, config: str, params: Path | None = None) -> Any:
    report = process_bag(bag, out, config=load_graph_config(REPO / 'config' / config),
                         params_file=params)
    return report


@pytest.fixture(scope='module')
def sideways(tmp_path_factory: pytest.TempPathFactory) -> MultiviewReport:
    out = tmp_path_factory.mktemp('mvs') / 'out'
    report = _process(BAGS / 'mvs_sideways', out, 'multiview_pipeline.yaml')
    # the first frame has no keyframe to be swept against: its one counted drop
    assert {reason: n for counts in report.drops.values() for reason, n in counts.items()} \
        == {'no_baseline': 1}, report.format()
    return evaluate_multiview_bag(out)


def test_moving_camera_depth_against_the_truth(sideways: MultiviewReport) -> None:
    scores = sideways.summary()
    assert scores.median_rel <= 0.012
    assert scores.within_2 >= 0.62
    assert scores.coverage >= 0.90


def test_moving_camera_sigma_is_honest(sideways: MultiviewReport) -> None:
    # the share of errors within one published standard deviation (68 % for a Gaussian)
    assert 0.60 <= sideways.summary().within_sigma <= 0.76


def test_the_depth_filter_converges(sideways: MultiviewReport) -> None:
    first, last = sideways.frames[0][1], sideways.frames[-1][1]
    # measured: 9.8 % on the first frame (one source, 5 cm away), 0.98 % on the last
    assert last.median_rel <= 0.2 * first.median_rel
    assert last.within_2 >= 3 * first.within_2


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> MultiviewReport:
    folder = tmp_path_factory.mktemp('rig')
    _process(BAGS / 'mvs_rig', folder / 'mvs', 'multiview_rig.yaml')
    # the stereo graph on the same bag (its middle and right cameras), as many disparities
    # as the sweep has planes
    _process(folder / 'mvs', folder / 'both', 'stereo_pipeline.yaml',
             REPO / 'config' / 'disparity_64.yaml')
    return evaluate_multiview_bag(folder / 'both', skip=2)


def test_a_rig_beats_two_view_stereo_most_where_one_view_is_occluded(
        rig: MultiviewReport) -> None:
    c = rig.stereo
    assert c is not None
    assert c.mvs_bad1 <= 0.6 * c.stereo_bad1
    assert c.mvs_bad2 <= 0.45 * c.stereo_bad2
    assert c.mvs_bad1_occluded <= 0.4 * c.stereo_bad1_occluded
    assert 0.02 < c.occluded_share < 0.2  # the comparison has occluded pixels to show


def test_real_views_agree_with_each_other_and_stay_in_the_box(tmp_path: Path) -> None:
    views = tmp_path / 'temple'
    done = run_cli(['import-views', str(TEMPLE / 'templeSR_par.txt'), str(views),
                    '--bbox', *BBOX])
    assert done.returncode == 0, done.stderr
    params = tmp_path / 'temple.yaml'
    # delay 1: each view is swept against both ring neighbours; uniqueness 15: the
    # background is dark and textureless
    params.write_text('/**:\n  ros__parameters: {min_depth: 0.45, max_depth: 0.8, '
                      'planes: 128, delay: 1, uniqueness_ratio: 15.0}\n')
    done = run_cli(['process', str(views), str(tmp_path / 'out'), '--config',
                    'config/multiview_pipeline.yaml', '--namespace', '/views', '--params',
                    str(params)])
    assert done.returncode == 0, done.stderr
    report = evaluate_views_bag(tmp_path / 'out')
    agree = np.array([row[1] for row in report.rows])
    inside = np.array([row[2] for row in report.rows])
    coverage = np.array([row[3] for row in report.rows])
    assert len(report.rows) >= 14  # the first view has no baseline yet
    # measured (medians over the views): 86.1 % of a view's depths confirmed by a
    # neighbour's within 1 %, 87.2 % of its points inside the temple's bounding box, 56.7 %
    # of the temple's pixels with a depth
    assert float(np.median(agree)) >= 0.82
    assert float(np.median(inside)) >= 0.82
    assert float(np.median(coverage)) >= 0.50


def _run(noise_deg: float, noise_m: float) -> float:
    """Median |dZ|/Z of the last 6 of 16 frames of a 320x240 sideways sequence."""
    config = SequenceConfig(motion='sideways', width=320, height=240, n_frames=16,
                            pose_noise_deg=noise_deg, pose_noise_m=noise_m)
    stream = MvsStream(MvsParams(min_depth=0.9, max_depth=8.0, planes=64, paths=8),
                       StreamParams())
    errors = []
    for view in simulate_sequence(config):
        out = stream.process(Frame(view.image, view.intrinsics, view.reported_pose,
                                   view.stamp_ns))
        if isinstance(out, StreamDepth) and view.index >= 10:
            ok = np.isfinite(out.depth) & np.isfinite(view.depth)
            errors.append(float(np.median(np.abs(out.depth[ok] - view.depth[ok]) /
                                          view.depth[ok])))
    return float(np.mean(errors))


def test_pose_noise_degrades_gracefully() -> None:
    exact, noisy = _run(0.0, 0.0), _run(0.2, 0.005)
    # measured: 1.09 % with exact poses, 5.54 % with 0.2 degree / 5 mm of independent
    # noise on every frame's reported pose (0.2 degree is 0.9 px at this focal length)
    assert exact <= 0.013
    assert noisy <= 0.07
