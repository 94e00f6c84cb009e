"""Keep freed memory in the process, so large messages do not page-fault on every frame.

glibc serves an allocation above its mmap threshold (128 KiB at first, raised to the size
of a mapped block when one is freed) with fresh pages from the kernel and returns them on
free; it also hands the top of the heap back once more than 128 KiB there is free. Every
image, disparity image or point cloud a node receives or publishes is such an allocation,
several times over (the DDS sample, the serialised buffer, the Python bytes, the numpy
array), so each frame paid a page fault per 4 KiB and the kernel zeroing every page again.
Measured on this package's machine with a raw subscription to a 9.8 MB PointCloud2 from
another process: 22 to 25 ms of CPU per message received, 6.5 ms with
:func:`keep_freed_memory` (both net of the 4.6 ms a 1 KiB message cost: the subscriber's
spinning).

The settings: allocations up to 32 MiB (glibc's largest mmap threshold on 64-bit) come from
the heap, and up to :data:`TRIM_THRESHOLD` of free heap is kept for the next frame. The
memory a process holds is then its peak use plus at most that, not more.
"""

from __future__ import annotations

import ctypes
import os
import platform
from collections.abc import Mapping

#: mallopt parameter numbers (glibc's malloc.h).
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
#: Allocations below this come from the heap (glibc's maximum on 64-bit systems).
MMAP_THRESHOLD = 32 << 20
#: Free memory at the top of the heap kept before it is returned to the kernel.
TRIM_THRESHOLD = 128 << 20
#: Extra heap requested at a time when the heap grows.
TOP_PAD = 16 << 20
#: Environment variables through which a user tunes glibc's malloc (their choice wins).
USER_VARIABLES = ('GLIBC_TUNABLES', 'MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_',
                  'MALLOC_TOP_PAD_', 'MALLOC_ARENA_MAX')


def keep_freed_memory(env: Mapping[str, str] | None = None) -> bool:
    """Apply the settings above to this process's glibc malloc.

    Nothing changes outside glibc (another C library, macOS, Windows) or when one of
    :data:`USER_VARIABLES` is set.

    Returns:
        Whether every setting was applied.
    """
    env = os.environ if env is None else env
    if any(env.get(name) for name in USER_VARIABLES):
        return False
    if platform.system() != 'Linux' or platform.libc_ver()[0] != 'glibc':
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD), (M_TRIM_THRESHOLD, TRIM_THRESHOLD),
        (M_TOP_PAD, TOP_PAD)))
