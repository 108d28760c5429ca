"""``whitted CMD ...`` imports only CMD's module (start-up time: the bench parts, the report,
the gate's verdicts and golden store are not imported for ``render``),
and the full parser still lists every subcommand (references: the subcommand names
``whitted --help`` has always listed)."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OTHERS = ("whitted.bench", "whitted.view", "whitted.compare", "whitted.study",
          "evaluation.bench", "evaluation.gate.report", "evaluation.gate.verdict",
          "reference.golden")


def test_render_imports_no_other_command():
    code = ("import sys; from whitted.cli import build_parser; "
            "build_parser(['render', 'x.toml']).parse_args(['render', 'x.toml']); "
            f"print([m for m in {OTHERS!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "[]"


def test_full_parser_lists_every_command():
    from whitted.cli import build_parser
    text = build_parser().format_help()
    for name in ("render", "compare", "check", "reference", "export", "convert", "bench",
                 "study", "hard-cases", "view", "data"):
        assert name in text
    assert build_parser(["export"]).parse_args(
        ["export", "s.toml", "--mitsuba-xml", "o.xml"]).command == "export"
