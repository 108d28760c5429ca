"""The study's report: factor lines, Pareto fronts, equal-time and equal-error rows, the
markdown, PNG + SVG plots and the HTML page (``write_outputs``)."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

import numpy as np

from renderer.outputs import atomic_path, check_output_dir, write_text

from .points import FACTORS, MODEL_FACTORS, OPTIONAL_SETTINGS, REFS, SETTING_KEYS, busy_load


# =========================================================================================
# Analysis: factor lines, Pareto front, tables, sentences
# =========================================================================================
def differs(settings: dict, default: dict) -> list[str]:
    return [k for k in SETTING_KEYS + OPTIONAL_SETTINGS if settings.get(k) != default.get(k)]


def point_label(settings: dict, default: dict) -> str:
    d = differs(settings, default)
    return ", ".join(f"{k}={settings[k]}" for k in d) or "default"


def time_of(p: dict) -> float:
    return float(p["timing"]["kernel_ms"])


def err_of(p: dict, ref: str, metric: str = "relmse") -> float | None:
    e = p["errors"].get(ref)
    return None if e is None or metric not in e else float(e[metric]["mean"])


def scene_points(data: dict, label: str) -> list[dict]:
    return [p for p in data["points"].values() if p["scene"] == label]


def factor_line(data: dict, label: str, factor: str) -> list[dict]:
    """Points of ``label`` that differ from its default in ``factor`` only (and the default),
    in the order of the factor's values."""
    default = data["scenes"][label]["default"]
    if factor not in default:
        return []                     # an optional setting this scene does not have
    pts = [p for p in scene_points(data, label)
           if set(differs(p["settings"], default)) <= {factor}]
    order = {"precision": ["float32", "float64"], "effects": ["auto", "all"],
             "combination": ["scene", "constant", "fresnel"]}
    if factor in order:
        return sorted(pts, key=lambda p: order[factor].index(p["settings"][factor]))
    if factor in ("accel", "intersection"):
        return sorted(pts, key=lambda p: str(p["settings"][factor]))
    return sorted(pts, key=lambda p: p["settings"][factor])


def pareto(points: list[dict], ref: str, metric: str = "relmse") -> list[dict]:
    """Points not beaten in both time and error (model changes excluded), by time."""
    cand = [p for p in points if p["settings"]["combination"] == "scene"
            and err_of(p, ref, metric) is not None]
    cand.sort(key=lambda p: (time_of(p), err_of(p, ref, metric)))
    front, best = [], math.inf
    for p in cand:
        e = err_of(p, ref, metric)
        if e < best:
            front.append(p)
            best = e
    return front


def _fmt(x, digits=3) -> str:
    if x is None:
        return "–"
    if x == 0:
        return "0"
    return f"{x:.{digits}g}" if 1e-3 <= abs(x) < 1e4 else f"{x:.{digits - 1}e}"


def budgets(lo: float, hi: float) -> list[float]:
    """1-2-5 steps from ``lo`` to ``hi``."""
    out = []
    k = math.floor(math.log10(max(lo, 1e-9)))
    while True:
        for m in (1, 2, 5):
            b = m * 10.0 ** k
            if b >= lo * 0.999:
                out.append(b)
            if b >= hi:
                return out
        k += 1


def equal_time_rows(points: list[dict], default: dict, ref: str) -> list[dict]:
    pts = [p for p in points if p["settings"]["combination"] == "scene"
           and err_of(p, ref) is not None]
    if not pts:
        return []
    rows = []
    for b in budgets(min(map(time_of, pts)), max(map(time_of, pts))):
        ok = [p for p in pts if time_of(p) <= b]
        if not ok:
            continue
        best = min(ok, key=lambda p: err_of(p, ref))
        rows.append({"budget_ms": b, "setting": point_label(best["settings"], default),
                     "kernel_ms": time_of(best), "relmse": err_of(best, ref),
                     "relmse_std": best["errors"][ref]["relmse"]["std"],
                     "rmse": err_of(best, ref, "rmse"), "flip": err_of(best, ref, "flip_mean")})
    return rows


def equal_error_rows(points: list[dict], default: dict, ref: str) -> list[dict]:
    pts = [p for p in points if p["settings"]["combination"] == "scene"
           and err_of(p, ref) is not None and err_of(p, ref) > 0]
    if not pts:
        return []
    lo = min(err_of(p, ref) for p in pts)
    hi = max(err_of(p, ref) for p in pts)
    rows = []
    k = math.ceil(math.log10(hi))
    while 10.0 ** k >= lo * 0.999 and len(rows) < 8:
        target = 10.0 ** k
        ok = [p for p in pts if err_of(p, ref) <= target]
        if ok:
            best = min(ok, key=time_of)
            rows.append({"target": target, "setting": point_label(best["settings"], default),
                         "kernel_ms": time_of(best), "relmse": err_of(best, ref)})
        k -= 1
    return rows


def _find(line: list[dict], factor: str, value) -> dict | None:
    for p in line:
        if p["settings"][factor] == value:
            return p
    return None


def _ratio(a, b):
    return None if a is None or b is None or b == 0 else a / b


def factor_sentences(data: dict, label: str) -> dict:
    """One sentence per factor of what it buys on scene ``label`` (from the data)."""
    default = data["scenes"][label]["default"]
    ref = "golden" if data["scenes"][label].get("golden", {}).get("path") else "own"
    out = {}
    base = _find(factor_line(data, label, "spp"), "spp", default["spp"])
    if base is None:
        return out

    def cmp(p, q, metric="rmse", r="own"):
        return _ratio(err_of(p, r, metric), err_of(q, r, metric)), _ratio(time_of(p), time_of(q))

    line = factor_line(data, label, "spp")
    steps = [(a, b) for a, b in zip(line, line[1:])]
    if steps:
        parts = []
        for a, b in steps:
            e, t = cmp(b, a)
            if e and t:
                parts.append(f"{a['settings']['spp']}→{b['settings']['spp']}: RMSE ÷{1 / e:.2f} "
                             f"at {t:.2f}× time")
        out["spp"] = ("4× spp (vs own reference) " + "; ".join(parts) + ".") if parts else None
    line = factor_line(data, label, "max_depth")
    if len(line) > 1:
        dd = default["max_depth"]
        # the shallowest depth from which every depth up to the default gives its image
        same_from = None
        for p in sorted((p for p in line if p["settings"]["max_depth"] <= dd),
                        key=lambda p: -p["settings"]["max_depth"]):
            if p["image_sha256"] != base["image_sha256"]:
                break
            same_from = p["settings"]["max_depth"]
        deeper = [p for p in line if p["settings"]["max_depth"] > dd]
        d0 = _find(line, "max_depth", 0)
        e, t = cmp(base, d0, "relmse", ref) if d0 else (None, None)
        s = (f"depth 0→{dd}: relMSE vs {ref} ×{_fmt(e)} at {_fmt(t)}× time"
             if e and t else "")
        if same_from is not None and same_from < dd:
            shallow = _find(line, "max_depth", same_from)
            s += (f"; from depth {same_from} to {dd} the image is bitwise the default's "
                  f"(depth {same_from} costs {_fmt(_ratio(time_of(shallow), time_of(base)))}× "
                  "the default's time)")
        if deeper and all(p["image_sha256"] == base["image_sha256"] for p in deeper):
            s += (f"; deeper than {dd} the image is bitwise the default's (depth "
                  f"{deeper[-1]['settings']['max_depth']} costs "
                  f"{_fmt(_ratio(time_of(deeper[-1]), time_of(base)))}× time for nothing)")
        elif deeper:
            e2, t2 = cmp(deeper[-1], base, "relmse", ref)
            s += (f"; deeper than {dd} changes the image (more bounces than the scene's "
                  f"depth, which the golden and the own reference stop at): depth "
                  f"{deeper[-1]['settings']['max_depth']} relMSE vs {ref} ×{_fmt(e2)} at "
                  f"{_fmt(t2)}× time")
        out["max_depth"] = s.lstrip("; ") + "."
    line = factor_line(data, label, "min_weight")
    if len(line) > 1:
        parts = []
        for p in line:
            if p is base:
                continue
            e, t = cmp(p, base, "relmse", "own")
            same = p["image_sha256"] == base["image_sha256"]
            parts.append(f"cut-off {p['settings']['min_weight']:g}: "
                         + ("same image" if same else f"relMSE vs own ×{_fmt(e)}")
                         + f" at {_fmt(t)}× time")
        out["min_weight"] = (f"vs cut-off {default['min_weight']:g}: " + "; ".join(parts) + ".")
    for factor, label_of in (("precision", "float64"), ("effects", "all")):
        p = _find(factor_line(data, label, factor), factor, label_of)
        if p:
            e, t = cmp(p, base, "rmse", ref)
            same = p["image_sha256"] == base["image_sha256"]
            out[factor] = (f"{factor}={label_of}: "
                           + ("the same image" if same else f"RMSE vs {ref} ×{_fmt(e)}")
                           + f" at {_fmt(t)}× time.")
    line = factor_line(data, label, "accel")
    if len(line) > 1:
        fastest = min(line, key=time_of)
        same = len({tuple(p["image_sha256"]) for p in line}) == 1
        slow = max(line, key=time_of)
        ratio = time_of(slow) / time_of(fastest)
        out["accel"] = (f"{'same image from every accelerator' if same else 'IMAGES DIFFER'}; "
                        f"{fastest['settings']['accel']} is {ratio:.1f}× "
                        f"faster than {slow['settings']['accel']}.")
    line = factor_line(data, label, "intersection")
    if len(line) == 1:
        out["intersection"] = (f"only {line[0]['settings']['intersection']} is registered: "
                               "nothing to compare yet.")
    elif line:
        out["intersection"] = "; ".join(
            f"{p['settings']['intersection']}: {_fmt(time_of(p))} ms, RMSE vs {ref} "
            f"{_fmt(err_of(p, ref, 'rmse'))}" for p in line) + "."
    line = factor_line(data, label, "combination")
    if len(line) > 1:
        out["combination"] = "model change: " + "; ".join(
            f"{p['settings']['combination']}: relMSE vs {ref} {_fmt(err_of(p, ref))}, "
            f"{_fmt(time_of(p))} ms" for p in line) + "." + (
            "" if ref == "golden" else " (no golden: each model is compared with its own "
            "high-spp render, so this is sampling error, not the model difference)")
    return out


def _median(xs):
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return statistics.median(xs) if xs else None


def p_cpu_time(p: dict) -> bool:
    """Whether cost ratios of ``p`` use the process's CPU time per frozen frame instead of
    the kernel time: on the LLVM backend, where a shared machine makes kernel (wall) times
    include waiting for a core while CPU time does not."""
    return p.get("device", {}).get("backend") == "llvm"


def summary_sentences(data: dict) -> list[str]:
    """What each factor costs, one sentence per factor: the median over scenes of the error
    and time ratios of one step away from the default (the README's section). On the LLVM
    backend the time ratio is of CPU time per frame where both points have it."""
    rows = {}

    def step(name, factor, value_of, metric="rmse", ref="own"):
        for label, info in data["scenes"].items():
            d = info.get("default")
            if not d:
                continue
            line = factor_line(data, label, factor)
            base = _find(line, factor, d[factor])
            other = _find(line, factor, value_of(d))
            if base is None or other is None or other is base:
                continue
            r = "golden" if ref == "golden" and base["errors"].get("golden") else "own"
            cpu = [p["timing"].get("frozen_cpu_ms") for p in (other, base)]
            if p_cpu_time(base) and all(cpu):
                t, unit = _ratio(cpu[0], cpu[1]), "CPU time"
            else:
                t, unit = _ratio(time_of(other), time_of(base)), "time"
            rows.setdefault(name, []).append(
                (_ratio(err_of(other, r, metric), err_of(base, r, metric)), t,
                 other["image_sha256"] == base["image_sha256"], r, unit))

    step("4× spp", "spp", lambda d: d["spp"] * 4)
    step("¼ spp", "spp", lambda d: d["spp"] // 4)
    step("one bounce less (max depth − 1)", "max_depth", lambda d: d["max_depth"] - 1,
         "relmse", "golden")
    step("no secondary rays (max depth 0)", "max_depth", lambda d: 0, "relmse", "golden")
    step("cut-off 0 (trace every branch)", "min_weight", lambda d: 0.0, "relmse")
    step("cut-off 0.1", "min_weight", lambda d: 0.1, "relmse")
    step("float64", "precision", lambda d: "float64", "rmse", "golden")
    step("brute force instead of the BVH", "accel", lambda d: "brute")
    step("per-object boxes instead of the BVH", "accel", lambda d: "boxes")
    step("the all-effects kernel", "effects", lambda d: "all")
    out = []
    for name, rs in rows.items():
        e = _median([r[0] for r in rs])
        t = _median([r[1] for r in rs])
        same = all(r[2] for r in rs)
        metric = "relMSE" if "depth" in name or "cut-off" in name else "RMSE"
        ref = rs[0][3]
        if same:
            what = "the same image (bitwise)"
        elif e is None:
            what = "error n/a"
        elif e < 1:
            what = f"{metric} vs {ref} ÷{1 / e:.2f}"
        else:
            what = f"{metric} vs {ref} ×{e:.2f}"
        units = {r[4] for r in rs}
        unit = units.pop() if len(units) == 1 else "time (CPU time where measured)"
        out.append(f"{name}: {what} at {_fmt(t)}× {unit} (median of {len(rs)} scene"
                   f"{'s' if len(rs) > 1 else ''})")
    return out


# =========================================================================================
# Outputs: markdown, plots, HTML
# =========================================================================================
def _md_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def markdown(data: dict) -> str:
    meta = data["meta"]
    dev = meta.get("device") or {}
    out = [f"# Accuracy vs time: {dev.get('device', '?')} ({meta.get('backend')})", ""]
    prof = meta.get("profile", {})
    out.append(f"Dr.Jit {dev.get('drjit')}, Python {dev.get('python')}; profile "
               f"`{prof.get('name')}`: {prof.get('size')} px high, seeds "
               f"{prof.get('seeds')}, own reference {prof.get('ref_spp')} spp; time = kernel "
               f"time of the frozen frame (median of {prof.get('repeats')} after "
               f"{prof.get('warmup')} warm-up). Executor: {meta.get('executor')}.")
    for note in meta.get("metric_notes", []):
        out.append(f"Note: {note}.")
    runs = meta.get("runs", [])
    if runs:
        out.append("Runs: " + "; ".join(f"{r['date']} {r['points']} points in {r['wall_s']} s"
                                         + (" (stopped by budget)" if r.get('stopped_by_budget')
                                            else "") + (f" ({r['note']})" if r.get("note") else "")
                                         for r in runs) + ".")
    lines = summary_sentences(data)
    if lines:
        out += ["", "## What each factor costs", "",
                "One step away from each scene's default; ratios are the median over scenes of "
                "(error, kernel time; on LLVM the process's CPU time per frame where measured, "
                "which waiting for a core on a shared machine does not inflate) relative to the "
                "default.", ""]
        out += [f"- {x}." for x in lines]
        out.append("")
    loads = [p["timing"].get("loadavg_1m") for p in data["points"].values()]
    loads = [x for x in loads if x is not None]
    cores = dev.get("cores") or 1
    if loads and max(loads) > busy_load(cores):
        out.append(f"**Measured under load**: the 1-minute load average was {min(loads):.1f}–"
                   f"{max(loads):.1f} on {cores} cores while points were timed (other work on "
                   "the machine), so kernel times include waiting for a core and time ratios "
                   "between points are uncertain by a factor of a few; the errors are not "
                   "affected (renders are deterministic).")
        out.append("")
    if meta.get("missing"):
        out.append(f"**{len(meta['missing'])} points of the sweep not measured yet** "
                   "(resume the run to add them).")
    out.append("")
    for label, info in data["scenes"].items():
        pts = scene_points(data, label)
        if not pts:
            continue
        default = info["default"]
        g = info.get("golden", {})
        out.append(f"## {label}")
        out.append("")
        out.append(f"Default: {', '.join(f'{k}={v}' for k, v in default.items())}. Golden: "
                   + (f"`{g['path']}` ({g.get('spp')} spp, its own noise RMSE "
                      f"{_fmt(g.get('noise_rmse'))})" if g.get("path") else
                      "**missing** (errors vs golden not available)") + ".")
        if info.get("skipped"):
            out.append("Skipped: " + "; ".join(info["skipped"]) + ".")
        out.append("")
        out.append("What each factor buys:")
        out.append("")
        for f, s in factor_sentences(data, label).items():
            if s:
                out.append(f"- **{f}**: {s}")
        out.append("")
        out.append(f"![{label}]({label}.png) ([SVG]({label}.svg))")
        out.append("")
        for ref in REFS:
            rows = equal_time_rows(pts, default, ref)
            if rows:
                out.append(f"Equal time (vs {ref}): the best setting within each "
                           "kernel-time budget")
                out.append("")
                out.append(_md_table(["budget ms", "best setting", "kernel ms", "relMSE (± std)",
                                      "RMSE", "mean FLIP"],
                                     [[_fmt(r["budget_ms"]), r["setting"], _fmt(r["kernel_ms"]),
                                       f"{_fmt(r['relmse'])} ± {_fmt(r['relmse_std'], 2)}",
                                       _fmt(r["rmse"]), _fmt(r["flip"])] for r in rows]))
                out.append("")
            rows = equal_error_rows(pts, default, ref)
            if rows:
                out.append(f"Equal error (vs {ref}): the cheapest setting reaching each relMSE")
                out.append("")
                out.append(_md_table(["relMSE ≤", "cheapest setting", "kernel ms", "relMSE"],
                                     [[_fmt(r["target"]), r["setting"], _fmt(r["kernel_ms"]),
                                       _fmt(r["relmse"])] for r in rows]))
                out.append("")
        out.append("All points (mean over seeds; ± = std over seeds):")
        out.append("")
        rows = []
        front = {p["key"] for p in pareto(pts, "golden" if g.get("path") else "own")}
        for p in sorted(pts, key=time_of):
            t = p["timing"]
            rows.append([point_label(p["settings"], default) + (" ★" if p["key"] in front else ""),
                         _fmt(t["kernel_ms"]), _fmt(t["frozen_wall_ms"]),
                         _fmt(t["compile_ms"]), _fmt(t.get("trace_ms")),
                         *[f"{_fmt(err_of(p, r))} ± {_fmt(p['errors'][r]['relmse']['std'], 2)}"
                           if p["errors"].get(r) else "–" for r in REFS],
                         *[_fmt(err_of(p, r, "rmse")) for r in REFS],
                         _fmt(err_of(p, "golden", "flip_mean")),
                         _fmt(err_of(p, "golden", "flip_p95")),
                         _fmt(err_of(p, "golden", "de2000_mean"))])
        out.append(_md_table(["setting (★ Pareto)", "kernel ms", "frozen wall ms", "compile ms",
                              "trace ms", "relMSE golden", "relMSE own", "RMSE golden",
                              "RMSE own", "FLIP golden", "FLIP p95 golden", "ΔE00 golden"], rows))
        out.append("")
    return "\n".join(out) + "\n"


_STYLE = {"spp": ("tab:blue", "o"), "max_depth": ("tab:orange", "s"),
          "min_weight": ("tab:green", "^"), "precision": ("tab:red", "D"),
          "intersection": ("tab:purple", "v"), "accel": ("tab:brown", "P"),
          "effects": ("tab:pink", "X"), "combination": ("tab:gray", "*"),
          "shadow_samples": ("tab:olive", "h")}


def plot_scene(data: dict, label: str, out: Path, metric: str = "relmse") -> list[Path]:
    """Log-log error vs kernel time of one scene: one panel per reference (lines per factor,
    the grid as grey dots, the Pareto front in black), and the model change apart."""
    import matplotlib
    matplotlib.use("Agg")
    matplotlib.rcParams["svg.hashsalt"] = "whitted-study"     # same plot, same file
    import matplotlib.pyplot as plt
    pts = scene_points(data, label)
    refs = [r for r in REFS if any(p["errors"].get(r) for p in pts)]
    fig, axes = plt.subplots(1, len(refs) + 1, figsize=(5.2 * (len(refs) + 1), 4.4),
                             squeeze=False)
    axes = axes[0]
    default = data["scenes"][label]["default"]
    for ax, ref in zip(axes, refs):
        def ys(points, ref=ref):
            return [max(err_of(p, ref, metric), 1e-12) for p in points]
        grid = [p for p in pts if len(differs(p["settings"], default)) > 1]
        if grid:
            ax.scatter([time_of(p) for p in grid], ys(grid),
                       s=9, color="0.75", label="spp × depth grid", zorder=1)
        for f in FACTORS:
            if f in MODEL_FACTORS:
                continue
            line = factor_line(data, label, f)
            if len(line) < 2:
                continue
            c, m = _STYLE[f]
            x = [time_of(p) for p in line]
            y = [max(err_of(p, ref, metric), 1e-12) for p in line]
            lo = [max(p["errors"][ref][metric]["min"], 1e-12) for p in line]
            hi = [p["errors"][ref][metric]["max"] for p in line]
            ax.errorbar(x, y, yerr=[np.subtract(y, lo), np.subtract(hi, y)], color=c, marker=m,
                        ms=4, lw=1.2, capsize=2, label=f, zorder=3)
            if f in ("spp", "max_depth", "min_weight"):
                for p, xi, yi in zip(line, x, y):
                    ax.annotate(f"{p['settings'][f]:g}", (xi, yi), fontsize=6, color=c,
                                xytext=(3, 3), textcoords="offset points")
        front = pareto(pts, ref, metric)
        if front:
            ax.step([time_of(p) for p in front], ys(front),
                    where="post", color="k", lw=1, ls="--", zorder=4, label="Pareto front")
            ax.scatter([time_of(p) for p in front], ys(front),
                       s=40, facecolors="none", edgecolors="k", zorder=5)
        g = data["scenes"][label].get("golden", {})
        if ref == "golden" and g.get("noise_rmse") and metric == "rmse":
            ax.axhline(g["noise_rmse"], color="k", lw=0.6, ls=":", label="golden's own noise")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("kernel time per frame (ms)")
        ax.set_ylabel(f"{metric} vs {ref} (mean over seeds; bars: min–max)")
        ax.set_title(f"{label}: vs {'Mitsuba golden' if ref == 'golden' else 'own high-spp'}")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    ax = axes[-1]
    line = factor_line(data, label, "combination")
    for ref, c in (("golden", "k"), ("own", "tab:gray")):
        sel = [p for p in line if p["errors"].get(ref)]
        if sel:
            yv = [max(err_of(p, ref, metric), 1e-12) for p in sel]
            ax.scatter([time_of(p) for p in sel], yv, color=c, marker="*", s=60,
                       label=f"vs {ref}")
            for p, y in zip(sel, yv):
                ax.annotate(p["settings"]["combination"], (time_of(p), y),
                            fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(f"{label}: combination (a model change)")
    ax.set_xlabel("kernel time per frame (ms)")
    ax.set_ylabel(metric)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    if line:
        ax.legend(fontsize=7)
    fig.tight_layout()
    paths = []
    for ext in ("png", "svg"):
        p = Path(out) / f"{label}.{ext}"
        with atomic_path(p, overwrite=True) as tmp:
            fig.savefig(tmp, format=ext, dpi=110,
                        metadata={"Date": None} if ext == "svg" else None)
        paths.append(p)
    plt.close(fig)
    return paths


def _md_to_html(md: str) -> str:
    """The small markdown subset ``markdown()`` writes (headings, lists, tables, images)."""
    import html
    import re
    out, table = [], []

    def inline(s):
        s = html.escape(s)
        s = re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", r'<img src="\2" alt="\1">', s)
        s = re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r'<a href="\2">\1</a>', s)
        s = re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", s)
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", s)

    def flush():
        if table:
            rows = [r for r in table if not set(r.replace("|", "").strip()) <= {"-"}]
            cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
            out.append("<table><tr>" + "".join(f"<th>{inline(c)}</th>" for c in cells[0])
                       + "</tr>" + "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r)
                                           + "</tr>" for r in cells[1:]) + "</table>")
            table.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("## "):
            out.append(f"<h2>{inline(line[3:])}</h2>")
        elif line.startswith("# "):
            out.append(f"<h1>{inline(line[2:])}</h1>")
        elif line.startswith("- "):
            out.append(f"<li>{inline(line[2:])}</li>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    flush()
    return "\n".join(out)


def write_outputs(data: dict, out) -> list[Path]:
    """study.md, <scene>.png/.svg and index.html in ``out`` from the results ``data``."""
    out = check_output_dir(out)
    written = []
    for label in data["scenes"]:
        if scene_points(data, label):
            try:
                written += plot_scene(data, label, out)
            except ImportError:
                break
    md = markdown(data)
    write_text(out / "study.md", md, overwrite=True)
    written.append(out / "study.md")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>Accuracy vs time</title>"
            "<style>body{font-family:sans-serif;max-width:1400px;margin:auto;padding:1em}"
            "table{border-collapse:collapse;font-size:12px;margin:0.5em 0}"
            "td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:100%}</style></head>"
            f"<body>{_md_to_html(md)}<p><a href='study.json'>study.json</a> (all points)</p>"
            "</body></html>\n")
    write_text(out / "index.html", page, overwrite=True)
    written.append(out / "index.html")
    return written
