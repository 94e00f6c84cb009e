"""Plain numpy reference of the learned-free confidence map (``depth_nodes/core/confidence.py``):
:func:`~depth_nodes.core.confidence.confidence_map` written as numpy on checked inputs, for
``test_cross_check.py``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.confidence import SMOOTHNESS_WINDOW, box_mean, outside_distance

F32 = NDArray[np.float32]


def _smoothness(disparity: F32, scale: float) -> F32:
    finite = np.isfinite(disparity)
    values = np.where(finite, disparity, 0.0).astype(np.float32)
    count = box_mean(finite.astype(np.float32), SMOOTHNESS_WINDOW)
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = box_mean(values, SMOOTHNESS_WINDOW) / count
        deviation = np.where(finite & (count > 0), np.abs(disparity - mean), 0.0)
    return (1.0 / (1.0 + np.square(deviation / scale))).astype(np.float32)


def confidence_reference(ratio: NDArray[Any], diff: NDArray[Any], keep: NDArray[np.bool_],
                         window: int, support_window: int, scale: float, factor: float,
                         smooth_scale: float, outside_scale: float,
                         out: NDArray[Any] | None, fill: NDArray[np.bool_] | None) -> F32:
    """:func:`confidence_map` in numpy on checked inputs (any float dtype; the reference
    of the float32 kernels in the tests)."""
    distinct = (1.0 - np.clip(np.nan_to_num(ratio, nan=1.0), 0.0, 1.0)).astype(np.float32)
    if window > 1:
        distinct = box_mean(distinct, window)
    with np.errstate(invalid='ignore', over='ignore'):
        agree = 1.0 / (1.0 + np.square(np.nan_to_num(diff, nan=np.inf) / scale))
    shared = distinct
    if support_window > 1:
        shared = shared * box_mean(keep.astype(np.float32), support_window)
    if out is not None:
        if smooth_scale > 0:
            shared = shared * _smoothness(out, smooth_scale)
        if outside_scale > 0:
            outside = outside_distance(out)
            extrapolated = np.isnan(diff) & (outside > 0)
            agree = np.where(extrapolated, 1.0 / (1.0 + outside / outside_scale), agree)
    conf = np.where(keep, shared * agree, 0.0)
    if fill is not None:
        conf = np.where(fill & ~keep, factor * shared, conf)
    result: F32 = np.clip(conf, 0.0, 1.0).astype(np.float32)
    return result
