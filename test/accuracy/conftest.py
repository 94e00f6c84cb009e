"""Every data set through the shipped graph as it is (5 paths) and with 8 paths: the
targets hold for both (the session fixtures of test/conftest.py run each once)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

Reports = dict[str, tuple[Path, Any]]


@pytest.fixture(params=['real_reports', 'real_reports_8_paths'])
def real(request: pytest.FixtureRequest) -> Reports:
    """Teddy and Cones, ``{pair: (output bag, EvalReport)}``."""
    return request.getfixturevalue(request.param)  # type: ignore[no-any-return]


@pytest.fixture(params=['stereo_reports', 'stereo_reports_8_paths'])
def simulated(request: pytest.FixtureRequest) -> Reports:
    """The bundled simulator bags, ``{bag: (output bag, EvalReport)}``."""
    return request.getfixturevalue(request.param)  # type: ignore[no-any-return]
