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

from depth_nodes.core.tof.decoder import (
    FLYING,
    LOW_AMPLITUDE,
    OUT_OF_RANGE,
    SATURATED,
    ToFDecoder,
    ToFResult,
    decode_tof,
)
from depth_nodes.core.tof.flying import (
    BETWEEN_SIGMAS,
    NOISE_SIGMAS,
    remove_flying_pixels,
)
from depth_nodes.core.tof.params import (
    SPEED_OF_LIGHT,
    ToFParams,
    check_frequencies,
    unambiguous_range,
)
from depth_nodes.core.tof.phase import phase_of, phasors, unwrap

__all__ = ['BETWEEN_SIGMAS', 'FLYING', 'LOW_AMPLITUDE', 'NOISE_SIGMAS', 'OUT_OF_RANGE',
           'SATURATED', 'SPEED_OF_LIGHT', 'ToFDecoder', 'ToFParams', 'ToFResult',
           'check_frequencies', 'decode_tof', 'phase_of', 'phasors', 'remove_flying_pixels',
           'unambiguous_range', 'unwrap']
