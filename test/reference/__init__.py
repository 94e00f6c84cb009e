"""The plain references of the package's numba kernels: numpy or Python written to
compute what each kernel computes, so that the tests (marker ``kernels``) can hold the two
equal, compiled and again with ``NUMBA_DISABLE_JIT=1``.

They are test code: one module per area of the package, mirroring ``depth_nodes/core``
(``sgm.py`` for ``core/sgm/``, ``tof.py`` for ``core/tof/``, ``geometry.py`` for
``core/geometry/``, ...) or ``depth_nodes/ros`` (``pointcloud.py``); nothing under
``depth_nodes/`` imports them, and the package defines no reference of its own
(``test/packaging/test_reference_rule.py``). A reference may use its
module's helpers (an argument check, a table, a scalar formula run as plain Python), not
the kernel it is the reference of.
"""
