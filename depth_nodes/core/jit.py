"""How the package compiles its numba kernels, and their meaning with the JIT off.

With ``NUMBA_DISABLE_JIT=1`` numba's decorators return the plain Python functions, so
every kernel runs interpreted: the tests run the kernels against their plain references
that way too (``pytest -m kernels``; ``test/packaging/test_kernels_without_jit.py``), so
that both the compiled and the interpreted code are tested, as stumpy does. Two pieces
have no Python meaning of their own and are handled here:

* an ``@intrinsic`` (code emitted as LLVM IR: a popcount, a 32-bit key) raises
  ``NotImplementedError`` when called from Python: :func:`intrinsic` takes the plain
  function it stands for and returns that one with the JIT off;
* a compiled kernel's ``py_func`` (the references call a few scalar kernels through it)
  does not exist on a plain function: :func:`python_function`.

Everything else has one already: ``prange`` is ``range``, and ``parallel=True`` or
:func:`no_nrt_kernel`'s options leave the plain function as any ``njit`` does.

NO_NRT: the selection and cost-row kernels, which take a view of an array for every pixel
(``cost[y, x]``, ``total[x]``), are compiled with numba's ``_nrt=False``: no reference
counting (:func:`no_nrt_kernel`). With it, numba increments and decrements the parent
array's count (an atomic operation) around every view it cannot prove short-lived;
measured with ``perf`` on one thread (640x480, 128 disparities, 8 paths), those two calls
took 19 % of a frame. Such a kernel cannot allocate: its scratch comes from its caller.
``_nrt`` is an internal option of numba (pinned in ``requirements/constraints.txt``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
from numba.extending import intrinsic as numba_intrinsic

F = TypeVar('F', bound=Callable[..., Any])

#: True when numba compiles (the usual case); False under ``NUMBA_DISABLE_JIT=1``.
JIT_ENABLED = not numba.config.DISABLE_JIT  # type: ignore[attr-defined]


def no_nrt_kernel(*, parallel: bool = False) -> Callable[[F], F]:
    """``njit(cache=True, nogil=True)`` without reference counting (see NO_NRT)."""
    options: Any = {'cache': True, 'nogil': True, 'parallel': parallel, '_nrt': False}
    return cast(Callable[[F], F], numba.njit(**options))


def intrinsic(plain: Callable[..., Any]) -> Callable[[Callable[..., Any]], Any]:
    """Decorator of an intrinsic's typing function: ``numba.extending.intrinsic`` of it, or
    ``plain``, the Python function computing the same value, when the JIT is off.

    Typical use::

        def _popcount_plain(value): ...

        @intrinsic(_popcount_plain)
        def popcount(typingctx, value): ...
    """
    def wrap(typer: Callable[..., Any]) -> Any:
        return numba_intrinsic(typer) if JIT_ENABLED else plain
    return wrap


def python_function(kernel: Callable[..., Any]) -> Callable[..., Any]:
    """The Python function of a compiled kernel (the kernel itself with the JIT off)."""
    function: Callable[..., Any] = getattr(kernel, 'py_func', kernel)
    return function
