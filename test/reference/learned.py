"""Plain numpy references of the learned parts: the feature network's forward pass
(``depth_nodes/core/learned/network.py``, which runs it in numba), for
``test_learned_cost.py`` and, beside the training's JAX network, ``test_train.py``; the
learned confidence's signals and network (``core/learned/confidence.py``), for
``test_learned_confidence.py``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.confidence import box_mean, outside_distance
from depth_nodes.core.cross_check import MISMATCH, OCCLUDED, OUTSIDE, SPECKLE, VALID
from depth_nodes.core.learned.confidence import CAP_PX, ConfidenceModel
from depth_nodes.core.learned.network import NORM_FLOOR, FeatureNet, normalise

F32 = NDArray[np.float32]


# -- depth_nodes.core.learned.network ----------------------------------------------------------
def conv3x3_reference(x: F32, kernel: F32, bias: F32) -> F32:
    """'Same' 3x3 convolution (correlation, as the deep-learning libraries define it) of an
    (H, W, C_in) array with zero padding: (H, W, C_out) float32."""
    h, w, c_in = x.shape
    padded = np.zeros((h + 2, w + 2, c_in), np.float32)
    padded[1:-1, 1:-1] = x
    out = np.empty((h, w, kernel.shape[3]), np.float32)
    out[:] = bias
    for dy in range(3):
        for dx in range(3):
            tap = padded[dy:dy + h, dx:dx + w].reshape(h * w, c_in)
            out.reshape(h * w, -1)[:] += tap @ kernel[dy, dx]
    return out


def features_reference(net: FeatureNet, image: NDArray[Any]) -> F32:
    """Plain numpy version of :func:`features`."""
    x = normalise(image, net.window)[:, :, None]
    last = len(net.kernels) - 1
    for i, (kernel, bias) in enumerate(zip(net.kernels, net.biases, strict=True)):
        x = conv3x3_reference(x, kernel, bias)
        if i < last:
            np.maximum(x, 0.0, out=x)
    norm = np.sqrt((x * x).sum(axis=2, keepdims=True))
    unit: F32 = (x / np.maximum(norm, np.float32(NORM_FLOOR))).astype(np.float32)
    return unit


# -- depth_nodes.core.learned.confidence -------------------------------------------------------
def _gap(invalid: NDArray[np.bool_], cap: float) -> tuple[F32, F32]:
    """Per pixel, the distance in px along its row to the nearest ``invalid`` pixel on the
    left and on the right (``cap`` when none is nearer)."""
    h, w = invalid.shape
    xs = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))
    last = np.maximum.accumulate(np.where(invalid, xs, -np.inf), axis=1)
    first = np.minimum.accumulate(np.where(invalid, xs, np.inf)[:, ::-1], axis=1)[:, ::-1]
    return (np.minimum(xs - last, cap).astype(np.float32),
            np.minimum(first - xs, cap).astype(np.float32))


def confidence_signals_reference(raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[Any],
                       filled: NDArray[np.bool_], max_diff: float) -> F32:
    """Plain numpy :func:`~depth_nodes.core.learned.confidence.confidence_signals`:
    (H, W, len(SIGNALS)) float32 signals of every pixel (a non-finite left-right difference
    counts as none).

    Args:
        raw: (H, W) the matcher's left disparity (NaN invalid).
        cost_ratio: (H, W) best / second-best aggregated cost (NaN counts as 1).
        difference: (H, W) left-right difference in px (NaN: no partner).
        labels: (H, W) uint8 labels of the left-right check and speckle filter.
        filled: (H, W) bool, the pixels a hole filling gave a value.
        max_diff: The left-right threshold in px.
    """
    h, w = raw.shape
    finite = np.isfinite(raw)
    distinct = 1.0 - np.clip(np.nan_to_num(cost_ratio, nan=1.0), 0.0, 1.0).astype(np.float32)
    lr = np.where(np.isfinite(difference), np.minimum(difference, CAP_PX),
                  CAP_PX).astype(np.float32)
    agree = ((lr <= max_diff) & np.isfinite(difference)).astype(np.float32)
    valid = (labels == VALID).astype(np.float32)
    values = np.where(finite, raw, 0.0).astype(np.float32)
    count = box_mean(finite.astype(np.float32), 5)
    # a disparity near float32's limit (hostile input) squares to inf: its spread is then
    # capped like any spread over CAP_PX
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        mean = box_mean(values, 5) / count
        square = box_mean(values * values, 5) / count
        deviation = np.where(finite & (count > 0), np.abs(raw - mean), CAP_PX)
        spread = np.sqrt(np.maximum(np.nan_to_num(square - mean * mean, nan=0.0), 0.0))
    outside = outside_distance(raw)
    columns = [distinct, box_mean(distinct, 5), box_mean(distinct, 9), lr / CAP_PX,
               np.isnan(difference).astype(np.float32), box_mean(agree, 9), box_mean(valid, 9),
               np.minimum(deviation, CAP_PX) / CAP_PX, np.minimum(spread, CAP_PX) / CAP_PX,
               np.minimum(outside, 2 * CAP_PX) / (2 * CAP_PX), valid,
               (labels == OCCLUDED).astype(np.float32), (labels == MISMATCH).astype(np.float32),
               (labels == SPECKLE).astype(np.float32), (labels == OUTSIDE).astype(np.float32),
               np.asarray(filled, np.float32), box_mean(agree, 5), box_mean(valid, 25),
               *(g / (2 * CAP_PX) for g in _gap(labels != VALID, 2 * CAP_PX)),
               np.minimum(np.abs(np.nan_to_num(np.gradient(values, axis=1), nan=CAP_PX)),
                          CAP_PX) / CAP_PX]
    return np.stack([np.asarray(c, np.float32).reshape(h, w) for c in columns], axis=2)


def predict_reference(model: ConfidenceModel, signals: F32) -> F32:
    """Plain numpy :meth:`~depth_nodes.core.learned.confidence.ConfidenceModel.predict`."""
    h, w = signals.shape[:2]
    x = signals.reshape(h * w, -1)
    last = len(model.matrices) - 1
    for i, (m, b) in enumerate(zip(model.matrices, model.biases, strict=True)):
        x = x @ m + b
        if i < last:
            np.maximum(x, 0.0, out=x)
    with np.errstate(over='ignore'):
        p = 1.0 / (1.0 + np.exp(-x[:, 0]))
    out: F32 = p.reshape(h, w).astype(np.float32)
    return out
