"""The hard-case report: the table as markdown, JSON and an HTML page with each case's
image (``write_report``)."""

from __future__ import annotations

import html
import json
from dataclasses import asdict
from pathlib import Path

from evaluation import write_result

from .cases import Row


def markdown(rows: list[Row], header: str = "") -> str:
    """The table as markdown (case, variant, criterion, measured, pass)."""
    out = [header, ""] if header else []
    out += ["| case | variant | criterion | measured | pass |", "|---|---|---|---|---|"]
    for r in rows:
        cells = [r.case, r.variant, r.criterion, r.measured, "yes" if r.passed else "**NO**"]
        out.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(out) + "\n"


def page(rows: list[Row], header: str = "") -> str:
    """The table as an HTML page, each case's image beside its row."""
    e = html.escape
    body = [f"<h1>Hard cases</h1><p>{e(header)}</p><table>",
            "<tr><th>case</th><th>variant</th><th>criterion</th><th>measured</th>"
            "<th>pass</th><th>image</th></tr>"]
    for r in rows:
        img = f'<img src="{e(r.image)}" width="128">' if r.image else ""
        cls = "ok" if r.passed else "red"
        body.append(f'<tr class="{cls}"><td>{e(r.case)}</td><td>{e(r.variant)}</td>'
                    f"<td>{e(r.criterion)}</td><td>{e(r.measured)}</td>"
                    f"<td>{'yes' if r.passed else 'NO'}</td><td>{img}</td></tr>")
    body.append("</table>")
    style = ("body{font-family:sans-serif}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:4px;font-size:13px;vertical-align:top}"
             "tr.red{background:#fdd}")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>Hard cases</title>"
            f"<style>{style}</style></head><body>{''.join(body)}</body></html>\n")


def write_report(rows: list[Row], out: Path, meta: dict) -> dict:
    """Write ``hard_cases.md``, ``hard_cases.json`` and ``index.html`` into ``out``
    (atomically); returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    header = ", ".join(f"{k}: {v}" for k, v in meta.items())
    paths = {"markdown": out / "hard_cases.md", "json": out / "hard_cases.json",
             "html": out / "index.html"}
    write_result(paths["markdown"], markdown(rows, header))
    write_result(paths["json"], json.dumps({"meta": meta, "rows": [asdict(r) for r in rows],
                                             "passed": all(r.passed for r in rows)},
                                            indent=1, default=float))
    write_result(paths["html"], page(rows, header))
    return paths
