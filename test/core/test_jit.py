"""core/jit.py: the intrinsics compute what their plain-Python paths compute, and the
kernels are compiled unless ``NUMBA_DISABLE_JIT`` says otherwise. Marked ``kernels``, so
that test/packaging/test_kernels_without_jit.py runs them again with the JIT off."""

from __future__ import annotations

import os

import numba
import numpy as np
import pytest

from depth_nodes.core.jit import JIT_ENABLED, python_function
from depth_nodes.core.sgm.census import census_transform, popcount
from depth_nodes.core.sgm.select import cost_key, subpixel_offset

pytestmark = pytest.mark.kernels


@numba.njit
def _popcounts(values: np.ndarray, out: np.ndarray) -> None:
    for i in range(values.shape[0]):
        out[i] = popcount(values[i])


@numba.njit
def _keys(costs: np.ndarray, ks: np.ndarray, out: np.ndarray) -> None:
    for i in range(costs.shape[0]):
        out[i] = cost_key(costs[i], ks[i])


@pytest.mark.parametrize('dtype', [np.uint16, np.uint32, np.uint64])
def test_popcount_counts_the_set_bits(dtype: type) -> None:
    rng = np.random.default_rng(0)
    top = np.iinfo(dtype).max
    values = np.concatenate([rng.integers(0, top, 200, dtype=dtype, endpoint=True),
                             np.array([0, 1, top], dtype)])
    out = np.empty_like(values)
    _popcounts(values, out)
    np.testing.assert_array_equal(out, [int(v).bit_count() for v in values])
    assert out.dtype == dtype
    assert out[-1] == np.iinfo(dtype).bits


@pytest.mark.parametrize('dtype', [np.uint8, np.uint16])
def test_cost_key_puts_the_cost_above_the_index(dtype: type) -> None:
    rng = np.random.default_rng(1)
    costs = rng.integers(0, np.iinfo(dtype).max, 300, dtype=dtype, endpoint=True)
    ks = rng.integers(0, 65536, 300).astype(np.int64)
    out = np.empty(300, np.uint32)
    _keys(costs, ks, out)
    np.testing.assert_array_equal(out, (costs.astype(np.uint64) << 16) | ks.astype(np.uint64))


def test_kernels_are_compiled_unless_the_jit_is_off() -> None:
    """``NUMBA_DISABLE_JIT=1`` leaves every kernel a plain function (the run of the
    kernels' tests without the JIT relies on it); otherwise each is compiled."""
    off = os.environ.get('NUMBA_DISABLE_JIT', '0') not in ('', '0')
    assert JIT_ENABLED is not off
    assert isinstance(subpixel_offset, numba.core.registry.CPUDispatcher) is JIT_ENABLED
    plain = python_function(subpixel_offset)
    assert not isinstance(plain, numba.core.registry.CPUDispatcher)
    # a parabola through costs 3, 1, 2: its minimum 1/6 px right, rounded to 1/32 px
    assert plain(1, 3.0, 1.0, 2.0) == subpixel_offset(1, 3.0, 1.0, 2.0) == 5 / 32
    census = census_transform(np.arange(25, dtype=np.uint8).reshape(5, 5), (3, 3))
    assert census[2, 2] == 0b11110000  # the four neighbours before the centre are darker
