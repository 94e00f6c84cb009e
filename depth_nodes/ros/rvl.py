"""RVL, the lossless depth-image code of image_transport's ``compressedDepth rvl`` format
(A. D. Wilson, "Fast Lossless Depth Image Compression", ISS 2017).

The stream is a sequence of 32-bit little-endian words, each holding eight 4-bit nibbles,
most significant first. A number is written in nibbles of 3 bits, least significant
group first, the nibble's top bit set while more follow. The image, in row order, is
coded as runs: the number of zero pixels, the number of non-zero pixels, then each
non-zero pixel as the zigzag code of its difference to the previous non-zero pixel.

:func:`rvl_decode` checks every read against the input's end and every run against the
pixel count, so a damaged stream is an error, never a read or write out of bounds.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from depth_nodes.errors import DecodeError

__all__ = ['rvl_decode', 'rvl_encode']

U16 = NDArray[np.uint16]

_OK, _TRUNCATED, _OVERRUN, _TOO_LONG = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def _decode(words: NDArray[np.uint32], out: U16) -> int:
    n_words = words.shape[0]
    total = out.shape[0]
    w = 0          # next word to load
    word = 0       # the nibbles not read yet, top aligned
    left = 0       # nibbles left in ``word``
    done = 0
    previous = 0
    state = 0      # 0: zeros next, 1: non-zeros next, 2: values
    run = 0
    while done < total:
        # read one variable-length number
        value = 0
        shift = 0
        while True:
            if left == 0:
                if w >= n_words:
                    return _TRUNCATED
                word = int(words[w])
                w += 1
                left = 8
            nibble = (word >> 28) & 0xF
            word = (word << 4) & 0xFFFFFFFF
            left -= 1
            if shift > 30:
                return _TOO_LONG
            value |= (nibble & 0x7) << shift
            shift += 3
            if not nibble & 0x8:
                break
        if state == 0:
            if value > total - done:
                return _OVERRUN
            for i in range(value):
                out[done + i] = 0
            done += value
            state = 1
        elif state == 1:
            if value > total - done:
                return _OVERRUN
            run = value
            state = 2 if run else 0
        else:
            delta = (value >> 1) ^ -(value & 1)
            previous = (previous + delta) & 0xFFFF
            out[done] = previous
            done += 1
            run -= 1
            if run == 0:
                state = 0
    return _OK


def rvl_decode(data: bytes | NDArray[np.uint8], width: int, height: int) -> U16:
    """Decode ``width x height`` uint16 pixels from an RVL stream.

    Raises:
        DecodeError: The stream ends early, or a run or a number does not fit the image.
    """
    buf = np.frombuffer(bytes(data), np.uint8)
    pad = (-buf.size) % 4
    if pad:  # the encoder always writes whole words; tolerate a short tail as zeros
        buf = np.concatenate([buf, np.zeros(pad, np.uint8)])
    words = buf.view('<u4').astype(np.uint32)
    out = np.empty(width * height, np.uint16)
    status = _decode(words, out)
    if status != _OK:
        why = {_TRUNCATED: 'the stream ends before the image does',
               _OVERRUN: 'a run is longer than the image',
               _TOO_LONG: 'a number has too many digits'}[status]
        raise DecodeError(f'corrupt RVL data for a {width}x{height} image: {why}')
    return out.reshape(height, width)


def rvl_encode(depth: U16) -> bytes:
    """Encode uint16 pixels (row order) as an RVL stream (tests and tools; plain Python)."""
    flat = np.asarray(depth, np.uint16).ravel()
    nibbles: list[int] = []

    def number(value: int) -> None:
        while True:
            nibble = value & 0x7
            value >>= 3
            nibbles.append(nibble | (0x8 if value else 0))
            if not value:
                return

    i, n, previous = 0, flat.size, 0
    while i < n:
        start = i
        while i < n and flat[i] == 0:
            i += 1
        number(i - start)
        start = i
        while i < n and flat[i] != 0:
            i += 1
        number(i - start)
        for value in flat[start:i]:
            delta = int(value) - previous
            number(-2 * delta - 1 if delta < 0 else 2 * delta)  # zigzag
            previous = int(value)
    nibbles += [0] * ((-len(nibbles)) % 8)
    words = [int(''.join(f'{x:x}' for x in nibbles[k:k + 8]), 16)
             for k in range(0, len(nibbles), 8)]
    return np.array(words, '<u4').tobytes()
