"""Side-by-side report of our renders against Mitsuba's: one HTML page plus PNG strips.

``write_report(out_dir, entries, *, title)`` writes::

    out_dir/index.html              the page (no external resources; images are files beside it)
    out_dir/<entry>/ours.png        sRGB-encoded, clipped to [0, 1]
    out_dir/<entry>/mitsuba.png
    out_dir/<entry>/ours.exr        the linear images (float32 OpenEXR, e.g. for tev)
    out_dir/<entry>/mitsuba.exr
    out_dir/<entry>/absdiff.png     |ours - Mitsuba| (max over RGB), inferno, 0 .. scale
    out_dir/<entry>/flip.png        HDR-FLIP error map, magma, 0 .. 1
    out_dir/<entry>/strip.png       the four panels in a row with labels
    out_dir/<entry>/metrics.json    the metrics and the caller's run information

On the page, hovering over the "ours" or "Mitsuba" panel shows the other image in its place
and clicking pins the swap (as tev or Blender's render-result slots do), so differences jump
out as flicker.
"""
from __future__ import annotations

import html
import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from renderer.film import srgb_encode, write_exr
from renderer.outputs import atomic_path, check_output_dir, write_bytes, write_text

from .metrics import abs_error_heatmap, colormap_stops, flip_error, flip_heatmap, metrics

__all__ = ["ReportEntry", "format_metrics_table", "write_report"]

HEAT_CMAP = "inferno"
FLIP_CMAP = "magma"


@dataclass
class ReportEntry:
    """One comparison (a scene view) in a report.

    name: label, e.g. "cornell / front (classic)"; also gives the entry's folder name.
    ours, ref: float32 (H, W, 3) linear RGB: our image and Mitsuba's.
    ours_seconds, ref_seconds: render times, or None if unknown (e.g. a stored golden).
    effects: our kernel's effect set, as text (e.g. "shadows, reflection").
    operations: our kernel's operation counts, as text.
    info: further (label, text) rows for the run table (settings, golden file, ...).
    metrics: ``evaluation.gate.metrics.metrics`` of (ours, ref); computed and stored by
        ``write_report`` when None.
    verdict: the regression gate's status (PASS, WARN, FAIL, ...; ``evaluation.gate.verdict``)
        or None when the entry was not judged; verdict_reason: its one-line reason.
    thresholds: the rule's thresholds used, name -> (value, why).
    overlay: uint8 (H, W, 3) or None: the exact rule's verdict drawn over the golden
        (``evaluation.gate.rules.exact_overlay``: hard pixels red, excused ties yellow,
        ill-conditioned pixels orange, the rest of the tie mask magenta), shown beside the
        images (the gate sets it for a FAIL).
    metadata: {"ours": fields, "golden": fields} (``evaluation.gate.imagemeta``): written into
        the headers of the entry's ``ours.exr`` and ``mitsuba.exr``.
    """

    name: str
    ours: np.ndarray
    ref: np.ndarray
    ours_seconds: float | None = None
    ref_seconds: float | None = None
    effects: str = ""
    operations: str = ""
    info: dict[str, str] = field(default_factory=dict)
    metrics: dict | None = None
    verdict: str | None = None
    verdict_reason: str = ""
    thresholds: dict[str, tuple] = field(default_factory=dict)
    metadata: dict[str, dict] = field(default_factory=dict)
    overlay: np.ndarray | None = None


# ---- formatting ---------------------------------------------------------------------------
def _num(x: float | int | None, digits: int = 4) -> str:
    if x is None:
        return "—"
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    if x == 0:
        return "0"
    if not np.isfinite(x):
        return str(x)
    return f"{x:.{digits}g}" if 1e-3 <= abs(x) < 1e5 else f"{x:.{max(digits - 1, 1)}e}"


def _seconds(s: float | None) -> str:
    if s is None:
        return "—"
    return f"{s * 1e3:.1f} ms" if s < 1 else f"{s:.2f} s"


def _metric_rows(m: dict) -> list[tuple[str, str, str]]:
    """(label, value, explanation) rows of the metrics table."""
    share = m["outliers"] / max(m["pixels"], 1)
    return [
        ("RMSE", _num(m["rmse"]), "sqrt(mean (ours − ref)²)"),
        ("relMSE", _num(m["relmse"]), f"mean (ours − ref)² / (ref² + ε), ε = {m['eps']:g}"),
        ("max abs error", _num(m["max_abs"]), "over pixels and channels"),
        ("relative error", f"{_num(m['mean_rel'])} mean, {_num(m['max_rel'])} max",
         "per pixel: max over RGB of |ours − ref| / max(|ref|, ε)"),
        ("outlier pixels", f"{m['outliers']:,} of {m['pixels']:,} ({share:.2%})",
         m["outlier_rule"]),
        ("non-finite pixels", f"{m['nonfinite_pixels']:,}", "NaN or inf in either image"),
        ("mean FLIP", _num(m["flip_mean"]), "HDR-FLIP, 0 = identical"),
        ("ΔE2000", f"{_num(m['de2000_mean'])} mean, {_num(m['de2000_p99'])} p99, "
                   f"{_num(m['de2000_max'])} max",
         "CIEDE2000, linear sRGB → Lab (D65)"),
    ]


def _run_rows(e: ReportEntry) -> list[tuple[str, str]]:
    rows = [
        ("ours: time", _seconds(e.ours_seconds)),
        ("Mitsuba: time", _seconds(e.ref_seconds)),
        ("effect set", e.effects or "—"),
        ("operation counts", e.operations or "—"),
    ]
    rows += [(str(k), str(v)) for k, v in e.info.items()]
    return rows


def format_metrics_table(entries: list[ReportEntry]) -> str:
    """A plain-text table of the main metrics, one line per entry (for the terminal).

    Entries must carry metrics (``write_report`` fills them in)."""
    head = ("entry", "RMSE", "relMSE", "max abs", "outliers", "FLIP", "ΔE mean", "ΔE p99",
            "ours", "Mitsuba")
    rows = [head]
    for e in entries:
        m = e.metrics
        rows.append((e.name, _num(m["rmse"]), _num(m["relmse"]), _num(m["max_abs"]),
                     f"{m['outliers']}", _num(m["flip_mean"]), _num(m["de2000_mean"]),
                     _num(m["de2000_p99"]), _seconds(e.ours_seconds), _seconds(e.ref_seconds)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                       for i, (c, w) in enumerate(zip(r, widths))) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


# ---- images -------------------------------------------------------------------------------
def _save_png(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    with atomic_path(path, overwrite=True) as tmp:
        Image.fromarray(np.ascontiguousarray(rgb, np.uint8), "RGB").save(tmp, format="PNG")


def _strip(panels: list[tuple[str, np.ndarray]]) -> np.ndarray:
    """Panels uint8 (H, W, 3) side by side with a label bar above each: uint8 image."""
    from PIL import Image, ImageDraw, ImageFont

    h, w, _ = panels[0][1].shape
    zoom = max(1, -(-160 // w))                   # small images are enlarged (nearest)
    ph, pw, gap, bar = h * zoom, w * zoom, 6, 24
    canvas = Image.new("RGB", (len(panels) * pw + (len(panels) + 1) * gap, ph + bar + gap),
                       (250, 250, 250))
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=13)
    for i, (label, rgb) in enumerate(panels):
        x = gap + i * (pw + gap)
        img = Image.fromarray(rgb, "RGB").resize((pw, ph), Image.Resampling.NEAREST)
        canvas.paste(img, (x, bar))
        text = label
        while draw.textlength(text, font=font) > pw and len(text) > 4:
            text = text[:-2] + "…"
        draw.text((x, 5), text, fill=(40, 40, 40), font=font)
    return np.asarray(canvas)


def _slug(name: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.") or "entry"
    slug, k = base, 2
    while slug in taken:
        slug, k = f"{base}-{k}", k + 1
    taken.add(slug)
    return slug


# ---- page ---------------------------------------------------------------------------------
_CSS = """
:root { --fg:#1d2126; --muted:#6b7280; --line:#e3e6ea; --bg:#f6f7f9; --card:#fff;
        --accent:#2563eb; }
* { box-sizing: border-box; }
body { margin:0; font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;
       color:var(--fg); background:var(--bg); }
header { padding:20px 32px 12px; border-bottom:1px solid var(--line); background:var(--card); }
header h1 { margin:0 0 4px; font-size:22px; }
header p { margin:0; color:var(--muted); }
main { padding:20px 32px 40px; max-width:1800px; }
section.entry { background:var(--card); border:1px solid var(--line); border-radius:8px;
                padding:16px 20px 18px; margin:0 0 22px; }
section.entry h2 { margin:0 0 12px; font-size:17px; }
.strip { display:grid; grid-template-columns:repeat(4, minmax(0, 1fr)); gap:12px; }
figure { margin:0; }
figure img { width:100%; display:block; image-rendering:pixelated; border:1px solid var(--line);
             background:#000; }
figure.swap img { cursor:pointer; }
figure.swap.pinned img { outline:3px solid var(--accent); outline-offset:-3px; }
figcaption { font-size:12.5px; color:var(--muted); margin-top:5px; min-height:34px; }
figcaption b { color:var(--fg); font-weight:600; }
.bar { height:9px; border-radius:2px; margin:4px 0 2px; border:1px solid var(--line); }
.scale { display:flex; justify-content:space-between; font-variant-numeric:tabular-nums; }
.tables { display:grid; grid-template-columns:minmax(0, 3fr) minmax(0, 2fr); gap:24px;
          margin-top:16px; align-items:start; }
table { border-collapse:collapse; width:100%; }
th, td { text-align:left; padding:5px 10px 5px 0; border-bottom:1px solid var(--line);
         vertical-align:top; overflow-wrap:anywhere; }
th { font-weight:600; white-space:nowrap; }
td.v { font-variant-numeric:tabular-nums; white-space:nowrap; }
td.note, .note { color:var(--muted); font-size:12.5px; }
table.summary td, table.summary th { padding-right:18px; }
table.summary td.v { text-align:right; }
a { color:var(--accent); text-decoration:none; }
.hint { color:var(--muted); font-size:12.5px; margin:14px 0 10px; }
.verdict { font-weight:700; padding:1px 7px; border-radius:4px; color:#fff; }
.v-PASS { background:#15803d; } .v-WARN { background:#b45309; }
.v-FAIL, .v-SIZE { background:#b91c1c; }
.v-MISSING, .v-STALE, .v-ERROR { background:#6b21a8; }
p.reason { margin:0 0 10px; }
"""

_JS = """
for (const fig of document.querySelectorAll('figure.swap')) {
  const img = fig.querySelector('img'), cap = fig.querySelector('figcaption b');
  const show = (other) => {
    img.src = other ? fig.dataset.other : fig.dataset.own;
    cap.textContent = other ? fig.dataset.otherLabel : fig.dataset.ownLabel;
  };
  const pinned = () => fig.classList.contains('pinned');
  fig.addEventListener('mouseenter', () => { if (!pinned()) show(true); });
  fig.addEventListener('mouseleave', () => { if (!pinned()) show(false); });
  fig.addEventListener('click', () => { fig.classList.toggle('pinned'); show(pinned()); });
}
"""


def _gradient(cmap: str) -> str:
    return "linear-gradient(to right, " + ", ".join(colormap_stops(cmap, 11)) + ")"


def _swap_figure(own: str, own_label: str, other: str, other_label: str) -> str:
    e = html.escape
    return (f'<figure class="swap" data-own="{e(own)}" data-other="{e(other)}" '
            f'data-own-label="{e(own_label)}" data-other-label="{e(other_label)}">'
            f'<img src="{e(own)}" alt="{e(own_label)}">'
            f'<figcaption><b>{e(own_label)}</b><br>hover: {e(other_label)} in place · '
            f'click: pin</figcaption></figure>')


def _map_figure(src: str, label: str, cmap: str, lo: str, hi: str) -> str:
    e = html.escape
    return (f'<figure><img src="{e(src)}" alt="{e(label)}"><figcaption><b>{e(label)}</b>'
            f'<div class="bar" style="background:{_gradient(cmap)}"></div>'
            f'<div class="scale"><span>{e(lo)}</span><span>{e(hi)}</span></div>'
            f'</figcaption></figure>')


def _badge(status: str | None) -> str:
    if not status:
        return ""
    s = html.escape(status)
    return f'<span class="verdict v-{s}">{s}</span> '


def _thresholds_html(th: dict) -> str:
    if not th:
        return ""
    esc = html.escape
    rows = "".join(f'<tr><th>{esc(k)}</th><td class="v">{esc(_num(v))}</td>'
                   f'<td class="note">{esc(why)}</td></tr>' for k, (v, why) in th.items())
    return f'<table class="thresholds"><tr><th colspan="3">thresholds</th></tr>{rows}</table>'


def _entry_html(e: ReportEntry, slug: str, scale: float) -> str:
    esc = html.escape
    h, w, _ = e.ours.shape
    strip = "".join([
        _swap_figure(f"{slug}/ours.png", "ours (Dr.Jit)", f"{slug}/mitsuba.png", "Mitsuba 3"),
        _swap_figure(f"{slug}/mitsuba.png", "Mitsuba 3", f"{slug}/ours.png", "ours (Dr.Jit)"),
        _map_figure(f"{slug}/absdiff.png", "|ours − Mitsuba|, max over RGB", HEAT_CMAP,
                    "0", f"{scale:.3g}"),
        _map_figure(f"{slug}/flip.png", "HDR-FLIP error", FLIP_CMAP, "0", "1"),
        (f'<figure><img src="{esc(slug)}/rule.png" alt="exact rule"><figcaption><b>exact '
         'rule</b>: hard pixels red, excused (tie probe) yellow, other tie-mask pixels '
         'magenta</figcaption></figure>') if e.overlay is not None else "",
    ])
    metric_rows = "".join(f'<tr><th>{esc(k)}</th><td class="v">{esc(v)}</td>'
                          f'<td class="note">{esc(n)}</td></tr>'
                          for k, v, n in _metric_rows(e.metrics))
    run_rows = "".join(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in _run_rows(e))
    reason = (f'<p class="reason">{_badge(e.verdict)}{esc(e.verdict_reason)}</p>'
              if e.verdict else "")
    return (f'<section class="entry" id="{esc(slug)}"><h2>{_badge(e.verdict)}{esc(e.name)} '
            f'<span class="note">{w}×{h} · <a href="{esc(slug)}/strip.png">strip.png</a> · '
            f'<a href="{esc(slug)}/metrics.json">metrics.json</a> · '
            f'<a href="{esc(slug)}/ours.exr">ours.exr</a> · '
            f'<a href="{esc(slug)}/mitsuba.exr">mitsuba.exr</a></span></h2>'
            f'{reason}<div class="strip">{strip}</div>'
            f'<div class="tables"><table>{metric_rows}</table><div><table>{run_rows}</table>'
            f'{_thresholds_html(e.thresholds)}</div></div>'
            f'</section>')


def _summary_html(entries: list[ReportEntry], slugs: list[str]) -> str:
    esc = html.escape
    judged = any(e.verdict for e in entries)
    head = (("verdict",) if judged else ()) + (
        "entry", "RMSE", "max abs", "outliers", "mean FLIP", "ΔE mean", "ΔE p99", "ours",
        "Mitsuba")
    rows = []
    for e, s in zip(entries, slugs):
        m = e.metrics
        first = f"<td>{_badge(e.verdict)}</td>" if judged else ""
        cells = [_num(m["rmse"]), _num(m["max_abs"]), f"{m['outliers']:,}", _num(m["flip_mean"]),
                 _num(m["de2000_mean"]), _num(m["de2000_p99"]), _seconds(e.ours_seconds),
                 _seconds(e.ref_seconds)]
        rows.append(f'<tr>{first}<td><a href="#{esc(s)}">{esc(e.name)}</a></td>'
                    + "".join(f'<td class="v">{esc(c)}</td>' for c in cells) + "</tr>")
    return ('<table class="summary"><tr>' + "".join(f"<th>{esc(h)}</th>" for h in head)
            + "</tr>" + "".join(rows) + "</table>")


def _notes_html(notes) -> str:
    if not notes:
        return ""
    esc = html.escape
    rows = "".join(f"<tr><td>{_badge(status)}</td><td>{esc(name)}</td>"
                   f'<td class="note">{esc(reason)}</td></tr>' for status, name, reason in notes)
    return ('<table class="summary"><tr><th>verdict</th><th>entry</th><th>reason</th></tr>'
            f"{rows}</table>")


#: Files of a study folder (``evaluation.study.write_outputs``) that the report carries.
STUDY_FILES = ("index.html", "study.md", "study.json", "*.png", "*.svg")


def study_section(out_dir: str | Path, study_dirs) -> str:
    """The report's "Accuracy vs time" page: each study folder (``whitted study --out DIR``:
    index.html, study.md, study.json, one PNG/SVG plot per scene) is copied to
    ``out_dir/study/<folder name>/`` and linked, its first plot shown; returns the HTML
    section ('' when there is none)."""
    esc = html.escape
    items = []
    for d in study_dirs:
        d = Path(d)
        if not (d / "index.html").exists():
            continue
        dest = Path(out_dir) / "study" / d.name
        dest.mkdir(parents=True, exist_ok=True)
        for pattern in STUDY_FILES:
            for f in sorted(d.glob(pattern)):
                write_bytes(dest / f.name, f.read_bytes(), overwrite=True)
        title = d.name
        md = d / "study.md"
        if md.exists():
            first = md.read_text(encoding="utf-8").splitlines()[:1]
            title = first[0].lstrip("# ").strip() if first else d.name
        plots = sorted(dest.glob("*.png"))
        img = (f'<a href="study/{esc(d.name)}/index.html"><img src="study/{esc(d.name)}/'
               f'{esc(plots[0].name)}" alt="{esc(title)}" style="max-width:100%"></a>'
               if plots else "")
        items.append(f'<li><a href="study/{esc(d.name)}/index.html">{esc(title)}</a> '
                     f'(<a href="study/{esc(d.name)}/study.json">study.json</a>){img}</li>')
    if not items:
        return ""
    return ('<section class="entry" id="accuracy-vs-time"><h2>Accuracy vs time</h2>'
            "<p>What each setting (spp, depth, cut-off, precision, intersection routine, "
            "accelerator, effect kernel) costs in kernel time and buys in error against the "
            "Mitsuba golden and our own high-spp render (<code>whitted study</code>):</p><ul>"
            + "".join(items) + "</ul></section>")


def write_report(out_dir: str | Path, entries: list[ReportEntry], *, title: str,
                 overwrite: bool = False, notes=(), studies=()) -> Path:
    """Write the HTML report and per-entry PNGs into ``out_dir``; return the page's path.

    entries: the comparisons, in page order; an entry without metrics gets them computed
        (``evaluation.gate.metrics.metrics``) and stored on it, so the caller can print them
        afterwards.
    overwrite: replace the files of an existing, non-empty ``out_dir``; otherwise that is a
        ``FileExistsError``.
    notes: (status, name, reason) of verdicts without images (a missing or stale golden),
        listed first.
    studies: accuracy-vs-time study folders (``whitted study --out``) to carry as the
        report's "Accuracy vs time" page (``study_section``).
    """
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"report folder {out} already exists and is not empty")
    if not entries and not notes:
        raise ValueError("entries: expected at least one comparison")
    check_output_dir(out)

    taken: set[str] = set()
    slugs, sections = [], []
    for e in entries:
        if e.ours.shape != e.ref.shape:
            raise ValueError(f"entry {e.name!r}: ours {e.ours.shape} and ref {e.ref.shape} differ")
        slug = _slug(e.name, taken)
        slugs.append(slug)
        folder = out / slug
        folder.mkdir(exist_ok=True)

        flip_map, _ = flip_error(e.ours, e.ref)
        if e.metrics is None:
            e.metrics = metrics(e.ours, e.ref, flip_map=flip_map)
        heat, scale = abs_error_heatmap(e.ours, e.ref, cmap=HEAT_CMAP)
        panels = [
            ("ours (Dr.Jit)", srgb_encode(e.ours)),
            ("Mitsuba 3", srgb_encode(e.ref)),
            (f"|diff| 0..{scale:.3g}", heat),
            ("FLIP 0..1", flip_heatmap(flip_map, cmap=FLIP_CMAP)),
        ]
        for fname, (_, rgb) in zip(("ours", "mitsuba", "absdiff", "flip"), panels):
            _save_png(folder / f"{fname}.png", rgb)
        if e.overlay is not None:
            _save_png(folder / "rule.png", e.overlay)
        write_exr(folder / "ours.exr", e.ours, overwrite=True,
                  metadata=e.metadata.get("ours"))
        write_exr(folder / "mitsuba.exr", e.ref, overwrite=True,
                  metadata=e.metadata.get("golden"))
        _save_png(folder / "strip.png", _strip(panels))
        record = {"name": e.name, "metrics": e.metrics, "absdiff_scale": scale,
                  "ours_seconds": e.ours_seconds, "ref_seconds": e.ref_seconds,
                  "effects": e.effects, "operations": e.operations, "info": e.info}
        write_text(folder / "metrics.json", json.dumps(record, indent=2, default=str) + "\n",
                   overwrite=True)
        sections.append(_entry_html(e, slug, scale))

    esc = html.escape
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>"
        f"<header><h1>{esc(title)}</h1><p>{len(entries)} comparison(s) · {stamp} · images are "
        "sRGB-encoded, clipped to [0, 1]; metrics are on the linear images"
        "</p></header><main>"
        f"{_notes_html(notes)}"
        f"{_summary_html(entries, slugs) if len(entries) > 1 or notes else ''}"
        '<p class="hint">Hover over ours or Mitsuba to see the other image in its place; '
        "click to pin the swap.</p>"
        + "".join(sections)
        + study_section(out, studies)
        + f"</main><script>{_JS}</script></body></html>\n"
    )
    index = out / "index.html"
    write_text(index, page, overwrite=True)
    return index
