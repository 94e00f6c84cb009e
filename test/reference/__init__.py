"""The plain references of the package's numba kernels: numpy or Python written to
compute what each kernel computes, so that the tests (marker ``kernels``) can hold the two
equal, compiled and again with ``NUMBA_DISABLE_JIT=1``.

They are test code: one module per core area, mirroring ``depth_nodes/core`` (``sgm.py``
for ``core/sgm/``, ``tof.py`` for ``core/tof/``, ...); nothing under ``depth_nodes/``
imports them, and the package defines no reference of its own but the few
``test/packaging/test_reference_rule.py`` lists with the reason. A reference may use its
module's helpers (an argument check, a table, a scalar formula run as plain Python), not
the kernel it is the reference of.
"""
