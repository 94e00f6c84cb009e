"""Where the kernels' plain references live: they are test code, under ``test/reference/``,
one module per area of the package (README, "Developing the kernels"). The package defines
none of them, and every one of them serves a test."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from helpers import REPO, TEST_DIR

#: A reference's name: anything ending in ``_reference`` (``MvsStream._reference``, the
#: stream's reference view, is no plain reference).
REFERENCE = re.compile(r'\w_reference$')

REFERENCE_DIR = TEST_DIR / 'reference'


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _defined(tree: ast.Module) -> list[str]:
    """Every function and method the module defines, nested ones included."""
    return [node.name for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)]


def _names(node: ast.AST) -> set[str]:
    """Every name a piece of code reads, plain or as an attribute."""
    return {n.id if isinstance(n, ast.Name) else n.attr for n in ast.walk(node)
            if isinstance(n, ast.Name | ast.Attribute)}


def test_the_package_defines_no_reference() -> None:
    """Where kernels live (core, ros, sim); the tools' ``_write_reference`` writes the
    speckle reference image, no plain reference."""
    found = {(path.relative_to(REPO).as_posix(), name)
             for layer in ('core', 'ros', 'sim')
             for path in sorted((REPO / 'depth_nodes' / layer).rglob('*.py'))
             for name in _defined(_tree(path)) if REFERENCE.search(name)}
    assert not found, sorted(found)


def test_the_package_imports_no_test_reference() -> None:
    for path in sorted((REPO / 'depth_nodes').rglob('*.py')):
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ImportFrom) and node.level == 0:
                assert node.module is None or node.module.split('.')[0] != 'reference', path
            elif isinstance(node, ast.Import):
                assert all(a.name.split('.')[0] != 'reference' for a in node.names), path


def test_each_reference_module_mirrors_an_area_of_the_package() -> None:
    modules = sorted(p for p in REFERENCE_DIR.glob('*.py') if p.name != '__init__.py')
    assert len(modules) >= 8
    for path in modules:
        areas = [REPO / 'depth_nodes' / layer / path.stem
                 for layer in ('core', 'ros', 'tools/evaluation')]
        assert any(a.is_dir() or a.with_suffix('.py').is_file() for a in areas), path.name


def test_every_reference_serves_a_test() -> None:
    # top-level references of test/reference/ and the names each one's body reads
    bodies = {node.name: _names(node)
              for path in sorted(REFERENCE_DIR.glob('*.py'))
              for node in _tree(path).body
              if isinstance(node, ast.FunctionDef) and REFERENCE.search(node.name)}
    assert len(bodies) >= 25
    read = set().union(*(_names(_tree(path)) for path in sorted(TEST_DIR.rglob('test_*.py'))))
    # a reference a test calls serves it, and so does every reference that one calls
    used = set(bodies) & read
    while grown := set(bodies) & set().union(*(bodies[name] for name in used)) - used:
        used |= grown
    assert used == set(bodies), sorted(set(bodies) - used)
