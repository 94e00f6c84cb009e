"""Continuous-wave time of flight: raw correlation samples -> range, REP 118 depth,
amplitude and confidence (no ROS).

A frame holds, for each modulation frequency ``f`` (one to three), ``N`` correlation
samples (``N`` >= 3 phase steps), plane ``j * N + k`` for frequency ``j`` and step ``k``:

    c_jk = B_j + A_j cos(phi_j - 2 pi k / N),    phi_j = 4 pi f_j r / c  (mod 2 pi)

with ``r`` the distance along the pixel's ray (the light goes out and back: d = c phi /
(4 pi f)), ``A_j`` the amplitude of the returned modulation and ``B_j`` the offset
(ambient light plus the return's own mean). Each frequency alone repeats every
``c / (2 f)``; together they repeat every ``c / (2 g)``, ``g`` the greatest common divisor
of the frequencies (:func:`unambiguous_range`). Unwrapping tries every wrap count of the
lowest frequency within that range and keeps the one on which all frequencies agree best,
weighted by their expected noise (the usual lookup of multi-frequency cameras).

Then, per pixel of the raw image:

* **saturated**: a sample at or above ``saturation_level`` (the phase is wrong there);
* **low amplitude**: ``A`` of every frequency below ``min_amplitude``;
* **flying pixels**: a pixel that sees two surfaces at a depth edge measures a mixture of
  both, a range in between that belongs to neither (:func:`remove_flying_pixels`). It is
  removed when its range lies between its two neighbours' along one of the four
  directions and those two are more than ``flying_pixel_threshold`` plus their noise
  apart beyond what the slopes on either side explain, or when it differs from a
  neighbour by more than ``jump_edge_threshold`` of the range: both sides of a depth edge
  go, also the grazing edge of an object, where light bounced off the surface behind it
  outweighs the weak direct return. A surface seen at a slant stays;
* **confidence** in [0, 1]: the depth noise expected from shot noise (samples taken as
  counts of ``electrons_per_count``), relative to ``noise_reference`` of the range, times
  the agreement of the frequencies after unwrapping (a wrong wrap count, multipath or a
  mixed pixel make them disagree).

The lens is corrected last: the range image is remapped (nearest pixel: ranges are not
interpolated across edges) onto the CameraInfo's rectified pinhole ``P``, and the range
along each rectified ray becomes Z (REP 118 wants Z, a ToF camera measures the ray
length).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.rectify import rectification_maps
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.errors import ArgumentError

__all__ = ['SPEED_OF_LIGHT', 'ToFParams', 'ToFResult', 'decode_tof', 'phasors',
           'remove_flying_pixels', 'unambiguous_range', 'unwrap']

#: m/s.
SPEED_OF_LIGHT = 299_792_458.0
#: Flags of :attr:`ToFResult.flags`.
SATURATED, LOW_AMPLITUDE, FLYING, OUT_OF_RANGE = 1, 2, 4, 8

F32 = NDArray[np.float32]


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


def _check_samples(samples: NDArray[Any], planes: int) -> NDArray[Any]:
    """The samples as the phasor kernel reads them: a driver's uint16 counts or float32 as
    they are (no per-frame copy), anything else as float32."""
    arr = np.asarray(samples)
    if arr.ndim != 3 or arr.shape[0] != planes:
        raise ArgumentError(f'samples must be ({planes}, H, W) (frequencies x phase steps '
                            f'planes), got shape {arr.shape}')
    keep = arr.dtype if arr.dtype in (np.uint16, np.float32) else np.float32
    return np.ascontiguousarray(arr, dtype=keep)


#: atan(x) = x * p(x^2) on [0, 1], p's coefficients fitted here by least squares (degree
#: 6 in x^2): at most 8e-7 rad off, 0.2 micrometres of range at 100 MHz.
_ATAN = (0.99999659, -0.3331901, 0.19823293, -0.13294171, 0.08076284, -0.03461291,
         0.0071513)


@numba.njit(cache=True, nogil=True, inline='always')
def phase_of(im: float, re: float) -> float:
    """The angle of ``re + i im`` in [0, 2 pi) (``atan2`` by a polynomial: 3x faster
    here, 8e-7 rad off at most)."""
    ax, ay = abs(re), abs(im)
    if ax == 0.0 and ay == 0.0:
        return 0.0
    swap = ay > ax
    x = ax / ay if swap else ay / ax
    t = x * x
    a = x * (_ATAN[0] + t * (_ATAN[1] + t * (_ATAN[2] + t * (_ATAN[3] + t * (
        _ATAN[4] + t * (_ATAN[5] + t * _ATAN[6]))))))
    if swap:
        a = 0.5 * np.pi - a
    if re < 0.0:
        a = np.pi - a
    if im < 0.0:
        a = 2.0 * np.pi - a
    return a if a < 2.0 * np.pi else 0.0


@numba.njit(cache=True, nogil=True, parallel=True)
def _phasor_kernel(samples: NDArray[Any], n_freq: int, steps: int,
                   saturation: float, phase: F32, amplitude: F32, offset: F32,
                   saturated: NDArray[np.bool_]) -> None:
    _, height, width = samples.shape
    cos_k = np.cos(2.0 * np.pi * np.arange(steps) / steps)
    sin_k = np.sin(2.0 * np.pi * np.arange(steps) / steps)
    for y in numba.prange(height):
        for x in range(width):
            sat = False
            for j in range(n_freq):
                re = 0.0
                im = 0.0
                total = 0.0
                for k in range(steps):
                    c = samples[j * steps + k, y, x]
                    if c >= saturation:
                        sat = True
                    re += c * cos_k[k]
                    im += c * sin_k[k]
                    total += c
                phase[j, y, x] = phase_of(im, re)
                amplitude[j, y, x] = 2.0 / steps * np.sqrt(re * re + im * im)
                offset[j, y, x] = total / steps
            saturated[y, x] = sat


def phasors(samples: NDArray[Any], n_freq: int, steps: int, saturation: float
            ) -> tuple[F32, F32, F32, NDArray[np.bool_]]:
    """Phase (in [0, 2 pi)), amplitude and offset of each frequency, and the saturated mask.

    Args:
        samples: (n_freq * steps, H, W) correlation samples.
        n_freq: Number of modulation frequencies.
        steps: Phase steps per frequency.
        saturation: A sample at or above this saturates its pixel.

    Returns:
        (n_freq, H, W) float32 phase, amplitude, offset; (H, W) bool saturated.
    """
    arr = _check_samples(samples, n_freq * steps)
    shape = (n_freq, *arr.shape[1:])
    phase, amplitude, offset = (np.empty(shape, np.float32) for _ in range(3))
    saturated = np.empty(arr.shape[1:], np.bool_)
    _phasor_kernel(arr, n_freq, steps, float(saturation), phase, amplitude, offset, saturated)
    return phase, amplitude, offset, saturated


def phasors_reference(samples: NDArray[Any], n_freq: int, steps: int, saturation: float
                      ) -> tuple[F32, F32, F32, NDArray[np.bool_]]:
    """Plain numpy reference of :func:`phasors` (for the tests)."""
    arr = np.asarray(samples, np.float64).reshape(n_freq, steps, *samples.shape[1:])
    theta = 2 * np.pi * np.arange(steps) / steps
    re = np.tensordot(np.cos(theta), arr, axes=([0], [1]))
    im = np.tensordot(np.sin(theta), arr, axes=([0], [1]))
    phase = np.mod(np.arctan2(im, re), 2 * np.pi)
    saturated: NDArray[np.bool_] = np.asarray((arr >= saturation).any(axis=(0, 1)))
    return (phase.astype(np.float32), (2 / steps * np.hypot(re, im)).astype(np.float32),
            arr.mean(axis=1).astype(np.float32), saturated)


@numba.njit(cache=True, nogil=True, parallel=True)
def _unwrap_kernel(phase: F32, amplitude: F32, offset: F32, wrap: NDArray[np.float64],
                   base: int, wraps: int, steps: int, gain: float, limit: float,
                   out_range: F32, out_sigma: F32, out_chi2: F32) -> None:
    n_freq, height, width = phase.shape
    inv_wrap = 1.0 / wrap
    for y in numba.prange(height):
        sig2 = np.empty(n_freq)  # scratch, once a row
        frac = np.empty(n_freq)
        weight = np.empty(n_freq)
        pair_weight = np.empty(n_freq)
        for x in range(width):
            var_sum = 0.0
            ok = True
            for j in range(n_freq):
                a = amplitude[j, y, x]
                if not a > 0.0:
                    ok = False
                    break
                s_phi = np.sqrt(2.0 / steps * (max(offset[j, y, x], 0.0) / gain + 1.0)) / a
                s_r = wrap[j] / (2.0 * np.pi) * s_phi
                sig2[j] = s_r * s_r
                frac[j] = phase[j, y, x] * (0.5 / np.pi) * wrap[j]
                weight[j] = 1.0 / sig2[j]
                var_sum += weight[j]
            if not ok:
                out_range[y, x] = np.nan
                out_sigma[y, x] = np.inf
                out_chi2[y, x] = np.inf
                continue
            for j in range(n_freq):
                pair_weight[j] = 1.0 / (sig2[j] + sig2[base])
            best_cost = np.inf
            best_r = np.nan
            for n in range(wraps):
                r0 = frac[base] + n * wrap[base]
                if r0 >= limit:
                    break
                cost = 0.0
                mean = 0.0
                for j in range(n_freq):
                    nj = np.floor((r0 - frac[j]) * inv_wrap[j] + 0.5)
                    rj = frac[j] + nj * wrap[j]
                    cost += (rj - r0) * (rj - r0) * pair_weight[j]
                    mean += rj * weight[j]
                if cost < best_cost:
                    best_cost = cost
                    best_r = mean / var_sum
            out_range[y, x] = best_r
            out_sigma[y, x] = 1.0 / np.sqrt(var_sum)
            out_chi2[y, x] = best_cost


def unwrap(phase: F32, amplitude: F32, offset: F32, frequencies_mhz: Any, steps: int,
           electrons_per_count: float = 1.0) -> tuple[F32, F32, F32]:
    """Range along each pixel's ray from the phases of all the frequencies.

    Every wrap count of the lowest frequency below the unambiguous range is tried; each
    other frequency takes its nearest wrap count, and the candidate whose ranges agree
    best (squared differences over their variances) wins. The range is the
    inverse-variance mean of the frequencies' ranges on that candidate.

    Returns:
        (H, W) float32 range (metres; NaN where an amplitude is 0), its expected standard
        deviation from shot noise, and the disagreement of the frequencies (a chi-square
        with ``n_freq - 1`` degrees of freedom; 0 with one frequency).
    """
    freqs = check_frequencies(frequencies_mhz)
    if phase.shape[0] != len(freqs):
        raise ArgumentError(f'{phase.shape[0]} phase planes for {len(freqs)} frequencies')
    wrap = np.array([SPEED_OF_LIGHT / (2 * f * 1e6) for f in freqs])
    base = int(np.argmax(wrap))
    limit = unambiguous_range(freqs)
    wraps = math.ceil(limit / wrap[base] - 1e-9)
    shape = phase.shape[1:]
    out_range, out_sigma, out_chi2 = (np.empty(shape, np.float32) for _ in range(3))
    _unwrap_kernel(np.ascontiguousarray(phase, np.float32),
                   np.ascontiguousarray(amplitude, np.float32),
                   np.ascontiguousarray(offset, np.float32), wrap, base, wraps, int(steps),
                   float(electrons_per_count), limit * (1 + 1e-9), out_range, out_sigma,
                   out_chi2)
    return out_range, out_sigma, out_chi2


#: Standard deviations of two ranges' combined noise a jump must exceed besides
#: ``jump_edge_threshold`` of the range.
NOISE_SIGMAS = 3.0
#: Standard deviations of two neighbours' combined noise their gap must exceed besides
#: ``flying_pixel_threshold`` and the slopes beyond them for the pixel between them to be
#: flying.
BETWEEN_SIGMAS = 2.5
#: The four directions the flying-pixel test looks along: (dy, dx).
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


@numba.njit(cache=True, nogil=True, parallel=True)
def _flying_kernel(r: F32, sigma: F32, absolute: float, jump: float,
                   out: NDArray[np.bool_]) -> None:
    """``r`` and ``sigma`` padded by two pixels (NaN and 0): no bounds to check."""
    height, width = out.shape
    for y in numba.prange(height):
        for x in range(width):
            out[y, x] = False
            d = r[y + 2, x + 2]
            if not np.isfinite(d):
                continue
            s = sigma[y + 2, x + 2]
            flying = False
            if jump > 0.0:  # next to a jump to any of the 8 neighbours
                limit = jump * d
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        step = abs(d - r[y + 2 + dy, x + 2 + dx])  # NaN: never true
                        if step > limit:
                            sn = sigma[y + 2 + dy, x + 2 + dx]
                            if step > limit + NOISE_SIGMAS * np.sqrt(s * s + sn * sn):
                                flying = True
            if absolute > 0.0 and not flying:
                # along the four directions: between its two neighbours, in a gap wider
                # than their noise and than the slopes beyond them explain (unknown pixels
                # there: not judged in that direction)
                for k in range(4):
                    dy, dx = (0, 1) if k == 0 else (1, 0) if k == 1 else (1, 1) if k == 2 \
                        else (1, -1)
                    a = r[y + 2 - dy, x + 2 - dx]
                    b = r[y + 2 + dy, x + 2 + dx]
                    if not (d - a) * (d - b) < 0.0:
                        continue
                    sa = sigma[y + 2 - dy, x + 2 - dx]
                    sb = sigma[y + 2 + dy, x + 2 + dx]
                    gap = abs(a - b)
                    if not gap > absolute + BETWEEN_SIGMAS * max(sa, sb):  # cheap first
                        continue
                    beyond = abs(a - r[y + 2 - 2 * dy, x + 2 - 2 * dx]) + \
                        abs(b - r[y + 2 + 2 * dy, x + 2 + 2 * dx])
                    # NaN beyond: not judged
                    if gap - beyond > absolute + BETWEEN_SIGMAS * np.sqrt(sa * sa + sb * sb):
                        flying = True
            out[y, x] = flying


def remove_flying_pixels(range_m: F32, absolute: float, jump: float = 0.0,
                         sigma: F32 | None = None) -> NDArray[np.bool_]:
    """The flying pixels of a range image (see the module notes), True where:

    * (``absolute`` > 0) along one of the four directions through the pixel, its range
      lies between the two neighbours', and their gap, less the steps from each of them to
      the pixel beyond it, exceeds ``absolute`` plus ``BETWEEN_SIGMAS`` times their
      combined noise: a pixel in a gap between two surfaces is a mixture of them, wherever
      in the gap it lies; a surface seen at a slant steps as much beyond the neighbours as
      between them, and passes;
    * (``jump`` > 0) its range differs from one of its 8 neighbours' by more than ``jump``
      times the range plus ``NOISE_SIGMAS`` times their combined noise: both sides of every
      depth edge, where mixed pixels close to one surface and the grazing edges of objects
      (whose weak direct return the light bounced off the surface behind outweighs) leave
      ranges that belong to neither surface.

    ``sigma`` is the range's expected noise (default 0). Neighbours outside the image or
    unknown are not used (nor a direction whose pixel beyond a neighbour is); unknown
    pixels are never flying.
    """
    r = np.ascontiguousarray(range_m, np.float32)
    out = np.zeros(r.shape, np.bool_)
    noise = np.zeros(r.shape, np.float32) if sigma is None else \
        np.ascontiguousarray(np.nan_to_num(sigma, nan=0.0, posinf=0.0), np.float32)
    if absolute > 0 or jump > 0:
        _flying_kernel(np.pad(r, 2, constant_values=np.nan), np.pad(noise, 2),
                       float(absolute), float(jump), out)
    return out


def flying_reference(range_m: F32, absolute: float, jump: float = 0.0,
                     sigma: F32 | None = None) -> NDArray[np.bool_]:
    """Plain numpy reference of :func:`remove_flying_pixels` (for the tests)."""
    r = np.asarray(range_m, np.float64)
    h, w = r.shape
    noise = np.zeros((h, w)) if sigma is None else np.nan_to_num(
        np.asarray(sigma, np.float64), nan=0.0, posinf=0.0)
    pad = np.pad(r, 2, constant_values=np.nan)
    pad_s = np.pad(noise, 2)

    def at(dy: int, dx: int, image: NDArray[np.float64] = pad) -> NDArray[np.float64]:
        return image[2 + dy:2 + dy + h, 2 + dx:2 + dx + w]

    out = np.zeros((h, w), bool)
    with np.errstate(invalid='ignore'):
        if jump > 0:
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    out |= np.abs(r - at(dy, dx)) > jump * r + NOISE_SIGMAS * np.sqrt(
                        noise ** 2 + at(dy, dx, pad_s) ** 2)
        if absolute > 0:
            for dy, dx in _DIRECTIONS:
                a, b = at(-dy, -dx), at(dy, dx)
                beyond = np.abs(a - at(-2 * dy, -2 * dx)) + np.abs(b - at(2 * dy, 2 * dx))
                unexplained = np.abs(a - b) - beyond
                sa, sb = at(-dy, -dx, pad_s), at(dy, dx, pad_s)
                out |= ((r - a) * (r - b) < 0) & \
                    (unexplained > absolute + BETWEEN_SIGMAS * np.sqrt(sa ** 2 + sb ** 2))
    return out & np.isfinite(r)


@dataclass
class ToFResult:
    """One decoded frame, on the rectified grid of the CameraInfo's ``P``.

    Attributes:
        depth: (H, W) float32 Z, metres, NaN where not published.
        amplitude: (H, W) float32 modulation amplitude (the strongest frequency's).
        confidence: (H, W) float32 in [0, 1].
        flags: (H, W) uint8: :data:`SATURATED`, :data:`LOW_AMPLITUDE`, :data:`FLYING`,
            :data:`OUT_OF_RANGE` (bits; 0 where the depth is published or only the
            confidence was too low).
        range_raw: (H, W) float32 range along the rays on the raw grid, before any mask.
    """

    depth: F32
    amplitude: F32
    confidence: F32
    flags: NDArray[np.uint8]
    range_raw: F32


class ToFDecoder:
    """Decodes frames of one camera: keeps the rectification maps of its calibration."""

    def __init__(self) -> None:
        self._key: Any = None
        self._maps: tuple[NDArray[Any], NDArray[Any]] | None = None
        self._ray_norm: F32 | None = None

    def _geometry(self, camera: CameraModel) -> tuple[NDArray[Any], NDArray[Any], F32]:
        key = (camera.width, camera.height, camera.distortion_model,
               *(np.asarray(m, np.float64).tobytes() for m in (camera.K, camera.D, camera.R,
                                                              camera.P)))
        if key != self._key or self._maps is None or self._ray_norm is None:
            map_x, map_y = rectification_maps(camera, fixed_point=False)
            P = camera.binned().projection
            h, w = map_x.shape
            u = (np.arange(w) - P[0, 2]) / P[0, 0]
            v = (np.arange(h) - P[1, 2]) / P[1, 1]
            self._ray_norm = np.sqrt(u[None, :] ** 2 + v[:, None] ** 2 + 1).astype(np.float32)
            self._maps = (map_x, map_y)
            self._key = key
        return self._maps[0], self._maps[1], self._ray_norm

    def decode(self, samples: NDArray[Any], camera: CameraModel, frequencies_mhz: Any,
               params: ToFParams) -> ToFResult:
        """Decode one frame: see :func:`decode_tof`."""
        freqs = check_frequencies(frequencies_mhz)
        params.validate()
        steps = params.phase_steps
        arr = _check_samples(samples, len(freqs) * steps)
        model = camera.binned()
        if arr.shape[1:] != (model.height, model.width):
            raise ArgumentError(f'samples are {arr.shape[2]}x{arr.shape[1]} but the camera is '
                                f'{model.width}x{model.height}')
        phase, amplitude, offset, saturated = phasors(arr, len(freqs), steps,
                                                      params.saturation_level)
        range_m, sigma, chi2 = unwrap(phase, amplitude, offset, freqs, steps,
                                      params.electrons_per_count)
        low = (amplitude < params.min_amplitude).all(axis=0)
        flags = np.zeros(range_m.shape, np.uint8)
        flags[saturated] |= SATURATED
        flags[low] |= LOW_AMPLITUDE
        judged = np.where(flags == 0, range_m, np.nan).astype(np.float32)
        flags[remove_flying_pixels(judged, params.flying_pixel_threshold,
                                   params.jump_edge_threshold, sigma)] |= FLYING
        with np.errstate(divide='ignore', invalid='ignore'):
            relative = sigma / (params.noise_reference * range_m)
            agreement = np.exp(-chi2 / (16.0 * max(len(freqs) - 1, 1)))
            confidence = np.where(flags == 0, agreement / (1.0 + relative * relative), 0.0)
        confidence = np.nan_to_num(confidence.astype(np.float32), nan=0.0)
        strongest = amplitude.max(axis=0)
        map_x, map_y, ray_norm = self._geometry(camera)

        def rect(image: NDArray[Any]) -> NDArray[Any]:
            return cv2.remap(image, map_x, map_y, cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)

        r_rect = cv2.remap(range_m, map_x, map_y, cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=float('nan'))
        conf_rect = rect(confidence)
        flags_rect = rect(flags)
        depth = (r_rect / ray_norm).astype(np.float32)
        far = params.depth_max or unambiguous_range(freqs)
        with np.errstate(invalid='ignore'):
            outside = ~((depth >= params.depth_min) & (depth <= far))
        flags_rect[outside & (flags_rect == 0)] |= OUT_OF_RANGE
        keep = (flags_rect == 0) & (conf_rect >= params.min_confidence) & np.isfinite(depth)
        return ToFResult(depth=np.where(keep, depth, np.nan).astype(np.float32),
                         amplitude=rect(strongest), confidence=conf_rect, flags=flags_rect,
                         range_raw=range_m)


def decode_tof(samples: NDArray[Any], camera: CameraModel, frequencies_mhz: Any,
               params: ToFParams | None = None) -> ToFResult:
    """Decode one raw frame into depth, amplitude and confidence on the rectified grid.

    Args:
        samples: (n_freq * phase_steps, H, W) correlation samples, frequency-major.
        camera: The raw camera (its ``K``, ``D``, ``R``, ``P``: the depth is on ``P``'s grid).
        frequencies_mhz: The modulation frequencies, in the order of the planes.
        params: Decoding settings (default :class:`ToFParams`).

    Raises:
        ArgumentError: Samples of the wrong shape, bad frequencies or settings.
    """
    return ToFDecoder().decode(samples, camera, frequencies_mhz, params or ToFParams())
