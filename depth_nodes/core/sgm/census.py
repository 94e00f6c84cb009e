"""The census transform and the popcount its Hamming distances use.

A pixel's census signature holds one bit per neighbour of its window, set when the
neighbour is darker than the centre: a gain or offset between the cameras does not change
it. Two signatures are compared by the number of bits in which they differ
(:func:`popcount` of their XOR). The plain numpy version the tests compare the kernel
with is ``census_transform_reference`` in ``test/reference/sgm.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, prange, types
from numpy.typing import NDArray

from depth_nodes.core.jit import intrinsic
from depth_nodes.errors import ArgumentError

#: A census image: uint32 or uint64 (:func:`census_dtype`).
Census = NDArray[np.unsignedinteger[Any]]


def census_dtype(window: tuple[int, int]) -> type[np.unsignedinteger[Any]]:
    """uint32 when the window's neighbours fit 32 bits (5x5: 24), else uint64.

    The cost kernel then runs the Hamming distance on 32-bit lanes, twice as many per
    vector as 64-bit ones.
    """
    return np.uint32 if window[0] * window[1] - 1 <= 32 else np.uint64


@njit(cache=True, nogil=True)
def _census_row(padded: NDArray[Any], y: int, ry: int, rx: int, width: int,
                mirror: bool, bits: Census) -> None:
    """Census of one row of a border-padded image, accumulated neighbour by neighbour so
    the loop over x vectorises. ``mirror`` takes the neighbours in mirrored x order (for
    an image flipped left-right, see :func:`census_transform`)."""
    for x in range(width):
        bits[x] = 0
    centre = padded[y + ry, rx:rx + width]
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy == 0 and dx == 0:
                continue
            sx = -dx if mirror else dx
            # row views indexed by the loop counter alone: the loop vectorises
            neighbour = padded[y + ry + dy, rx + sx:rx + sx + width]
            for x in range(width):
                darker = neighbour[x] < centre[x]
                bits[x] = (bits[x] << np.uint64(1)) | np.uint64(darker)


@njit(parallel=True, cache=True, nogil=True)
def _census_kernel(padded: NDArray[Any], win_h: int, win_w: int, mirror: bool,
                   out: Census) -> None:
    h, w = out.shape
    for y in prange(h):
        _census_row(padded, y, win_h // 2, win_w // 2, w, mirror, out[y])


def census_transform(image: NDArray[np.generic], window: tuple[int, int],
                     out: Census | None = None, *, mirrored: bool = False) -> Census:
    """Census signature of every pixel: one bit per window neighbour, set when the
    neighbour is darker than the centre (borders replicated).

    Args:
        image: (H, W) grey image (any real dtype).
        window: (height, width), odd, at most 63 neighbours (e.g. 9x7).
        out: Optional (H, W) buffer to fill, of :func:`census_dtype` or uint64.
        mirrored: Fill ``out`` with the census mirrored left-right (``out[:, ::-1]`` is
            then the plain census, same bit order); the cost kernel reads the right
            image's census this way.

    Raises:
        ArgumentError: ``out`` holds fewer bits than the window has neighbours.
    """
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):  # integers are compared as they are
        img = img.astype(np.float32, copy=False)
    if mirrored:
        img = img[:, ::-1]
    if out is None:
        out = np.empty(img.shape, census_dtype(window))
    if np.iinfo(out.dtype).bits < window[0] * window[1] - 1:
        raise ArgumentError(f'a {out.dtype} census holds fewer bits than a {window[0]}x'
                            f'{window[1]} window has neighbours')
    ry, rx = window[0] // 2, window[1] // 2
    padded = np.pad(img, ((ry, ry), (rx, rx)), mode='edge')
    _census_kernel(padded, window[0], window[1], mirrored, out)
    return out


def _popcount_plain(value: Any) -> Any:
    """:func:`popcount` in Python (the JIT off): the number of set bits, in value's type."""
    return type(value)(int(value).bit_count())


@intrinsic(_popcount_plain)
def popcount(typingctx: Any, value: Any) -> Any:
    """Number of set bits of a uint16, uint32 or uint64, in the same type (LLVM's ctpop:
    one instruction per vector where the CPU has one, e.g. AVX-512 VPOPCNTDQ / BITALG).
    The cost kernels and speckle matching compare census signatures with it."""
    if value not in (types.uint16, types.uint32, types.uint64):
        return None

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.ctpop(args[0])

    return value(value), codegen
