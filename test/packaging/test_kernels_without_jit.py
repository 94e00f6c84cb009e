"""The numba kernels run as plain Python too (stumpy's habit): the core tests marked
``kernels`` (each a kernel against its plain reference) run again with
``NUMBA_DISABLE_JIT=1``, so that both the compiled and the interpreted code are tested.
With the JIT off those tests take small inputs (``helpers.kernel_size``): the run takes
about half a minute on two cores."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from helpers import REPO

pytestmark = pytest.mark.slow


def test_the_kernel_tests_pass_with_the_jit_off() -> None:
    env = {**os.environ, 'NUMBA_DISABLE_JIT': '1'}
    # numpy scalars warn where the compiled kernels overflow to inf or wrap around on
    # purpose: the results are compared, the warnings would only bury the summary
    result = subprocess.run(
        [sys.executable, '-m', 'pytest', '-m', 'kernels', 'test/core', '-q',
         '-p', 'no:cacheprovider', '-W', 'ignore::RuntimeWarning'],
        cwd=REPO, env=env, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    passed = re.search(r'(\d+) passed', result.stdout)
    assert passed is not None, result.stdout[-2000:]
    assert int(passed.group(1)) > 100
    assert ' failed' not in result.stdout
    assert ' skipped' not in result.stdout
