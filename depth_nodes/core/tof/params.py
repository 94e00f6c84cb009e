"""The tof decoding's settings, the modulation frequencies' checks and the range they
leave unambiguous."""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

from depth_nodes.core.settings import check_settings, setting
from depth_nodes.errors import ArgumentError

#: m/s.
SPEED_OF_LIGHT = 299_792_458.0


@dataclass(frozen=True)
class ToFParams:
    """The tof node's settings of the decoding, named as its parameters."""

    phase_steps: int = setting(4, 'Correlation samples per modulation frequency (phase '
                               'steps 2 pi k / N)', low=3, high=16)
    saturation_level: float = setting(4095.0, 'A raw sample at or above this is saturated '
                                      '(the pixel gets no depth)', low=1.0, high=1e9)
    min_amplitude: float = setting(10.0, 'Smallest modulation amplitude, counts, of a '
                                   'pixel with depth', low=0.0, high=1e9)
    electrons_per_count: float = setting(1.0, 'Sensor gain for the shot-noise model of the '
                                         'confidence', low=1e-3, high=1e3)
    noise_reference: float = setting(0.01, 'Relative depth noise at which the confidence is '
                                     '0.5 (from shot noise alone)', low=1e-4, high=1.0)
    min_confidence: float = setting(0.5, 'Pixels below this confidence get no depth',
                                    low=0.0, high=1.0)
    flying_pixel_threshold: float = setting(0.01, 'Flying pixels: the gap, metres, beyond '
                                            'their noise, between the two neighbours of a '
                                            'range that lies between them (0: keep them)',
                                            low=0.0, high=10.0)
    jump_edge_threshold: float = setting(0.02, 'Flying pixels: both sides of a range jump '
                                         'larger than this fraction of the range (0: off)',
                                         low=0.0, high=10.0)
    depth_min: float = setting(0.05, 'Nearest depth Z published, metres', low=0.0,
                               high=1e4)
    depth_max: float = setting(0.0, 'Farthest depth Z published, metres (0: the unambiguous '
                               'range)', low=0.0, high=1e5)

    def validate(self) -> ToFParams:
        """Check every field; returns self.

        Raises:
            ArgumentError: The first rule broken.
        """
        check_settings(self, 'tof parameter')
        if self.depth_max and self.depth_max <= self.depth_min:
            raise ArgumentError(f'depth_max ({self.depth_max:g}) must be greater than '
                                f'depth_min ({self.depth_min:g}) or 0')
        return self


def check_frequencies(frequencies_mhz: Any) -> tuple[float, ...]:
    """The modulation frequencies, MHz, checked: one to three, distinct, positive, with a
    common divisor of at least 1 kHz (so the unambiguous range is finite).

    Raises:
        ArgumentError: Anything else.
    """
    try:
        values = tuple(float(f) for f in frequencies_mhz)
    except (TypeError, ValueError):
        raise ArgumentError(f'modulation frequencies must be numbers (MHz), got '
                            f'{frequencies_mhz!r}') from None
    if not 1 <= len(values) <= 3:
        raise ArgumentError(f'one to three modulation frequencies, got {len(values)}')
    if not all(math.isfinite(f) and 0.001 <= f <= 10_000 for f in values):
        raise ArgumentError(f'modulation frequencies must be in [0.001, 10000] MHz, got '
                            f'{values}')
    if len(set(values)) != len(values):
        raise ArgumentError(f'modulation frequencies must differ, got {values}')
    for f in values:
        if abs(f * 1000 - round(f * 1000)) > 1e-6:
            raise ArgumentError(f'modulation frequencies are taken to 1 kHz, got {f} MHz')
    return values


def unambiguous_range(frequencies_mhz: Any) -> float:
    """Range, metres, after which the phases of all the frequencies repeat together:
    ``c / (2 g)``, ``g`` their greatest common divisor (to 1 kHz)."""
    khz = [round(f * 1000) for f in check_frequencies(frequencies_mhz)]
    g = Fraction(khz[0])
    for f in khz[1:]:
        g = Fraction(math.gcd(int(g), f))
    return SPEED_OF_LIGHT / (2 * float(g) * 1000)
