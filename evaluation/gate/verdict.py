"""Verdicts: our render of a scene view against its golden, judged by the case's rule.

One ``Verdict`` per scene x view x shading x mode, with a status and its exit code in the
style of OpenImageIO's ``idiff`` (the overall code of a run is the largest):

====  =========  ==========================================================================
code  status     meaning
====  =========  ==========================================================================
0     PASS       the rule of the mode passed (``evaluation.gate.rules``)
1     WARN       it passed, but a ``[check.warn]`` level of the scene file was exceeded
2     FAIL       the rule failed: our image differs from the golden
3     SIZE       our image and the golden differ in size
4     MISSING    no golden for this content in any store (the line says how to render it)
4     STALE      a golden of this scene/view exists but what it depends on has changed
4     ERROR      a scene file, threshold or golden file could not be read
====  =========  ==========================================================================

Each verdict carries the reason in one line, the pixels each rule excused (the exact rule
excuses only pixels our tie probe shows to depend on a geometric tie, and lists each), the
rule's numbers and the thresholds used (with their source: the defaults of
``evaluation.gate.rules`` or the scene file's ``[check]`` table). ``check_scenes`` runs them;
``format_line``, ``to_json`` and ``write_junit`` present them.

What is compared: exact mode, our image and its tie mask (``evaluation.gate.rules.tie_probe``'s
two renders, here through the cached renderers); converged mode, ``batches`` independent
renders of ours at the golden's ``batch_spp`` (``evaluation.gate.rules.render_batches``: our own
variance) against the golden's mean and variance.
"""
from __future__ import annotations

import difflib
import json
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from reference import MODES
from reference import golden as golden_store
from renderer.outputs import write_bytes
from renderer.scene import SHADING_MODES, SceneError, load_scene

from .exit_codes import EXIT_CODES
from .rules import (
    OUR_SEED,
    RULES,
    THRESHOLDS,
    Batches,
    Threshold,
    matching,
    nudge_probe,
    render_batches,
)

#: What ``check`` compares when neither the command line nor the scene's ``[check]`` says.
DEFAULT_MODES = ("exact",)
DEFAULT_SHADINGS = SHADING_MODES


@dataclass
class Verdict:
    """The judgement of one scene view in one shading and mode (module docstring)."""

    scene: str                       # scene name (file stem)
    scene_file: str                  # the scene file as given
    view: int
    view_name: str
    shading: str
    mode: str
    status: str
    reason: str
    excused: dict[str, int] = field(default_factory=dict)
    result: dict = field(default_factory=dict)
    thresholds: dict[str, dict] = field(default_factory=dict)
    golden: str | None = None
    command: str = ""
    seconds: float = 0.0
    ours: np.ndarray | None = field(default=None, repr=False)
    ref: np.ndarray | None = field(default=None, repr=False)
    ties: np.ndarray | None = field(default=None, repr=False)   # exact: the tie mask
    #: image metadata of both sides (``evaluation.gate.imagemeta``): {"ours": ..., "golden": ...}
    metadata: dict[str, dict] = field(default_factory=dict)
    #: the metadata fields that differ (``imagemeta.differences``), one phrase each
    differences: list[str] = field(default_factory=list)
    label: str = ""                  # the name to show instead of scene/view shading mode

    @property
    def name(self) -> str:
        return self.label or f"{self.scene}/{self.view_name} {self.shading} {self.mode}"

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.status]

    def as_dict(self) -> dict:
        keys = ("scene", "scene_file", "view", "view_name", "shading", "mode", "status",
                "reason", "excused", "result", "thresholds", "golden", "command", "seconds",
                "metadata", "differences")
        out = {k: getattr(self, k) for k in keys}
        out["exit_code"] = self.exit_code
        out["name"] = self.name
        return out


def exit_code(verdicts) -> int:
    """The run's exit code: the largest of its verdicts' (4 when there are none)."""
    return max((v.exit_code for v in verdicts), default=4)


# ---- thresholds -----------------------------------------------------------------------------
#: The values a threshold may take: name -> (test, what it must be). Any other name: a
#: number >= 0.
_RANGES = {
    "alpha": (lambda v: 0 < v < 1, "a probability strictly between 0 and 1"),
    "batches": (lambda v: isinstance(v, int) and v >= 2,
                "an integer >= 2 (the t-test needs a variance of ours)"),
    "nudges": (lambda v: isinstance(v, int) and v >= 1, "an integer >= 1"),
}


def threshold_values(mode: str, values: dict, *, why: str, where) -> dict[str, Threshold]:
    """``evaluation.gate.rules.THRESHOLDS[mode]`` with ``values`` (name -> number) in place
    of the defaults they name, each with the reason ``why``. ``where(name)`` is how the
    source names a threshold in an error (``check.exact.max_rel`` in a scene file,
    ``--threshold max_rel`` on the command line). Raises ``ValueError`` (one line, starting
    with ``where(name)``) for a name the rule does not have (with the closest valid one) or
    a value out of its range (``_RANGES``)."""
    out = dict(THRESHOLDS[mode])
    for name, value in values.items():
        if name not in out:
            close = difflib.get_close_matches(name, list(out), n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"{where(name)}: unknown threshold (valid: "
                             f"{', '.join(out)}){hint}")
        test, what = _RANGES.get(name, (lambda v: v >= 0, "a number >= 0"))
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not test(value):
            raise ValueError(f"{where(name)}: expected {what}, got {value!r}")
        out[name] = Threshold(value, why)
    return out


def thresholds_for(scene, mode: str) -> dict[str, Threshold]:
    """The thresholds of ``mode`` for ``scene``: ``evaluation.gate.rules.THRESHOLDS[mode]`` with the
    scene file's ``[check.<mode>]`` values in place of the defaults they name. Raises
    ``SceneError`` (file and field) for a name the rule does not have or a value out of its
    range (``threshold_values``)."""
    reason = scene.check.get("reason", "")
    why = f"set in {Path(scene.path).name} [check.{mode}]" + (f": {reason}" if reason else "")
    try:
        return threshold_values(mode, scene.check.get(mode, {}), why=why,
                                where=lambda name: f"check.{mode}.{name}")
    except ValueError as e:
        raise SceneError(f"{scene.path}: {e}") from None


def _threshold_rows(th: dict[str, Threshold], defaults: dict[str, Threshold]) -> dict:
    return {k: {"value": t.value, "why": t.why,
                "source": "default" if defaults.get(k) == t else "scene"}
            for k, t in th.items()}


# ---- judging one image ----------------------------------------------------------------------
def _fmt(x) -> str:
    return f"{x:.3g}" if isinstance(x, float) else f"{x:,}" if isinstance(x, int) else str(x)


def _pixels(pxs, n: int = 5) -> str:
    """``(y, x)`` of the first ``n`` pixels of a rule's list, for a reason line."""
    shown = ", ".join(f"({y},{x})" for y, x in pxs[:n])
    return shown + (", ..." if len(pxs) > n else "")


def explain(mode: str, res: dict, th: dict,
            probed: bool = True) -> tuple[str, dict[str, int]]:
    """(one-line reason, pixels excused per rule) of a rule's result ``res``. A rule may
    give both itself (``res["reason"]``, and ``res["excused"]`` as a dict); otherwise they
    are read from the numbers of ``check_exact`` / ``check_converged``. ``probed``: whether
    an exact comparison had a tie mask (``whitted diff`` of two image files has none)."""
    given = res.get("excused")
    excused = dict(given) if isinstance(given, dict) else {}
    if "reason" in res:
        return res["reason"], excused
    val = {k: t[0] for k, t in th.items()}
    if mode == "exact":
        if res.get("excused_pixels"):
            excused["tie-probe pixels"] = res["excused_pixels"]
        if res.get("ill_conditioned_pixels"):
            excused["ill-conditioned pixels (nudge probe)"] = res["ill_conditioned_pixels"]
        mask = (f"tie mask {_fmt(res.get('tie_pixels', 0))} pixels" if probed
                else "no tie probe")
        if res.get("ok"):
            ill = res.get("ill_conditioned_pixels", 0)
            return (f"mean rel {_fmt(res.get('mean_rel', 0.0))}, max rel (held) "
                    f"{_fmt(res.get('max_rel_held', res.get('max_rel', 0.0)))}, "
                    f"{mask}"
                    + (f", {ill:,} ill-conditioned pixels excused (their value moves beyond "
                       f"max_rel under a nudge of the primary ray by "
                       f"{val.get('nudge_ulps', 0):g} ulp)" if ill else "")), excused
        why = []
        if res.get("hard_pixels", 0):
            where = (" where neither the tie probe nor the nudge probe excuses" if probed
                     else " (no tie probe)")
            why.append(f"{res['hard_pixels']:,} pixels above max_rel {val.get('max_rel', 0):g}"
                       f"{where} (worst rel "
                       f"{_fmt(res.get('max_rel_held', res.get('max_rel')))}; "
                       f"{_pixels(res.get('hard', []))})")
        if "mean_rel" in val and res.get("mean_rel", 0) > val["mean_rel"]:
            why.append(f"mean rel {_fmt(res['mean_rel'])} > {val['mean_rel']:g}")
        return "; ".join(why) or "the exact rule failed", excused
    if mode == "converged":
        failed = res.get("failed_values", 0)
        if res.get("ok"):
            return (f"t-test: every value passes (max |t| {_fmt(res.get('max_t', 0.0))}, "
                    f"alpha {val.get('alpha', 0):g} family-wise)"), excused
        return (f"t-test: {failed:,} values in {res.get('failed_pixels', 0):,} pixels fail "
                f"at alpha {val.get('alpha', 0):g} (max |t| {_fmt(res.get('max_t', 0.0))}; "
                f"{_pixels(res.get('failed', []))})", excused)
    return ("passed" if res.get("ok") else "failed"), excused


def judge(ours, golden, mode: str, th: dict, warn: dict | None = None,
          scene=None, ties: np.ndarray | None = None,
          nudged: np.ndarray | None = None) -> tuple[str, str, dict, dict]:
    """Apply the rule of ``mode`` to ours and a ``reference.golden.Golden``: exact, our
    image, ``ties``, its tie mask (``evaluation.gate.rules.tie_probe``; None excuses
    nothing) and ``nudged``, our nudged renders (``evaluation.gate.rules.nudge_probe``;
    None excuses nothing); converged, our ``evaluation.gate.rules.Batches`` at the
    golden's ``batch_spp``.

    Returns (status, reason, excused, result): SIZE when the shapes differ, else PASS / FAIL
    from the rule, PASS turned WARN when a ``warn`` level (name -> value of the rule's
    result) is exceeded. ``scene`` names the file in the error for an unknown warn name."""
    if not isinstance(ours, Batches):
        ours = np.asarray(ours, np.float32)
    shape = ours.mean.shape if isinstance(ours, Batches) else ours.shape
    if shape != golden.image.shape:
        return ("SIZE", f"ours is {shape[1]}x{shape[0]}, the golden "
                        f"{golden.image.shape[1]}x{golden.image.shape[0]}", {}, {})
    res = RULES[mode](ours, golden, th, ties, nudged)
    reason, excused = explain(mode, res, th, probed=ties is not None)
    status = "PASS" if res["ok"] else "FAIL"
    if status == "PASS" and warn:
        over = []
        for name, level in warn.items():
            if name not in res or not isinstance(res[name], (int, float)):
                numeric = [k for k, v in res.items() if isinstance(v, (int, float))
                           and not isinstance(v, bool)]
                where = f"{scene.path}: " if scene is not None else ""
                raise SceneError(f"{where}check.warn.{name}: not a number the {mode} rule "
                                 f"reports (valid: {', '.join(numeric)})")
            if res[name] > level:
                over.append(f"{name} {_fmt(res[name])} > warn level {level:g}")
        if over:
            status, reason = "WARN", f"{reason}; " + "; ".join(over)
    # the numbers, and the pixel lists of the rule ([[y, x], ...]: excused, hard, failed)
    clean = {k: v for k, v in res.items() if isinstance(v, (bool, int, float, str, list))}
    return status, reason, excused, clean


# ---- running the checks ---------------------------------------------------------------------
def plan_for(scene, modes=None, shadings=None) -> tuple[tuple, tuple]:
    """(modes, shadings) to check: the command line's, else the scene's ``[check]``, else
    ``DEFAULT_MODES`` / ``DEFAULT_SHADINGS``."""
    modes = tuple(modes or scene.check.get("modes") or DEFAULT_MODES)
    shadings = tuple(shadings or scene.check.get("shadings") or DEFAULT_SHADINGS)
    return modes, shadings


def _ours(renderers: dict, scene, view: int, mode: str, golden, opts: dict, th: dict,
          render=None):
    """Ours for ``scene.cameras[view]`` at the golden's size and sampling: exact, ``(image,
    ties)`` (``evaluation.gate.rules.tie_probe``'s two renders: the renderer's and the one with
    ``tie_break="other"`` at ``tie_slack`` x the scene's diagonal); converged,
    ``(Batches, None)`` of ``th["batches"]`` renders at the golden's ``batch_spp``
    (``evaluation.gate.rules.render_batches``). One ``Renderer`` (upload and accelerator) per
    scene, size and tie-break. ``render(renderer, view, label)`` renders an exact image
    (the CLI's ``whitted.progress.render_view``: a progress bar and Ctrl-C between bands)
    and returns a dict with the RenderResult under ``"result"``; None:
    ``renderer.render(view)``. Ours spawns secondary and shadow rays with the rule the
    golden records (``spawn``: Mitsuba's own for every golden of the harness), so the two
    images trace the same rays; our default scale-free rule is held by the hard-case suite
    and the float64 oracle instead."""
    from renderer.render import Renderer

    w, h = golden.meta["resolution"]
    sized_key = (id(scene), w, h, golden.meta.get("spawn"))
    if sized_key not in renderers:
        renderers[sized_key] = matching(scene, golden)
    sized = renderers[sized_key]
    if mode == "converged":
        return render_batches(sized, view, batches=int(th["batches"][0]),
                              spp=int(golden.meta["batch_spp"]), seed=OUR_SEED, **opts), None
    d = float(th["tie_slack"][0]) * sized.diagonal
    label = f"{scene.name}/{scene.cameras[view].name} {scene.settings.shading} {mode}"
    images = []
    for tie in ("lowest", "other"):
        key = (*sized_key, tie)
        if key not in renderers:
            probe = {} if tie == "lowest" else {"tie_break": "other", "tie_window": d,
                                                "tie_slack": d}
            renderers[key] = Renderer(sized, spp=1, exact=True, **probe, **opts)
        r = renderers[key]
        if render is None:
            images.append(np.asarray(r.render(view).image, np.float32))
        else:
            images.append(np.asarray(render(r, view, label if tie == "lowest" else
                                            f"{label} (tie probe)")["result"].image,
                                     np.float32))
    return images[0], np.any(images[1] != images[0], axis=-1)


def _nudged(renderers: dict, scene, view: int, golden, th: dict) -> np.ndarray:
    """The nudge probe's renders (``evaluation.gate.rules.nudge_probe``) of ``view`` by the
    renderer ``_ours`` made for this scene, size and the plain tie-break."""
    w, h = golden.meta["resolution"]
    r = renderers[(id(scene), w, h, golden.meta.get("spawn"), "lowest")]
    return nudge_probe(r, view, ulps=float(th["nudge_ulps"][0]),
                       nudges=int(th["nudges"][0]))


def check_scene(scene_path, stores, *, modes=None, shadings=None, views=None,
                backend: str = "llvm", precision: str = "float32", accel: str | None = None,
                keep_images: bool = False, progress=None, render=None,
                read: dict | None = None) -> list[Verdict]:
    """Every verdict of one scene file against the golden ``stores`` (searched in order).

    modes / shadings / views: what to check (default ``plan_for``; views: every view).
    backend, precision, accel: how our renderer runs. keep_images: keep ours and the golden
    on each verdict (for a report). progress: called with each verdict as it is made.
    render: how our image is rendered (``_ours``). read: how the file is read
    (``load_scene``'s ``defines`` and ``approximate``: ``-D``, ``--approximate``)."""
    scene_path = Path(scene_path)
    shown = str(scene_path)
    opts = {"backend": backend, "precision": precision}
    if accel:
        opts["accel"] = accel

    def error(message, **kw):
        v = Verdict(scene_path.stem, shown, kw.get("view", -1), kw.get("view_name", "*"),
                    kw.get("shading", "*"), kw.get("mode", "*"), "ERROR", message)
        if progress:
            progress(v)
        return v

    try:
        read = read or {}
        base = load_scene(scene_path, **read)
        modes, shadings = plan_for(base, modes, shadings)
        ths = {m: thresholds_for(base, m) for m in modes}
    except SceneError as e:
        return [error(str(e))]
    except OSError as e:
        return [error(f"{scene_path}: cannot read: {e}")]
    out = []
    for shading in shadings:
        scene = load_scene(scene_path, shading=shading, **read)
        renderers: dict = {}
        for v, cam in enumerate(scene.cameras):
            if views is not None and v not in views and cam.name not in views:
                continue
            for mode in modes:
                t0 = time.perf_counter()
                verdict = Verdict(scene.name, shown, v, cam.name, shading, mode, "ERROR", "",
                                  thresholds=_threshold_rows(ths[mode], THRESHOLDS[mode]))
                try:
                    found = golden_store.find_golden(scene, view=v, shading=shading,
                                                     mode=mode, stores=stores)
                    verdict.command = found.command
                    if found.status != "ok":
                        verdict.status = found.status.upper()
                        verdict.reason = found.message
                        verdict.golden = str(found.path) if found.path else None
                    else:
                        g = found.golden
                        verdict.golden = golden_store._display(g.path)
                        ours, ties = _ours(renderers, scene, v, mode, g, opts, ths[mode],
                                           render)
                        (verdict.status, verdict.reason, verdict.excused,
                         verdict.result) = judge(ours, g, mode, ths[mode],
                                                 scene.check.get("warn"), scene, ties)
                        if mode == "exact" and verdict.result.get("hard_pixels"):
                            # hard pixels: the nudge probe says which are ill-conditioned
                            # (its renders only for a case that would fail without it)
                            nudged = _nudged(renderers, scene, v, g, ths[mode])
                            (verdict.status, verdict.reason, verdict.excused,
                             verdict.result) = judge(ours, g, mode, ths[mode],
                                                     scene.check.get("warn"), scene, ties,
                                                     nudged)
                        verdict.command = golden_store.regenerate_command(
                            scene.path, g.path.parent.parent)
                        _describe(verdict, matching(scene, g), v, mode, g, opts)
                        if keep_images:
                            verdict.ours = (ours.mean.astype(np.float32)
                                            if isinstance(ours, Batches) else ours)
                            verdict.ref, verdict.ties = g.image, ties
                except (golden_store.GoldenError, SceneError) as e:
                    verdict.status, verdict.reason = "ERROR", str(e)
                verdict.seconds = time.perf_counter() - t0
                if progress:
                    progress(verdict)
                out.append(verdict)
    return out


def _describe(verdict: Verdict, sized, view: int, mode: str, golden, opts: dict) -> None:
    """The metadata of ours (``sized``: the scene as rendered, at the golden's size) and of
    the golden (its EXR header, else its sidecar) on ``verdict``, and the fields that
    differ other than who rendered each."""
    from renderer.device import types

    from .imagemeta import differences, image_metadata, ours_metadata

    spp = None
    if mode == "converged":
        spp = int(golden.meta.get("batch_spp", 1)) * int(golden.meta.get("batches", 1))
    ours = ours_metadata(sized, view, backend=types(opts["backend"], opts["precision"]).backend,
                         precision=opts["precision"], exact=mode == "exact", spp=spp)
    theirs = image_metadata(golden.path) if golden.path and golden.path.is_file() else {}
    verdict.metadata = {"ours": ours, "golden": theirs}
    verdict.differences = differences(ours, theirs, names=("ours", "golden"),
                                      ignore=("renderer",))


def check_scenes(scene_paths, stores, **kw) -> list[Verdict]:
    """``check_scene`` for every path, in order."""
    out = []
    for p in scene_paths:
        out += check_scene(p, stores, **kw)
    return out


# ---- presenting -----------------------------------------------------------------------------
def format_line(v: Verdict) -> str:
    """One line: status, scene/view shading mode, the reason, the pixels each rule excused."""
    excused = ", ".join(f"{n:,} {rule}" for rule, n in v.excused.items())
    tail = f" [excused: {excused}]" if v.excused else ""
    return f"{v.status:<7} {v.name}: {v.reason}{tail}"


def summary_line(verdicts) -> str:
    counts = {}
    for v in verdicts:
        counts[v.status] = counts.get(v.status, 0) + 1
    parts = ", ".join(f"{n} {s}" for s, n in sorted(counts.items(),
                                                     key=lambda kv: EXIT_CODES[kv[0]]))
    return f"{len(verdicts)} checked: {parts or 'nothing'}; exit code {exit_code(verdicts)}"


def to_json(verdicts) -> dict:
    counts = {s: 0 for s in EXIT_CODES}
    for v in verdicts:
        counts[v.status] += 1
    return {"exit_code": exit_code(verdicts), "counts": counts,
            "exit_codes": EXIT_CODES, "verdicts": [v.as_dict() for v in verdicts]}


def _atomic_write(path: Path, data: bytes) -> None:
    """A gate artefact (JSON, JUnit) through the project's one atomic writer; it is
    replaced on every run by design."""
    write_bytes(Path(path), data, overwrite=True)


def write_json(verdicts, path) -> None:
    _atomic_write(Path(path), (json.dumps(to_json(verdicts), indent=1, default=str) + "\n")
                  .encode())


#: Largest file the report sniffers read (a report of this tool is far smaller).
_SNIFF_LIMIT = 256 << 20


def is_our_json(path) -> bool:
    """Whether ``path`` holds a verdict JSON as ``write_json`` writes it (an object with
    ``exit_code``, ``counts``, ``exit_codes`` and ``verdicts``): the only file ``--json``
    replaces without ``--force``."""
    path = Path(path)
    if path.stat().st_size > _SNIFF_LIMIT:
        return False
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return False
    return (isinstance(data, dict) and {"exit_code", "counts", "exit_codes", "verdicts"}
            <= data.keys() and isinstance(data["verdicts"], list))


def is_our_junit(path) -> bool:
    """Whether ``path`` holds JUnit XML as ``write_junit`` writes it (``testsuites`` whose
    suites are named ``whitted ...``): the only file ``--junit`` replaces without
    ``--force``."""
    path = Path(path)
    if path.stat().st_size > _SNIFF_LIMIT:
        return False
    try:
        root = ET.fromstring(path.read_bytes())
    except ET.ParseError:
        return False
    suites = root.findall("testsuite")
    return (root.tag == "testsuites" and bool(suites)
            and all(str(s.get("name", "")).startswith("whitted") for s in suites))


def junit_xml(verdicts, suite: str = "whitted check") -> bytes:
    """JUnit XML: one ``testcase`` per verdict (classname ``whitted.<scene>``, name ``<view>
    <shading> <mode>``, or the verdict's ``label``); FAIL and SIZE are ``failure``, MISSING /
    STALE / ERROR ``error``, WARN passes with its reason in ``system-out``."""
    verdicts = list(verdicts)
    fails = sum(v.status in ("FAIL", "SIZE") for v in verdicts)
    errors = sum(v.status in ("MISSING", "STALE", "ERROR") for v in verdicts)
    total = sum(v.seconds for v in verdicts)
    root = ET.Element("testsuites", tests=str(len(verdicts)), failures=str(fails),
                      errors=str(errors), time=f"{total:.3f}")
    ts = ET.SubElement(root, "testsuite", name=suite, tests=str(len(verdicts)),
                       failures=str(fails), errors=str(errors), skipped="0",
                       time=f"{total:.3f}")
    for v in verdicts:
        tc = ET.SubElement(ts, "testcase", classname=f"whitted.{v.scene}",
                           name=v.label or f"{v.view_name} {v.shading} {v.mode}",
                           time=f"{v.seconds:.3f}",
                           file=v.scene_file)
        detail = json.dumps({"result": v.result, "excused": v.excused,
                             "thresholds": v.thresholds, "golden": v.golden,
                             "command": v.command}, indent=1, default=str)
        if v.status in ("FAIL", "SIZE"):
            ET.SubElement(tc, "failure", message=f"{v.status}: {v.reason}",
                          type=v.status).text = detail
        elif v.status in ("MISSING", "STALE", "ERROR"):
            ET.SubElement(tc, "error", message=f"{v.status}: {v.reason}",
                          type=v.status).text = detail
        ET.SubElement(tc, "system-out").text = format_line(v)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def write_junit(verdicts, path) -> None:
    _atomic_write(Path(path), junit_xml(verdicts))


def report_entries(verdicts):
    """``evaluation.gate.report.ReportEntry`` for every verdict with both images, failures first
    (by exit code, largest first), each with its verdict and thresholds."""
    from .report import ReportEntry
    from .rules import exact_overlay

    ordered = sorted((v for v in verdicts if v.ours is not None),
                     key=lambda v: -v.exit_code)
    entries = []
    for v in ordered:
        excused = ", ".join(f"{n:,} {r}" for r, n in v.excused.items()) or "none"
        entries.append(ReportEntry(
            name=v.name, ours=v.ours, ref=v.ref, ours_seconds=v.seconds,
            verdict=v.status, verdict_reason=v.reason,
            thresholds={k: (t["value"], t["why"]) for k, t in v.thresholds.items()},
            info={"golden": v.golden or "—", "excused pixels": excused,
                  "re-render the golden": v.command,
                  **({"metadata differs": "; ".join(v.differences)} if v.differences else {})},
            metadata=v.metadata,
            overlay=exact_overlay(v.ours, v.ref, {k: (t["value"],) for k, t in
                                                  v.thresholds.items()}, v.ties,
                                  (v.result or {}).get("ill_conditioned"))
            if v.mode == "exact" and v.status == "FAIL" else None))
    return entries


__all__ = ["DEFAULT_MODES", "DEFAULT_SHADINGS", "EXIT_CODES", "MODES", "Verdict",
           "check_scene", "check_scenes", "exit_code", "explain", "format_line", "judge",
           "junit_xml", "report_entries", "summary_line", "threshold_values",
           "thresholds_for", "to_json",
           "write_json", "write_junit"]
