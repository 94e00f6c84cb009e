"""Meshes as binary PLY files (little endian: vertices x y z as float, optionally red green
blue as uchar; faces as a uchar count and int indices), what MeshLab, Open3D, Blender and
CloudCompare read. No ROS."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError

__all__ = ['read_ply', 'write_ply']

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]

_FACE = np.dtype([('count', 'u1'), ('index', '<i4', (3,))])


def write_ply(path: str | Path, vertices: F32, faces: I32, colors: U8 | None = None) -> None:
    """Write a triangle mesh; the file appears whole (written beside it, then renamed).

    Args:
        vertices: (N, 3) positions.
        faces: (M, 3) vertex indices.
        colors: (N, 3) uint8 RGB per vertex, or None.

    Raises:
        ArgumentError: A shape that does not fit, an index out of range.
        OSError: The file cannot be written.
    """
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ArgumentError(f'a mesh needs (N, 3) vertices and (M, 3) faces, got {v.shape} '
                            f'and {f.shape}')
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ArgumentError(f'a face index is outside the {len(v)} vertices')
    fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4')]
    if colors is not None:
        c = np.asarray(colors)
        if c.shape != v.shape or c.dtype != np.uint8:
            raise ArgumentError(f'colours must be (N, 3) uint8 like the vertices, got '
                                f'{c.shape} {c.dtype}')
        fields += [('red', 'u1'), ('green', 'u1'), ('blue', 'u1')]
    rows = np.empty(len(v), np.dtype(fields))
    rows['x'], rows['y'], rows['z'] = v[:, 0], v[:, 1], v[:, 2]
    if colors is not None:
        rows['red'], rows['green'], rows['blue'] = c[:, 0], c[:, 1], c[:, 2]
    face_rows = np.empty(len(f), _FACE)
    face_rows['count'] = 3
    face_rows['index'] = f
    header = ['ply', 'format binary_little_endian 1.0', 'comment written by depth_nodes',
              f'element vertex {len(v)}', 'property float x', 'property float y',
              'property float z']
    if colors is not None:
        header += ['property uchar red', 'property uchar green', 'property uchar blue']
    header += [f'element face {len(f)}', 'property list uchar int vertex_indices',
               'end_header']
    target = Path(path)
    partial = target.with_name(target.name + '.partial')
    with open(partial, 'wb') as out:
        out.write(('\n'.join(header) + '\n').encode('ascii'))
        out.write(rows.tobytes())
        out.write(face_rows.tobytes())
    os.replace(partial, target)


def read_ply(path: str | Path) -> tuple[F32, I32, U8 | None]:
    """A mesh :func:`write_ply` wrote: vertices, faces, colours (None without).

    Raises:
        ArgumentError: Not such a file.
    """
    data = Path(path).read_bytes()
    end = data.find(b'end_header\n')
    if not data.startswith(b'ply\n') or end < 0:
        raise ArgumentError(f'{path}: not a PLY file')
    header = data[:end].decode('ascii', 'replace').splitlines()
    if 'format binary_little_endian 1.0' not in header:
        raise ArgumentError(f'{path}: only binary little-endian PLY is read here')
    counts = {line.split()[1]: int(line.split()[2]) for line in header
              if line.startswith('element ')}
    coloured = 'property uchar red' in header
    fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4')]
    if coloured:
        fields += [('red', 'u1'), ('green', 'u1'), ('blue', 'u1')]
    vertex = np.dtype(fields)
    start = end + len(b'end_header\n')
    n, m = counts.get('vertex', 0), counts.get('face', 0)
    if len(data) != start + n * vertex.itemsize + m * _FACE.itemsize:
        raise ArgumentError(f'{path}: {len(data)} bytes do not hold {n} vertices and {m} '
                            f'triangles')
    rows = np.frombuffer(data, vertex, n, start)
    face_rows = np.frombuffer(data, _FACE, m, start + n * vertex.itemsize)
    vertices = np.stack([rows['x'], rows['y'], rows['z']], axis=1).astype(np.float32)
    colors = np.stack([rows['red'], rows['green'], rows['blue']], axis=1) if coloured \
        else None
    return vertices, face_rows['index'].astype(np.int32), colors
