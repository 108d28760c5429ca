"""The four top-level packages are layers; their imports may only point down the stack.

``renderer`` (the Dr.Jit tracer) imports none of the others and never Mitsuba;
``reference`` (the Mitsuba side) may import ``renderer`` (scenes) but not ``evaluation`` or
``whitted``; ``evaluation`` not ``whitted``. None of them imports ``lab`` (the experiments at the
repository root, never installed). Checked on the source with ``ast``, so a lazy import inside a
function counts too.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {
    "renderer": {"mitsuba", "reference", "evaluation", "whitted", "lab"},
    "reference": {"evaluation", "whitted", "lab"},
    "evaluation": {"whitted", "lab"},
    "whitted": {"lab"},
}


def imported_roots(path: Path) -> set[str]:
    """Top-level names of every absolute import in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_down_the_stack(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"{package}: no sources found"
    bad = {str(f.relative_to(ROOT)): sorted(imported_roots(f) & FORBIDDEN[package])
           for f in files}
    bad = {k: v for k, v in bad.items() if v}
    assert not bad, f"{package} imports a layer above it: {bad}"


def test_the_check_sees_an_upward_import(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    import mitsuba as mi\n    from whitted.cli import main\n")
    assert imported_roots(f) >= {"mitsuba", "whitted"}
