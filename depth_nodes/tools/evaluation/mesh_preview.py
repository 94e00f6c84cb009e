"""A triangle mesh drawn as a picture, on the CPU: the preview of `depth-nodes export-mesh
--preview` and of the docs' fused meshes (no GPU, no OpenGL).

:func:`render_mesh` projects the triangles through a pinhole camera (the optical
convention: x right, y down, z forward), keeps the nearest surface of each pixel in a
z-buffer and shades it with Lambert's law under a light fixed to the camera (up, left and
behind the viewer, :data:`LIGHT`) plus an ambient term: light grey, or the vertex colours.
Both sides of a triangle are lit alike (``|n . l|``): a fused mesh is an open surface, and
its back shows wherever the camera looks past an edge.

Two passes, two kernels. The first (:func:`_rasterise`) fills each triangle over the pixel
centres inside its projection (edge functions, edges included), keeps per pixel the
largest ``1 / z`` (interpolated linearly over the image, so exactly perspective-correct)
and the triangle that gave it; a triangle crossing the near plane is clipped to it first.
The second (:func:`_shade`) shades each covered pixel once, from the point where the
pixel's ray meets its triangle (barycentric weights from triple products), so the cost of
shading does not grow with the triangles drawn over each other.

The automatic view (:func:`auto_view`) looks at the centre of the mesh's bounding box from
a three-quarter view above it, on the side its triangles face (a TSDF mesh faces the free
space its camera looked from), at the distance that fits the whole box in the image.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
from numba import prange
from numpy.typing import ArrayLike, NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ArgumentError

__all__ = ['AMBIENT', 'BACKGROUND', 'DIFFUSE', 'GREY', 'LIGHT', 'NEAR_M', 'View', 'auto_view',
           'render_mesh']

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]
#: An explicit camera: its pose in the mesh's frame (world_from_camera, optical frame:
#: ``X_world = rotation @ X_camera + position``) and its pinhole intrinsics, whose width and
#: height are the image's. From a 4x4 matrix ``T``: ``Pose(T[:3, :3], T[:3, 3])``.
View = tuple[Pose, Intrinsics]

#: Direction towards the light in the camera's frame (x right, y down, z forward): up,
#: left and behind the viewer, so that faces turned to the camera are lit, none evenly.
LIGHT = np.array([-0.4, -0.6, -1.0]) / math.sqrt(0.4 ** 2 + 0.6 ** 2 + 1.0)
#: Shade of a pixel: its colour times ``AMBIENT + DIFFUSE * |n . LIGHT|``.
AMBIENT = 0.3
DIFFUSE = 0.7
#: Colour of a mesh without vertex colours, and of the background (RGB).
GREY = (205, 205, 205)
BACKGROUND = (255, 255, 255)
#: Near plane of an explicit view, metres: surface closer to the camera is cut away.
NEAR_M = 0.01
#: The automatic view: horizontal field of view, turn around the up axis from the side the
#: mesh faces, elevation above the horizontal, free border (a fraction of each half-image).
AUTO_FOV_DEG = 50.0
AUTO_AZIMUTH_DEG = 30.0
AUTO_ELEVATION_DEG = 35.0
AUTO_MARGIN = 0.05
#: The side the mesh faces decides the automatic view when the horizontal part of its
#: summed triangle normals is at least this fraction of their summed lengths.
FACING_MIN = 0.2
#: Largest image side, pixels.
MAX_SIDE = 16384


def render_mesh(vertices: ArrayLike, faces: ArrayLike, *, width: int = 960, height: int = 720,
                colors: ArrayLike | None = None, view: View | None = None,
                up: Sequence[float] = (0.0, 0.0, 1.0), smooth: bool = True) -> U8:
    """A picture of a triangle mesh.

    Args:
        vertices: (N, 3) positions. Triangles with a vertex that is not finite are left out.
        faces: (M, 3) vertex indices (any integer type), either winding.
        width: Image width, pixels.
        height: Image height, pixels.
        colors: (N, 3) uint8 RGB per vertex, or None for light grey (:data:`GREY`).
        view: The camera (:data:`View`: a world_from_camera :class:`Pose` and
            :class:`Intrinsics` of ``width`` x ``height``), or None for :func:`auto_view`.
        up: The mesh frame's up direction for the automatic view: (0, 0, 1) in REP 103
            (a robot's odometry), (0, -1, 0) in the simulator's world (y down).
        smooth: Normals interpolated from the vertices' (area-weighted) normals; False
            shades each triangle with its own normal.

    Returns:
        (height, width, 3) uint8 RGB, the background white.

    Raises:
        ArgumentError: No triangle, shapes or types that do not fit, a face index out of
            range, every triangle with a non-finite vertex, a bad size or view.
    """
    points, tris = _checked_mesh(vertices, faces)
    rgb = _checked_colors(colors, len(points))
    _check_size(width, height)
    normals = np.zeros_like(points)
    facing = np.zeros(4, np.float64)
    if smooth or view is None:
        _vertex_normals(points, tris, normals, facing)
    if view is None:
        pose, camera, near = _fit_view(points, tris, facing, _checked_up(up), width, height)
    else:
        pose, camera = _checked_view(view, width, height)
        near = NEAR_M
    # camera frame: R^T (X - t), as rows
    local = (points - pose.position) @ pose.rotation
    inv_depth = np.zeros((height, width), np.float64)
    index = np.full((height, width), -1, np.int32)
    _rasterise(local, tris, camera.fx, camera.fy, camera.cx, camera.cy, near, inv_depth,
               index, np.empty((7, 3), np.float64))
    image = np.empty((height, width, 3), np.uint8)
    _shade(local, tris, normals @ pose.rotation, rgb, index, camera.fx, camera.fy, camera.cx,
           camera.cy, LIGHT, AMBIENT, DIFFUSE, np.array(GREY, np.float64),
           np.array(BACKGROUND, np.uint8), smooth, image)
    return image


def auto_view(vertices: ArrayLike, faces: ArrayLike, *, width: int = 960, height: int = 720,
              up: Sequence[float] = (0.0, 0.0, 1.0)) -> View:
    """The camera :func:`render_mesh` takes when given no view.

    It looks at the centre of the bounding box of the triangles' (finite) vertices from
    :data:`AUTO_ELEVATION_DEG` above the horizontal (``up``), turned by
    :data:`AUTO_AZIMUTH_DEG` around ``up`` from the side the triangles face (the
    horizontal part of their summed normals; when that is weak, a closed object or a room
    seen from inside, from -x, or -y when ``up`` is along x). Its field of view is
    :data:`AUTO_FOV_DEG` across, and it stands at the distance where all eight corners of
    the box project inside the image with a :data:`AUTO_MARGIN` border.

    Raises:
        ArgumentError: As :func:`render_mesh`.
    """
    points, tris = _checked_mesh(vertices, faces)
    _check_size(width, height)
    facing = np.zeros(4, np.float64)
    _vertex_normals(points, tris, np.zeros_like(points), facing)
    pose, camera, _ = _fit_view(points, tris, facing, _checked_up(up), width, height)
    return pose, camera


def _checked_mesh(vertices: ArrayLike, faces: ArrayLike) -> tuple[F64, I32]:
    """float64 vertices, non-finite ones zeroed, and int32 faces without the triangles that
    used them."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not (np.issubdtype(v.dtype, np.floating)
                                               or np.issubdtype(v.dtype, np.integer)):
        raise ArgumentError(f'vertices must be (N, 3) numbers, got shape {v.shape} {v.dtype}')
    if f.ndim != 2 or f.shape[1] != 3 or not (np.issubdtype(f.dtype, np.integer) or f.size == 0):
        raise ArgumentError(f'faces must be (M, 3) integers, got shape {f.shape} {f.dtype}')
    if not len(f):
        raise ArgumentError('the mesh has no triangle to render')
    low, high = int(f.min()), int(f.max())
    if low < 0 or high >= len(v):
        raise ArgumentError(f'faces: index {low if low < 0 else high} is outside the '
                            f'{len(v)} vertices')
    points = v.astype(np.float64)
    finite = np.asarray(np.isfinite(points).all(axis=1), bool)
    tris = f.astype(np.int32)
    if not finite.all():
        tris = tris[np.take(finite, tris).all(axis=1)]
        if not len(tris):
            raise ArgumentError(f'every one of the {len(f)} triangles has a vertex that is '
                                'not finite')
        points[~finite] = 0.0
    return points, np.ascontiguousarray(tris)


def _checked_colors(colors: ArrayLike | None, count: int) -> U8:
    """(N, 3) uint8 colours, or a (0, 3) array for none."""
    if colors is None:
        return np.empty((0, 3), np.uint8)
    c = np.asarray(colors)
    if c.shape != (count, 3) or c.dtype != np.uint8:
        raise ArgumentError(f'colors must be ({count}, 3) uint8 like the vertices, got '
                            f'{c.shape} {c.dtype}')
    return np.ascontiguousarray(c)


def _check_size(width: int, height: int) -> None:
    for name, value in (('width', width), ('height', height)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) \
                or not 1 <= value <= MAX_SIDE:
            raise ArgumentError(f'{name} must be an integer from 1 to {MAX_SIDE}, got {value!r}')


def _checked_up(up: Sequence[float]) -> F64:
    u = np.asarray(up, np.float64)
    norm = float(np.linalg.norm(u)) if u.shape == (3,) else math.nan
    if not (math.isfinite(norm) and norm > 0):
        raise ArgumentError(f'up must be 3 finite numbers, not all zero, got {tuple(u.ravel())}')
    return u / norm


def _checked_view(view: object, width: int, height: int) -> View:
    if not (isinstance(view, tuple) and len(view) == 2 and isinstance(view[0], Pose)
            and isinstance(view[1], Intrinsics)):
        raise ArgumentError(f'view must be None or (Pose, Intrinsics), got '
                            f'{type(view).__name__}')
    pose, camera = view
    pose.validate()
    if not all(math.isfinite(value) for value in (camera.fx, camera.fy, camera.cx, camera.cy)) \
            or not (camera.fx > 0 and camera.fy > 0):
        raise ArgumentError(f'view: the focal lengths must be positive and every value finite, '
                            f'got fx {camera.fx} fy {camera.fy} cx {camera.cx} cy {camera.cy}')
    if (camera.width, camera.height) != (width, height):
        raise ArgumentError(f"view: the camera's image is {camera.width}x{camera.height}, the "
                            f'picture {width}x{height} (pass width and height to match)')
    return pose, camera


def _fit_view(points: F64, tris: I32, facing: F64, up: F64, width: int,
              height: int) -> tuple[Pose, Intrinsics, float]:
    """:func:`auto_view`'s camera and a near plane in front of the whole box; ``facing``
    is what :func:`_vertex_normals` summed."""
    bounds = np.empty((2, 3), np.float64)
    _bounds(points, tris, bounds)
    low, high = bounds
    centre = (low + high) / 2.0
    horizontal = facing[:3] - (facing[:3] @ up) * up
    if np.linalg.norm(horizontal) <= FACING_MIN * facing[3]:
        horizontal = -np.eye(3)[0 if abs(up[0]) < 0.9 else 1]
        horizontal = horizontal - (horizontal @ up) * up
    side = horizontal / np.linalg.norm(horizontal)
    azimuth, elevation = math.radians(AUTO_AZIMUTH_DEG), math.radians(AUTO_ELEVATION_DEG)
    around = math.cos(azimuth) * side + math.sin(azimuth) * np.cross(up, side)
    towards_camera = math.cos(elevation) * around + math.sin(elevation) * up
    forward = -towards_camera
    down = -(up - (up @ forward) * forward)
    down /= np.linalg.norm(down)
    rotation = np.column_stack([np.cross(down, forward), down, forward])
    focal = 0.5 * width / math.tan(math.radians(AUTO_FOV_DEG) / 2.0)
    half = np.array([max((width - 1) / 2.0 * (1.0 - AUTO_MARGIN), 0.5),
                     max((height - 1) / 2.0 * (1.0 - AUTO_MARGIN), 0.5)])
    corners = np.array([[(high if k >> axis & 1 else low)[axis] for axis in range(3)]
                        for k in range(8)])
    local = (corners - centre) @ rotation  # camera frame, camera at the centre
    size = max(float(np.linalg.norm(high - low)), 1e-6)
    # |focal * x / (distance + z)| <= half  <=>  distance >= focal |x| / half - z
    distance = max(float((focal * np.abs(local[:, :2]) / half - local[:, 2:]).max()),
                   float((0.01 * size - local[:, 2]).max()))
    near = 0.5 * float((distance + local[:, 2]).min())
    camera = Intrinsics(focal, focal, (width - 1) / 2.0, (height - 1) / 2.0, width, height)
    return Pose(rotation, centre + distance * towards_camera), camera, near


@numba.njit(cache=True, nogil=True)
def _bounds(points: F64, faces: I32, bounds: F64) -> None:
    """``bounds`` (2, 3): the least and the greatest coordinates of the faces' vertices."""
    for a in range(3):
        bounds[0, a], bounds[1, a] = math.inf, -math.inf
    for t in range(faces.shape[0]):
        for k in range(3):
            for a in range(3):
                value = points[faces[t, k], a]
                bounds[0, a] = min(bounds[0, a], value)
                bounds[1, a] = max(bounds[1, a], value)


@numba.njit(cache=True, nogil=True)
def _vertex_normals(points: F64, faces: I32, normals: F64, facing: F64) -> None:
    """Add each triangle's ``(p1 - p0) x (p2 - p0)`` (twice its area, along its normal) to
    its three vertices' ``normals``; ``facing`` (4,): those vectors' sum and, last, the sum
    of their lengths."""
    for t in range(faces.shape[0]):
        i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
        ax = points[i1, 0] - points[i0, 0]
        ay = points[i1, 1] - points[i0, 1]
        az = points[i1, 2] - points[i0, 2]
        bx = points[i2, 0] - points[i0, 0]
        by = points[i2, 1] - points[i0, 1]
        bz = points[i2, 2] - points[i0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        for i in (i0, i1, i2):
            normals[i, 0] += nx
            normals[i, 1] += ny
            normals[i, 2] += nz
        facing[0] += nx
        facing[1] += ny
        facing[2] += nz
        facing[3] += math.sqrt(nx * nx + ny * ny + nz * nz)


@numba.njit(cache=True, nogil=True)
def _fill(u0: float, v0: float, w0: float, u1: float, v1: float, w1: float, u2: float,
          v2: float, w2: float, triangle: int, inv_depth: F64, index: I32) -> None:
    """Draw one projected triangle (pixel coordinates ``u, v``, ``w = 1 / z``) over the
    pixel centres inside it or on its edges, where it is nearer than what is there."""
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if not (area != 0.0 and math.isfinite(area)):
        return
    height, width = inv_depth.shape
    x0 = max(math.ceil(max(min(u0, u1, u2), -1.0)), 0)
    x1 = min(math.floor(min(max(u0, u1, u2), float(width))), width - 1)
    y0 = max(math.ceil(max(min(v0, v1, v2), -1.0)), 0)
    y1 = min(math.floor(min(max(v0, v1, v2), float(height))), height - 1)
    scale = 1.0 / area
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            b0 = ((u2 - u1) * (y - v1) - (v2 - v1) * (x - u1)) * scale
            b1 = ((u0 - u2) * (y - v2) - (v0 - v2) * (x - u2)) * scale
            b2 = ((u1 - u0) * (y - v0) - (v1 - v0) * (x - u0)) * scale
            if b0 >= 0.0 and b1 >= 0.0 and b2 >= 0.0:
                w = b0 * w0 + b1 * w1 + b2 * w2
                if w > inv_depth[y, x]:
                    inv_depth[y, x] = w
                    index[y, x] = triangle


@numba.njit(cache=True, nogil=True)
def _rasterise(points: F64, faces: I32, fx: float, fy: float, cx: float, cy: float,
               near: float, inv_depth: F64, index: I32, scratch: F64) -> None:
    """The z-buffer pass: per pixel the largest ``1 / z`` of the triangles (``points`` in
    the camera frame) and the triangle's row, each triangle clipped to ``z >= near``.
    ``inv_depth`` starts at 0, ``index`` at -1; ``scratch`` is (7, 3)."""
    for t in range(faces.shape[0]):
        inside = 0
        for k in range(3):
            for a in range(3):
                scratch[k, a] = points[faces[t, k], a]
            if scratch[k, 2] >= near:
                inside += 1
        if inside == 3:
            z0, z1, z2 = scratch[0, 2], scratch[1, 2], scratch[2, 2]
            _fill(cx + fx * scratch[0, 0] / z0, cy + fy * scratch[0, 1] / z0, 1.0 / z0,
                  cx + fx * scratch[1, 0] / z1, cy + fy * scratch[1, 1] / z1, 1.0 / z1,
                  cx + fx * scratch[2, 0] / z2, cy + fy * scratch[2, 1] / z2, 1.0 / z2,
                  t, inv_depth, index)
            continue
        if inside == 0:
            continue
        # clip the triangle (rows 0-2) to the near plane: a polygon of 3 or 4 corners
        # (rows 3-6), drawn as a fan
        n = 3
        for k in range(3):
            j = (k + 1) % 3
            da, db = scratch[k, 2] - near, scratch[j, 2] - near
            if da >= 0.0:
                for a in range(3):
                    scratch[n, a] = scratch[k, a]
                n += 1
            if (da >= 0.0) != (db >= 0.0):
                s = da / (da - db)
                for a in range(3):
                    scratch[n, a] = scratch[k, a] + s * (scratch[j, a] - scratch[k, a])
                scratch[n, 2] = near
                n += 1
        za = scratch[3, 2]
        for k in range(4, n - 1):
            zb, zc = scratch[k, 2], scratch[k + 1, 2]
            _fill(cx + fx * scratch[3, 0] / za, cy + fy * scratch[3, 1] / za, 1.0 / za,
                  cx + fx * scratch[k, 0] / zb, cy + fy * scratch[k, 1] / zb, 1.0 / zb,
                  cx + fx * scratch[k + 1, 0] / zc, cy + fy * scratch[k + 1, 1] / zc,
                  1.0 / zc, t, inv_depth, index)


@numba.njit(cache=True, nogil=True, parallel=True)
def _shade(points: F64, faces: I32, normals: F64, colors: U8, index: I32, fx: float,
           fy: float, cx: float, cy: float, light: F64, ambient: float, diffuse: float,
           grey: F64, background: U8, smooth: bool, image: U8) -> None:
    """The shading pass: each pixel of ``index`` lit where its ray meets its triangle
    (``points`` and ``normals`` in the camera frame; ``colors`` (N, 3) or (0, 3) for
    ``grey``), the others ``background``."""
    height, width = index.shape
    for y in prange(height):
        for x in range(width):
            t = index[y, x]
            if t < 0:
                for c in range(3):
                    image[y, x, c] = background[c]
                continue
            i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
            rx, ry = (x - cx) / fx, (y - cy) / fy
            p0x, p0y, p0z = points[i0, 0], points[i0, 1], points[i0, 2]
            p1x, p1y, p1z = points[i1, 0], points[i1, 1], points[i1, 2]
            p2x, p2y, p2z = points[i2, 0], points[i2, 1], points[i2, 2]
            # the ray r meets the triangle at weights proportional to r . (pj x pk)
            b0 = rx * (p1y * p2z - p1z * p2y) + ry * (p1z * p2x - p1x * p2z) \
                + (p1x * p2y - p1y * p2x)
            b1 = rx * (p2y * p0z - p2z * p0y) + ry * (p2z * p0x - p2x * p0z) \
                + (p2x * p0y - p2y * p0x)
            b2 = rx * (p0y * p1z - p0z * p1y) + ry * (p0z * p1x - p0x * p1z) \
                + (p0x * p1y - p0y * p1x)
            s = b0 + b1 + b2
            if s != 0.0:  # else the triangle is edge-on: its weights are all but 0
                b0, b1, b2 = b0 / s, b1 / s, b2 / s
            b0, b1, b2 = max(b0, 0.0), max(b1, 0.0), max(b2, 0.0)
            s = b0 + b1 + b2
            if not s > 0.0:
                b0 = b1 = b2 = s = 1.0
            b0, b1, b2 = b0 / s, b1 / s, b2 / s
            ex, ey, ez = p1x - p0x, p1y - p0y, p1z - p0z
            fx_, fy_, fz_ = p2x - p0x, p2y - p0y, p2z - p0z
            nx, ny, nz = ey * fz_ - ez * fy_, ez * fx_ - ex * fz_, ex * fy_ - ey * fx_
            if smooth:
                mx = b0 * normals[i0, 0] + b1 * normals[i1, 0] + b2 * normals[i2, 0]
                my = b0 * normals[i0, 1] + b1 * normals[i1, 1] + b2 * normals[i2, 1]
                mz = b0 * normals[i0, 2] + b1 * normals[i1, 2] + b2 * normals[i2, 2]
                if mx * mx + my * my + mz * mz > 0.0:
                    nx, ny, nz = mx, my, mz
            length = math.sqrt(nx * nx + ny * ny + nz * nz)
            cosine = abs(nx * light[0] + ny * light[1] + nz * light[2]) / length \
                if length > 0.0 else 0.0
            shade = ambient + diffuse * cosine
            for c in range(3):
                if colors.shape[0] == 0:
                    base = grey[c]
                elif smooth:
                    base = b0 * colors[i0, c] + b1 * colors[i1, c] + b2 * colors[i2, c]
                else:
                    base = (float(colors[i0, c]) + colors[i1, c] + colors[i2, c]) / 3.0
                image[y, x, c] = min(int(base * shade + 0.5), 255)
