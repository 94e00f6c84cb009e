"""Geometric primitives, exact vectorised ray casting and view-independent shading.

All coordinates are in the world frame, which the stereo simulator takes to be the left
rectified camera frame (X right, Y down, Z forward, metres). A ray is ``o + t * d`` with
``t > 0``; directions need not be unit length, so ``t`` is in units of ``|d|`` (with
``d = (x, y, 1)`` it is the depth Z). Shading is Lambertian under one fixed directional
light plus ambient light and uses each surface's fixed outward normal, so the radiance of a
surface point does not depend on which camera looks at it.

Every primitive also gives the exact unsigned Euclidean distance of points to its surface
(:meth:`Primitive.distance`, :meth:`Scene.distance`: the nearest of a scene's surfaces), so
a reconstruction (a fused mesh) can be scored against the true surface in metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from depth_nodes.errors import ArgumentError
from depth_nodes.sim.texture import Texture

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int32]
#: A 3-vector given as a sequence or an array.
Vector = Sequence[float] | FloatArray

#: Direction towards the light (up, slightly left and towards the cameras).
LIGHT_DIRECTION = np.array([-0.4, -1.0, -0.6]) / np.linalg.norm([-0.4, -1.0, -0.6])
AMBIENT = 0.4
DIFFUSE = 0.6
#: Rays shorter than this (in units of |d|) do not count as hits.
T_MIN = 1e-9
#: Rays per chunk in :meth:`Scene.cast`; keeps temporaries inside the CPU caches.
CHUNK = 1 << 15


@dataclass(frozen=True)
class Material:
    """Reflectance of a surface: ``dark + texture * (bright - dark)`` per RGB channel.

    Attributes:
        dark: (3,) RGB reflectance where the texture factor is 0.
        bright: (3,) RGB reflectance where the texture factor is 1.
        texture: Pattern over the surface coordinates.
    """

    dark: tuple[float, float, float]
    bright: tuple[float, float, float]
    texture: Texture

    def reflectance(self, s: FloatArray, t: FloatArray) -> FloatArray:
        """(N, 3) RGB reflectance at surface coordinates ``(s, t)`` in metres."""
        factor = self.texture.evaluate(s, t)[:, None]
        dark = np.asarray(self.dark, dtype=np.float64)
        out: FloatArray = dark + factor * (np.asarray(self.bright, dtype=np.float64) - dark)
        return out


def _rows(v: FloatArray, n: int) -> FloatArray:
    """Broadcast a (3,) or (N, 3) array to (N, 3)."""
    return np.broadcast_to(v, (n, 3))


def _points(p: ArrayLike) -> FloatArray:
    """``p`` as an (N, 3) float64 array of finite points.

    Raises:
        ArgumentError: Another shape, or a NaN or infinite coordinate.
    """
    points = np.asarray(p, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ArgumentError(f'p must be an (N, 3) array of points, got shape {points.shape}')
    if not np.isfinite(points).all():
        raise ArgumentError('p must hold finite coordinates, got NaN or inf')
    return points


class Primitive:
    """Base class: a surface with an exact ray intersection and surface coordinates.

    Attributes:
        label: Role of the surface in the scene (``'pole'``, ``'weak'``...).
        material: Its reflectance.
    """

    label: str
    material: Material
    centre: FloatArray
    #: Bounding sphere (centre, radius) used to skip rays that cannot hit; None: unbounded.
    bound: tuple[FloatArray, float] | None = None

    def _place(self, label: str, material: Material, centre: Vector) -> None:
        self.label, self.material = label, material
        self.centre = np.asarray(centre, dtype=np.float64)

    def intersect(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """Nearest ray parameter ``t > T_MIN`` of the hit, ``inf`` where missed.

        Args:
            o: (3,) or (N, 3) ray origins.
            d: (N, 3) ray directions (any non-zero length).

        Returns:
            (N,) ray parameters.
        """
        raise NotImplementedError

    def surface(self, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Outward unit normals (N, 3) and surface coordinates s, t (N,) at points ``p``."""
        raise NotImplementedError

    def distance(self, p: ArrayLike) -> FloatArray:
        """Exact unsigned Euclidean distance of each point to the surface.

        Args:
            p: (N, 3) points, metres.

        Returns:
            (N,) float64 distances, metres (0 on the surface).

        Raises:
            ArgumentError: ``p`` is not (N, 3) or not finite.
        """
        return self._distance(_points(p))

    def _distance(self, p: FloatArray) -> FloatArray:
        """:meth:`distance` of checked (N, 3) float64 points."""
        raise NotImplementedError


class Rect(Primitive):
    """A planar rectangle (or an infinite plane when the half sizes are infinite).

    The normal is ``e1 x e2``; callers orient ``e1, e2`` so that it faces the cameras.
    """

    def __init__(
        self,
        label: str,
        material: Material,
        centre: Vector,
        e1: Vector,
        e2: Vector,
        half_size: tuple[float, float] = (np.inf, np.inf),
    ) -> None:
        self._place(label, material, centre)
        self.e1 = np.asarray(e1, dtype=np.float64) / np.linalg.norm(e1)
        e2v = np.asarray(e2, dtype=np.float64)
        e2v = e2v - (e2v @ self.e1) * self.e1
        self.e2 = e2v / np.linalg.norm(e2v)
        self.normal = np.cross(self.e1, self.e2)
        self.half_size = half_size
        finite = bool(np.isfinite(half_size[0]) and np.isfinite(half_size[1]))
        self.bound = (self.centre, float(np.hypot(*half_size))) if finite else None

    def intersect(self, o: FloatArray, d: FloatArray) -> FloatArray:
        oc = o - self.centre
        with np.errstate(divide='ignore', invalid='ignore'):
            t = -(oc @ self.normal) / (d @ self.normal)
            t = np.where(t > T_MIN, t, np.inf)
            if self.bound is not None:
                inside = (np.abs(oc @ self.e1 + t * (d @ self.e1)) <= self.half_size[0]) & (
                    np.abs(oc @ self.e2 + t * (d @ self.e2)) <= self.half_size[1]
                )
                t = np.where(inside, t, np.inf)
        return t

    def surface(self, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        rel = p - self.centre
        return _rows(self.normal, len(p)), rel @ self.e1, rel @ self.e2

    def _distance(self, p: FloatArray) -> FloatArray:
        # Out of plane, and past the edges in plane (an infinite half size: never past).
        rel = p - self.centre
        past1 = np.maximum(np.abs(rel @ self.e1) - self.half_size[0], 0.0)
        past2 = np.maximum(np.abs(rel @ self.e2) - self.half_size[1], 0.0)
        out: FloatArray = np.sqrt(past1 * past1 + past2 * past2 + (rel @ self.normal) ** 2)
        return out


class Box(Primitive):
    """An oriented box: centre, rotation (columns are the local axes) and half sizes."""

    def __init__(
        self,
        label: str,
        material: Material,
        centre: Vector,
        rotation: FloatArray,
        half_size: Vector,
    ) -> None:
        self._place(label, material, centre)
        self.rotation = np.asarray(rotation, dtype=np.float64)
        self.half_size = np.asarray(half_size, dtype=np.float64)
        self.bound = (self.centre, float(np.linalg.norm(self.half_size)))

    def intersect(self, o: FloatArray, d: FloatArray) -> FloatArray:
        lo = _rows((o - self.centre) @ self.rotation, len(d))
        ld = d @ self.rotation
        # A zero direction component becomes tiny: slab bounds of +-huge, never NaN.
        inv = 1.0 / np.where(ld == 0.0, 1e-300, ld)
        t_near = np.full(len(d), -np.inf)
        t_far = np.full(len(d), np.inf)
        for k in range(3):
            t1 = (-self.half_size[k] - lo[:, k]) * inv[:, k]
            t2 = (self.half_size[k] - lo[:, k]) * inv[:, k]
            t_near = np.maximum(t_near, np.minimum(t1, t2))
            t_far = np.minimum(t_far, np.maximum(t1, t2))
        t = np.where(t_near > T_MIN, t_near, t_far)
        return np.where((t_near <= t_far) & (t > T_MIN), t, np.inf)

    def surface(self, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        local = (p - self.centre) @ self.rotation
        ratio = np.abs(local) / self.half_size
        axis = np.argmax(ratio, axis=1)
        rows = np.arange(len(p))
        sign = np.sign(local[rows, axis])
        normal = self.rotation[:, axis].T * sign[:, None]
        # The two in-face coordinates, offset per face so faces do not repeat each other.
        first = np.where(axis == 0, local[:, 1], local[:, 0])
        second = np.where(axis == 2, local[:, 1], local[:, 2])
        face = axis * 2 + (sign > 0)
        return normal, first + 3.7 * face, second - 2.3 * face

    def _distance(self, p: FloatArray) -> FloatArray:
        # Per local axis, how far the point is past the face (negative: short of it).
        past = np.abs((p - self.centre) @ self.rotation) - self.half_size
        outside = np.linalg.norm(np.maximum(past, 0.0), axis=1)
        # A point inside is as far from the surface as from its nearest face.
        inside = np.maximum(-past.max(axis=1), 0.0)
        out: FloatArray = outside + inside
        return out


class Sphere(Primitive):
    """A sphere; surface coordinates are arc lengths (longitude seam faces away, +Z)."""

    def __init__(self, label: str, material: Material, centre: Vector, radius: float) -> None:
        self._place(label, material, centre)
        self.radius = float(radius)
        self.bound = (self.centre, self.radius)

    def intersect(self, o: FloatArray, d: FloatArray) -> FloatArray:
        oc = o - self.centre
        return _first_root(_dot(d, d), _dot(d, oc), _dot(oc, oc) - self.radius**2)

    def surface(self, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        n = (p - self.centre) / self.radius
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        s = self.radius * np.arctan2(n[:, 0], -n[:, 2])
        t = self.radius * np.arcsin(np.clip(n[:, 1], -1.0, 1.0))
        return n, s, t

    def _distance(self, p: FloatArray) -> FloatArray:
        out: FloatArray = np.abs(np.linalg.norm(p - self.centre, axis=1) - self.radius)
        return out


class Cylinder(Primitive):
    """An open (uncapped) finite cylinder: centre, unit axis, radius, half length."""

    def __init__(
        self,
        label: str,
        material: Material,
        centre: Vector,
        axis: Vector,
        radius: float,
        half_length: float,
    ) -> None:
        self._place(label, material, centre)
        self.axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
        helper = np.array([0.0, 0.0, 1.0]) if abs(self.axis[2]) < 0.9 else np.array([1.0, 0, 0])
        self.e1 = np.cross(self.axis, helper)
        self.e1 /= np.linalg.norm(self.e1)
        self.e2 = np.cross(self.axis, self.e1)
        self.radius = float(radius)
        self.half_length = float(half_length)
        self.bound = (self.centre, float(np.hypot(radius, half_length)))

    def intersect(self, o: FloatArray, d: FloatArray) -> FloatArray:
        oc = o - self.centre
        oc_axial = oc @ self.axis
        d_axial = d @ self.axis
        # Components perpendicular to the axis, from dot products only.
        a = _dot(d, d) - d_axial * d_axial
        b = _dot(d, oc) - oc_axial * d_axial
        c = _dot(oc, oc) - oc_axial * oc_axial - self.radius**2
        with np.errstate(invalid='ignore', divide='ignore'):
            root = np.sqrt(b * b - a * c)
            t_lo = (-b - root) / a
            t_hi = (-b + root) / a
            ok_lo = (t_lo > T_MIN) & (np.abs(oc_axial + t_lo * d_axial) <= self.half_length)
            ok_hi = (t_hi > T_MIN) & (np.abs(oc_axial + t_hi * d_axial) <= self.half_length)
        return np.where(ok_lo, t_lo, np.where(ok_hi, t_hi, np.inf))

    def surface(self, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        rel = p - self.centre
        axial = rel @ self.axis
        radial = rel - axial[:, None] * self.axis
        n = radial / np.linalg.norm(radial, axis=1, keepdims=True)
        s = self.radius * np.arctan2(n @ self.e2, n @ self.e1)
        return n, s, axial

    def _distance(self, p: FloatArray) -> FloatArray:
        # The nearest surface point is on the point's side of the axis, at its axial
        # position clamped to the length: past an end, on the rim (the cylinder is open).
        rel = p - self.centre
        axial = rel @ self.axis
        radial = np.linalg.norm(rel - axial[:, None] * self.axis, axis=1)
        past_end = np.maximum(np.abs(axial) - self.half_length, 0.0)
        out: FloatArray = np.hypot(past_end, radial - self.radius)
        return out


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise dot product of (N, 3) / (3,) arrays (matmul when one is a single vector)."""
    if a.ndim == 1 or b.ndim == 1:
        return a @ b if b.ndim == 1 else b @ a
    out: FloatArray = np.einsum('ij,ij->i', a, b)
    return out


def _bound_candidates(
    o: FloatArray, d: FloatArray, dd: FloatArray, centre: FloatArray, radius: float
) -> NDArray[np.intp]:
    """Indices of the rays that pass through the bounding sphere ahead of their origin."""
    oc = o - centre
    b = _dot(d, oc)
    c = _dot(oc, oc) - radius * radius
    return np.flatnonzero((b * b - dd * c >= 0.0) & ((c <= 0.0) | (b < 0.0)))


def _first_root(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Smallest root ``t > T_MIN`` of ``a t^2 + 2 b t + c``, ``inf`` if none."""
    with np.errstate(invalid='ignore'):
        root = np.sqrt(b * b - a * c)
        t_lo = (-b - root) / a
        t_hi = (-b + root) / a
    return np.where(t_lo > T_MIN, t_lo, np.where(t_hi > T_MIN, t_hi, np.inf))


@dataclass(frozen=True)
class Scene:
    """An ordered list of primitives; indices into it are the hit labels.

    Attributes:
        primitives: The surfaces.
    """

    primitives: tuple[Primitive, ...]

    @property
    def labels(self) -> list[str]:
        """Role label of each primitive, by index."""
        return [p.label for p in self.primitives]

    def cast(self, o: FloatArray, d: FloatArray) -> tuple[FloatArray, IntArray]:
        """Nearest hit of each ray.

        Args:
            o: (3,) common origin or (N, 3) per-ray origins.
            d: (N, 3) directions.

        Returns:
            (N,) ray parameter (``inf`` where nothing is hit) and (N,) int32 index of the
            primitive hit (-1 where nothing is hit).
        """
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        n = len(d)
        t_best = np.full(n, np.inf)
        idx = np.full(n, -1, dtype=np.int32)
        for start in range(0, n, CHUNK):
            sl = slice(start, min(start + CHUNK, n))
            oc = o if o.ndim == 1 else o[sl]
            dc = d[sl]
            tb = t_best[sl]
            ib = idx[sl]
            dd = _dot(dc, dc)
            for k, prim in enumerate(self.primitives):
                if prim.bound is None:
                    t = prim.intersect(oc, dc)
                    closer = t < tb
                    np.copyto(tb, t, where=closer)
                    np.copyto(ib, k, where=closer)
                    continue
                sel = _bound_candidates(oc, dc, dd, *prim.bound)
                if len(sel) == 0:
                    continue
                t = prim.intersect(oc if oc.ndim == 1 else oc[sel], dc[sel])
                closer = t < tb[sel]
                tb[sel[closer]] = t[closer]
                ib[sel[closer]] = k
        return t_best, idx

    def distance(self, p: ArrayLike) -> FloatArray:
        """Exact unsigned distance of each point to the nearest surface of the scene.

        Args:
            p: (N, 3) points, metres.

        Returns:
            (N,) float64 distances, metres (``inf`` for a scene without primitives).

        Raises:
            ArgumentError: ``p`` is not (N, 3) or not finite.
        """
        points = _points(p)
        out = np.full(len(points), np.inf)
        for start in range(0, len(points), CHUNK):  # chunked: temporaries stay in cache
            sl = slice(start, start + CHUNK)
            best = out[sl]
            for prim in self.primitives:
                np.minimum(best, prim._distance(points[sl]), out=best)
        return out

    def radiance(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """Linear RGB radiance (N, 3) seen along each ray (0 where nothing is hit)."""
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        out = np.empty((len(d), 3))
        for start in range(0, len(d), CHUNK):  # chunked: temporaries stay in cache
            sl = slice(start, min(start + CHUNK, len(d)))
            oc = o if o.ndim == 1 else o[sl]
            t, idx = self.cast(oc, d[sl])
            out[sl] = self.shade(oc, d[sl], t, idx)
        return out

    def shade(self, o: FloatArray, d: FloatArray, t: FloatArray, idx: IntArray) -> FloatArray:
        """Radiance (N, 3) of the hits ``(t, idx)`` from :meth:`cast` (0 for misses)."""
        out = np.zeros((len(d), 3))
        for k, prim in enumerate(self.primitives):
            sel = np.flatnonzero(idx == k)
            if len(sel) == 0:
                continue
            oo = o if o.ndim == 1 else o[sel]
            p = oo + t[sel, None] * d[sel]
            normal, s, tt = prim.surface(p)
            lambert = np.maximum(normal @ LIGHT_DIRECTION, 0.0)
            out[sel] = prim.material.reflectance(s, tt) * (AMBIENT + DIFFUSE * lambert)[:, None]
        return out
