"""The fused surface: the zero crossing of the TSDF as triangles, per block (no ROS).

Marching cubes (Lorensen and Cline, 1987) over each cube of eight neighbouring voxels; a
cube with a corner below ``min_weight`` (unobserved) gives no triangle. The case table is
built here, at import, from the cube's faces rather than written out: on each face the
edges where the value crosses 0 are joined in pairs (on a face whose corners alternate in
sign, around each negative corner: the free side stays connected), the pairs link up into
closed loops across the faces, and each loop is a fan of triangles facing the free
(positive) side. The rule depends on a face's corners only, so two cubes sharing a face cut
it the same way and the mesh is closed. Vertices are interpolated linearly along the
edges, from the edge's lower corner in every cube that shares it, so a vertex is the same
float in each and :func:`weld` merges them exactly; where the field is linear (a plane)
every vertex lies on the surface.

scikit-image's ``marching_cubes`` was measured first (docs/fusion.md): a call per block
takes 0.13 ms, so the hundreds of blocks a frame changes would take tens of milliseconds
or more; one call over the blocks stacked side by side leaks triangles between them.

A block's cubes reach one voxel into the blocks after it along x, y and z, so a block's
mesh is redone when it or one of those changes (:class:`~depth_nodes.core.fusion.layer.MeshLayer`).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.blocks import block_key, lookup
from depth_nodes.core.fusion.volume import TsdfVolume

__all__ = ['BlockMeshes', 'block_meshes', 'surface_points', 'weld']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

#: A cube's corners: corner ``x + 2 y + 4 z``; its 12 edges, lower corner first.
CORNERS = np.array([[c & 1, (c >> 1) & 1, c >> 2] for c in range(8)], np.int64)
EDGES = np.array([(c, c | 1 << b) for b in range(3) for c in range(8) if not (c >> b) & 1],
                 np.int64)
#: Most triangles of one case.
MAX_TRIANGLES = 12


def _case_table() -> tuple[NDArray[np.int8], NDArray[np.int8]]:
    """Per case (bit c set: corner c negative), the triangles as edge indices, and their
    count (see the module notes)."""
    edge_of = {(int(a), int(b)): n for n, (a, b) in enumerate(EDGES)}
    faces = []
    for b in range(3):
        u, v = (x for x in range(3) if x != b)
        for side in (0, 1):
            faces.append([side << b | du << u | dv << v
                          for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1))])
    table = np.full((256, 3 * MAX_TRIANGLES), -1, np.int8)
    counts = np.zeros(256, np.int8)
    for case in range(256):
        negative = [bool(case >> c & 1) for c in range(8)]
        links: dict[int, list[int]] = defaultdict(list)
        for face in faces:
            sides = [edge_of[tuple(sorted((face[i], face[(i + 1) % 4])))]  # type: ignore[index]
                     for i in range(4)]
            cut = [i for i in range(4) if negative[face[i]] != negative[face[(i + 1) % 4]]]
            if len(cut) == 2:
                pairs = [(cut[0], cut[1])]
            elif len(cut) == 4:  # alternating: cut off each negative corner
                pairs = [((i - 1) % 4, i) for i in range(4) if negative[face[i]]]
            else:
                pairs = []
            for i, j in pairs:
                links[sides[i]].append(sides[j])
                links[sides[j]].append(sides[i])
        triangles: list[int] = []
        seen: set[int] = set()
        for first in sorted(links):
            if first in seen:
                continue
            loop, previous, current = [first], -1, first
            while True:
                seen.add(current)
                step = next(e for e in links[current] if e != previous)
                if step == first:
                    break
                loop.append(step)
                previous, current = current, step
            loop = _facing_free_side(loop, negative)
            for k in range(1, len(loop) - 1):
                triangles += [loop[0], loop[k], loop[k + 1]]
        counts[case] = len(triangles) // 3
        table[case, :len(triangles)] = triangles
    return table, counts


def _facing_free_side(loop: list[int], negative: list[bool]) -> list[int]:
    """The loop in the order whose normal (Newell's, through the edges' midpoints) points
    from the negative corners it separates to the positive ones."""
    mid = [(CORNERS[EDGES[e, 0]] + CORNERS[EDGES[e, 1]]) / 2.0 for e in loop]
    normal = np.zeros(3)
    for k, here in enumerate(mid):
        normal += np.cross(here, mid[(k + 1) % len(mid)])
    outward = np.zeros(3)
    for e in loop:
        a, b = EDGES[e]
        outward += (CORNERS[b] - CORNERS[a]) * (1.0 if negative[a] else -1.0)
    return loop if normal @ outward > 0 else loop[::-1]


CASES, CASE_TRIANGLES = _case_table()
#: Triangles of each case (int64, as the kernels index with it).
TRIANGLE_COUNTS = CASE_TRIANGLES.astype(np.int64)


@numba.njit(cache=True, nogil=True)
def _gather(slot: int, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
            table_slots: I32, block: int, min_weight: float, values: F32,
            weights: F32) -> bool:
    """The block's voxels and one layer of the blocks after it, (B+1)^3 each (weight 0
    where a neighbour is not allocated); whether the observed ones change sign (else the
    block has no triangle)."""
    n = block + 1
    i, j, k = coords[slot, 0], coords[slot, 1], coords[slot, 2]
    # the block and its 7 neighbours after it, looked up once: sources[(kc * 2 + jb) * 2 + ia]
    sources = np.empty(8, np.int64)
    for m in range(8):
        ia, jb, kc = m & 1, (m >> 1) & 1, m >> 2
        sources[m] = slot if m == 0 else lookup(table_keys, table_slots,
                                                block_key(i + ia, j + jb, k + kc))
    negative = False
    positive = False
    for c in range(n):
        kc = c // block
        for b in range(n):
            jb = b // block
            for a in range(n):
                ia = a // block
                e = (c * n + b) * n + a
                source = sources[(kc * 2 + jb) * 2 + ia]
                if source < 0:
                    values[e] = 0.0
                    weights[e] = 0.0
                else:
                    f = ((c - kc * block) * block + (b - jb * block)) * block + (a - ia * block)
                    value = tsdf[source, f]
                    values[e] = value
                    weights[e] = weight[source, f]
                    if weights[e] > min_weight:
                        if value < 0.0:
                            negative = True
                        else:
                            positive = True
    return negative and positive


@numba.njit(cache=True, nogil=True)
def _block_cases(slot: int, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
                 table_slots: I32, block: int, min_weight: float, values: F32, weights: F32,
                 cases: NDArray[np.uint8]) -> int:
    """Each cube's case (0: no triangle, unobserved corners included) into ``cases``
    (B^3, cube ``(c B + b) B + a``), from the block's gathered voxels; returns the block's
    triangles."""
    cases[:] = 0
    if not _gather(slot, coords, tsdf, weight, table_keys, table_slots, block, min_weight,
                   values, weights):
        return 0
    n = block + 1
    count = 0
    for c in range(block):
        for b in range(block):
            for a in range(block):
                case = 0
                for corner in range(8):
                    e = ((c + CORNERS[corner, 2]) * n + b + CORNERS[corner, 1]) * n + a + \
                        CORNERS[corner, 0]
                    if not weights[e] > min_weight:
                        case = 0
                        break
                    if values[e] < 0.0:
                        case |= 1 << corner
                if case == 255:
                    case = 0
                if case:
                    cases[(c * block + b) * block + a] = case
                    count += TRIANGLE_COUNTS[case]
    return count


@numba.njit(cache=True, nogil=True)
def _emit_block(slot: int, coords: I32, block: int, voxel: float, values: F32,
                cases: NDArray[np.uint8], out: F32, start: int) -> None:
    """The triangles of the block's cubes with a case, as vertex rows from
    ``out[3 start]``."""
    n = block + 1
    f = np.empty(8, np.float64)
    crossing = np.empty((12, 3), np.float64)
    ox = coords[slot, 0] * block
    oy = coords[slot, 1] * block
    oz = coords[slot, 2] * block
    count = 0
    for cube in range(block * block * block):
        case = cases[cube]
        if case == 0:
            continue
        a = cube % block
        b = (cube // block) % block
        c = cube // (block * block)
        for corner in range(8):
            f[corner] = values[((c + CORNERS[corner, 2]) * n + b + CORNERS[corner, 1]) * n +
                               a + CORNERS[corner, 0]]
        for edge in range(12):
            lo, hi = EDGES[edge, 0], EDGES[edge, 1]
            if (f[lo] < 0.0) == (f[hi] < 0.0):
                continue
            t = f[lo] / (f[lo] - f[hi])
            crossing[edge, 0] = (ox + a + CORNERS[lo, 0] +
                                 t * (CORNERS[hi, 0] - CORNERS[lo, 0])) * voxel
            crossing[edge, 1] = (oy + b + CORNERS[lo, 1] +
                                 t * (CORNERS[hi, 1] - CORNERS[lo, 1])) * voxel
            crossing[edge, 2] = (oz + c + CORNERS[lo, 2] +
                                 t * (CORNERS[hi, 2] - CORNERS[lo, 2])) * voxel
        triangles = TRIANGLE_COUNTS[case]
        row = 3 * (start + count)
        for m in range(3 * triangles):
            edge = CASES[case, m]
            for axis in range(3):
                out[row + m, axis] = crossing[edge, axis]
        count += triangles


@numba.njit(cache=True, nogil=True, parallel=True)
def _count_all(slots: I32, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
               table_slots: I32, block: int, min_weight: float, counts: I64,
               cases: NDArray[np.uint8]) -> None:
    n = block + 1
    for m in numba.prange(len(slots)):
        values = np.empty(n * n * n, np.float32)
        weights = np.empty(n * n * n, np.float32)
        counts[m] = _block_cases(slots[m], coords, tsdf, weight, table_keys, table_slots,
                                 block, min_weight, values, weights, cases[m])


@numba.njit(cache=True, nogil=True, parallel=True)
def _emit_all(slots: I32, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
              table_slots: I32, block: int, voxel: float, min_weight: float, offsets: I64,
              cases: NDArray[np.uint8], out: F32) -> None:
    n = block + 1
    for m in numba.prange(len(slots)):
        if offsets[m + 1] == offsets[m]:
            continue
        values = np.empty(n * n * n, np.float32)
        weights = np.empty(n * n * n, np.float32)
        _gather(slots[m], coords, tsdf, weight, table_keys, table_slots, block, min_weight,
                values, weights)
        _emit_block(slots[m], coords, block, voxel, values, cases[m], out, offsets[m])


@dataclass
class BlockMeshes:
    """Triangles of some blocks, as one triangle soup.

    Attributes:
        slots: (M,) the blocks' slots.
        offsets: (M + 1,) block ``n``'s triangles are ``offsets[n]:offsets[n + 1]``.
        vertices: (3 T, 3) float32 world positions, three per triangle, counter-clockwise
            seen from the free side.
    """

    slots: I32
    offsets: I64
    vertices: F32

    def triangles(self, n: int) -> F32:
        """(3 t, 3) the vertices of block ``n``'s triangles."""
        out: F32 = self.vertices[3 * self.offsets[n]:3 * self.offsets[n + 1]]
        return out


def block_meshes(volume: TsdfVolume, slots: I32) -> BlockMeshes:
    """The triangles of blocks ``slots`` of the volume (see the module notes): each cube's
    case in one pass, then the triangles of the cubes that have some."""
    p = volume.params
    slots = np.ascontiguousarray(slots, np.int32)
    args = (slots, volume.coords, volume.tsdf, volume.weight, volume.table.keys,
            volume.table.slots, p.block_size)
    counts = np.zeros(len(slots), np.int64)
    cases = np.empty((len(slots), p.block_size ** 3), np.uint8)
    _count_all(*args, p.min_weight, counts, cases)
    offsets = np.zeros(len(slots) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    vertices = np.empty((3 * int(offsets[-1]), 3), np.float32)
    _emit_all(*args, p.voxel_size, p.min_weight, offsets, cases, vertices)
    return BlockMeshes(slots, offsets, vertices)


@numba.njit(cache=True, nogil=True)
def _block_crossings(slot: int, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
                     table_slots: I32, block: int, voxel: float, min_weight: float,
                     out: F32, start: int, emit: bool) -> int:
    n = block + 1
    values = np.empty(n * n * n, np.float32)
    weights = np.empty(n * n * n, np.float32)
    if not _gather(slot, coords, tsdf, weight, table_keys, table_slots, block, min_weight,
                   values, weights):
        return 0
    ox = coords[slot, 0] * block
    oy = coords[slot, 1] * block
    oz = coords[slot, 2] * block
    count = 0
    for c in range(block):
        for b in range(block):
            for a in range(block):
                e = (c * n + b) * n + a
                if not weights[e] > min_weight:
                    continue
                f0 = values[e]
                for axis in range(3):
                    step = 1 if axis == 0 else (n if axis == 1 else n * n)
                    if not weights[e + step] > min_weight:
                        continue
                    f1 = values[e + step]
                    if (f0 < 0.0) == (f1 < 0.0):
                        continue
                    if emit:
                        t = f0 / (f0 - f1)
                        row = start + count
                        out[row, 0] = (ox + a + (t if axis == 0 else 0.0)) * voxel
                        out[row, 1] = (oy + b + (t if axis == 1 else 0.0)) * voxel
                        out[row, 2] = (oz + c + (t if axis == 2 else 0.0)) * voxel
                    count += 1
    return count


@numba.njit(cache=True, nogil=True, parallel=True)
def _crossings_all(slots: I32, coords: I32, tsdf: F32, weight: F32, table_keys: I64,
                   table_slots: I32, block: int, voxel: float, min_weight: float,
                   offsets: I64, out: F32, emit: bool) -> None:
    for n in numba.prange(len(slots)):
        count = _block_crossings(slots[n], coords, tsdf, weight, table_keys, table_slots,
                                 block, voxel, min_weight, out, offsets[n], emit)
        if not emit:
            offsets[n + 1] = count


def surface_points(volume: TsdfVolume, slots: I32 | None = None) -> F32:
    """(N, 3) float32 points of the surface: where the value crosses 0 between two
    observed voxels along x, y or z (marching cubes' vertices), in blocks ``slots`` (all
    by default)."""
    p = volume.params
    slots = volume.slots() if slots is None else np.ascontiguousarray(slots, np.int32)
    args = (slots, volume.coords, volume.tsdf, volume.weight, volume.table.keys,
            volume.table.slots, p.block_size, p.voxel_size, p.min_weight)
    offsets = np.zeros(len(slots) + 1, np.int64)
    scratch = np.empty((0, 3), np.float32)
    _crossings_all(*args, offsets, scratch, False)
    np.cumsum(offsets, out=offsets)
    out = np.empty((int(offsets[-1]), 3), np.float32)
    _crossings_all(*args, offsets, out, True)
    return out


def weld(vertices: F32) -> tuple[F32, I32]:
    """A triangle soup ((3 T, 3), three rows a triangle) as shared vertices and (T, 3)
    faces: equal positions become one vertex; triangles that collapse to a line or a
    point (a crossing on a corner) are left out."""
    soup = np.ascontiguousarray(vertices, np.float32)
    if not len(soup):
        return np.empty((0, 3), np.float32), np.empty((0, 3), np.int32)
    rows = soup.view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1, 3).astype(np.int32)
    whole = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & \
        (faces[:, 0] != faces[:, 2])
    return soup[first], faces[whole]
