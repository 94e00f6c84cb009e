"""Procedural textures evaluated from surface coordinates in metres.

A texture maps surface coordinates ``(s, t)`` (metres along the surface, so the pattern
sticks to the surface as it moves) to a reflectance factor in ``[0, 1]``. Textures are pure
functions of the coordinates and of their own parameters, so both cameras of a stereo pair
see exactly the same pattern. Every kind is band-limited to a few pixels at the depth the
scene builder designed it for, which keeps the supersampled renders close to alias-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

FloatArray = NDArray[np.float64]

NOISE = 'noise'
WEAK = 'weak'
STRIPES = 'stripes'
GRID = 'grid'
CHECKER = 'checker'
KINDS = (NOISE, WEAK, STRIPES, GRID, CHECKER)


@dataclass(frozen=True)
class Texture:
    """A procedural reflectance pattern.

    Attributes:
        kind: One of ``noise`` (multi-octave value noise, strong), ``weak`` (smooth,
            very low contrast), ``stripes`` (sinusoid along ``s``), ``grid`` (product of
            two sinusoids) or ``checker`` (soft-edged checkerboard).
        period_m: Coarsest period of the pattern in metres (noise: the first octave;
            stripes/grid/checker: the repeat length).
        seed: Lattice hash seed of the noise kinds.
        octaves: Number of octaves of ``noise`` (each halves the period).
        contrast: Peak-to-peak amplitude of the factor around ``mean``.
        mean: Mean reflectance factor.
    """

    kind: str
    period_m: float
    seed: int = 0
    octaves: int = 4
    contrast: float = 0.7
    mean: float = 0.65

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ArgumentError(f'texture kind must be one of {KINDS}, got {self.kind!r}')
        if not self.period_m > 0:
            raise ArgumentError(f'texture period_m must be positive, got {self.period_m}')

    def evaluate(self, s: FloatArray, t: FloatArray) -> FloatArray:
        """Reflectance factor at surface coordinates.

        Args:
            s: (N,) first surface coordinate in metres.
            t: (N,) second surface coordinate in metres.

        Returns:
            (N,) factor, clipped to ``[0, 1]``.
        """
        return evaluate_texture(self, s, t)


def evaluate_texture(tex: Texture, s: FloatArray, t: FloatArray) -> FloatArray:
    """Evaluate ``tex`` at surface coordinates ``(s, t)`` (metres); see :class:`Texture`."""
    s = np.asarray(s, dtype=np.float64) / tex.period_m
    t = np.asarray(t, dtype=np.float64) / tex.period_m
    if tex.kind == NOISE:
        pattern = fractal_noise(s, t, tex.seed, tex.octaves) - 0.5
    elif tex.kind == WEAK:
        pattern = value_noise(s, t, tex.seed) - 0.5
    elif tex.kind == STRIPES:
        pattern = 0.5 * np.sin(2.0 * np.pi * s)
    elif tex.kind == GRID:
        pattern = 0.5 * np.sin(2.0 * np.pi * s) * np.sin(2.0 * np.pi * t)
    else:  # CHECKER: sharpened product of sines, soft edges of about a tenth of a cell
        prod = np.sin(np.pi * s) * np.sin(np.pi * t)
        pattern = 0.5 * np.clip(4.0 * prod, -1.0, 1.0)
    return np.clip(tex.mean + tex.contrast * pattern, 0.0, 1.0)


_PRIME_X = np.uint32(0x27D4EB2D)
_PRIME_Y = np.uint32(0x165667B1)


def _mix(h: NDArray[np.uint32]) -> FloatArray:
    """Finalise a 32-bit lattice hash (murmur3 avalanche) into a value in [0, 1)."""
    h = h ^ (h >> np.uint32(15))
    h *= np.uint32(0x85EBCA77)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0xC2B2AE3D)
    h ^= h >> np.uint32(16)
    return h.astype(np.float64) * (1.0 / 4294967296.0)


def value_noise(s: FloatArray, t: FloatArray, seed: int) -> FloatArray:
    """Smooth value noise with unit lattice spacing, values in [0, 1].

    Random values on the integer lattice (a hash of the lattice point and the seed),
    blended with a quintic (C2) fade.

    Args:
        s: (N,) coordinates in lattice units.
        t: (N,) coordinates in lattice units.
        seed: Lattice hash seed.

    Returns:
        (N,) noise values.
    """
    fs = np.floor(s)
    ft = np.floor(t)
    a = s - fs
    b = t - ft
    a = a * a * a * (a * (a * 6.0 - 15.0) + 10.0)
    b = b * b * b * (b * (b * 6.0 - 15.0) + 10.0)
    # uint32 arithmetic wraps, which is what a hash wants (negative lattice indices too).
    hx = fs.astype(np.int64).astype(np.uint32) * _PRIME_X
    hy = ft.astype(np.int64).astype(np.uint32) * _PRIME_Y
    hx1 = hx + _PRIME_X  # the hash of lattice column ix + 1
    hy1 = hy + _PRIME_Y
    salt = np.uint32((seed * 0x9E3779B9) & 0xFFFFFFFF)
    v00 = _mix((hx ^ hy) + salt)
    v10 = _mix((hx1 ^ hy) + salt)
    v01 = _mix((hx ^ hy1) + salt)
    v11 = _mix((hx1 ^ hy1) + salt)
    top = v00 + a * (v10 - v00)
    bottom = v01 + a * (v11 - v01)
    return top + b * (bottom - top)


def fractal_noise(s: FloatArray, t: FloatArray, seed: int, octaves: int) -> FloatArray:
    """Sum of ``octaves`` value-noise octaves (period halves, amplitude x0.8), in [0, 1].

    The result is rescaled so its typical peak-to-peak range is about 1.

    Args:
        s: (N,) coordinates in units of the first octave's period.
        t: (N,) coordinates in units of the first octave's period.
        seed: Lattice hash seed (each octave uses a derived seed).
        octaves: Number of octaves, >= 1.

    Returns:
        (N,) noise values, clipped to [0, 1].
    """
    total = np.zeros_like(s)
    amplitude = 1.0
    norm = 0.0
    scale = 1.0
    for octave in range(octaves):
        # Offsets decorrelate the octaves' lattices (no shared zero crossing at the origin).
        total += amplitude * value_noise(
            s * scale + 17.3 * octave, t * scale - 9.1 * octave, seed + 7919 * octave
        )
        norm += amplitude
        amplitude *= 0.8
        scale *= 2.0
    # Sums of octaves concentrate around 0.5; stretch so most values span [0, 1].
    return np.clip(0.5 + 1.6 * (total / norm - 0.5), 0.0, 1.0)
