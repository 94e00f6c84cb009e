"""Plain numpy references of multi-view stereo's kernels (``depth_nodes/core/mvs/``): the
plane sweep's cost (the same float32 arithmetic in the same order, so the same integers),
the parallax of a sweep, the geometric consistency of depth maps, and the fusion of
depth over time and its state's warp; for ``test_mvs_kernels.py``."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Motion
from depth_nodes.core.mvs.cost import TOP_COST, SweepCostInputs
from depth_nodes.core.mvs.fusion import PRIOR_COUNT, FilterSettings, FilterState

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


# -- depth_nodes.core.mvs.cost ----------------------------------------------------------------
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


# -- depth_nodes.core.mvs.matcher --------------------------------------------------------------
def parallax_reference(rho: F32, inputs: SweepCostInputs
                       ) -> tuple[F32, F32, NDArray[np.uint8]]:
    """Plain numpy version of :func:`parallax`."""
    h, w = rho.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = [inputs.k_inv[i, 0] * xs + inputs.k_inv[i, 1] * ys + inputs.k_inv[i, 2]
            for i in range(3)]
    s = sum(inputs.normal[i] * rays[i] for i in range(3))
    lo, hi = float(inputs.rho[0]), float(inputs.rho[-1])
    r = rho.astype(np.float64)
    rate = np.zeros((h, w))
    span = np.zeros((h, w))
    covered = np.zeros((h, w), np.uint8)
    with np.errstate(invalid='ignore', divide='ignore'):
        for j in range(inputs.a_matrix.shape[0]):
            m = inputs.a_matrix[j]
            a = [m[i, 0] * xs + m[i, 1] * ys + m[i, 2] for i in range(3)]
            b = [inputs.b_vector[j, i] * s for i in range(3)]
            w_lo, w_hi = a[2] + lo * b[2], a[2] + hi * b[2]
            ends = (w_lo > 1e-9) & (w_hi > 1e-9)
            ends_uv = [((a[0] + q * b[0]) / wq, (a[1] + q * b[1]) / wq)
                       for q, wq in ((lo, w_lo), (hi, w_hi))]
            du = ends_uv[1][0] - ends_uv[0][0]
            dv = ends_uv[1][1] - ends_uv[0][1]
            span = np.maximum(span, np.where(ends, np.sqrt(du * du + dv * dv), 0.0))
            inside = ends.copy()
            for u_end, v_end in ends_uv:
                inside &= (u_end >= 0) & (u_end <= w - 1) & (v_end >= 0) & (v_end <= h - 1)
            covered += inside.astype(np.uint8)
            wz = a[2] + r * b[2]
            u, v = (a[0] + r * b[0]) / wz, (a[1] + r * b[1]) / wz
            seen = (r > 0) & np.isfinite(r) & (wz > 1e-9) & (u >= 0) & (u <= w - 1) & \
                (v >= 0) & (v <= h - 1)
            du = (b[0] * a[2] - a[0] * b[2]) / (wz * wz)
            dv = (b[1] * a[2] - a[1] * b[2]) / (wz * wz)
            rate = np.maximum(rate, np.where(seen, np.sqrt(du * du + dv * dv), 0.0))
    return rate.astype(np.float32), span.astype(np.float32), covered


# -- depth_nodes.core.mvs.consistency ----------------------------------------------------------
def consistency_reference(depth: F32, k_ref: F64,
                          others: list[tuple[F32, F64, tuple[F64, F64]]], *,
                          max_px: float = 1.0, max_relative: float = 0.01
                          ) -> tuple[U8, U8]:
    """Plain numpy version of :func:`consistency`."""
    h, w = depth.shape
    checked = np.zeros((h, w), np.uint8)
    agreed = np.zeros((h, w), np.uint8)
    ys, xs = np.mgrid[0:h, 0:w]
    pix = np.stack([xs, ys, np.ones_like(xs)], axis=-1).astype(np.float64)
    k_inv = np.linalg.inv(k_ref)
    z = depth.astype(np.float64)
    ok = np.isfinite(z) & (z > 0)
    points = (pix @ k_inv.T) * np.where(ok, z, 0.0)[..., None]
    for other, k_other, (rotation, translation) in others:
        oh, ow = other.shape
        q = points @ np.asarray(rotation).T + np.asarray(translation)
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = (q @ np.asarray(k_other).T)[..., :2] / q[..., 2:3]
        inside = ok & (q[..., 2] > 1e-9) & (uv[..., 0] >= -0.5) & (uv[..., 0] < ow - 0.5) & \
            (uv[..., 1] >= -0.5) & (uv[..., 1] < oh - 0.5)
        ui = np.where(inside, np.floor(uv[..., 0] + 0.5), 0).astype(int)
        vi = np.where(inside, np.floor(uv[..., 1] + 0.5), 0).astype(int)
        zo = other[vi, ui].astype(np.float64)
        has = inside & np.isfinite(zo) & (zo > 0)
        checked += has.astype(np.uint8)
        back_pix = np.stack([ui, vi, np.ones_like(ui)], axis=-1).astype(np.float64)
        o = (back_pix @ np.linalg.inv(k_other).T) * np.where(has, zo, 0.0)[..., None]
        b = (o - np.asarray(translation)) @ np.asarray(rotation)
        with np.errstate(divide='ignore', invalid='ignore'):
            ruv = (b @ np.asarray(k_ref).T)[..., :2] / b[..., 2:3]
            near = ((ruv[..., 0] - xs) ** 2 + (ruv[..., 1] - ys) ** 2 <= max_px * max_px) & \
                (np.abs(b[..., 2] - z) <= max_relative * z) & (b[..., 2] > 1e-9)
        agreed += (has & near).astype(np.uint8)
    return checked, agreed


# -- depth_nodes.core.mvs.fusion ---------------------------------------------------------------
def fuse_reference(state: FilterState, rho_m: F32, var_m: F32,
                   settings: FilterSettings) -> FilterState:
    """Plain Python version of :func:`fuse` (returns a new state)."""
    out = FilterState(state.rho.copy(), state.var.copy(), state.a.copy(), state.b.copy())
    h, w = state.shape
    for y in range(h):
        for x in range(w):
            m, vm = float(rho_m[y, x]), float(var_m[y, x])
            if not (m > 0 and math.isfinite(m) and vm > 0 and math.isfinite(vm)):
                continue
            p = float(out.rho[y, x])
            vp = float(out.var[y, x]) + settings.correlation * vm
            if not (p > 0 and math.isfinite(p) and vp > 0):
                prior = 1.0 if settings.method == 'kalman' else PRIOR_COUNT
                out.rho[y, x], out.var[y, x] = m, vm
                out.a[y, x], out.b[y, x] = prior, 0.0 if settings.method == 'kalman' else prior
                continue
            if settings.method == 'kalman':
                if (m - p) ** 2 <= settings.gate ** 2 * (vp + vm):
                    out.rho[y, x] = (p * vm + m * vp) / (vp + vm)
                    out.var[y, x] = vp * vm / (vp + vm)
                    out.a[y, x] += 1.0
                    out.b[y, x] = 0.0
                else:
                    out.b[y, x] += 1.0
                    if out.b[y, x] > out.a[y, x] or vm < vp:
                        out.rho[y, x], out.var[y, x], out.a[y, x], out.b[y, x] = m, vm, 1, 0
                continue
            aa, bb = float(out.a[y, x]), float(out.b[y, x])
            s2 = vp * vm / (vp + vm)
            mean = s2 * (p / vp + m / vm)
            c1 = aa / (aa + bb) * math.exp(-0.5 * (m - p) ** 2 / (vp + vm)) / math.sqrt(
                2 * math.pi * (vp + vm))
            c2 = bb / (aa + bb) / settings.rho_range
            if not c1 + c2 > 0:
                continue
            c1, c2 = c1 / (c1 + c2), c2 / (c1 + c2)
            f = c1 * (aa + 1) / (aa + bb + 1) + c2 * aa / (aa + bb + 1)
            e = (c1 * (aa + 1) * (aa + 2) + c2 * aa * (aa + 1)) / ((aa + bb + 1) * (aa + bb + 2))
            new_mean = c1 * mean + c2 * p
            new_var = c1 * (s2 + mean * mean) + c2 * (vp + p * p) - new_mean * new_mean
            denominator = f - e / f
            if not (new_var > 0 and math.isfinite(new_mean) and denominator != 0):
                continue
            new_a = (e - f) / denominator
            if not (new_a > 0 and math.isfinite(new_a)):
                continue
            out.rho[y, x], out.var[y, x] = new_mean, new_var
            out.a[y, x], out.b[y, x] = new_a, new_a * (1 - f) / f
    return out


# -- depth_nodes.core.mvs.fusion: the warp --------------------------------------------------
def warp_state_reference(state: FilterState, old: Intrinsics, new: Intrinsics,
                         motion: Motion, *, process_sigma: float) -> FilterState:
    """:func:`~depth_nodes.core.mvs.fusion.warp_state` written out with rays: each estimate
    to the pixel holding its point, the nearest winning, in row order."""
    out = FilterState.empty(new.shape)
    rotation, translation = (np.asarray(v, np.float64) for v in motion)
    h, w = state.shape
    k_inv = np.linalg.inv(old.matrix)
    for y in range(h):
        for x in range(w):
            r = float(state.rho[y, x])
            if not (r > 0 and math.isfinite(r)):
                continue
            ray = k_inv @ np.array([x, y, 1.0])
            q = rotation @ ray
            s = q + translation * r
            if not s[2] > 1e-12:
                continue
            u, v = (new.matrix @ s)[:2] / s[2]
            if not (-0.5 <= u < new.width - 0.5 and -0.5 <= v < new.height - 0.5):
                continue
            xi, yi = math.floor(u + 0.5), math.floor(v + 0.5)
            new_rho = r / s[2]
            old_rho = float(out.rho[yi, xi])
            if math.isfinite(old_rho) and old_rho >= new_rho:
                continue
            gain = q[2] / (s[2] * s[2])
            out.rho[yi, xi] = new_rho
            out.var[yi, xi] = state.var[y, x] * gain * gain + (process_sigma * new_rho) ** 2
            out.a[yi, xi] = state.a[y, x]
            out.b[yi, xi] = state.b[y, x]
    return out
