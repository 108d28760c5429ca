"""Mutation check of the rules: plant one realistic bug at a time, run the tests that guard
it, and count the mutants the tests catch.

    python -m evaluation.meta.mutation                 # every mutant, a table and the score
    python -m evaluation.meta.mutation NAME ...        # some mutants (names: --list)
    python -m evaluation.meta.mutation --json out.json # also write the results (atomically)
    python -m evaluation.meta.mutation --count NAME    # every selected test: how many fail

Each mutant is a source patch of one renderer module (``old`` must occur exactly once in
the file, so a refactor that moves the code makes the mutant *invalid*, said, not silently
"caught"). It runs in a fresh subprocess (``--run-one NAME``) that installs an import hook
*before* anything of the project is imported: the hook compiles the patched source for
that module, so every ``from ... import`` sees the bug, and nothing on disk changes. The
hook also primes ``linecache`` with the patched text, since ``@dr.syntax`` re-reads a
function's source. The subprocess runs the mutant's tests with ``pytest -x --assert=plain``
(pytest's assertion rewriter would import the project's modules itself): exit status
1 (a test failed) is *caught*, 0 is *survived*, anything else (collection error, no tests)
is *invalid*.

The tests named are the gate's own (golden exact cases, planted-defect tests, closed-form
tests); ``tests/test_mutation.py`` runs a small subset in CI (slow marker).
"""
from __future__ import annotations

import argparse
import importlib.abc
import importlib.machinery
import importlib.util
import json
import linecache
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from evaluation import write_result

ROOT = Path(__file__).resolve().parents[2]

#: pytest selections the mutants share.
GOLDEN_EXACT = ["tests/test_golden_regression.py", "-k", "exact_matches"]
GOLDEN_CASES = ["tests/test_golden_regression.py", "-k",
                "exact_matches and (mirror_background or fresnel_glass)"]
#: The tests that require a wrong render to fail the exact rule (through the tie probe).
MUST_FAIL_EXACT = ["tests/test_rules_must_fail.py", "tests/test_golden_regression.py", "-k",
                   "exact_rule_fails or exact_check_fails or crack or patch_off"]
#: MUST_FAIL_EXACT and the nudge probe's rule test.
MUST_FAIL_NUDGE = ["tests/test_rules_must_fail.py", "tests/test_golden_regression.py",
                   "tests/test_nudge_probe.py", "-k", "exact_rule_fails or exact_check_fails "
                   "or crack or patch_off or rule_excuses"]
#: The nudge probe's own tests and the glass bunny's exact goldens (which it lets pass).
NUDGE_TESTS = ["tests/test_nudge_probe.py", "tests/test_golden_regression.py", "-k",
               "not agrees_to_depth and (glass_bunny or rule_excuses)"]
#: The sphere light's closed-form test and the soft-shadow scene's converged goldens.
SOFT_TESTS = ["tests/test_soft_shadows.py", "tests/test_golden_regression.py", "-k",
              "centre_point or (converged_matches and cornell_soft)"]
#: The tests that require a wrong render to fail the converged rule.
MUST_FAIL_CONVERGED = ["tests/test_rules_must_fail.py", "tests/test_golden_regression.py",
                       "-k", "converged_rule_fails or converged_check_fails"]


@dataclass(frozen=True)
class Mutant:
    """One planted bug: in ``module`` (dotted name), ``old`` -> ``new``; ``tests`` are pytest
    arguments (paths, ``-k`` expressions); ``why`` says what the bug is."""

    name: str
    module: str
    old: str
    new: str
    why: str
    tests: tuple = field(default_factory=tuple)


def _m(name, module, old, new, why, *tests):
    return Mutant(name, module, old, new, why, tuple(tests) or tuple(GOLDEN_EXACT))


MUTANTS = [
    _m("camera_half_pixel", "renderer.camera",
       "px = t.Float(x) + 0.5", "px = t.Float(x) + 0.0",
       "exact rays through the pixel corner instead of its centre (x only)"),
    _m("swapped_aspect", "renderer.camera",
       "tan_x = tan_y * cam.width / cam.height", "tan_x = tan_y * cam.height / cam.width",
       "horizontal field of view from height / width (square images cannot see it)",
       *GOLDEN_CASES),
    _m("snell_eta_inverted", "renderer.shade",
       "eta = dr.select(entering, rcp(ior), ior)",
       "eta = dr.select(entering, ior, rcp(ior))",
       "relative index of refraction upside down"),
    _m("shading_normal_not_normalised", "renderer.shade",
       "ns = dr.select(sm, normalize(n_i), ng)", "ns = dr.select(sm, n_i, ng)",
       "interpolated vertex normal used without normalising"),
    _m("shadow_ray_ignored", "renderer.shade",
       "        lit &= ~blocked\n", "        lit &= ~(blocked & False)\n",
       "the shadow ray is traced but its answer ignored"),
    _m("pruning_gt", "renderer.integrator",
       "go_r = can_branch & (dr.max(w_r) >= opt.min_weight)",
       "go_r = can_branch & (dr.max(w_r) > opt.min_weight)",
       "weight pruning with > instead of >= (MODEL.md: a child exists if its weight >= "
       "min_weight)",
       "tests/test_analytic.py", "-k", "pruning"),
    _m("float64_falls_back_to_float32", "renderer.device",
       's = "64" if precision == "float64" else ""', 's = ""',
       "precision='float64' silently renders with float32 arrays",
       "tests/test_precision.py"),
    _m("missing_edge_slack", "renderer.accel.triangle",
       "return 16.0 * unit_roundoff(double)", "return 0.0 * unit_roundoff(double)",
       "Möller–Trumbore without the edge slack: leaks at shared edges and vertices (not the "
       "default routine since the watertight test is, so the closed-mesh hard case, which "
       "runs every routine, guards it)",
       "tests/hard/test_hard_rays.py", "-k", "closed_mesh_from_inside"),
    _m("background_not_weighted", "renderer.integrator",
       "radiance = dr.select(missed, dr.fma(weight, sa.background, radiance), radiance)",
       "radiance = dr.select(missed, sa.background + radiance, radiance)",
       "an escaping secondary ray adds the background at full weight", *GOLDEN_CASES),
    _m("phong_exponent_off_by_one", "renderer.shade",
       "spec = phong_power(rv, lobe.n)", "spec = phong_power(rv, lobe.n + 1.0)",
       "Phong exponent n + 1"),
    _m("ambient_halved", "renderer.shade",
       "result = sa.ambient * ka", "result = sa.ambient * ka * 0.5",
       "ambient term halved"),
    _m("fresnel_entering_wrong", "renderer.shade",
       "F = fresnel(cos_s, ior)[0]", "F = fresnel(dr.abs(cos_s), ior)[0]",
       "Fresnel reflectance computed as if every ray were entering", *GOLDEN_CASES),
    _m("fresnel_weights_swapped", "renderer.shade",
       "w_refl = dr.select(use_f, k_refl * F, w_refl)",
       "w_refl = dr.select(use_f, k_refl * (1.0 - F), w_refl)",
       "Fresnel: reflected share 1 - F", *GOLDEN_CASES),
    _m("eta_squared_missing", "renderer.shade",
       "w_refr = w_refr * (eta * eta)", "w_refr = w_refr * 1.0",
       "physical mode without the eta^2 radiance compression",
       "tests/test_golden_regression.py", "tests/test_reference_translation.py", "-k",
       "exact_matches or open_constant"),
    _m("reference_eta_squared_missing", "reference.plugins",
       'scale = dr.square(eta_ti) if self.shading == "physical" else 1.0', "scale = 1.0",
       "the reference plugin's constant-weight glass without the eta^2 factor (closed "
       "glass cancels it: only the open sheet sees it)",
       "tests/test_reference_translation.py", "-k", "open_constant"),
    _m("reference_eta_squared_inverted", "reference.plugins",
       'scale = dr.square(eta_ti) if self.shading == "physical" else 1.0',
       'scale = dr.square(1.0 / eta_ti) if self.shading == "physical" else 1.0',
       "the reference plugin's eta^2 factor upside down (eta_it^2 for eta_ti^2)",
       "tests/test_reference_translation.py", "-k", "open_constant"),
    _m("tir_loses_energy", "renderer.shade",
       "w_refl = dr.select(tir, k_refl + k_refr, k_refl)",
       "w_refl = dr.select(tir, k_refl, k_refl)",
       "constant weights: total internal reflection drops the refracted share"),
    _m("inverse_square_ignored", "renderer.lights",
       "falloff = dr.select(inverse_square, rcp(dist2), 1.0)", "falloff = 1.0",
       "classic lights with falloff = 'inverse_square' do not fall off", *GOLDEN_CASES),
    _m("cone_pdf_sin2", "renderer.lights",
       "Li = intensity * (2.0 * rcp(dc2 * (1.0 + cos_max)))",
       "Li = intensity * (2.0 * rcp(dc2))",
       "sphere light: cone pdf 1/(2π sin²θmax) instead of 1/(2π (1 - cosθmax))",
       *SOFT_TESTS),
    _m("cone_pdf_disk", "renderer.lights",
       "Li = intensity * (2.0 * rcp(dc2 * (1.0 + cos_max)))",
       "Li = intensity * rcp(dc2)",
       "sphere light: the cone weighted by the projected disk π sin²θmax (wrong by "
       "(1 + cosθmax) / 2)",
       *SOFT_TESTS),
    _m("point_light_through_cone", "renderer.lights",
       "return dr.select(kind == 1, b, dr.select(kind == 2, c, a))",
       "return dr.select(kind == 2, c, b)",
       "in a soft-shadow kernel a point light is cone-sampled as a sphere of radius 0 "
       "(right in the limit, not bit for bit)",
       "tests/test_soft_shadows.py", "-k", "bitwise"),
    _m("shadow_key_ignores_tile", "renderer.camera",
       "    if tile.first_row is not None:\n        y = y + tile.first_row\n    return x, y",
       "    return x, y",
       "the rays' pixels (so the shadow samples' keys) forget the tile's first row: a tiled "
       "render differs",
       "tests/test_soft_shadows.py", "-k", "batching"),
    _m("rectangle_back_side", "renderer.lights",
       "g = dr.select(two, dr.abs(cos_l), dr.maximum(cos_l, 0.0))",
       "g = dr.select(two, dr.abs(cos_l), dr.maximum(-cos_l, 0.0))",
       "a one-sided rectangle light emits from its back",
       "tests/test_soft_shadows.py", "-k", "form_factor"),
    _m("kd_not_over_pi", "renderer.shade",
       "kd = kd * INV_PI", "kd = kd * 1.0",
       "physical diffuse lobe kd instead of kd / pi"),
    _m("specular_normalisation", "renderer.shade",
       "ks = ks * ((n_exp + 2.0) * INV_TWO_PI)", "ks = ks * ((n_exp + 1.0) * INV_TWO_PI)",
       "physical Phong lobe normalised with (n + 1) / 2 pi"),
    _m("reflect_sign", "renderer.shade",
       "return dr.fma(N, -2.0 * dr.dot(d, N), d)", "return dr.fma(N, 2.0 * dr.dot(d, N), d)",
       "mirror direction with the wrong sign"),
    _m("no_ray_offset", "renderer.shade",
       "sign = dr.select(dr.dot(direction, ng) >= 0, F(1.0), F(-1.0))",
       "sign = dr.select(dr.dot(direction, ng) >= 0, F(-1.0), F(1.0))",
       "secondary and shadow rays offset to the wrong side (self-intersection)"),
    _m("max_depth_off_by_one", "renderer.integrator",
       "can_branch = on_surface & (depth < max_depth)",
       "can_branch = on_surface & (depth + 1 < max_depth)",
       "one specular bounce fewer than max_depth"),
    _m("light_behind_surface", "renderer.shade",
       "lit = ctx.active & (cos_theta > 0)", "lit = ctx.active & (cos_theta > -0.2)",
       "lights a little behind the surface still contribute"),
    _m("shading_normal_not_flipped", "renderer.shade",
       "N = dr.select(dr.dot(V, sp.ns) >= 0, sp.ns, -sp.ns)", "N = sp.ns",
       "two-sided shading lost: back faces are shaded with the far-side normal"),
    _m("jitter_correlated", "renderer.camera",
       "py = t.Float(y) + (t.Float(s // k) + xi2) * inv_k",
       "py = t.Float(y) + (t.Float(s // k) + xi1) * inv_k",
       "converged mode: one random number for both axes, so every sample lies on its "
       "stratum's diagonal (a bias at edges; plain uniform jitter would be unbiased)",
       "tests/test_golden_regression.py", "-k",
       "converged_matches and (cornell_box-front or platonic_solids-front-classic)"),
    # ---- the rules themselves: each must fail several tests (tests/test_mutation.py) ----
    _m("tie_probe_excuses_all", "evaluation.gate.rules",
       "    return image, np.any(other != image, axis=-1)",
       "    return image, np.ones(image.shape[:2], bool)",
       "the tie probe's mask holds every pixel: the exact rule excuses any difference",
       *MUST_FAIL_EXACT),
    _m("tie_window_a_tenth_of_the_scene", "evaluation.gate.rules",
       "    d = float(slack) * scene.diagonal", "    d = 0.1 * scene.diagonal",
       "the probe's window and slack a tenth of the scene, not 1e-5 of it: every surface "
       "behind another one near it is a 'tie'", *MUST_FAIL_EXACT),
    _m("exact_rule_ignores_the_mask", "evaluation.gate.rules",
       "    hard = bad & ~tie & ~ill\n", "    hard = bad & False\n",
       "the exact rule holds no pixel above max_rel hard, tie or not", *MUST_FAIL_EXACT),
    _m("nudge_probe_excuses_all", "evaluation.gate.rules",
       "    return candidates & (spread > max_rel) & within(ref) & within(ours)",
       "    return candidates",
       "the nudge probe excuses every hard pixel it is asked about", *MUST_FAIL_NUDGE),
    _m("nudge_range_ignored", "evaluation.gate.rules",
       "    return candidates & (spread > max_rel) & within(ref) & within(ours)",
       "    return candidates & (spread > max_rel)",
       "the nudge probe excuses a pixel that moves, wherever the golden and ours lie",
       *MUST_FAIL_NUDGE),
    _m("nudge_ours_not_spanned", "evaluation.gate.rules",
       "    return candidates & (spread > max_rel) & within(ref) & within(ours)",
       "    return candidates & (spread > max_rel) & within(ref)",
       "the nudge probe does not ask that ours lie among the nudged values: an image the "
       "probe's renderer does not render (a bug outside the frame function) is excused "
       "wherever the probe's values move", *MUST_FAIL_NUDGE[:-2], "tests/test_check.py",
       "-k", MUST_FAIL_NUDGE[-1] + " or exits_0_on_the_real"),
    _m("nudge_probe_never_runs", "evaluation.gate.verdict",
       'if mode == "exact" and verdict.result.get("hard_pixels"):',
       'if mode == "exact" and False:',
       "whitted check never runs the nudge probe: the glass bunny's ill-conditioned pixels "
       "fail it", *NUDGE_TESTS),
    _m("t_test_always_passes", "evaluation.gate.rules",
       '"ok": bool(mask.all())}', '"ok": True}',
       "the converged rule's verdict ignores its t-test", *MUST_FAIL_CONVERGED),
    _m("welch_never_rejects", "evaluation.gate.metrics",
       "    t = np.nan_to_num(np.abs(m_a - m_r) / np.sqrt(var), nan=np.inf)",
       "    t = np.zeros(m_a.shape)",
       "the t statistic is 0 for every value: no difference of means is significant",
       *MUST_FAIL_CONVERGED),
    _m("t_test_variance_times_100", "evaluation.gate.rules",
       "frac, mask, tval = welch_test(ours.mean, ours.var, ours.n, ref_mean, ref.var, ref.n,",
       "frac, mask, tval = welch_test(ours.mean, 100 * ours.var, ours.n, ref_mean,\n"
       "                                  100 * ref.var, ref.n,",
       "the converged rule's variances 100x too large (a per-sample variance for a per-mean "
       "one, say): only gross errors fail", *MUST_FAIL_CONVERGED),
    _m("right_angles_inexact", "renderer.scene.loader",
       "    (sx, sy, sz), (cx, cy, cz) = _sin_cos_degrees(deg)\n",
       "    cx, cy, cz = np.cos(np.radians(deg))\n    sx, sy, sz = np.sin(np.radians(deg))\n",
       "rotations from np.radians: cos 90° = 6e-17 tilts the Cornell box's walls by an ulp, "
       "the floor pokes through them and float64 shadow rays from its edges are blocked "
       "at their origin (the float64 gate; the tie probe must not excuse it)",
       "tests/test_golden_regression.py", "-k", "cornell_box_exact_in_float64"),
]
#: No change at all (``old`` == ``new``): must survive, or the harness itself is broken.
CONTROL = _m("control_no_change", "renderer.shade", "result = sa.ambient * ka",
             "result = sa.ambient * ka", "no change (the harness's control): every "
             "selection the mutants use, which must all pass",
             "tests/test_golden_regression.py", "tests/test_analytic.py",
             "tests/test_precision.py", "tests/hard/test_hard_rays.py",
             "tests/test_rules_must_fail.py", "tests/test_nudge_probe.py",
             "tests/test_reference_translation.py", "-k",
             "exact_matches or pruning or far_from_the_origin or closed_mesh_from_inside or "
             "cornell_box_exact_in_float64 or "
             "(converged_matches and (cornell_box-front or platonic_solids-front-classic)) or "
             "rule_fails or check_fails or crack or patch_off or rule_excuses or glass_bunny "
             "or open_constant")
BY_NAME = {m.name: m for m in (*MUTANTS, CONTROL)}


# ---- applying one mutant in this process (before the project is imported) --------------------
class _PatchedLoader(importlib.machinery.SourceFileLoader):
    def __init__(self, fullname, path, mutant: Mutant):
        super().__init__(fullname, path)
        self.mutant = mutant

    def get_source(self, fullname):
        return patch_source(Path(self.path).read_text(), self.mutant)

    def get_code(self, fullname):
        src = self.get_source(fullname)
        # ``@dr.syntax`` re-reads a function's source through ``inspect``/``linecache``:
        # prime the cache with the patched text (mtime None: never re-read from disk)
        linecache.cache[self.path] = (len(src), None, src.splitlines(True), self.path)
        return compile(src, self.path, "exec", dont_inherit=True)


class _Finder(importlib.abc.MetaPathFinder):
    def __init__(self, mutant: Mutant):
        self.mutant = mutant

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.mutant.module:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname.rsplit(".", 1)[-1], path)
        if spec is None or not spec.origin:
            return None
        return importlib.util.spec_from_file_location(
            fullname, spec.origin, loader=_PatchedLoader(fullname, spec.origin, self.mutant),
            submodule_search_locations=spec.submodule_search_locations)


def module_file(module: str) -> Path:
    return ROOT.joinpath(*module.split(".")).with_suffix(".py")


def patch_source(src: str, m: Mutant) -> str:
    """``src`` with the mutant's one occurrence of ``old`` replaced; ValueError if ``old``
    does not occur exactly once."""
    n = src.count(m.old)
    if n != 1:
        raise ValueError(f"mutant {m.name}: {m.module} holds {n} copies of {m.old!r}, "
                         f"expected exactly one")
    return src.replace(m.old, m.new)


def install(m: Mutant) -> None:
    """Make the next import of ``m.module`` compile the patched source."""
    if any(k == m.module or k.startswith(m.module + ".") for k in sys.modules):
        raise RuntimeError(f"mutant {m.name}: {m.module} was imported before the patch")
    patch_source(module_file(m.module).read_text(), m)      # fail early if invalid
    sys.meta_path.insert(0, _Finder(m))


class _FailedTests:
    """A pytest plugin that records the node ids of the tests that fail."""

    def __init__(self):
        self.failed: list[str] = []

    def pytest_runtest_logreport(self, report):
        if report.failed and report.nodeid not in self.failed:
            self.failed.append(report.nodeid)


#: The line ``--run-one --count`` prints before exiting: the failed tests as JSON.
FAILED_MARK = "mutation-failed-tests: "


def run_one(name: str, extra: list[str], *, count: bool = False) -> int:
    """In this process: install mutant ``name`` and run its tests (pytest -x; every one of
    them with ``count``, which then prints ``FAILED_MARK`` and the failed tests' ids)."""
    m = BY_NAME[name]
    install(m)
    import pytest
    os.chdir(ROOT)
    # --assert=plain: pytest's assertion-rewriting import hook goes first in sys.meta_path
    # and claims every module of a distribution that provides a pytest11 plugin (ours:
    # evaluation.gate.pytest_plugin), so with it renderer.* would be imported unpatched (measured:
    # every mutant survived)
    rec = _FailedTests()
    rc = int(pytest.main([*([] if count else ["-x"]), "-q", "-p", "no:cacheprovider",
                          "--assert=plain", *m.tests, *extra], plugins=[rec]))
    if count:
        print(FAILED_MARK + json.dumps(rec.failed), flush=True)
    return rc


# ---- the driver -----------------------------------------------------------------------------
def run(names, *, timeout: float = 1800.0, progress=print, count: bool = False) -> list[dict]:
    """Every mutant of ``names`` in its own subprocess; one result dict each: name, status
    (caught / survived / invalid / timeout), seconds, the tests run, and the last lines of
    the output. With ``count`` every selected test runs (no ``-x``) and the dict also holds
    ``failed_tests`` (node ids) and ``caught_by`` (their number): how many tests see the
    bug, not only whether one does."""
    out = []
    for i, name in enumerate(names):
        m = BY_NAME[name]
        t0 = time.time()
        try:
            patch_source(module_file(m.module).read_text(), m)
        except ValueError as e:
            out.append({"name": name, "status": "invalid", "seconds": 0.0, "why": m.why,
                        "tests": list(m.tests), "tail": str(e)})
            progress(f"[{i + 1}/{len(names)}] {name}: invalid ({e})")
            continue
        try:
            p = subprocess.run([sys.executable, "-m", "evaluation.meta.mutation",
                                "--run-one", name, *(["--count"] if count else [])],
                               cwd=ROOT, capture_output=True, text=True, timeout=timeout)
            status = {0: "survived", 1: "caught"}.get(p.returncode, "invalid")
            lines = (p.stdout + p.stderr).strip().splitlines()
            failed = [json.loads(ln[len(FAILED_MARK):]) for ln in lines
                      if ln.startswith(FAILED_MARK)]
            lines = [ln for ln in lines if not ln.startswith(FAILED_MARK)]
            tail = "\n".join(lines[-6:])
        except subprocess.TimeoutExpired:
            status, tail, failed = "timeout", f"no verdict within {timeout:.0f} s", []
        dt = time.time() - t0
        res = {"name": name, "status": status, "seconds": round(dt, 1), "why": m.why,
               "tests": list(m.tests), "tail": tail}
        if count:
            res["failed_tests"] = failed[-1] if failed else []
            res["caught_by"] = len(res["failed_tests"])
        out.append(res)
        by = f", failed {res['caught_by']} tests" if count else ""
        progress(f"[{i + 1}/{len(names)}] {name}: {status}{by} ({dt:.0f} s)")
    return out


def score(results: list[dict]) -> dict:
    valid = [r for r in results if r["status"] in ("caught", "survived")]
    caught = sum(r["status"] == "caught" for r in valid)
    return {"mutants": len(results), "valid": len(valid), "caught": caught,
            "score": (caught / len(valid)) if valid else None,
            "survivors": [r["name"] for r in valid if r["status"] == "survived"],
            "invalid": [r["name"] for r in results if r["status"] not in ("caught", "survived")]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m evaluation.meta.mutation",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", help="mutants to run (default: all)")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per mutant")
    ap.add_argument("--count", action="store_true",
                    help="run every selected test (no -x) and report how many fail")
    ap.add_argument("--run-one", help=argparse.SUPPRESS)
    args, extra = ap.parse_known_args(argv)
    if args.run_one:
        return run_one(args.run_one, extra, count=args.count)
    if args.list:
        for m in MUTANTS:
            print(f"{m.name:32s} {m.module:26s} {m.why}")
        return 0
    unknown = [n for n in args.names if n not in BY_NAME]
    if unknown:
        print(f"mutation: unknown mutant(s) {unknown}; choose from {sorted(BY_NAME)}",
              file=sys.stderr)
        return 2
    try:
        results = run(args.names or [m.name for m in MUTANTS], timeout=args.timeout,
                      count=args.count)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    s = score(results)
    print(json.dumps(s))
    if args.json:
        write_result(Path(args.json), json.dumps({"score": s, "mutants": results}, indent=1)
                      + "\n")
    return 0 if not s["survivors"] else 1


if __name__ == "__main__":
    sys.exit(main())
