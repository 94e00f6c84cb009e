"""Per-pixel standard deviation of a depth image, from what its source gives.

* stereo: a disparity error of ``disparity_sigma`` px is a depth error of
  ``Z^2 disparity_sigma / (f B)`` (f the focal length in px, B the baseline in m);
* time of flight: the tof node's confidence is ``1 / (1 + (sigma / (r Z))^2)`` for a pixel
  whose frequencies agree (``r`` its ``noise_reference``,
  :class:`~depth_nodes.core.tof.ToFParams`), so ``sigma = r Z sqrt(1 / c - 1)``;
* a source that publishes its own (multiview_stereo's ``sigma``) is taken as it is.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]

#: Where the standard deviation comes from (the node's ``noise_model``).
NOISE_MODELS = ('none', 'stereo', 'tof', 'sigma')


def stereo_sigma(depth: F32, focal_px: float, baseline_m: float, disparity_sigma: float
                 ) -> F32:
    """Standard deviation of Z, metres, of a stereo camera (NaN where no depth).

    Raises:
        ArgumentError: A focal length or baseline that is not positive.
    """
    if not (focal_px > 0 and baseline_m > 0 and disparity_sigma >= 0):
        raise ArgumentError(f'stereo noise needs a positive focal length and baseline, got '
                            f'{focal_px} px and {baseline_m} m')
    z = np.asarray(depth, np.float32)
    with np.errstate(over='ignore'):  # a depth beyond 1e19 m: an infinite sigma
        out: F32 = (z * z * np.float32(disparity_sigma / (focal_px * baseline_m))).astype(
            np.float32)
    return out


def tof_sigma(depth: F32, confidence: F32, noise_reference: float) -> F32:
    """Standard deviation of Z, metres, from the tof node's confidence (NaN where the
    confidence is not in (0, 1] or there is no depth).

    Raises:
        ArgumentError: Mismatched shapes or a noise reference that is not positive.
    """
    z = np.asarray(depth, np.float32)
    c = np.asarray(confidence, np.float32)
    if c.shape != z.shape:
        raise ArgumentError(f'confidence is {c.shape[1::-1]} but the depth is '
                            f'{z.shape[1::-1]}')
    if not noise_reference > 0:
        raise ArgumentError(f'noise_reference must be positive, got {noise_reference}')
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):  # c of 1e-40
        ok = (c > 0) & (c <= 1)
        out = np.where(ok, noise_reference * z * np.sqrt(np.maximum(1.0 / c - 1.0, 0.0)),
                       np.nan)
    return out.astype(np.float32)
