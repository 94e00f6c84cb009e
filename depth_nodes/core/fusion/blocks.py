"""Block coordinates and the block hash of the fused volume (voxel hashing, Niessner et al.
2013): a block is B x B x B voxels, found from its integer coordinates through an
open-addressing hash table held in numpy arrays, so that numba kernels look blocks up too
(a mesh cube at a block's face needs its neighbour's voxels). No ROS.

A block's coordinates ``(i, j, k)`` pack into one int64 key (21 bits each, offset by
:data:`OFFSET`): the map reaches 2^20 blocks from the origin along each axis, some 170 km at
2 cm voxels and blocks of 8. The table stores each key with the slot of the block's voxels
in the volume's arrays; a removed key leaves a tombstone, and the table is rebuilt when
keys and tombstones fill half of it.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ['BEFORE', 'EMPTY', 'OFFSET', 'BlockTable', 'block_key', 'coords_keys', 'key_coords',
           'lookup']

I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

#: Half the range of a coordinate: (i + OFFSET) fits in 21 bits.
OFFSET = 1 << 20
_MASK = (1 << 21) - 1
#: A free entry of the table; a removed one.
EMPTY, TOMBSTONE = -1, -2
#: The blocks whose cubes reach into a block: those before it by 0 or 1 along each axis.
BEFORE = np.array([(-dx, -dy, -dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)
                   if dx or dy or dz], np.int32)
#: Multiplier of the hash (the golden ratio's fraction of 2^64, as a signed int64).
_GOLDEN = -7046029254386353131


@numba.njit(cache=True, nogil=True, inline='always')
def block_key(i: int, j: int, k: int) -> int:
    """The int64 key of block ``(i, j, k)``."""
    return ((int(i) + OFFSET) << 42) | ((int(j) + OFFSET) << 21) | (int(k) + OFFSET)


def coords_keys(coords: I32) -> I64:
    """(N,) keys of (N, 3) block coordinates (the inverse of :func:`key_coords`)."""
    c = np.asarray(coords, np.int64).reshape(-1, 3) + OFFSET
    keys: I64 = (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
    return keys


def key_coords(keys: I64) -> I32:
    """(N, 3) block coordinates of (N,) keys."""
    keys = np.asarray(keys, np.int64)
    out = np.empty((len(keys), 3), np.int32)
    out[:, 0] = (keys >> 42) - OFFSET
    out[:, 1] = ((keys >> 21) & _MASK) - OFFSET
    out[:, 2] = (keys & _MASK) - OFFSET
    return out


@numba.njit(cache=True, nogil=True, inline='always')
def _home(key: int, mask: int) -> int:
    return ((int(key) * _GOLDEN) >> 20) & mask


@numba.njit(cache=True, nogil=True)
def lookup(table_keys: I64, table_slots: I32, key: int) -> int:
    """The slot of ``key``, or -1 when the table does not hold it."""
    mask = len(table_keys) - 1
    h = _home(key, mask)
    while True:
        stored = table_keys[h]
        if stored == key:
            return int(table_slots[h])
        if stored == EMPTY:
            return -1
        h = (h + 1) & mask


@numba.njit(cache=True, nogil=True)
def _insert(table_keys: I64, table_slots: I32, key: int, slot: int) -> int:
    """Put ``key -> slot``; returns 1 when it took a free entry, 0 a tombstone or its own."""
    mask = len(table_keys) - 1
    h = _home(key, mask)
    grave = -1
    while True:
        stored = table_keys[h]
        if stored == key:
            table_slots[h] = slot
            return 0
        if stored == TOMBSTONE and grave < 0:
            grave = h
        elif stored == EMPTY:
            if grave >= 0:
                table_keys[grave] = key
                table_slots[grave] = slot
                return 0
            table_keys[h] = key
            table_slots[h] = slot
            return 1
        h = (h + 1) & mask


@numba.njit(cache=True, nogil=True)
def _remove(table_keys: I64, key: int) -> bool:
    mask = len(table_keys) - 1
    h = _home(key, mask)
    while True:
        stored = table_keys[h]
        if stored == key:
            table_keys[h] = TOMBSTONE
            return True
        if stored == EMPTY:
            return False
        h = (h + 1) & mask


@numba.njit(cache=True, nogil=True)
def _lookup_many(table_keys: I64, table_slots: I32, keys: I64, out: I32) -> None:
    for n in range(len(keys)):
        out[n] = lookup(table_keys, table_slots, keys[n])


class BlockTable:
    """Block key -> slot, for the volume (see the module notes)."""

    def __init__(self, capacity: int = 1024) -> None:
        size = 16
        while size < 2 * capacity:
            size *= 2
        self.keys: I64 = np.full(size, EMPTY, np.int64)
        self.slots: I32 = np.full(size, -1, np.int32)
        self.count = 0
        self._filled = 0  # keys and tombstones

    def __len__(self) -> int:
        return self.count

    def find(self, keys: I64) -> I32:
        """The slot of each key (-1: absent)."""
        out = np.empty(len(keys), np.int32)
        _lookup_many(self.keys, self.slots, np.ascontiguousarray(keys, np.int64), out)
        return out

    def add(self, keys: I64, slots: I32) -> None:
        """Put each ``keys[n] -> slots[n]`` (none of them held yet)."""
        if 2 * (self._filled + len(keys)) > len(self.keys):
            self._rebuild(self.count + len(keys))
        for key, slot in zip(keys.tolist(), slots.tolist(), strict=True):
            self._filled += _insert(self.keys, self.slots, key, slot)
        self.count += len(keys)

    def remove(self, keys: I64) -> None:
        """Forget each key (they are held)."""
        for key in keys.tolist():
            self.count -= int(_remove(self.keys, key))

    def clear(self) -> None:
        self.keys.fill(EMPTY)
        self.count = self._filled = 0

    def _rebuild(self, wanted: int) -> None:
        held = self.keys >= 0
        keys, slots = self.keys[held], self.slots[held]
        size = len(self.keys)
        while size < 4 * wanted:
            size *= 2
        self.keys = np.full(size, EMPTY, np.int64)
        self.slots = np.full(size, -1, np.int32)
        self._filled = 0
        for key, slot in zip(keys.tolist(), slots.tolist(), strict=True):
            self._filled += _insert(self.keys, self.slots, key, slot)
