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
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.core.confidence import box_mean
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


@njit(cache=True, nogil=True, parallel=True, error_model='numpy')
def _base_maps(raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[np.uint8],
               max_diff: float, distinct: F32, agree: F32, valid: F32, finite: F32,
               values: F32, squares: F32) -> None:
    """The per-pixel maps the box means are taken of (rows in parallel)."""
    h, w = raw.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for y in prange(h):
        for x in range(w):
            ratio = cost_ratio[y, x]
            distinct[y, x] = one - (one if ratio != ratio else min(max(ratio, zero), one))
            diff = difference[y, x]
            agree[y, x] = one if (abs(diff) < np.inf and diff <= max_diff) else zero
            valid[y, x] = one if labels[y, x] == VALID else zero
            d = raw[y, x]
            known = d == d and abs(d) < np.inf
            finite[y, x] = one if known else zero
            v = d if known else zero
            values[y, x] = v
            squares[y, x] = v * v


@njit(cache=True, nogil=True, parallel=True, error_model='numpy')
def _assemble(raw: F32, difference: F32, labels: NDArray[np.uint8], filled: NDArray[np.bool_],
              distinct: F32, distinct_5: F32, distinct_9: F32, agree_5: F32, agree_9: F32,
              valid: F32, valid_9: F32, valid_25: F32, count: F32, mean_sum: F32,
              square_sum: F32, values: F32, out: F32) -> None:
    """The (len(SIGNALS), H, W) signal planes, in :data:`SIGNALS`' order, from the maps
    and their box means (rows in parallel; the gaps along each row computed here)."""
    h, w = raw.shape
    cap = np.float32(CAP_PX)
    cap2 = np.float32(2 * CAP_PX)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for y in prange(h):
        last = -1e9
        for x in range(w):  # distance to the nearest invalid pixel on the left
            if labels[y, x] != VALID:
                last = float(x)
            out[18, y, x] = np.float32(min(float(x) - last, 2 * CAP_PX) / (2 * CAP_PX))
        first = 1e9
        for x in range(w - 1, -1, -1):  # ... and on the right
            if labels[y, x] != VALID:
                first = float(x)
            out[19, y, x] = np.float32(min(first - float(x), 2 * CAP_PX) / (2 * CAP_PX))
        dev, spr, lrs, none, occl, mism, spec, outs, fill, slope, outd = \
            out[7, y], out[8, y], out[3, y], out[4, y], out[11, y], out[12, y], \
            out[13, y], out[14, y], out[15, y], out[20, y], out[9, y]
        for x in range(w):  # the raw disparity's deviation and spread in 5x5
            d = raw[y, x]
            n = count[y, x]
            mean = mean_sum[y, x] / n
            var = square_sum[y, x] / n - mean * mean
            known = (d == d) & (abs(d) < np.inf) & (n > zero)
            deviation = abs(d - mean) if known else cap
            dev[x] = min(deviation, cap) / cap
            spread = np.sqrt(var) if (n > zero) & (var > zero) else zero
            spr[x] = min(spread, cap) / cap
        for x in range(w):  # the left-right difference
            diff = difference[y, x]
            lrs[x] = (min(diff, cap) if abs(diff) < np.inf else cap) / cap
            none[x] = one if diff != diff else zero
        for x in range(w):  # the labels, the filled pixels, the match's distance outside
            label = labels[y, x]
            occl[x] = one if label == OCCLUDED else zero
            mism[x] = one if label == MISMATCH else zero
            spec[x] = one if label == SPECKLE else zero
            outs[x] = one if label == OUTSIDE else zero
            fill[x] = one if filled[y, x] else zero
            # core.confidence.outside_distance: the partner's px beyond the image
            partner = np.floor(np.float32(x) - raw[y, x] + np.float32(0.5))
            beyond = max(-partner, partner - np.float32(w - 1))
            outd[x] = min(beyond if beyond > zero else zero, cap2) / cap2
        row = values[y]
        for x in range(1, w - 1):  # the slope: central differences, one-sided at the ends
            step = np.float32(0.5) * (row[x + 1] - row[x - 1])
            slope[x] = min(abs(step) if step == step else cap, cap) / cap
        if w > 1:
            for x, step in ((0, row[1] - row[0]), (w - 1, row[w - 1] - row[w - 2])):
                slope[x] = min(abs(step) if step == step else cap, cap) / cap
        else:
            slope[0] = zero
        out[0, y] = distinct[y]
        out[1, y] = distinct_5[y]
        out[2, y] = distinct_9[y]
        out[5, y] = agree_9[y]
        out[6, y] = valid_9[y]
        out[10, y] = valid[y]
        out[16, y] = agree_5[y]
        out[17, y] = valid_25[y]


def signal_planes(raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[Any],
                  filled: NDArray[np.bool_], max_diff: float) -> F32:
    """(len(SIGNALS), H, W) float32 signals of every pixel, one plane each (the layout the
    network's kernel reads): see :func:`confidence_signals`."""
    h, w = raw.shape
    disparity, ratio, diff = (np.ascontiguousarray(a, np.float32)
                              for a in (raw, cost_ratio, difference))
    lab = np.ascontiguousarray(labels, np.uint8)
    distinct, agree, valid, finite, values, squares = (np.empty((h, w), np.float32)
                                                       for _ in range(6))
    _base_maps(disparity, ratio, diff, lab, float(max_diff), distinct, agree, valid, finite,
               values, squares)
    out = np.empty((len(SIGNALS), h, w), np.float32)
    _assemble(disparity, diff, lab, np.ascontiguousarray(filled, np.bool_), distinct,
              box_mean(distinct, 5), box_mean(distinct, 9), box_mean(agree, 5),
              box_mean(agree, 9), valid, box_mean(valid, 9), box_mean(valid, 25),
              box_mean(finite, 5), box_mean(values, 5), box_mean(squares, 5),
              values, out)
    return out


def confidence_signals(raw: F32, cost_ratio: F32, difference: F32, labels: NDArray[Any],
                       filled: NDArray[np.bool_], max_diff: float) -> F32:
    """(H, W, len(SIGNALS)) float32 signals of every pixel (a view of
    :func:`signal_planes`): the distinctiveness 1 - cost ratio and its 5x5 and 9x9 means,
    the left-right difference (over :data:`CAP_PX`) and whether there is one, the shares
    of agreeing and valid pixels around, the deviation and spread of the raw disparity in
    5x5, how far outside the right image the match lies, the labels, the filled pixels,
    the distance along the row to the nearest dropped pixel on each side, the slope.

    Args:
        raw: (H, W) the matcher's left disparity (NaN invalid).
        cost_ratio: (H, W) best / second-best aggregated cost (NaN counts as 1).
        difference: (H, W) left-right difference in px (NaN: no partner).
        labels: (H, W) uint8 labels of the left-right check and speckle filter.
        filled: (H, W) bool, the pixels a hole filling gave a value.
        max_diff: The left-right threshold in px.
    """
    out: F32 = signal_planes(raw, cost_ratio, difference, labels, filled,
                             max_diff).transpose(1, 2, 0)
    return out


@njit(cache=True, nogil=True, parallel=True, fastmath={'contract'})
def _predict(planes: F32, w1: F32, b1: F32, w2: F32, b2: F32, w3: F32, b3: F32,
             out: F32) -> None:
    """The two-hidden-layer network on signal planes, row by row (rows in parallel; each
    unit a loop over x, which vectorises), then the sigmoid."""
    n_in, h, w = planes.shape
    n1, n2 = w1.shape[1], w2.shape[1]
    for y in prange(h):
        hidden1 = np.empty((n1, w), np.float32)
        hidden2 = np.empty((n2, w), np.float32)
        for j in range(n1):
            row = hidden1[j]
            for x in range(w):
                row[x] = b1[j]
            for i in range(n_in):
                weight = w1[i, j]
                src = planes[i, y]
                for x in range(w):
                    row[x] += weight * src[x]
            for x in range(w):
                row[x] = max(row[x], np.float32(0.0))
        for j in range(n2):
            row = hidden2[j]
            for x in range(w):
                row[x] = b2[j]
            for i in range(n1):
                weight = w2[i, j]
                src = hidden1[i]
                for x in range(w):
                    row[x] += weight * src[x]
            for x in range(w):
                row[x] = max(row[x], np.float32(0.0))
        dst = out[y]
        for x in range(w):
            dst[x] = b3[0]
        for i in range(n2):
            weight = w3[i, 0]
            src = hidden2[i]
            for x in range(w):
                dst[x] += weight * src[x]
        for x in range(w):
            dst[x] = np.float32(1.0) / (np.float32(1.0) + np.exp(-max(dst[x],
                                                                     np.float32(-80.0))))


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
        if len(self.matrices) != 3:
            raise WeightsError(f'the confidence model has two hidden layers, not '
                               f'{len(self.matrices) - 1}')

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
        """The probability of every pixel from its signals (cross_check's ``model``)."""
        return self.predict_planes(signal_planes(raw, cost_ratio, difference, labels,
                                                 filled, max_diff))

    def predict(self, signals: F32) -> F32:
        """(H, W) float32 probability in [0, 1] from (H, W, len(SIGNALS)) signals.

        Raises:
            ArgumentError: ``signals`` does not have len(SIGNALS) channels.
        """
        if signals.ndim != 3 or signals.shape[2] != len(SIGNALS):
            raise ArgumentError(f'signals {signals.shape} must be (H, W, {len(SIGNALS)})')
        return self.predict_planes(np.ascontiguousarray(signals.transpose(2, 0, 1)))

    def predict_planes(self, planes: F32) -> F32:
        """(H, W) float32 probability in [0, 1] from (len(SIGNALS), H, W) signal planes."""
        out = np.empty(planes.shape[1:], np.float32)
        w1, w2, w3 = self.matrices
        b1, b2, b3 = self.biases
        _predict(np.ascontiguousarray(planes, np.float32), w1, b1, w2, b2, w3, b3, out)
        return out
