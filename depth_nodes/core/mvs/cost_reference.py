"""The plain numpy version of the plane sweep's cost kernel
(:mod:`depth_nodes.core.mvs.cost`): the same float32 arithmetic in the same order, so the
same integers; the tests hold the two equal."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.mvs.cost import TOP_COST, SweepCostInputs

__all__ = ['sweep_cost_reference']

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]


def sweep_cost_reference(inputs: SweepCostInputs) -> U8:
    """Plain numpy version of :func:`sweep_cost_volume`: the same float32 arithmetic in
    the same order, so the same integers."""
    h, w, n = inputs.shape
    views = inputs.src_grey.shape[0]
    f32 = np.float32
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pixels = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    k = inputs.k_inv
    rays = [k[i, 0] * xs + k[i, 1] * ys + k[i, 2] for i in range(3)]
    s = inputs.normal[0] * rays[0] + inputs.normal[1] * rays[1] + inputs.normal[2] * rays[2]
    costs = np.full((views, h, w, n), -1, np.int64)
    hamming = np.vectorize(lambda v: bin(int(v)).count('1'), otypes=[np.int64])
    ref_census = inputs.ref_census.reshape(h, w)
    ref_grey = inputs.ref_grey.reshape(h, w)
    for j in range(views):
        m = inputs.a_matrix[j]
        a = [(m[i, 0] * pixels[..., 0] + m[i, 1] * pixels[..., 1] + m[i, 2]).astype(f32)
             for i in range(3)]
        b = [(inputs.b_vector[j, i] * s).astype(f32) for i in range(3)]
        census = inputs.src_census[j].reshape(h, w)
        grey = inputs.src_grey[j].reshape(-1)
        for label in range(n):
            r = inputs.rho[label]
            with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
                wz = a[2] + r * b[2]
                inv = f32(1.0) / wz
                u = (a[0] + r * b[0]) * inv
                v = (a[1] + r * b[1]) * inv
            low, high = (1, 3) if inputs.zncc else (0, 1)
            ok = (s > 1e-12) & (wz > 0) & (u >= low) & (u <= w - high) & \
                (v >= low) & (v <= h - high)
            uc = np.minimum(np.maximum(np.where(ok, u, 0), f32(0)), f32(w - 1) - f32(1e-3))
            vc = np.minimum(np.maximum(np.where(ok, v, 0), f32(0)), f32(h - 1) - f32(1e-3))
            xi, yi = uc.astype(np.int32), vc.astype(np.int32)
            fu, fv = (uc - xi.astype(f32)).astype(f32), (vc - yi.astype(f32)).astype(f32)
            value = np.zeros((h, w), np.int64)
            if inputs.zncc:
                value = _zncc_reference(grey, yi.astype(np.int64) * w + xi, w, fu, fv,
                                        inputs.ref_window.reshape(h, w, 10))
            elif inputs.census_weight:
                near = census[yi + (fv >= 0.5), xi + (fu >= 0.5)]
                value += inputs.census_weight * hamming(ref_census ^ near)
            if inputs.intensity_weight and not inputs.zncc:
                i0 = yi.astype(np.int64) * w + xi
                p00, p01, p10, p11 = grey[i0], grey[i0 + 1], grey[i0 + w], grey[i0 + w + 1]
                top = p00 + fu * (p01 - p00)
                bottom = p10 + fu * (p11 - p10)
                diff = np.minimum(np.abs(ref_grey - (top + fv * (bottom - top))),
                                  f32(inputs.truncation))
                value += (f32(inputs.intensity_weight) * diff + f32(0.5)).astype(np.int64)
            costs[j, ..., label] = np.where(ok, np.minimum(value, TOP_COST), -1)
    valid = costs >= 0
    big = np.iinfo(np.int64).max
    ordered = np.sort(np.where(valid, costs, big), axis=0)
    seen = valid.sum(axis=0)
    used = np.minimum(seen, inputs.best_k)
    total = np.zeros((h, w, n), np.int64)
    for i in range(views):
        total += np.where(i < used, ordered[i], 0)
    mean = (2 * total + used) // np.maximum(2 * used, 1)
    out: U8 = np.where(seen > 0, mean, inputs.unseen_cost).astype(np.uint8)
    return out


def _zncc_reference(grey: F32, i0: NDArray[np.int64], w: int, fu: F32, fv: F32,
                    window: F32) -> NDArray[np.int64]:
    """:func:`_zncc_cost` on whole images (float32, the same order of operations)."""
    f32 = np.float32
    total = np.zeros(i0.shape, f32)
    squares = np.zeros(i0.shape, f32)
    cross = np.zeros(i0.shape, f32)
    c = 0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            b = np.clip(i0 + dy * w + dx, 0, grey.size - w - 2)
            top = grey[b] + fu * (grey[b + 1] - grey[b])
            bottom = grey[b + w] + fu * (grey[b + w + 1] - grey[b + w])
            value = (top + fv * (bottom - top)).astype(f32)
            total = total + value
            squares = squares + value * value
            cross = cross + window[..., c] * value
            c += 1
    mean = total / f32(9.0)
    spread = squares / f32(9.0) - mean * mean
    with np.errstate(invalid='ignore', divide='ignore'):
        zncc = cross / (f32(9.0) * np.sqrt(spread).astype(f32))
        cost = (f32(32.0) * (f32(1.0) - np.minimum(zncc, f32(1.0))) + f32(0.5)).astype(np.int64)
    flat = ~((spread > f32(1e-2)) & (window[..., 9] > 0))
    out: NDArray[np.int64] = np.where(flat, 32, cost)
    return out
