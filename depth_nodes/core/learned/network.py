"""The learned matching cost's feature network: its weights, its input normalisation and
its forward pass in numba (no training dependency).

The network maps a grey image to one unit vector of ``channels`` features per pixel:

* the image is normalised locally (:func:`normalise`): minus the mean of a
  ``window`` x ``window`` box, over that box's standard deviation, so a gain or an offset
  between the cameras, or vignetting, changes nothing (census is invariant the same way);
* ``layers`` 3x3 convolutions (zero padding at the image border), a ReLU after each but
  the last; the receptive field is (2 layers + 1) square;
* each pixel's features divided by their norm, so the cost of a match is
  ``1 - cosine`` (``cost.py``).

The training (``depth_nodes.tools.train``) evaluates the same network on patches with
JAX; the tests compare both with the plain numpy forward pass (``features_reference`` in
``test/reference/learned.py``). :class:`FeatureNet` reads and writes the shipped
``.npz``: the weights and the recipe that made them.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError, ConfigError

F32 = NDArray[np.float32]

#: The weights shipped with the package (``depth-nodes train-cost`` wrote them).
SHIPPED = Path(__file__).with_name('weights') / 'cost_features.npz'
#: Added to the local variance, (grey levels)^2: a flat patch stays flat, not noise blown up.
VARIANCE_FLOOR = 4.0
#: A feature vector shorter than this is divided by it instead (stays near zero).
NORM_FLOOR = 1e-6


class WeightsError(ConfigError):
    """A weights file that is missing, unreadable or inconsistent."""


@dataclass(frozen=True)
class FeatureNet:
    """The feature network's parameters.

    Attributes:
        kernels: Per layer, a (3, 3, C_in, C_out) float32 kernel (C_in = 1 first).
        biases: Per layer, a (C_out,) float32 bias.
        window: Side of the local normalisation box, px (odd).
        recipe: How the weights were made (the training command's settings and figures).
    """

    kernels: tuple[F32, ...]
    biases: tuple[F32, ...]
    window: int
    recipe: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.kernels or len(self.kernels) != len(self.biases):
            raise WeightsError('a feature network needs one bias per kernel, and a kernel')
        c_in = 1
        for i, (k, b) in enumerate(zip(self.kernels, self.biases, strict=True)):
            if k.ndim != 4 or k.shape[:3] != (3, 3, c_in) or b.shape != (k.shape[3],):
                raise WeightsError(f'layer {i}: kernel {k.shape} / bias {b.shape} do not '
                                   f'follow a layer of {c_in} channels')
            c_in = k.shape[3]
        if self.window < 3 or self.window % 2 == 0:
            raise WeightsError(f'normalisation window {self.window} must be odd and >= 3')

    @property
    def channels(self) -> int:
        """Features per pixel."""
        return int(self.kernels[-1].shape[3])

    @property
    def radius(self) -> int:
        """Pixels either side of a pixel that its features see (normalisation aside)."""
        return len(self.kernels)

    @property
    def nbytes(self) -> int:
        """Bytes of the weights."""
        return sum(k.nbytes + b.nbytes for k, b in zip(self.kernels, self.biases, strict=True))

    def save(self, path: str | Path) -> None:
        """Write the weights and the recipe to an ``.npz``."""
        write_layers(path, 'kernel', self.kernels, self.biases, self.recipe,
                     window=np.int32(self.window))

    @classmethod
    def load(cls, path: str | Path = SHIPPED) -> FeatureNet:
        """Read an ``.npz`` that :meth:`save` wrote.

        Raises:
            WeightsError: The file is missing, not an ``.npz`` of this layout, or
                inconsistent.
        """
        kernels, biases, recipe, extra = read_layers(path, 'kernel', 'feature')
        if 'window' not in extra:
            raise WeightsError(f'cannot read feature weights {path}: no window')
        return cls(kernels, biases, int(extra['window']), recipe)


def write_layers(path: str | Path, name: str, weights: tuple[F32, ...],
                 biases: tuple[F32, ...], recipe: dict[str, Any], **extra: Any) -> None:
    """An ``.npz`` of a network's layers (``<name>0``, ``bias0``, ...), its recipe (JSON)
    and ``extra`` arrays: the layout of both learned parts' weights."""
    arrays: dict[str, Any] = {'recipe': np.array(json.dumps(recipe, sort_keys=True)), **extra}
    for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
        arrays[f'{name}{i}'] = w.astype(np.float32)
        arrays[f'bias{i}'] = b.astype(np.float32)
    np.savez_compressed(path, **arrays)


def read_layers(path: str | Path, name: str, what: str) -> tuple[
        tuple[F32, ...], tuple[F32, ...], dict[str, Any], dict[str, Any]]:
    """What :func:`write_layers` wrote: the layers' weights and biases, the recipe, and
    every other array by name.

    Raises:
        WeightsError: ``cannot read <what> weights <path>: why``.
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            n = sum(1 for key in data.files if key.startswith(name))
            weights = tuple(np.asarray(data[f'{name}{i}'], np.float32) for i in range(n))
            biases = tuple(np.asarray(data[f'bias{i}'], np.float32) for i in range(n))
            recipe = json.loads(str(data['recipe']))
            extra = {key: data[key] for key in data.files
                     if key != 'recipe' and not key.startswith((name, 'bias'))}
    except (OSError, KeyError, ValueError) as error:
        raise WeightsError(f'cannot read {what} weights {path}: {error}') from None
    return weights, biases, recipe, extra


@functools.cache
def shipped_features() -> FeatureNet:
    """The shipped weights, read once per process.

    Raises:
        WeightsError: The shipped file is missing or damaged.
    """
    return FeatureNet.load(SHIPPED)


def normalise(image: NDArray[Any], window: int, out: F32 | None = None,
              border: int = 0) -> F32:
    """(image - local mean) / sqrt(local variance + :data:`VARIANCE_FLOOR`), over a
    ``window`` square box (the border replicated), as float32; written into the interior
    of ``out`` (an (H + 2 border, W + 2 border) float32 array) if given.

    Raises:
        ArgumentError: ``image`` is not a 2-D grey image.
    """
    if image.ndim != 2:
        raise ArgumentError(f'image {image.shape} must be a grey (H, W) image')
    img = np.asarray(image, np.float32)
    size = (window, window)
    mean = np.asarray(cv2.boxFilter(img, cv2.CV_32F, size, borderType=cv2.BORDER_REPLICATE),
                      np.float32)
    square = np.asarray(cv2.boxFilter(img * img, cv2.CV_32F, size,
                                      borderType=cv2.BORDER_REPLICATE), np.float32)
    if out is None:
        out = np.empty(img.shape, np.float32)
    _normalised(img, mean, square, border, out)
    return out


@njit(cache=True, nogil=True, parallel=True)
def _normalised(img: F32, mean: F32, square: F32, border: int, out: F32) -> None:
    """The last step of :func:`normalise`, in float32 as numpy would compute it, in one
    pass (rows in parallel), into ``out``'s interior (``border`` px in from each side)."""
    h, w = img.shape
    zero = np.float32(0.0)
    floor = np.float32(VARIANCE_FLOOR)
    for y in prange(h):
        row = out[y + border]
        for x in range(w):
            m = mean[y, x]
            variance = max(square[y, x] - m * m, zero) + floor
            row[x + border] = (img[y, x] - m) / np.sqrt(variance)


@njit(cache=True, nogil=True, parallel=True, fastmath={'contract'})
def _conv3x3(inp: F32, kernel: F32, bias: F32, relu: bool, out: F32) -> None:
    """One layer: ``out[co] = bias[co] + sum over ci, dy, dx of kernel[dy, dx, ci, co] *
    inp[ci, y + dy, x + dx]`` (a correlation), then a ReLU if ``relu``. ``inp`` is (Cin,
    H + 2, W + 2) with a zero border (the convolution's zero padding), ``out`` (Cout, H + 2,
    W + 2) gets its interior written (its border stays zero). Rows in parallel, each tap a
    loop over x (it vectorises; multiply and add contracted into one FMA, so the sums differ
    from numpy's in the last bits)."""
    cin, hp, wp = inp.shape
    cout = kernel.shape[3]
    h, w = hp - 2, wp - 2
    zero = np.float32(0.0)
    for y in prange(h):
        row = np.empty(w, np.float32)
        for co in range(cout):
            for x in range(w):
                row[x] = bias[co]
            for ci in range(cin):
                for dy in range(3):
                    src = inp[ci, y + dy]
                    for dx in range(3):
                        tap = kernel[dy, dx, ci, co]
                        for x in range(w):
                            row[x] += tap * src[x + dx]
            dst = out[co, y + 1]
            if relu:
                for x in range(w):
                    dst[x + 1] = max(row[x], zero)
            else:
                for x in range(w):
                    dst[x + 1] = row[x]


class FeatureExtractor:
    """The network's convolutions in numba (:func:`_conv3x3`, a layer at a time, rows in
    parallel), built once for a :class:`FeatureNet`; each layer's map is kept from frame to
    frame (allocated again only for another image size).

    Args:
        net: The weights.
    """

    def __init__(self, net: FeatureNet) -> None:
        self.net = net
        self._maps: list[F32] = []

    def raw(self, image: NDArray[Any]) -> F32:
        """(C, H, W) float32 features of a grey image before the division by their norm
        (a view of a buffer the next call writes over).

        Raises:
            ArgumentError: ``image`` is not a 2-D grey image.
        """
        out: F32 = self.padded(image)[:, 1:-1, 1:-1]
        return out

    def padded(self, image: NDArray[Any]) -> F32:
        """:meth:`raw` with a border of one zero pixel: (C, H + 2, W + 2), contiguous (what
        the next kernels read fastest).

        Raises:
            ArgumentError: ``image`` is not a 2-D grey image.
        """
        if image.ndim != 2:
            raise ArgumentError(f'image {image.shape} must be a grey (H, W) image')
        h, w = image.shape
        sizes = [1] + [int(k.shape[3]) for k in self.net.kernels]
        if not self._maps or self._maps[0].shape[1:] != (h + 2, w + 2):
            self._maps = [np.zeros((c, h + 2, w + 2), np.float32) for c in sizes]
        normalise(image, self.net.window, self._maps[0][0], border=1)
        last = len(self.net.kernels) - 1
        for i, (kernel, bias) in enumerate(zip(self.net.kernels, self.net.biases,
                                               strict=True)):
            _conv3x3(self._maps[i], kernel, bias, i < last, self._maps[i + 1])
        return self._maps[-1]

    def features(self, image: NDArray[Any]) -> F32:
        """(H, W, C) float32 unit feature vectors (a zero vector where every feature is 0).

        Raises:
            ArgumentError: ``image`` is not a 2-D grey image.
        """
        x = self.raw(image).transpose(1, 2, 0)
        norm = np.sqrt((x * x).sum(axis=2, keepdims=True))
        return np.ascontiguousarray(x / np.maximum(norm, np.float32(NORM_FLOOR)))
