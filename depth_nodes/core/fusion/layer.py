"""The mesh layer: each block's triangles, kept and redone only where the volume changed
(as nvblox's and voxblox's mesh layers follow the TSDF blocks marked changed). No ROS.

:meth:`MeshLayer.update` asks the volume which blocks changed and which were dropped since
the last update, redoes the changed blocks and the blocks before them along x, y and z
(whose cubes reach into them), and says which blocks' triangles are new and which blocks
have none any more: what a viewer needs to redraw the mesh incrementally (one marker per
block, a delete for a block gone).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.blocks import BEFORE, coords_keys
from depth_nodes.core.fusion.mesh import block_meshes, weld
from depth_nodes.core.fusion.volume import TsdfVolume

__all__ = ['MeshLayer', 'MeshUpdate']

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

@dataclass
class MeshUpdate:
    """What changed in the mesh.

    Attributes:
        blocks: Block slot -> its (3 t, 3) triangle soup, for each block redone that has
            triangles (a viewer replaces that block's mesh).
        deleted: Slots of blocks with no triangles now that had some (a viewer deletes
            them).
        triangles: Triangles of the whole mesh after the update.
    """

    blocks: dict[int, F32]
    deleted: list[int]
    triangles: int


class MeshLayer:
    """Every block's triangles (see the module notes)."""

    def __init__(self) -> None:
        self.blocks: dict[int, F32] = {}

    def clear(self) -> list[int]:
        """Forget the mesh; returns the blocks a viewer must delete."""
        gone = sorted(self.blocks)
        self.blocks = {}
        return gone

    def update(self, volume: TsdfVolume) -> MeshUpdate:
        """Redo the blocks of ``volume`` that changed (see the module notes)."""
        changed, removed = volume.take_changes()
        redo = set(changed.tolist())
        if len(changed):
            coords = volume.coords[changed]
            before = (coords[:, None, :] + BEFORE[None, :, :]).reshape(-1, 3)
            keys = coords_keys(before)
            found = volume.table.find(keys)
            redo.update(found[found >= 0].tolist())
        slots = np.array(sorted(redo), np.int32)
        meshes = block_meshes(volume, slots)
        new: dict[int, F32] = {}
        deleted = [s for s in removed.tolist() if self.blocks.pop(s, None) is not None]
        for n, slot in enumerate(slots.tolist()):
            triangles = meshes.triangles(n)
            if len(triangles):
                self.blocks[slot] = new[slot] = triangles
            elif self.blocks.pop(slot, None) is not None:
                deleted.append(slot)
        return MeshUpdate(new, sorted(set(deleted)), self.triangle_count)

    @property
    def triangle_count(self) -> int:
        return sum(len(t) for t in self.blocks.values()) // 3

    def soup(self) -> F32:
        """(3 T, 3) every triangle of the mesh."""
        if not self.blocks:
            return np.empty((0, 3), np.float32)
        return np.concatenate([self.blocks[s] for s in sorted(self.blocks)])

    def mesh(self) -> tuple[F32, I32]:
        """The whole mesh as shared vertices and (T, 3) faces (:func:`weld`)."""
        return weld(self.soup())
