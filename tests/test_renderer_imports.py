"""The renderer's modules import each other at the top only, and every such import points
down: the module graph has no cycle.

A function-local import of a sibling renderer module is how an import loop hides (the
accelerator interface importing the traversal that imports it); it fails here, whatever
its reason. Imports of optional third-party packages inside a function (OpenEXR,
imageio) stay allowed. Checked on the source with ``ast``, then each module is imported.
"""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted((ROOT / "renderer").rglob("*.py"))


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def renderer_imports(path: Path) -> list[tuple[str, bool, int]]:
    """``(module, at_top, line)`` of every import in ``path`` of a ``renderer`` module
    (relative imports resolved; ``from . import x`` gives the module ``x`` where it is
    one); ``at_top``: at module level (not inside a function or class)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    top = {id(n) for n in tree.body}
    known = {module_name(p) for p in MODULES}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod
                       for a in node.names]
        else:
            continue
        for t in targets:
            if t == "renderer" or t.startswith("renderer."):
                out.append((t, id(node) in top, node.lineno))
    return out


def cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` (a list of modules, the first repeated last), or None."""
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m):
        state[m] = 1
        path.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return path[path.index(n):] + [n]
            if n not in state and (found := visit(n)):
                return found
        state[m] = 2
        path.pop()
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_cycle_finder_finds_a_loop_and_passes_a_chain():
    assert cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_function_local_import_of_a_renderer_module():
    local = [f"{p.relative_to(ROOT)}:{line} imports {mod}"
             for p in MODULES for mod, at_top, line in renderer_imports(p) if not at_top]
    assert not local, f"function-local imports of renderer modules (an import loop?): {local}"


def test_renderer_imports_point_down():
    graph = {module_name(p): {m for m, at_top, _ in renderer_imports(p) if at_top}
             for p in MODULES}
    loop = cycle(graph)
    assert loop is None, f"import loop: {' -> '.join(loop)}"


@pytest.mark.parametrize("module", [module_name(p) for p in MODULES])
def test_each_renderer_module_imports(module):
    importlib.import_module(module)
