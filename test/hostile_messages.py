"""Hostile variants of valid ROS messages, by message type: what the structured
hostile-input test (test/nodes/test_hostile_inputs.py) sends every node instead of one of
its valid messages.

:func:`variants` gives every variant of one valid message as ``(name, message)``, each a
fresh copy with one thing wrong or unusual:

* Image (also a DisparityImage's image): sizes 0x0, Wx0, 0xH, 1xN, Nx1, 1x1, odd, half
  and double (a size its paired inputs do not have); every encoding the package reads,
  and encodings it does not; for float pixels NaN, +-inf, negative, zero, tiny,
  subnormal, huge and float32's largest, everywhere or in one pixel (a 16UC1 depth gets
  these too, as the same depth in 32FC1 metres); for integer pixels 0 and the largest;
  fields that disagree (step, data length, height, byte order);
* CameraInfo: K, P or both all zero; NaN, inf, zero, negative, tiny and huge focal
  lengths and principal points; a baseline (P[0, 3]) of the wrong sign, NaN or huge;
  distortion coefficients NaN, too many or none, unknown models; R zero, NaN or not a
  rotation; sizes 0x0, 1x1, half, double and 2**31 - 1; binning and ROI that leave no
  image or cut it;
* DisparityImage: f, t, the disparity range and delta_d zero, negative, NaN, inf or
  inverted; a valid_window outside the image; and every Image variant of its image;
* std_msgs/Header (a pattern tag): tags empty, malformed, out of range or huge;
* any other type (a new node's input): every float field NaN, inf and huge, every string
  empty and nonsense.

:func:`stamp_variants` gives the stamp cases of any message with a header: the previous
frame's stamp (duplicated), an older one (out of order), nanosec >= 1e9, 0, and far in
the future.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from stereo_msgs.msg import DisparityImage

from depth_nodes.ros.image import READABLE_ENCODINGS, array_to_image, image_to_array

Variant = tuple[str, Any]

#: Float values that are legal in a message and hostile to the code reading it.
FLOATS = {'nan': math.nan, 'inf': math.inf, '-inf': -math.inf, 'negative': -1.0,
          'zero': 0.0, 'tiny': 1e-30, 'subnormal': 1e-45, 'huge': 1e30,
          'float32 max': float(np.finfo(np.float32).max)}
#: Encodings of ROS that the package does not read, and names that are none.
UNREAD_ENCODINGS = ('', 'nonsense', '64FC1', '32FC3', '16SC1', '8SC1', '32SC1')
#: Pattern tags (``<sequence>:<index>/<count>``) that are not usable.
BAD_TAGS = ('', 'nonsense', 'x' * 300, '0:0/0', '0:7/3', '0:0/1000000', '-1:0/5',
            '0:-1/5', '1:2:3/4', '0:0/1', '\x00')
#: The stamp cases of :func:`stamp_variants`.
STAMP_CASES = ('stamp duplicated', 'stamp out of order', 'stamp nanosec 1e9',
               'stamp nanosec max', 'stamp zero', 'stamp far future')


def variants(msg: Any) -> Iterator[Variant]:
    """Every hostile variant of a valid message (see the module docstring), stamps
    excepted."""
    if isinstance(msg, Image):
        yield from image_variants(msg)
    elif isinstance(msg, CameraInfo):
        yield from camera_info_variants(msg)
    elif isinstance(msg, DisparityImage):
        yield from disparity_variants(msg)
    elif isinstance(msg, Header):
        for tag in BAD_TAGS:
            yield f'tag {tag[:20]!r}', _changed(msg, frame_id=tag)
    else:
        yield from generic_variants(msg)


def _changed(msg: Any, **fields: Any) -> Any:
    out = copy.deepcopy(msg)
    for name, value in fields.items():
        setattr(out, name, value)
    return out


def _raw_image(like: Image, encoding: str, height: int, width: int,
               rng: np.random.Generator) -> Image:
    """An Image of random bytes laid out as ``encoding`` (its stored dtype and channels)."""
    dtype, channels = READABLE_ENCODINGS[encoding]
    rows = height + height // 2 if encoding == 'nv21' else height
    msg = Image(header=copy.deepcopy(like.header), height=height, width=width,
                encoding=encoding, step=width * channels * dtype.itemsize)
    msg.data = rng.integers(0, 256, msg.step * rows, dtype=np.uint8).tobytes()
    return msg


def _float_values(pixels: Any, remade: Callable[[Any], Image]) -> Iterator[Variant]:
    h, w = pixels.shape[:2]
    for name, value in FLOATS.items():
        yield f'pixels all {name}', remade(np.full_like(pixels, value))
        one = pixels.copy()
        one[h // 2, w // 2] = value
        yield f'one pixel {name}', remade(one)


def image_variants(msg: Image) -> Iterator[Variant]:
    """Sizes, encodings, pixel values and inconsistent fields of an Image."""
    pixels = np.array(image_to_array(msg))
    h, w = pixels.shape[:2]

    def remade(p: Any) -> Image:
        return array_to_image(np.ascontiguousarray(p), msg.encoding, copy.deepcopy(msg.header))

    sizes = {'0x0': pixels[:0, :0], f'{w}x0': pixels[:0], f'0x{h}': pixels[:, :0],
             f'{w}x1': pixels[:1], f'1x{h}': pixels[:, :1], '1x1': pixels[:1, :1],
             f'odd {w - 1}x{h - 1}': pixels[:h - 1, :w - 1],
             f'half {w // 2}x{h // 2}': pixels[::2, ::2],
             f'double {2 * w}x{2 * h}': np.repeat(np.repeat(pixels, 2, 0), 2, 1)}
    for name, sized in sizes.items():
        yield f'size {name}', remade(sized)
    rng = np.random.default_rng(33)
    for encoding in READABLE_ENCODINGS:
        if encoding != msg.encoding:
            yield f'encoding {encoding}', _raw_image(msg, encoding, h, w, rng)
    for encoding in UNREAD_ENCODINGS:
        yield f'encoding {encoding!r}', _changed(msg, encoding=encoding)
    if pixels.dtype.kind == 'f':
        yield from _float_values(pixels, remade)
    else:
        top = np.iinfo(pixels.dtype).max
        yield 'pixels all zero', remade(np.zeros_like(pixels))
        yield 'pixels all max', remade(np.full_like(pixels, top))
        one = pixels.copy()
        one[h // 2, w // 2] = top
        yield 'one pixel max', remade(one)
    if msg.encoding == '16UC1':  # millimetres: the same depth in metres, 32FC1, too
        yield from ((f'32FC1 {name}', v) for name, v in _float_values(
            pixels.astype(np.float32) / 1000, lambda p: array_to_image(
                p, '32FC1', copy.deepcopy(msg.header))))
    data = bytes(msg.data)
    yield 'step smaller than a row', _changed(msg, step=max(msg.step - 1, 0))
    yield 'step 2**32 - 1', _changed(msg, step=2**32 - 1)
    yield 'data empty', _changed(msg, data=b'')
    yield 'data half', _changed(msg, data=data[:len(data) // 2])
    yield 'data longer', _changed(msg, data=data + bytes(64))
    yield 'big endian', _changed(msg, is_bigendian=1)
    yield 'height beyond the data', _changed(msg, height=2 * h)
    yield 'width beyond the step', _changed(msg, width=msg.step + 1)


def _matrix_changed(msg: CameraInfo, name: str, index: int | None, value: float) -> Any:
    values = np.array(getattr(msg, name), dtype=np.float64)
    if index is None:
        values[:] = value
    else:
        values[index] = value
    return _changed(msg, **{name: values})


def camera_info_variants(msg: CameraInfo) -> Iterator[Variant]:
    """Calibrations that are missing, not finite, degenerate or of another size."""
    yield 'K all zero', _matrix_changed(msg, 'k', None, 0.0)
    yield 'P all zero', _matrix_changed(msg, 'p', None, 0.0)
    both = _matrix_changed(msg, 'k', None, 0.0)
    both.p = np.zeros(12)
    yield 'K and P all zero', both
    for name in ('nan', 'inf', 'zero', 'negative', 'tiny', 'huge'):
        for field, index, what in (('k', 0, 'K fx'), ('p', 0, 'P fx'), ('k', 2, 'K cx'),
                                   ('p', 6, 'P cy'), ('p', 3, 'P Tx')):
            yield f'{what} {name}', _matrix_changed(msg, field, index, FLOATS[name])
    yield 'P Tx positive', _matrix_changed(msg, 'p', 3, 6.0)
    yield 'P Tx -1e300', _matrix_changed(msg, 'p', 3, -1e300)
    yield 'D nan', _changed(msg, d=[math.nan] * 5)
    yield 'D inf', _changed(msg, d=[math.inf] * 5)
    yield 'D 100 values', _changed(msg, d=[0.0] * 100)
    yield 'D none', _changed(msg, d=[])
    yield 'D huge', _changed(msg, d=[1e30] * 5)
    for model in ('', 'nonsense', 'equidistant', 'rational_polynomial'):
        yield f'distortion model {model!r}', _changed(msg, distortion_model=model)
    yield 'R all zero', _matrix_changed(msg, 'r', None, 0.0)
    yield 'R nan', _matrix_changed(msg, 'r', 0, math.nan)
    yield 'R not a rotation', _changed(msg, r=2.0 * np.array(msg.r))
    w, h = int(msg.width), int(msg.height)
    for name, (width, height) in {'0x0': (0, 0), '1x1': (1, 1),
                                  'half': (w // 2, h // 2), 'double': (2 * w, 2 * h),
                                  '2**31 - 1': (2**31 - 1, 2**31 - 1),
                                  'width 2**31 - 1': (2**31 - 1, h)}.items():
        yield f'size {name}', _changed(msg, width=width, height=height)
    yield 'binning 2**31 - 1', _changed(msg, binning_x=2**31 - 1, binning_y=2**31 - 1)
    yield 'binning 2', _changed(msg, binning_x=2, binning_y=2)
    outside = copy.deepcopy(msg)
    outside.roi.x_offset, outside.roi.width, outside.roi.height = w - 2, 10, 10
    yield 'roi outside the image', outside
    inside = copy.deepcopy(msg)
    inside.roi.x_offset, inside.roi.y_offset, inside.roi.width, inside.roi.height = 3, 2, 20, 10
    yield 'roi 20x10', inside


def disparity_variants(msg: DisparityImage) -> Iterator[Variant]:
    """A DisparityImage's fields, then every variant of its image."""
    for field in ('f', 't', 'delta_d', 'min_disparity', 'max_disparity'):
        for name in ('nan', 'inf', '-inf', 'zero', 'negative', 'huge'):
            yield f'{field} {name}', _changed(msg, **{field: FLOATS[name]})
    yield 'min above max', _changed(msg, min_disparity=msg.max_disparity + 1.0)
    outside = copy.deepcopy(msg)
    outside.valid_window.x_offset = msg.image.width - 2
    outside.valid_window.width = 30
    yield 'valid_window outside the image', outside
    for name, image in image_variants(msg.image):
        yield f'image {name}', _changed(msg, image=image)


def generic_variants(msg: Any, prefix: str = '') -> Iterator[Variant]:
    """A message of another type: each float field (or array of floats) NaN, inf and huge,
    each string empty and nonsense, one field at a time (nested ones included)."""
    for field, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, field)
        if hasattr(value, 'get_fields_and_field_types'):
            for name, changed in generic_variants(value, f'{prefix}{field}.'):
                yield name, _changed(msg, **{field: changed})
        elif kind in ('float', 'double') or 'double[' in kind or 'float[' in kind:
            for name in ('nan', 'inf', 'huge'):
                new = (FLOATS[name] if kind in ('float', 'double') else
                       np.full(len(value), FLOATS[name]))
                yield f'{prefix}{field} {name}', _changed(msg, **{field: new})
        elif kind == 'string':
            for text in ('', 'nonsense'):
                yield f'{prefix}{field} {text!r}', _changed(msg, **{field: text})


def stamp_variants(msg: Any, previous: int) -> Iterator[Variant]:
    """The message with a bad stamp (:data:`STAMP_CASES`), ``previous`` (ns) being the
    stamp of the frame before it; nothing for a message without a header."""
    for case in STAMP_CASES:
        out = copy.deepcopy(msg)
        stamp = out.stamp if isinstance(out, Header) else getattr(
            getattr(out, 'header', None), 'stamp', None)
        if stamp is None:
            return
        ns = {'stamp duplicated': previous, 'stamp out of order': previous - 1_000_000,
              'stamp zero': 0, 'stamp far future': (2**31 - 1) * 10**9}.get(case)
        if ns is not None:
            stamp.sec, stamp.nanosec = divmod(ns, 10**9)
        else:
            stamp.nanosec = 10**9 if case == 'stamp nanosec 1e9' else 2**32 - 1
        yield case, out
