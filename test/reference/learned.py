"""Plain numpy reference of the learned feature network's forward pass
(``depth_nodes/core/learned/network.py``, which runs it on OpenCV's dnn module); for
``test_learned_cost.py`` and, beside the training's JAX network, ``test_train.py``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

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
