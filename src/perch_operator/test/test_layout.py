"""The operator package's layout: no import circle, and the command line sits on top."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import perch_operator

ROOT = Path(perch_operator.__file__).parent


def _imports() -> dict[str, set[str]]:
    """Module -> perch_operator modules it imports (at module level or inside functions)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for path in ROOT.rglob("*.py"):
        module = ".".join(path.relative_to(ROOT.parent).with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("perch_operator."):
                edges[module].add(node.module)
    return edges


def _cycle(edges: dict[str, set[str]]) -> list[str]:
    done: set[str] = set()
    path: list[str] = []

    def visit(module: str) -> list[str]:
        if module in path:
            return path[path.index(module):] + [module]
        if module in done:
            return []
        path.append(module)
        for other in sorted(edges.get(module, ())):
            found = visit(other)
            if found:
                return found
        path.pop()
        done.add(module)
        return []

    for module in sorted(edges):
        found = visit(module)
        if found:
            return found
    return []


def test_no_module_imports_one_that_imports_it_back():
    assert _cycle(_imports()) == []


def test_the_cycle_finder_finds_a_circle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_only_the_command_line_and_benchmarks_use_the_command_line():
    lower = ("perch_operator.coordinator", "perch_operator.outputs", "perch_operator.api")
    wrong = sorted((module, imported) for module, imports in _imports().items() for imported in imports
                   if module.startswith(lower) and imported.startswith(("perch_operator.cli", "perch_operator.bench")))
    assert wrong == []


def test_every_module_sits_in_a_role_folder():
    flat = sorted(p.name for p in ROOT.glob("*.py") if p.name != "__init__.py")
    assert flat == []
    assert {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()} == {
        "coordinator", "cli", "api", "outputs", "bench"}
