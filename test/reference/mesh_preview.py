"""Plain reference of :mod:`depth_nodes.tools.evaluation.mesh_preview` (tiny images and
meshes only): a ray caster rather than a rasteriser. Each pixel's ray is intersected with
every triangle (Moller and Trumbore, 1997); the nearest hit at ``z >= near`` wins, the
first of equal ones; the pixel is shaded from that hit."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.tools.evaluation.mesh_preview import (
    AMBIENT,
    BACKGROUND,
    DIFFUSE,
    GREY,
    LIGHT,
)

F64 = NDArray[np.float64]


def _cross(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _dot(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def ray_hit(ray: F64, p0: F64, p1: F64, p2: F64) -> tuple[float, float, float] | None:
    """Where the ray ``t * ray`` from the camera meets the triangle: ``(t, u, v)`` with the
    point ``(1 - u - v) p0 + u p1 + v p2``, edges included; None if it misses or the
    triangle is edge-on."""
    r = tuple(float(c) for c in ray)
    a, b, c = (tuple(float(x) for x in p) for p in (p0, p1, p2))
    e1 = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    e2 = (c[0] - a[0], c[1] - a[1], c[2] - a[2])
    p = _cross(r, e2)
    det = _dot(e1, p)
    if det == 0.0:
        return None
    s = (-a[0], -a[1], -a[2])
    u = _dot(s, p) / det
    q = _cross(s, e1)
    v = _dot(r, q) / det
    if u < 0.0 or v < 0.0 or u + v > 1.0:
        return None
    return _dot(e2, q) / det, u, v


def visible_reference(points: F64, faces: NDArray[np.integer], camera: Intrinsics,
                      near: float) -> tuple[F64, NDArray[np.int32]]:
    """``(1 / z, triangle)`` of the nearest surface at each pixel centre (0 and -1 where
    none), ``points`` in the camera frame."""
    inv_depth = np.zeros((camera.height, camera.width))
    index = np.full((camera.height, camera.width), -1, np.int32)
    for y in range(camera.height):
        for x in range(camera.width):
            ray = np.array([(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0])
            for t, (i, j, k) in enumerate(faces):
                hit = ray_hit(ray, points[i], points[j], points[k])
                if hit is None or hit[0] < near:
                    continue
                if 1.0 / hit[0] > inv_depth[y, x]:
                    inv_depth[y, x] = 1.0 / hit[0]
                    index[y, x] = t
    return inv_depth, index


def vertex_normals_reference(points: F64, faces: NDArray[np.integer]) -> F64:
    """Each vertex's sum of its triangles' ``(p1 - p0) x (p2 - p0)``."""
    normals = np.zeros_like(points)
    for i, j, k in faces:
        n = np.cross(points[j] - points[i], points[k] - points[i])
        for vertex in (i, j, k):
            normals[vertex] += n
    return normals


def render_reference(vertices: F64, faces: NDArray[np.integer], pose: Pose,
                     camera: Intrinsics, near: float, *,
                     colors: NDArray[np.uint8] | None = None,
                     smooth: bool = True) -> NDArray[np.uint8]:
    """The picture ``render_mesh`` draws with the view ``(pose, camera)`` and that near
    plane (every vertex finite)."""
    points = (np.asarray(vertices, np.float64) - pose.position) @ pose.rotation
    normals = vertex_normals_reference(points, faces)
    _, index = visible_reference(points, faces, camera, near)
    image = np.empty((camera.height, camera.width, 3), np.uint8)
    image[:] = BACKGROUND
    for y, x in zip(*np.nonzero(index >= 0), strict=True):
        tri = faces[index[y, x]]
        p0, p1, p2 = points[tri]
        ray = np.array([(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0])
        hit = ray_hit(ray, p0, p1, p2)
        assert hit is not None
        _, u, v = hit
        weights = np.array([1.0 - u - v, u, v])
        normal = np.cross(p1 - p0, p2 - p0)
        if smooth and np.linalg.norm(weights @ normals[tri]) > 0:
            normal = weights @ normals[tri]
        shade = AMBIENT + DIFFUSE * abs(float(normal @ LIGHT)) / float(np.linalg.norm(normal))
        if colors is None:
            base = np.array(GREY, np.float64)
        elif smooth:
            base = weights @ colors[tri].astype(np.float64)
        else:
            base = colors[tri].astype(np.float64).mean(axis=0)
        image[y, x] = [min(math.floor(c * shade + 0.5), 255) for c in base]
    return image
