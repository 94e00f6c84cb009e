"""The learned confidence (cross_check's ``confidence_model: learned``): a small network
over per-pixel signals the matcher and the left-right check already have.

:func:`confidence_signals` turns the raw left disparity, the cost ratio, the left-right
difference, the labels, the output and its filled pixels into :data:`SIGNALS` (each
scaled to about [0, 1]); :class:`ConfidenceModel` (two hidden layers with ReLU, a
sigmoid out) maps them to the probability that the raw matcher's disparity is within
the training's threshold of the truth. The training is ``depth_nodes.tools.train``
(simulated scenes only); the weights ship beside the matching cost's.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.confidence import box_mean, outside_distance
from depth_nodes.core.cross_check import MISMATCH, OCCLUDED, OUTSIDE, SPECKLE, VALID
from depth_nodes.core.learned.network import WeightsError, read_layers, write_layers
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
#: The weights shipped with the package.
SHIPPED = Path(__file__).with_name('weights') / 'confidence.npz'
#: The signals, in the order the model takes them.
SIGNALS = ('distinct', 'distinct_5', 'distinct_9', 'lr_difference', 'lr_none',
           'agree_9', 'valid_9', 'deviation_5', 'spread_5', 'outside', 'valid', 'occluded',
           'mismatch', 'speckle', 'extrapolated', 'filled', 'agree_5', 'valid_25',
           'gap_left', 'gap_right', 'slope')
#: Cap in px of the differences and deviations among the signals.
CAP_PX = 8.0


def _gap(invalid: NDArray[np.bool_], cap: float) -> tuple[F32, F32]:
    """Per pixel, the distance in px along its row to the nearest ``invalid`` pixel on the
    left and on the right (``cap`` when none is nearer)."""
    h, w = invalid.shape
    xs = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))
    last = np.maximum.accumulate(np.where(invalid, xs, -np.inf), axis=1)
    first = np.minimum.accumulate(np.where(invalid, xs, np.inf)[:, ::-1], axis=1)[:, ::-1]
    return (np.minimum(xs - last, cap).astype(np.float32),
            np.minimum(first - xs, cap).astype(np.float32))


def confidence_signals(raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[Any],
                       filled: NDArray[np.bool_], max_diff: float) -> F32:
    """(H, W, len(SIGNALS)) float32 signals of every pixel.

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
    lr = np.minimum(np.nan_to_num(difference, nan=CAP_PX), CAP_PX).astype(np.float32)
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


@functools.cache
def shipped_confidence() -> ConfidenceModel:
    """The shipped model, read once per process.

    Raises:
        WeightsError: The shipped file is missing or damaged.
    """
    return ConfidenceModel.load(SHIPPED)


@dataclass(frozen=True)
class ConfidenceModel:
    """The network's weights: per layer a (F_in, F_out) matrix and a (F_out,) bias.

    Attributes:
        matrices: The layers' weights; the first takes ``len(SIGNALS)`` inputs, the last
            gives one output.
        biases: The layers' biases.
        recipe: How the weights were made.
    """

    matrices: tuple[F32, ...]
    biases: tuple[F32, ...]
    recipe: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n_in = len(SIGNALS)
        if not self.matrices or len(self.matrices) != len(self.biases):
            raise WeightsError('a confidence model needs one bias per layer, and a layer')
        for i, (m, b) in enumerate(zip(self.matrices, self.biases, strict=True)):
            if m.ndim != 2 or m.shape[0] != n_in or b.shape != (m.shape[1],):
                raise WeightsError(f'confidence layer {i}: weights {m.shape} / bias {b.shape} '
                                   f'do not follow {n_in} inputs')
            n_in = m.shape[1]
        if n_in != 1:
            raise WeightsError(f'the confidence model must end in one output, not {n_in}')

    def save(self, path: str | Path) -> None:
        """Write the weights and the recipe to an ``.npz``."""
        write_layers(path, 'matrix', self.matrices, self.biases, self.recipe,
                     signals=np.array(SIGNALS))

    @classmethod
    def load(cls, path: str | Path = SHIPPED) -> ConfidenceModel:
        """Read an ``.npz`` that :meth:`save` wrote.

        Raises:
            WeightsError: Missing, unreadable, inconsistent, or made for other signals.
        """
        matrices, biases, recipe, extra = read_layers(path, 'matrix', 'confidence')
        signals = tuple(str(s) for s in extra.get('signals', ()))
        if signals != SIGNALS:
            raise WeightsError(f'{path} was trained on other signals ({", ".join(signals)})')
        return cls(matrices, biases, recipe)

    def confidence(self, raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[Any],
                   filled: NDArray[np.bool_], max_diff: float) -> F32:
        """:meth:`predict` of :func:`confidence_signals` (cross_check's ``model``)."""
        return self.predict(confidence_signals(raw, cost_ratio, difference, labels, filled,
                                               max_diff))

    def predict(self, signals: F32) -> F32:
        """(H, W) float32 probability in [0, 1] from (H, W, len(SIGNALS)) signals.

        Raises:
            ArgumentError: ``signals`` does not have len(SIGNALS) channels.
        """
        if signals.ndim != 3 or signals.shape[2] != len(SIGNALS):
            raise ArgumentError(f'signals {signals.shape} must be (H, W, {len(SIGNALS)})')
        h, w = signals.shape[:2]
        x = signals.reshape(h * w, -1)
        last = len(self.matrices) - 1
        for i, (m, b) in enumerate(zip(self.matrices, self.biases, strict=True)):
            x = x @ m + b
            if i < last:
                np.maximum(x, 0.0, out=x)
        with np.errstate(over='ignore'):
            p = 1.0 / (1.0 + np.exp(-x[:, 0]))
        return p.reshape(h, w).astype(np.float32)
