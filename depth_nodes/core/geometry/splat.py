"""Forward splatting: the points of a depth image moved into another camera, the nearest
surface winning where several land on one pixel (a z-buffer); no ROS.

One kernel serves every warp of the package: depth registered into a colour camera
(``register_depth``), the depth filter's temporal memory moved with the camera, and
multi-view stereo's per-pixel filter moved into the next reference view. It gives, per
target pixel, the Z that landed there and which source pixel it came from
(:class:`Splat`); each user then carries its own values along that index (a variance, a
history, filter counts) with its own rule.

A source pixel covers, in the target, the pixel centres of its *footprint*
(:data:`FOOTPRINTS`):

* ``point``: none: only the target pixel holding its centre (a per-pixel state, which must
  not be smeared);
* ``box``: the pixel's size scaled by the change of depth and focal length, around its
  centre (cheap; exact for a motion along the optical axis);
* ``corners``: the bounding box of the pixel's four corners at its depth, projected
  (follows a rotation about the axis and perspective).

A footprint that covers no pixel centre (the target coarser than the source) gives its Z to
the target pixel holding its centre. Points behind the target camera do not land; neither
do unknown values (not finite and positive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry.pinhole import Intrinsics
from depth_nodes.core.geometry.pose import Motion
from depth_nodes.core.geometry.rotation import check_rotation
from depth_nodes.errors import ArgumentError

__all__ = ['FOOTPRINTS', 'Splat', 'splat']

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

#: How much of the target a source pixel covers (see the module notes).
FOOTPRINTS = ('point', 'box', 'corners')
_FOOTPRINT = {name: k for k, name in enumerate(FOOTPRINTS)}


@dataclass
class Splat:
    """Where a depth image landed in the target camera.

    Attributes:
        depth: (H, W) float64 Z in the target's optical frame, ``inf`` where nothing landed.
        index: (H, W) int32 flat index (``y * width + x``) of the source pixel that landed
            there, -1 where none did.
    """

    depth: F64
    index: I32

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> Splat:
        """Buffers for a target of ``shape`` (H, W), to pass as ``into``."""
        return cls(np.empty(shape), np.empty(shape, np.int32))

    @property
    def landed(self) -> NDArray[np.bool_]:
        """Target pixels a source point landed on."""
        out: NDArray[np.bool_] = self.index >= 0
        return out


def splat(values: NDArray[np.floating], source: Intrinsics, target: Intrinsics,
          motion: Motion, *, footprint: str, inverse: bool = False,
          into: Splat | None = None) -> Splat:
    """The source depth image's points moved by ``motion`` into ``target``, z-buffered.

    Args:
        values: (H, W) of the source: Z in metres, or (``inverse``) 1 / Z; any value not
            finite and positive is unknown.
        source: The source camera (its size is ``values``').
        target: The target camera.
        motion: ``(R, t)`` taking source optical-frame points into the target's.
        footprint: One of :data:`FOOTPRINTS`.
        inverse: ``values`` hold inverse depth.
        into: A result of the target's size to write over instead of allocating (a warp
            that runs every frame reuses its memory).

    Raises:
        ArgumentError: Shapes that do not fit, a motion that is not rigid, an unknown
            footprint.
    """
    arr = np.asarray(values)
    if arr.shape != (source.height, source.width):
        raise ArgumentError(f'the source is {arr.shape[1::-1]} but its camera '
                            f'{source.width}x{source.height}')
    if arr.size >= 2**31:
        raise ArgumentError(f'a source of {arr.size} pixels is more than a splat indexes')
    if footprint not in _FOOTPRINT:
        raise ArgumentError(f'footprint {footprint!r}: one of {", ".join(FOOTPRINTS)}')
    R = np.ascontiguousarray(check_rotation(motion[0], 'a motion\'s rotation'))
    t = np.ascontiguousarray(motion[1], dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ArgumentError(f'a motion\'s translation must be 3 finite values, got '
                            f'{tuple(np.ravel(motion[1]).tolist())}')
    shape = (target.height, target.width)
    if into is None or into.depth.shape != shape:
        into = Splat.empty(shape)
    into.depth.fill(np.inf)
    into.index.fill(-1)
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float32)
    _splat_kernel(np.ascontiguousarray(arr), bool(inverse), source.vector, target.vector, R,
                  t, _FOOTPRINT[footprint], into.depth, into.index)
    return into


@numba.njit(cache=True, nogil=True, error_model='numpy')
def _splat_kernel(values: NDArray[np.floating], inverse: bool, src: F64, dst: F64, R: F64,
                  t: F64, footprint: int, zbuf: F64, index: I32) -> None:
    h, w = values.shape
    oh, ow = zbuf.shape
    h_end, w_end = float(oh), float(ow)
    # the camera and the motion as scalars: the first loop then vectorises
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], \
        R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    fu, fv, cu, cv = dst[0], dst[1], dst[2], dst[3]
    half_u, half_v = 0.5 * dst[0] / src[0], 0.5 * dst[1] / src[1]
    inv_fx, inv_fy, cx, cy = 1.0 / src[0], 1.0 / src[1], src[2], src[3]
    zs = np.empty(w)
    box = np.empty((4, w))  # each point's footprint: u and v from, u and v to
    for y in range(h):
        ny = (y - cy) * inv_fy
        for x in range(w):  # the row's points, projected (no branch: NaN flows through)
            value = np.float64(values[y, x])
            z = 1.0 / value if inverse else value
            px, py = (x - cx) * inv_fx * z, ny * z
            zc = r20 * px + r21 * py + r22 * z + t2
            inv = 1.0 / zc
            uc = fu * (r00 * px + r01 * py + r02 * z + t0) * inv + cu
            vc = fv * (r10 * px + r11 * py + r12 * z + t1) * inv + cv
            zs[x] = zc if value > 0.0 else np.nan
            if footprint == 1:
                ratio = z * inv
                box[0, x], box[2, x] = uc - half_u * ratio, uc + half_u * ratio
                box[1, x], box[3, x] = vc - half_v * ratio, vc + half_v * ratio
            else:
                box[0, x], box[2, x] = uc, uc
                box[1, x], box[3, x] = vc, vc
        if footprint == 2:  # the corners' bounding box, of the corners ahead of the camera
            for x in range(w):
                if not zs[x] > 0.0:
                    continue
                value = np.float64(values[y, x])
                z = 1.0 / value if inverse else value
                u_lo, v_lo, u_hi, v_hi = np.inf, np.inf, -np.inf, -np.inf
                for du in (-0.5, 0.5):
                    for dv in (-0.5, 0.5):
                        px, py = (x + du - cx) * inv_fx * z, (y + dv - cy) * inv_fy * z
                        pz = r20 * px + r21 * py + r22 * z + t2
                        if not pz > 0.0:
                            continue
                        pu = fu * (r00 * px + r01 * py + r02 * z + t0) / pz + cu
                        pv = fv * (r10 * px + r11 * py + r12 * z + t1) / pz + cv
                        u_lo, u_hi = min(u_lo, pu), max(u_hi, pu)
                        v_lo, v_hi = min(v_lo, pv), max(v_hi, pv)
                if u_lo <= u_hi and v_lo <= v_hi:
                    box[0, x], box[1, x], box[2, x], box[3, x] = u_lo, v_lo, u_hi, v_hi
        base = y * w
        for x in range(w):  # ... and splatted
            zc = zs[x]
            if not zc > 0.0:  # behind the camera, or unknown
                continue
            u0, v0, u1, v1 = box[0, x], box[1, x], box[2, x], box[3, x]
            c0, c1 = np.ceil(u0), np.ceil(u1) - 1.0
            r0, r1 = np.ceil(v0), np.ceil(v1) - 1.0
            if not (c0 <= c1 and r0 <= r1):  # covers no pixel centre: the one holding its
                c0 = c1 = np.floor(0.5 * (u0 + u1) + 0.5)  # centre
                r0 = r1 = np.floor(0.5 * (v0 + v1) + 0.5)
            # clipped to the image before int(): a float beyond int64 (a depth of 1e-30 m
            # projects ~1e30 px away) has no defined int
            c_first, c_last = min(max(c0, 0.0), w_end), max(min(c1, w_end - 1.0), -1.0)
            r_first, r_last = min(max(r0, 0.0), h_end), max(min(r1, h_end - 1.0), -1.0)
            for r in range(int(r_first), int(r_last) + 1):
                for c in range(int(c_first), int(c_last) + 1):
                    if zc < zbuf[r, c]:
                        zbuf[r, c] = zc
                        index[r, c] = base + x
