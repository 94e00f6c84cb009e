"""The README's Python example runs as printed and its numbers hold against ground truth;
every file the README and docs/ link to exists."""

from __future__ import annotations

import re
import subprocess
import sys

from helpers import REPO


def test_the_python_example_runs_and_is_accurate() -> None:
    text = (REPO / 'README.md').read_text()
    (code,) = re.findall(r'```python\n(.*?)```', text, flags=re.S)
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=REPO, check=False, timeout=300)
    assert result.returncode == 0, result.stderr
    density, bad2 = map(float, re.fullmatch(r'density ([\d.]+), sparse bad-2 ([\d.]+)\n',
                                             result.stdout).groups())
    # Teddy with the default matcher: most pixels estimated, few of them more than 2 px off
    assert density > 0.85
    assert bad2 < 0.05


def test_links_point_at_files_that_exist() -> None:
    for page in [REPO / 'README.md', *(REPO / 'docs').glob('*.md')]:
        for target in re.findall(r'\]\(([^)#:]+)(?:#[^)]*)?\)', page.read_text()):
            assert (page.parent / target).exists(), (page.name, target)
