"""No function in ``renderer/`` takes more than ``MAX_PARAMETERS`` parameters: state that
travels together goes in a record (``traverse.TraversalRay``, ``traverse.Stack``,
``render.RenderOptions``, ``bvh_build.BuildOptions``, ...), not in an argument list.

Checked on the source with ``ast``: every ``def`` and ``lambda``, counting positional,
keyword-only, ``*args`` and ``**kwargs`` parameters, but not a method's ``self``/``cls``.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_PARAMETERS = 8


def parameter_counts(path: Path) -> list[tuple[str, int, int]]:
    """``(name, line, parameters)`` of every function and lambda in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        a = node.args
        names = [p.arg for p in a.posonlyargs + a.args]
        count = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
        if names and names[0] in ("self", "cls"):
            count -= 1
        out.append((getattr(node, "name", "<lambda>"), node.lineno, count))
    return out


def test_parameter_counter_counts_every_kind():
    """The counter itself: positional, keyword-only, ``*args``, ``**kwargs``; not ``self``."""
    src = ROOT / "tests" / "_signature_sample.py"
    src.write_text("def f(a, b, /, c, *d, e, f=1, **g): pass\n"
                   "class K:\n    def m(self, a, b): pass\n"
                   "h = lambda x, y: x\n")
    try:
        got = {name: n for name, _, n in parameter_counts(src)}
    finally:
        src.unlink()
    assert got == {"f": 7, "m": 2, "<lambda>": 2}


def test_no_renderer_function_takes_more_than_eight_parameters():
    over = [f"{p.relative_to(ROOT)}:{line} {name} ({n})"
            for p in sorted((ROOT / "renderer").rglob("*.py"))
            for name, line, n in parameter_counts(p) if n > MAX_PARAMETERS]
    assert not over, f"more than {MAX_PARAMETERS} parameters (use a record): {over}"
