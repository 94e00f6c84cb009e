"""The fused volume: a block-sparse truncated signed distance function (TSDF) built from
depth images at known poses (KinectFusion's update over voxel hashing, as nvblox and
voxblox keep it). No ROS.

A block is allocated where a frame's truncation band crosses it
(:func:`~depth_nodes.core.fusion.integrate.touched_keys`); every allocated block the camera
sees is then updated (:func:`~depth_nodes.core.fusion.integrate.integrate_blocks`), so
space seen through is carved in blocks that hold a surface, while empty space costs no
memory. The volume remembers which blocks changed and which were dropped since the mesh
last asked (:meth:`TsdfVolume.take_changes`): the mesh follows the blocks marked changed.

Memory is bounded: the voxels' arrays never outgrow ``memory_mb``; a frame that needs more
blocks drops the blocks farthest from the camera (its own farthest new blocks included).
``clearing_radius`` drops blocks far from the camera, ``decay_factor`` forgets what is not
seen again.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.blocks import BEFORE, BlockTable, coords_keys, key_coords
from depth_nodes.core.fusion.integrate import (
    MODE_CODES,
    decay_blocks,
    integrate_blocks,
    touch_samples,
    touched_keys,
    visible_blocks,
)
from depth_nodes.core.fusion.params import TsdfParams
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ArgumentError

__all__ = ['BYTES_PER_VOXEL', 'Integrated', 'TsdfVolume']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

#: A voxel's value and weight, float32 each.
BYTES_PER_VOXEL = 8
#: Per block besides its voxels: coordinates, key, flags, and its share of the hash table
#: (rebuilt to a power of two of at least 4 entries a block: at most 8, a key and a slot
#: each).
BYTES_PER_BLOCK = 3 * 4 + 8 + 2 + 8 * (8 + 4)
#: Blocks the arrays hold at first (they double as needed, up to memory_mb).
INITIAL_BLOCKS = 256


@dataclass
class Integrated:
    """What one frame did to the volume.

    Attributes:
        touched: Blocks the frame's truncation band crosses.
        allocated: Of those, new.
        refused: New blocks not allocated: farther than every block memory_mb keeps.
        in_view: Allocated blocks the camera sees (updated or carved).
        voxels: Voxels updated.
        evicted: Blocks dropped for memory.
        cleared: Blocks dropped by clearing_radius or forgotten by decay_factor.
        seconds: Time of each stage (allocate, integrate, maintain).
    """

    touched: int = 0
    allocated: int = 0
    refused: int = 0
    in_view: int = 0
    voxels: int = 0
    evicted: int = 0
    cleared: int = 0
    seconds: dict[str, float] = field(default_factory=dict)


class TsdfVolume:
    """A block-sparse TSDF (see the module notes).

    Attributes:
        tsdf: (capacity, B^3) float32 value of each voxel, -1 to 1 of the truncation.
        weight: (capacity, B^3) float32 weight (0: unobserved).
        coords: (capacity, 3) int32 block coordinates of each slot.
        used: (capacity,) whether a slot holds a block.
        table: Block key -> slot.
    """

    def __init__(self, params: TsdfParams | None = None) -> None:
        self.params = (params or TsdfParams()).validate()
        self._allocate_arrays(min(INITIAL_BLOCKS, self.block_limit))
        self._scratch = np.empty(0, np.int64)
        self._just_allocated = np.empty(0, np.int32)

    # ------------------------------------------------------------------ state
    def _allocate_arrays(self, capacity: int) -> None:
        voxels = self.params.block_size ** 3
        self.tsdf: F32 = np.zeros((capacity, voxels), np.float32)
        self.weight: F32 = np.zeros((capacity, voxels), np.float32)
        self.coords: I32 = np.zeros((capacity, 3), np.int32)
        self.keys: I64 = np.full(capacity, -1, np.int64)
        self.used = np.zeros(capacity, np.bool_)
        self.changed = np.zeros(capacity, np.bool_)
        self.table = BlockTable(capacity)
        self._free = list(range(capacity - 1, -1, -1))
        self._removed: set[int] = set()

    def _grow(self, capacity: int) -> None:
        old = len(self.used)
        extra = capacity - old
        self.tsdf = np.concatenate([self.tsdf, np.zeros((extra, self.tsdf.shape[1]),
                                                        np.float32)])
        self.weight = np.concatenate([self.weight, np.zeros((extra, self.weight.shape[1]),
                                                            np.float32)])
        self.coords = np.concatenate([self.coords, np.zeros((extra, 3), np.int32)])
        self.keys = np.concatenate([self.keys, np.full(extra, -1, np.int64)])
        self.used = np.concatenate([self.used, np.zeros(extra, np.bool_)])
        self.changed = np.concatenate([self.changed, np.zeros(extra, np.bool_)])
        self._free = list(range(capacity - 1, old - 1, -1)) + self._free

    @property
    def block_count(self) -> int:
        """Blocks allocated."""
        return len(self.table)

    @property
    def capacity(self) -> int:
        """Blocks the arrays hold now."""
        return len(self.used)

    @property
    def block_limit(self) -> int:
        """Most blocks ``memory_mb`` allows."""
        per_block = self.params.block_size ** 3 * BYTES_PER_VOXEL + BYTES_PER_BLOCK
        return max(1, int(self.params.memory_mb * 2 ** 20 // per_block))

    @property
    def memory_bytes(self) -> int:
        """Bytes of the voxels' and blocks' arrays."""
        return int(self.tsdf.nbytes + self.weight.nbytes + self.coords.nbytes +
                   self.keys.nbytes + self.used.nbytes + self.changed.nbytes +
                   self.table.keys.nbytes + self.table.slots.nbytes)

    def slots(self) -> I32:
        """The slots holding a block."""
        return np.flatnonzero(self.used).astype(np.int32)

    def block_centres(self, slots: I32) -> F64:
        """(N, 3) world centres of the blocks in ``slots``."""
        return self._centres(self.coords[slots])

    def _centres(self, coords: I32) -> F64:
        p = self.params
        centre = (coords * p.block_size + 0.5 * (p.block_size - 1)) * p.voxel_size
        return centre.astype(np.float64)

    def configure(self, params: TsdfParams) -> bool:
        """Take new settings; a new voxel or block size clears the map (True then)."""
        params = params.validate()
        reshape = (params.voxel_size, params.block_size) != \
            (self.params.voxel_size, self.params.block_size)
        self.params = params
        if reshape:
            self.clear()
        return reshape

    def clear(self) -> None:
        """Forget every block (the mesh is told of each)."""
        removed = self._removed | set(self.slots().tolist())
        self._allocate_arrays(min(INITIAL_BLOCKS, self.block_limit))
        self._removed = removed

    def take_changes(self) -> tuple[I32, I32]:
        """The slots whose blocks changed since the last call (allocated, updated, carved
        or decayed; the mesh redoes them and their neighbours below), and the slots whose
        blocks were dropped and hold none now; both are then forgotten."""
        changed = np.flatnonzero(self.changed & self.used).astype(np.int32)
        self.changed[:] = False
        removed = np.array(sorted(s for s in self._removed
                                  if s >= self.capacity or not self.used[s]), np.int32)
        self._removed = set()
        return changed, removed

    # ------------------------------------------------------------------ work
    def integrate(self, depth: F32, camera: Intrinsics, pose: Pose, *,
                  noise: F32 | None = None) -> Integrated:
        """Fuse one depth image seen from ``pose`` (the camera's optical frame in the
        world).

        Args:
            depth: (H, W) float32 Z in metres; NaN, inf or <= 0 unknown.
            camera: Its pinhole camera (H, W its size).
            pose: The camera in the world.
            noise: (H, W) float32 sigma (metres) for ``weighting_mode: sigma``, or the
                confidence (0 - 1) for ``confidence``; ignored otherwise.

        Raises:
            ArgumentError: A shape or dtype that does not fit, a weighting mode without its
                image.
        """
        p = self.params
        depth = self._checked(depth, camera, 'depth')
        mode = MODE_CODES[p.weighting_mode]
        if mode >= 2:
            if noise is None:
                raise ArgumentError(f'weighting_mode {p.weighting_mode} needs a '
                                    f'{"sigma" if mode == 2 else "confidence"} image')
            aux = self._checked(noise, camera, 'sigma' if mode == 2 else 'confidence')
        else:
            aux = np.zeros((1, 1), np.float32)
        pose.validate()
        result = Integrated()
        start = time.perf_counter()
        self._allocate(depth, camera, pose, result)
        allocated = time.perf_counter()
        to_camera = pose.inverse()
        seen = visible_blocks(self.coords, self.used, p.voxel_size, p.block_size,
                              to_camera.rotation, to_camera.position, camera.vector,
                              camera.width, camera.height,
                              p.max_integration_distance + p.truncation_m)
        slots = np.flatnonzero(seen).astype(np.int32)
        result.in_view = len(slots)
        counts = np.zeros(len(slots), np.int64)
        integrate_blocks(
            depth, aux, mode, camera.vector, to_camera.rotation, to_camera.position, slots,
            self.coords, self.tsdf, self.weight, p.voxel_size, p.block_size, p.truncation_m,
            p.min_integration_distance, p.max_integration_distance, p.max_weight,
            p.weight_dropoff, p.free_space_carving, p.allow_clear, self.changed, counts)
        result.voxels = int(counts.sum())
        if not result.voxels and result.allocated:
            self._undo_allocation()  # a frame that fused nothing leaves no trace
            result.allocated = 0
        integrated = time.perf_counter()
        result.cleared = self._maintain(pose.position)
        done = time.perf_counter()
        result.seconds = {'allocate': allocated - start, 'integrate': integrated - allocated,
                          'maintain': done - integrated}
        return result

    def _checked(self, image: F32, camera: Intrinsics, what: str) -> F32:
        array = np.asarray(image)
        if array.ndim != 2 or array.shape != camera.shape:
            raise ArgumentError(f'{what}: shape {array.shape} does not match the camera\'s '
                                f'{camera.shape}')
        if array.dtype != np.float32:
            raise ArgumentError(f'{what}: float32 expected, got {array.dtype}')
        return np.ascontiguousarray(array)

    def _allocate(self, depth: F32, camera: Intrinsics, pose: Pose,
                  result: Integrated) -> None:
        p = self.params
        samples = touch_samples(p.voxel_size, p.block_size, p.truncation_m)
        if len(self._scratch) < depth.size * samples:
            self._scratch = np.empty(depth.size * samples, np.int64)
        keys = touched_keys(depth, camera.vector, pose.rotation, pose.position,
                            voxel=p.voxel_size, block=p.block_size, truncation=p.truncation_m,
                            min_depth=p.min_integration_distance,
                            max_depth=p.max_integration_distance, buffer=self._scratch)
        result.touched = len(keys)
        new = keys[self.table.find(keys) < 0]
        if not len(new):
            return
        limit = self.block_limit
        if self.block_count + len(new) > limit:
            new = self._make_room(new, pose.position, limit, result)
        if self.block_count + len(new) > self.capacity:
            wanted = self.capacity
            while wanted < self.block_count + len(new):
                wanted *= 2
            self._grow(min(wanted, limit))
        slots = np.array([self._free.pop() for _ in range(len(new))], np.int32)
        self.tsdf[slots] = 0.0
        self.weight[slots] = 0.0
        self.coords[slots] = key_coords(new)
        self.keys[slots] = new
        self.used[slots] = True
        self.changed[slots] = True
        self.table.add(new, slots)
        self._just_allocated = slots
        result.allocated = len(new)

    def _undo_allocation(self) -> None:
        """Forget the blocks the last frame allocated, as if it never came (its slots back
        on the free list in their order)."""
        slots = self._just_allocated
        self.table.remove(self.keys[slots])
        self.used[slots] = False
        self.changed[slots] = False
        self.keys[slots] = -1
        self._free.extend(slots[::-1].tolist())
        self._just_allocated = np.empty(0, np.int32)

    def _make_room(self, new: I64, camera: F64, limit: int, result: Integrated) -> I64:
        """Keep the ``limit`` blocks nearest the camera among the allocated and ``new``
        ones: drop the others (returns the new ones kept)."""
        old = self.slots()
        centre_new = self._centres(key_coords(new))
        distance = np.concatenate([
            np.linalg.norm(self.block_centres(old) - camera, axis=1),
            np.linalg.norm(centre_new - camera, axis=1)])
        keep = np.zeros(len(distance), bool)
        keep[np.argsort(distance, kind='stable')[:limit]] = True
        drop = old[~keep[:len(old)]]
        self._remove(drop)
        result.evicted = len(drop)
        result.refused = int((~keep[len(old):]).sum())
        kept: I64 = new[keep[len(old):]]
        return kept

    def _maintain(self, camera: F64) -> int:
        """clearing_radius and decay_factor; returns the blocks dropped."""
        p = self.params
        dropped = 0
        if p.clearing_radius > 0:
            slots = self.slots()
            far = np.linalg.norm(self.block_centres(slots) - camera, axis=1) > \
                p.clearing_radius
            self._remove(slots[far])
            dropped += int(far.sum())
        if p.decay_factor < 1.0:
            slots = self.slots()
            observed = np.zeros(len(slots), np.int32)
            decay_blocks(slots, self.tsdf, self.weight, p.decay_factor, p.min_weight, observed)
            self.changed[slots] = True
            empty = slots[observed == 0]
            self._remove(empty)
            dropped += len(empty)
        return dropped

    def _remove(self, slots: I32) -> None:
        """Drop blocks; the blocks before them along x, y, z (whose cubes reach into them)
        are marked changed."""
        if not len(slots):
            return
        before = (self.coords[slots][:, None, :] + BEFORE[None, :, :]).reshape(-1, 3)
        self.table.remove(self.keys[slots])
        found = self.table.find(coords_keys(before))
        self.changed[found[found >= 0]] = True
        self.used[slots] = False
        self.changed[slots] = False
        self.keys[slots] = -1
        self._free.extend(slots.tolist())
        self._removed.update(slots.tolist())
