"""Argument checks shared by the core modules (messages name the argument)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError


def check_float_map(name: str, arr: NDArray[Any], shape: tuple[int, ...] | None = None) -> None:
    """Check that ``arr`` is a (H, W) floating-point array (of ``shape`` when given).

    Raises:
        ArgumentError: It is not.
    """
    if arr.ndim != 2:
        raise ArgumentError(f'{name} must be a (H, W) array, got shape {arr.shape}')
    if shape is not None and arr.shape != shape:
        raise ArgumentError(f'{name} must have the disparity shape {shape}, got {arr.shape}')
    if not np.issubdtype(arr.dtype, np.floating):
        raise ArgumentError(f'{name} must be a float array, got dtype {arr.dtype}')


def float_map(name: str, value: Any, shape: tuple[int, ...] | None = None) -> NDArray[np.float32]:
    """``value`` as a contiguous (H, W) float32 array (see :func:`check_float_map`)."""
    arr = np.asarray(value)
    check_float_map(name, arr, shape)
    return np.ascontiguousarray(arr, dtype=np.float32)


def non_negative(name: str, value: float) -> float:
    """``value`` as a float, which must be finite and >= 0.

    Raises:
        ArgumentError: It is not.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value >= 0):
        raise ArgumentError(f'{name} must be a finite number >= 0, got {value!r}')
    return float(value)
