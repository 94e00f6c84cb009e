"""The accuracy targets every stereo data set is held to (real pairs and simulator bags),
as assertions on a `depth-nodes eval` report. Not a test module: the accuracy tests import
it."""

from __future__ import annotations

import pytest

from depth_nodes.core.metrics import optimal_auc
from depth_nodes.tools.evaluation.evaluate import EvalReport

RAW, CHECKED = '/stereo/disparity', '/stereo/disparity_checked'
DEFAULTS = 'opencv SGBM MODE_SGBM, stereo_image_proc defaults'


def assert_beats_opencv(report: EvalReport) -> None:
    """The raw `disparity`: dense bad-2 at most 0.6x OpenCV's best grid setting, sparse
    bad-2 below every OpenCV setting's (stereo_image_proc's defaults and the 18 of the grid)
    at an equal or higher density. The dense `disparity_checked`: every pixel estimated,
    bad-2 at most 0.5x OpenCV's best dense."""
    raw, checked = report.row(RAW), report.row(CHECKED)
    assert raw.missing_frames == 0
    assert checked.missing_frames == 0
    assert len(report.grid) == 18
    best = report.opencv_best('bad_dense')
    assert raw.bad_dense <= 0.6 * best.bad_dense, (raw, best)
    for theirs in [*report.grid, report.row(DEFAULTS)]:
        assert raw.density >= theirs.density, theirs.method
        assert raw.bad_sparse < theirs.bad_sparse, theirs.method
    assert checked.density == pytest.approx(1.0, abs=1e-3)
    assert checked.bad_dense <= 0.5 * best.bad_dense, (checked, best)


def assert_confidence_ranks_errors(report: EvalReport, *, own_limit: float) -> None:
    """Over the raw matcher's pixels the confidence's AUC is under a fifth of the raw
    error rate (a random order's AUC; the optimum is about e^2 / 2), and over its own
    disparity's pixels the AUC is within ``own_limit`` x the optimum."""
    row = report.row(CHECKED)
    assert row.auc_ratio is not None
    assert row.auc_ratio_own is not None
    e = report.row(RAW).bad_sparse
    assert row.auc_ratio * optimal_auc(e) < 0.2 * e, (row.auc_ratio, e)
    assert row.auc_ratio_own <= own_limit, row.auc_ratio_own
