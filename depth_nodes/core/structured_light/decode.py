"""Per-pixel decoding of a captured pattern sequence into projector coordinates.

Steps, per camera pixel:

1. ``lit``: white minus black must reach ``shadow_threshold`` grey levels, else the pixel
   is in the projector's shadow, outside its image, or too dark to decode.
2. Gray code: bit ``b`` is 1 where the pattern is brighter than its inverse (a per-pixel
   threshold that cancels albedo and ambient light); the bits give the Gray code of the
   projector column (row), converted to binary. Codes beyond the projector size are
   invalid.
3. Phase (``phase`` mode): the wrapped phase of N equally spaced steps, by least squares
   ``phi = atan2(sum I_k sin d_k, sum I_k cos d_k)`` with ``d_k = 2 pi k / N``; its
   amplitude ``B = 2 / N * hypot(...)`` must reach ``min_modulation`` grey levels. The
   period order comes from the Gray-code column: the unwrapped coordinate is the one
   nearest to it (tolerates Gray errors of up to half a period); a pixel whose phase and
   Gray coordinate disagree by more than a quarter period is invalid.

Confidence is in [0, 1]: 0 at the modulation threshold, approaching 1 as the signal grows
(``1 - min_modulation / m``, ``m`` the phase amplitude, or the smallest Gray-bit contrast
in Gray modes), and 0 where the pixel is invalid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.structured_light.patterns import (
    BLACK,
    GRAY,
    GRAY_INVERSE,
    PHASE,
    WHITE,
    PatternSet,
    gray_to_binary,
)
from depth_nodes.errors import ConfigError

F32 = NDArray[np.float32]
Bool = NDArray[np.bool_]


@dataclass
class DecodeResult:
    """Projector coordinates per camera pixel.

    Attributes:
        u: (H, W) float32 projector column (pixel centres at integers), NaN where invalid.
        v: (H, W) float32 projector row, or None when rows are not coded.
        valid: (H, W) bool, every coded axis decoded.
        confidence: (H, W) float32 in [0, 1], 0 where invalid.
        lit: (H, W) bool, white - black >= shadow_threshold.
        modulation: (H, W) float32 white - black, grey levels.
    """

    u: F32
    v: F32 | None
    valid: Bool
    confidence: F32
    lit: Bool
    modulation: F32


def _check(images: NDArray[np.generic], pattern_set: PatternSet) -> NDArray[np.float32]:
    arr = np.asarray(images)
    if arr.ndim != 3:
        raise ConfigError(f'images must be a (frames, H, W) stack, got shape {arr.shape}')
    if arr.shape[0] != pattern_set.count:
        raise ConfigError(f'{pattern_set.mode} pattern set has {pattern_set.count} frames, '
                          f'got {arr.shape[0]} images')
    if pattern_set.mode == 'speckle':
        raise ConfigError('speckle frames are matched, not decoded: use speckle_depth')
    return arr.astype(np.float32, copy=False)


def decode_sequence(images: NDArray[np.generic], pattern_set: PatternSet, *,
                    shadow_threshold: float = 12.0, min_modulation: float = 4.0) -> DecodeResult:
    """Decode one captured sequence.

    Args:
        images: (F, H, W) grey images (uint8 or float) in the order of
            ``pattern_set.frames``.
        pattern_set: The projected pattern set.
        shadow_threshold: Minimum white - black, grey levels (>= 0).
        min_modulation: Minimum phase amplitude B (phase mode) in grey levels (>= 0);
            also the scale of the confidence.

    Returns:
        The coordinates, validity and confidence.

    Raises:
        ConfigError: Wrong stack shape or frame count, a speckle set, or a negative
            threshold.
    """
    if shadow_threshold < 0 or min_modulation < 0:
        raise ConfigError(f'shadow_threshold and min_modulation must be >= 0, got '
                          f'{shadow_threshold} and {min_modulation}')
    stack = _check(images, pattern_set)
    frames = pattern_set.frames
    roles = {(f.kind, f.axis, f.index): i for i, f in enumerate(frames)}
    white = stack[roles[(WHITE, -1, 0)]]
    black = stack[roles[(BLACK, -1, 0)]]
    modulation = white - black
    lit = modulation >= shadow_threshold
    valid = lit.copy()
    strength = np.full(white.shape, np.inf, dtype=np.float32)
    coords: list[F32] = []
    for axis in pattern_set.coded_axes:
        size = pattern_set.width if axis == 0 else pattern_set.height
        bits = pattern_set.bits(axis)
        code = np.zeros(white.shape, dtype=np.int64)
        margin = np.full(white.shape, np.inf, dtype=np.float32)
        for b in range(bits):
            diff = stack[roles[(GRAY, axis, b)]] - stack[roles[(GRAY_INVERSE, axis, b)]]
            code |= (diff > 0).astype(np.int64) << (bits - 1 - b)
            np.minimum(margin, np.abs(diff), out=margin)
        column = gray_to_binary(code, bits)
        valid &= column < size
        coord = column.astype(np.float32)
        if pattern_set.mode == 'phase':
            coord, amp = _unwrap(stack, roles, axis, pattern_set, coord)
            valid &= amp >= min_modulation
            valid &= np.abs(coord - column) <= pattern_set.period / 4
            valid &= (coord >= -0.5) & (coord <= size - 0.5)
            margin = amp
        np.minimum(strength, margin, out=strength)
        coords.append(coord)
    with np.errstate(divide='ignore', invalid='ignore'):
        confidence = np.where(valid, np.clip(1.0 - min_modulation / strength, 0.0, 1.0), 0.0)
    confidence = np.nan_to_num(confidence, nan=1.0).astype(np.float32)  # 0/0: no threshold
    u = np.where(valid, coords[0], np.nan).astype(np.float32)
    v = np.where(valid, coords[1], np.nan).astype(np.float32) if len(coords) > 1 else None
    return DecodeResult(u, v, valid, confidence, lit, modulation)


def wrapped_phase(steps: NDArray[np.float32]) -> tuple[F32, F32]:
    """Least-squares phase and amplitude of N equally shifted sinusoid samples.

    Args:
        steps: (N, H, W) intensities ``A + B cos(phi - 2 pi k / N)``, N >= 3.

    Returns:
        ``phi`` in [0, 2 pi) and ``B``, both (H, W) float32.
    """
    n = steps.shape[0]
    delta = 2 * np.pi * np.arange(n) / n
    s = np.tensordot(np.sin(delta).astype(np.float32), steps, axes=1)
    c = np.tensordot(np.cos(delta).astype(np.float32), steps, axes=1)
    phi = np.mod(np.arctan2(s, c), 2 * np.pi).astype(np.float32)
    return phi, (2.0 / n * np.hypot(s, c)).astype(np.float32)


def _unwrap(stack: NDArray[np.float32], roles: dict[tuple[str, int, int], int], axis: int,
            pattern_set: PatternSet, gray_coord: F32) -> tuple[F32, F32]:
    idx = [roles[(PHASE, axis, k)] for k in range(pattern_set.steps)]
    phi, amp = wrapped_phase(stack[idx])
    period = np.float32(pattern_set.period)
    wrapped = phi * (period / np.float32(2 * np.pi))
    order = np.rint((gray_coord - wrapped) / period)
    return (wrapped + order * period).astype(np.float32), amp
