"""Experiment (not part of the package): the downward SGM sweep with pixels in the lanes.

The shipped kernels keep the disparities of one pixel in a vector (``aggregate.path_step``:
16 disparities per 256-bit vector). Here a vector holds 16 neighbouring pixels at one
disparity instead, as GPU implementations lay out SGM: the three downward directions of a
tile of 16 pixels run through d with the previous row's d - 1, d, d + 1 held in registers
(one load per direction and d instead of three, no minimum across the lanes per pixel).
numba has no SIMD type, so this file defines one: an LLVM ``<16 x i16>`` value with
loads, stores, minima and lane shifts as intrinsics.

It times, on the bundled pair's cost volume (640x480, 128 disparities, the shipped graph's
census and P2 settings), one thread each:

1. ``aggregate.sweep_down``, as the matcher runs it;
2. pixel lanes with the cost and the sums in the pixel-lane layout (tiles of 16 pixels,
   pixel innermost): what the recurrence costs when nothing has to be rearranged;
3. pixel lanes on the matcher's layout (disparity innermost): each 16 x 16 block of costs
   transposed on the way in, each tile's sums transposed in a small buffer and copied out;
4. as 3 without writing the sums: the recurrence and the cost transposes alone.

Every variant's sums are checked against (1), bit for bit. Run from the repository with
``.venv/bin/python docs/experiments/pixel_lanes.py``. Results:
docs/experiments/speed_history.md.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, models, register_model

from depth_nodes.core.sgm import SgmParams
from depth_nodes.core.sgm.aggregate import SENTINEL, new_line_buffers, p2_table, sweep_down
from depth_nodes.core.sgm.matcher import _cost_inputs
from depth_nodes.tools.bench.sgm import _bundled_pair

LANES = 16
VT = ir.VectorType(ir.IntType(16), LANES)


class Vec(types.Type):
    """16 uint16 lanes."""

    def __init__(self) -> None:
        super().__init__(name='Vec16u16')


vec = Vec()


@register_model(Vec)
class _VecModel(models.PrimitiveModel):
    def __init__(self, dmm: Any, fe_type: Any) -> None:
        super().__init__(dmm, fe_type, VT)


def _address(context: Any, builder: Any, array_type: Any, array: Any, index: Any) -> Any:
    data = context.make_array(array_type)(context, builder, array).data
    return builder.gep(data, [index])


@intrinsic
def vload(typingctx: Any, array: Any, index: Any) -> Any:
    """16 uint16 from array[index:index + 16]."""
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        at = _address(context, builder, sig.args[0], args[0], args[1])
        return builder.load(builder.bitcast(at, VT.as_pointer()), align=2)
    return vec(array, index), codegen


@intrinsic
def vload8(typingctx: Any, array: Any, index: Any) -> Any:
    """16 uint8 from array[index:index + 16], widened to uint16."""
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        at = _address(context, builder, sig.args[0], args[0], args[1])
        bytes16 = ir.VectorType(ir.IntType(8), LANES).as_pointer()
        return builder.zext(builder.load(builder.bitcast(at, bytes16), align=1), VT)
    return vec(array, index), codegen


@intrinsic
def vstore(typingctx: Any, array: Any, index: Any, value: Any) -> Any:
    """array[index:index + 16] = value."""
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        at = _address(context, builder, sig.args[0], args[0], args[1])
        builder.store(args[2], builder.bitcast(at, VT.as_pointer()), align=2)
        return context.get_dummy_value()
    return types.void(array, index, value), codegen


@intrinsic
def vsplat(typingctx: Any, scalar: Any) -> Any:
    """``scalar`` (a uint16) in every lane."""
    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        undef = ir.Constant(VT, ir.Undefined)
        one = builder.insert_element(undef, args[0], ir.Constant(ir.IntType(32), 0))
        zeros = ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES)
        return builder.shuffle_vector(one, undef, zeros)
    return vec(scalar), codegen


def _binary(emit: Any) -> Any:
    @intrinsic
    def operation(typingctx: Any, a: Any, b: Any) -> Any:
        def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
            return emit(builder, args[0], args[1])
        return vec(a, b), codegen
    return operation


def _shuffle(indices: list[int]) -> Any:
    """Lanes ``indices`` of the 32 lanes of (a, b)."""
    mask = ir.Constant(ir.VectorType(ir.IntType(32), LANES), indices)
    return _binary(lambda builder, a, b: builder.shuffle_vector(a, b, mask))


vadd = _binary(lambda builder, a, b: builder.add(a, b))
vsub = _binary(lambda builder, a, b: builder.sub(a, b))
vmin = _binary(lambda builder, a, b: builder.select(builder.icmp_unsigned('<', a, b), a, b))
#: the lanes of x - 1 from the tile before (a) and this one (b)
from_left = _shuffle([LANES - 1, *range(LANES, 2 * LANES - 1)])
#: the lanes of x + 1 from this tile (a) and the one after (b)
from_right = _shuffle([*range(1, LANES), LANES])


def _swap(h: int) -> tuple[Any, Any]:
    """Exchange the off-diagonal h x h blocks of the 2h x 2h blocks of rows (a, a + h)."""
    low = [k if k & h == 0 else LANES + k - h for k in range(LANES)]
    high = [k + h if k & h == 0 else LANES + k for k in range(LANES)]
    return _shuffle(low), _shuffle(high)


(lo8, hi8), (lo4, hi4), (lo2, hi2), (lo1, hi1) = (_swap(h) for h in (8, 4, 2, 1))


@njit(nogil=True, inline='always')
def transpose(r0: Any, r1: Any, r2: Any, r3: Any, r4: Any, r5: Any, r6: Any, r7: Any,
              r8: Any, r9: Any, r10: Any, r11: Any, r12: Any, r13: Any, r14: Any,
              r15: Any) -> Any:
    """The 16 x 16 transpose of 16 vectors (rows), in four rounds of block swaps."""
    a0, a8 = lo8(r0, r8), hi8(r0, r8)
    a1, a9 = lo8(r1, r9), hi8(r1, r9)
    a2, a10 = lo8(r2, r10), hi8(r2, r10)
    a3, a11 = lo8(r3, r11), hi8(r3, r11)
    a4, a12 = lo8(r4, r12), hi8(r4, r12)
    a5, a13 = lo8(r5, r13), hi8(r5, r13)
    a6, a14 = lo8(r6, r14), hi8(r6, r14)
    a7, a15 = lo8(r7, r15), hi8(r7, r15)
    b0, b4 = lo4(a0, a4), hi4(a0, a4)
    b1, b5 = lo4(a1, a5), hi4(a1, a5)
    b2, b6 = lo4(a2, a6), hi4(a2, a6)
    b3, b7 = lo4(a3, a7), hi4(a3, a7)
    b8, b12 = lo4(a8, a12), hi4(a8, a12)
    b9, b13 = lo4(a9, a13), hi4(a9, a13)
    b10, b14 = lo4(a10, a14), hi4(a10, a14)
    b11, b15 = lo4(a11, a15), hi4(a11, a15)
    c0, c2 = lo2(b0, b2), hi2(b0, b2)
    c1, c3 = lo2(b1, b3), hi2(b1, b3)
    c4, c6 = lo2(b4, b6), hi2(b4, b6)
    c5, c7 = lo2(b5, b7), hi2(b5, b7)
    c8, c10 = lo2(b8, b10), hi2(b8, b10)
    c9, c11 = lo2(b9, b11), hi2(b9, b11)
    c12, c14 = lo2(b12, b14), hi2(b12, b14)
    c13, c15 = lo2(b13, b15), hi2(b13, b15)
    return (lo1(c0, c1), hi1(c0, c1), lo1(c2, c3), hi1(c2, c3), lo1(c4, c5), hi1(c4, c5),
            lo1(c6, c7), hi1(c6, c7), lo1(c8, c9), hi1(c8, c9), lo1(c10, c11),
            hi1(c10, c11), lo1(c12, c13), hi1(c12, c13), lo1(c14, c15), hi1(c14, c15))


@njit(nogil=True, inline='always')
def cost_block(cost: Any, at: int, stride: int, out: Any) -> None:
    """16 rows of 16 uint8 costs at cost[at + p * stride] (pixel p), transposed into out
    (disparity-major, 16 x 16 uint16)."""
    t = transpose(vload8(cost, at + 0 * stride),
                  vload8(cost, at + 1 * stride),
                  vload8(cost, at + 2 * stride),
                  vload8(cost, at + 3 * stride),
                  vload8(cost, at + 4 * stride),
                  vload8(cost, at + 5 * stride),
                  vload8(cost, at + 6 * stride),
                  vload8(cost, at + 7 * stride),
                  vload8(cost, at + 8 * stride),
                  vload8(cost, at + 9 * stride),
                  vload8(cost, at + 10 * stride),
                  vload8(cost, at + 11 * stride),
                  vload8(cost, at + 12 * stride),
                  vload8(cost, at + 13 * stride),
                  vload8(cost, at + 14 * stride),
                  vload8(cost, at + 15 * stride))
    vstore(out, 0, t[0])
    vstore(out, 16, t[1])
    vstore(out, 32, t[2])
    vstore(out, 48, t[3])
    vstore(out, 64, t[4])
    vstore(out, 80, t[5])
    vstore(out, 96, t[6])
    vstore(out, 112, t[7])
    vstore(out, 128, t[8])
    vstore(out, 144, t[9])
    vstore(out, 160, t[10])
    vstore(out, 176, t[11])
    vstore(out, 192, t[12])
    vstore(out, 208, t[13])
    vstore(out, 224, t[14])
    vstore(out, 240, t[15])


@njit(nogil=True, inline='always')
def sum_block(sums: Any, at: int, out: Any, to: int, stride: int) -> None:
    """The 16 x 16 block sums[at:at + 256] (disparity-major) transposed into out (pixel p
    at out[to + p * stride])."""
    t = transpose(vload(sums, at + 0),
                  vload(sums, at + 16),
                  vload(sums, at + 32),
                  vload(sums, at + 48),
                  vload(sums, at + 64),
                  vload(sums, at + 80),
                  vload(sums, at + 96),
                  vload(sums, at + 112),
                  vload(sums, at + 128),
                  vload(sums, at + 144),
                  vload(sums, at + 160),
                  vload(sums, at + 176),
                  vload(sums, at + 192),
                  vload(sums, at + 208),
                  vload(sums, at + 224),
                  vload(sums, at + 240))
    vstore(out, 0 * stride + to, t[0])
    vstore(out, 1 * stride + to, t[1])
    vstore(out, 2 * stride + to, t[2])
    vstore(out, 3 * stride + to, t[3])
    vstore(out, 4 * stride + to, t[4])
    vstore(out, 5 * stride + to, t[5])
    vstore(out, 6 * stride + to, t[6])
    vstore(out, 7 * stride + to, t[7])
    vstore(out, 8 * stride + to, t[8])
    vstore(out, 9 * stride + to, t[9])
    vstore(out, 10 * stride + to, t[10])
    vstore(out, 11 * stride + to, t[11])
    vstore(out, 12 * stride + to, t[12])
    vstore(out, 13 * stride + to, t[13])
    vstore(out, 14 * stride + to, t[14])
    vstore(out, 15 * stride + to, t[15])


@njit(nogil=True)
def sweep_lanes(cost: Any, tiled: bool, write: bool, image: Any, p1: int, p2: int,
                table: Any, paths: Any, minima: Any, p2_row: Any, cost_scratch: Any,
                tile_sums: Any, tile_out: Any, out: Any) -> None:
    """The downward directions (0, 1), (1, 1), (-1, 1) from row 0, summed into ``out``.

    cost: (H, W * D) uint8; tiled: pixel-lane layout (tile t of 16 pixels at t * D * 16,
    disparity d of it at + d * 16) for ``cost`` and ``out``, else the matcher's (pixel x
    at x * D). paths: (2, 3, (T + 2) * (D + 1) * 16) uint16, the L rows of image rows of
    either parity, per direction, tile t at (t + 1) * (D + 1) * 16 (tiles 0 and T + 1 stay
    zero: a path starts there), with SENTINEL at d = D. minima: (2, 3, (T + 2) * 16) min
    over d of those. The rest is scratch. W must be a multiple of 16.
    """
    h, w = image.shape
    n = cost.shape[1] // w
    tiles = w // 16
    stride = (n + 1) * 16
    q1 = vsplat(np.uint16(p1))
    big = vsplat(np.uint16(SENTINEL))
    for y in range(h):
        cur, prv = y % 2, (y + 1) % 2
        if y == 0:  # no row above: every path starts here (L = C)
            paths[prv, :, :] = 0
            minima[prv, :, :] = 0
            for j in range(3):
                for t in range(1, tiles + 1):
                    paths[prv, j, t * stride + n * 16:(t + 1) * stride] = SENTINEL
        for j in range(3):
            dx = 0 if j == 0 else (1 if j == 1 else -1)
            for x in range(w):
                xp = x - dx
                if y == 0 or table.shape[0] == 0 or xp < 0 or xp >= w:
                    p2_row[j, 16 + x] = p2
                else:
                    step = min(int(abs(image[y, x] - image[y - 1, xp])), table.shape[0] - 1)
                    p2_row[j, 16 + x] = table[step]
        a0, a1, a2 = paths[prv, 0], paths[prv, 1], paths[prv, 2]
        c0, c1, c2 = paths[cur, 0], paths[cur, 1], paths[cur, 2]
        crow, orow = cost[y], out[y]
        for t in range(tiles):
            here = (t + 1) * stride
            lanes = (t + 1) * 16
            m0 = vload(minima[prv, 0], lanes)
            m1 = from_left(vload(minima[prv, 1], lanes - 16), vload(minima[prv, 1], lanes))
            m2 = from_right(vload(minima[prv, 2], lanes), vload(minima[prv, 2], lanes + 16))
            j0 = vadd(m0, vload(p2_row[0], lanes))
            j1 = vadd(m1, vload(p2_row[1], lanes))
            j2 = vadd(m2, vload(p2_row[2], lanes))
            below0, below1, below2 = big, big, big  # L(d - 1) of the row above
            at0 = vload(a0, here)  # L(d)
            at1 = from_left(vload(a1, here - stride), vload(a1, here))
            at2 = from_right(vload(a2, here), vload(a2, here + stride))
            best0, best1, best2 = big, big, big
            for d in range(n):
                if not tiled and d % 16 == 0:
                    cost_block(crow, t * 16 * n + d, n, cost_scratch)
                nxt = here + (d + 1) * 16
                above0 = vload(a0, nxt)  # L(d + 1)
                above1 = from_left(vload(a1, nxt - stride), vload(a1, nxt))
                above2 = from_right(vload(a2, nxt), vload(a2, nxt + stride))
                c = (vload8(crow, (t * n + d) * 16) if tiled
                     else vload(cost_scratch, (d % 16) * 16))
                v0 = vsub(vadd(c, vmin(vmin(at0, vadd(vmin(below0, above0), q1)), j0)), m0)
                v1 = vsub(vadd(c, vmin(vmin(at1, vadd(vmin(below1, above1), q1)), j1)), m1)
                v2 = vsub(vadd(c, vmin(vmin(at2, vadd(vmin(below2, above2), q1)), j2)), m2)
                slot = here + d * 16
                vstore(c0, slot, v0)
                vstore(c1, slot, v1)
                vstore(c2, slot, v2)
                best0, best1, best2 = vmin(best0, v0), vmin(best1, v1), vmin(best2, v2)
                total = vadd(v0, vadd(v1, v2))
                if tiled:
                    vstore(orow, (t * n + d) * 16, total)
                else:
                    vstore(tile_sums, d * 16, total)
                below0, below1, below2 = at0, at1, at2
                at0, at1, at2 = above0, above1, above2
            vstore(minima[cur, 0], lanes, best0)
            vstore(minima[cur, 1], lanes, best1)
            vstore(minima[cur, 2], lanes, best2)
            if not tiled:
                for d in range(0, n, 16):
                    sum_block(tile_sums, d * 16, tile_out, d, n)
                if write:
                    orow[t * 16 * n:(t + 1) * 16 * n] = tile_out


@njit(parallel=True, nogil=True)
def run_lanes(cost: Any, tiled: bool, write: bool, image: Any, p1: int, p2: int,
              table: Any, paths: Any, minima: Any, p2_row: Any, cost_scratch: Any,
              tile_sums: Any, tile_out: Any, out: Any) -> None:
    """:func:`sweep_lanes` compiled like the shipped kernels (``aggregate``:
    ONE_THREAD_GUFUNC)."""
    for _ in prange(1):
        sweep_lanes(cost, tiled, write, image, p1, p2, table, paths, minima, p2_row,
                    cost_scratch, tile_sums, tile_out, out)


def lane_buffers(w: int, n: int) -> tuple[Any, ...]:
    """paths, minima, p2_row, cost_scratch, tile_sums, tile_out for :func:`sweep_lanes`."""
    tiles = w // 16
    paths = np.zeros((2, 3, tiles + 2, n + 1, 16), np.uint16)
    paths[:, :, 1:tiles + 1, n, :] = SENTINEL
    return (paths.reshape(2, 3, -1), np.zeros((2, 3, (tiles + 2) * 16), np.uint16),
            np.zeros((3, (tiles + 2) * 16), np.uint16), np.zeros(256, np.uint16),
            np.zeros(16 * n, np.uint16), np.zeros(16 * n, np.uint16))


def to_lanes(volume: Any) -> Any:
    """(H, W, D) -> the pixel-lane layout (H, W / 16, D, 16)."""
    h, w, n = volume.shape
    return np.ascontiguousarray(volume.reshape(h, w // 16, 16, n).transpose(0, 1, 3, 2))


def from_lanes(volume: Any) -> Any:
    """The pixel-lane layout back to (H, W, D)."""
    h, tiles, n, _ = volume.shape
    return volume.transpose(0, 1, 3, 2).reshape(h, tiles * 16, n)


def median_ms(run: Any, repeats: int = 9) -> float:
    run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def main() -> None:
    import numba
    numba.set_num_threads(1)
    left, right = _bundled_pair()
    p = SgmParams(paths=5, census_width=5, census_height=5, intensity_weight=1,
                  match_brightness=True, p2_adaptive_scale=8.0)
    h, w = left.shape
    n = p.disparity_range
    if w % 16 or n % 16:
        raise SystemExit(f'pixel_lanes: the width and the disparity range must be multiples'
                         f' of 16, got {w} and {n}')
    inputs = _cost_inputs(left, right, p, (np.empty((h, w), np.uint32),
                                           np.empty((h, w), np.uint32)))
    cost = inputs.rows(0, np.empty((h, w, n), np.uint8))
    image = np.ascontiguousarray(left, np.float32)
    table = p2_table(int(p.P1), int(p.P2), p.p2_adaptive_scale)
    dxs, dys = np.array([0, 1, -1]), np.array([1, 1, 1])
    rings, mbuf = new_line_buffers(3, w, n)
    shipped = np.empty((h, w, n), np.uint16)

    def run_shipped() -> None:
        sweep_down(cost, image, 0, h, dxs, dys, int(p.P1), int(p.P2), table, *rings, mbuf,
                   shipped)

    lanes_cost = to_lanes(cost).reshape(h, -1)
    lanes_out = np.empty((h, w * n), np.uint16)
    major_out = np.empty((h, w * n), np.uint16)
    buffers = lane_buffers(w, n)

    def variant(tiled: bool, write: bool, out: Any) -> Any:
        source = lanes_cost if tiled else cost.reshape(h, -1)
        return lambda: run_lanes(source, tiled, write, image, int(p.P1), int(p.P2), table,
                                 *buffers, out)

    times = {
        '1. shipped sweep_down (disparities in the lanes)': median_ms(run_shipped),
        '2. pixel lanes, pixel-lane layout in and out': median_ms(
            variant(True, True, lanes_out)),
        "3. pixel lanes, the matcher's layout in and out": median_ms(
            variant(False, True, major_out)),
        '4. as 3, the sums not written': median_ms(variant(False, False, major_out)),
    }
    print(f'downward sweep, 3 directions, {w}x{h}, {n} disparities, one thread '
          '(median of 9):')
    for name, ms in times.items():
        print(f'  {name:52s} {ms:6.1f} ms')
    same = (np.array_equal(from_lanes(lanes_out.reshape(h, w // 16, n, 16)), shipped)
            and np.array_equal(major_out.reshape(h, w, n), shipped))
    print('sums of 2 and 3 equal to 1, bit for bit:', same)
    if not same:
        raise SystemExit(1)


if __name__ == '__main__':
    main()
