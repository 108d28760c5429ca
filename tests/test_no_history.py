"""The product's sources say what the code does now: no hardware names, dates, speedup
figures, ``results/`` paths, issue numbers or before/after comparisons in ``renderer/``,
``reference/``, ``evaluation/`` or ``whitted/`` (code, docstrings and comments alike).
Measurements and their history live in ``lab/notes/``; a docstring may point to one note
there. The check reads the source lines, so it needs no import of the packages."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("renderer", "reference", "evaluation", "whitted")
#: What history looks like in a source line, by kind.
PATTERNS = {
    "hardware name": r"\b(?:H[12]00|A100|V100|L40S?|RTX ?\d{3,4}|GTX ?\d{3,4}|EPYC|Xeon|Ryzen"
                     r"|Threadripper)\b",
    "date": r"\b20\d\d-\d\d-\d\d\b",
    "results/ path": r"\bresults/",
    "speedup figure": r"\b\d+\.\d+ ?[x×](?![\w.])|\b\d+(?:\.\d+)?[-–]\d+(?:\.\d+)? ?[x×](?![\w.])",
    # this project's issues; an upstream bug (``drjit issue #532``) is a fact of the code
    "issue number": r"(?<!drjit )(?<!mitsuba )\bissue[- ]#?\d+",
    "before/after": r"\bbefore/after\b",
}
HISTORY = re.compile("|".join(f"(?P<k{i}>{p})" for i, p in enumerate(PATTERNS.values())),
                     re.IGNORECASE)


def history_lines(path: Path) -> list[str]:
    """``file:line: kind: text`` for every line of ``path`` that matches a pattern."""
    kinds = list(PATTERNS)
    out = []
    for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = HISTORY.search(line)
        if m:
            kind = kinds[int(m.lastgroup[1:])]
            out.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:"
                       f"{no}: {kind}: {line.strip()[:120]}")
    return out


def test_product_sources_carry_no_history():
    found = [hit for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py"))
             for hit in history_lines(f)]
    assert not found, f"{len(found)} line(s) of history in the product:\n" + "\n".join(found)


def test_the_check_sees_each_kind(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Fast on an H200 (2026-12-01, results/h200/x.md): 1.35x over the old\n'
                 'loop, 3-6x on CPU; see issue 12 and the before/after pair."""\n'
                 "SIZE = (48, 48)  # 48x48 images, 0.5 % of pixels, 1e-3 tolerance\n")
    hits = history_lines(f)
    assert [h.split(":")[1] for h in hits] == ["1", "2"]
    for text in ("H200", "2026-12-01", "results/", "1.35x", "3-6x", "issue 12", "before/after"):
        g = tmp_path / "one.py"
        g.write_text(f"# {text}\n")
        assert history_lines(g), text
    g.write_text("# arrays crash Dr.Jit's LLVM backend (drjit issue #532)\n")
    assert not history_lines(g)
