"""The README's Python example runs as printed and its numbers hold against ground truth;
every file the README and docs/ (experiments/ included) link to exists, and every section
of a page they link to."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

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


def pages() -> list[Path]:
    """The README and every page under docs/."""
    return [REPO / 'README.md', *sorted((REPO / 'docs').rglob('*.md'))]


def anchors(page: Path) -> set[str]:
    """The anchors of a page's headings, as GitHub makes them: lower case, spaces to
    hyphens, every character but letters, digits, ``-`` and ``_`` removed."""
    headings = re.findall(r'^#+ (.+)$', re.sub(r'```.*?```', '', page.read_text(), flags=re.S),
                          flags=re.M)
    return {re.sub(r'[^\w\- ]', '', h.strip().lower()).replace(' ', '-') for h in headings}


def test_links_point_at_files_that_exist() -> None:
    for page in pages():
        for target in re.findall(r'\]\(([^)#:]+)(?:#[^)]*)?\)', page.read_text()):
            assert (page.parent / target).exists(), (page.name, target)


def test_links_point_at_sections_that_exist() -> None:
    for page in pages():
        for target, anchor in re.findall(r'\]\(([^)#:]*)#([^)]+)\)', page.read_text()):
            linked = (page.parent / target) if target else page
            assert anchor in anchors(linked), (page.name, f'{target}#{anchor}')
