"""The filter's domain: a depth image and its variance in, the values the spatial and
temporal stages average out (1 / Z in the disparity domain, Z in the depth domain) and
their variance, and back. One pass each way over the image (:func:`to_domain`,
:func:`from_domain`); the plain definition of both is ``domain_reference`` in
``test/reference/depth_filter.py``.

In the disparity domain ``var(1 / Z) = var(Z) / Z^4`` (first order), and back; a depth so
small that its inverse overflows float32 is unknown there.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _to_kernel(raw: F32, sigma: F32, has_sigma: bool, disparity: bool, clean: F32, v: F32,
               var: F32) -> None:
    h, w = raw.shape
    for y in range(h):
        for x in range(w):
            z = raw[y, x]
            if not (z > 0.0 and z < np.inf):  # NaN, 0, negative, infinite: unknown
                clean[y, x] = np.nan
                v[y, x] = np.nan
                var[y, x] = np.nan
                continue
            clean[y, x] = z
            s2 = sigma[y, x] * sigma[y, x] if has_sigma else np.float32(0.0)
            if disparity:
                inv = np.float32(1.0) / z
                if not inv < np.inf:  # a depth so small its inverse overflows: unknown
                    clean[y, x] = np.nan
                    v[y, x] = np.nan
                    var[y, x] = np.nan
                    continue
                v[y, x] = inv
                var[y, x] = s2 * (inv * inv) * (inv * inv)
            else:
                v[y, x] = z
                var[y, x] = s2


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _from_kernel(v: F32, var: F32, disparity: bool, z: F32, sigma: F32) -> None:
    h, w = v.shape
    for y in range(h):
        for x in range(w):
            value = v[y, x]
            if not value > 0.0:
                z[y, x] = np.nan
                sigma[y, x] = np.nan
                continue
            if disparity:
                depth = np.float32(1.0) / value
                z[y, x] = depth
                sigma[y, x] = np.sqrt(var[y, x]) * depth * depth
            else:
                z[y, x] = value
                sigma[y, x] = np.sqrt(var[y, x])


def to_domain(depth: F32, sigma: F32 | None, disparity: bool) -> tuple[F32, F32, F32]:
    """``depth`` (Z, metres; NaN, zero, negative or infinite: unknown) and its standard
    deviation (None: zero) as the depth with NaN for every unknown pixel, the domain's
    values (NaN unknown) and their variance."""
    raw = np.ascontiguousarray(depth, np.float32)
    s = np.ascontiguousarray(sigma, np.float32) if sigma is not None else \
        np.zeros((1, 1), np.float32)
    clean = np.empty(raw.shape, np.float32)
    v = np.empty(raw.shape, np.float32)
    var = np.empty(raw.shape, np.float32)
    _to_kernel(raw, s, sigma is not None, disparity, clean, v, var)
    return clean, v, var


def from_domain(values: F32, var: F32, disparity: bool) -> tuple[F32, F32]:
    """The domain's values and variance as Z (metres, NaN unknown) and its standard
    deviation."""
    v = np.ascontiguousarray(values, np.float32)
    z = np.empty(v.shape, np.float32)
    sigma = np.empty(v.shape, np.float32)
    _from_kernel(v, np.ascontiguousarray(var, np.float32), disparity, z, sigma)
    return z, sigma
