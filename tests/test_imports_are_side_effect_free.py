"""Importing the evaluation and reference packages picks no Mitsuba variant, registers no
plugin and (for everything but the plugins themselves) does not even import Mitsuba;
``reference.plugins.register()`` is the explicit, idempotent registration."""
import subprocess
import sys
from pathlib import Path

import drjit as dr

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str) -> str:
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return run.stdout.strip()


def test_evaluation_and_reference_import_without_mitsuba():
    out = _python(
        "import sys\n"
        "import evaluation, evaluation.gate.metrics, evaluation.gate.rules\n"
        "import evaluation.gate.report, evaluation.gate.verdict\n"
        "import evaluation.bench\n"
        "import reference, reference.golden, reference.mitsuba_scene\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mitsuba'))\n")
    assert out == "[]"


def test_importing_plugins_picks_no_variant_and_registers_nothing():
    out = _python(
        "import mitsuba as mi\n"
        "import reference.plugins as p\n"
        "print(mi.variant(), p._PLUGINS)\n")
    assert out == "None {}"


def test_register_is_explicit_and_idempotent():
    out = _python(
        "import mitsuba as mi\n"
        "from reference import plugins\n"
        "try:\n"
        "    plugins.register()\n"
        "except RuntimeError as e:\n"
        "    print('refused:', 'no Mitsuba variant' in str(e))\n"
        "mi.set_variant('llvm_ad_rgb')\n"
        "first = plugins.register()\n"
        "print(plugins.register() is first, sorted(first))\n"
        "bsdf = mi.load_dict({'type': 'whitted_phong', 'kd': 0.5})\n"
        "print(isinstance(bsdf, first['whitted_phong']))\n")
    assert out.splitlines() == ["refused: True",
                                "True ['whitted', 'whitted_material', 'whitted_phong']",
                                "True"]


def test_importing_the_product_registers_no_triangle_routine():
    """Every module of the four packages imported: ``ROUTINES`` holds the renderer's own
    routines only (the wrong-on-purpose variants of the experiments live in ``lab/``)."""
    out = _python(
        "import importlib, pkgutil\n"
        "from renderer.accel import triangle\n"
        "before = sorted(triangle.ROUTINES)\n"
        "for top in ('renderer', 'reference', 'evaluation', 'whitted'):\n"
        "    pkg = importlib.import_module(top)\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, top + '.'):\n"
        "        if m.name != 'whitted.__main__':\n"
        "            importlib.import_module(m.name)\n"
        "import renderer.accel as A\n"
        "print(before == sorted(triangle.ROUTINES) == sorted(A.ROUTINES), before)\n")
    assert out == "True ['moller_trumbore', 'watertight']"


def test_importing_the_renderer_transforms_no_kernel_source():
    """``@renderer.device.syntax`` defers ``dr.syntax``'s source transformation to a
    kernel's first call: importing every kernel module transforms nothing."""
    out = _python(
        "import drjit as dr\n"
        "calls = []\n"
        "orig = dr.syntax\n"
        "dr.syntax = lambda f, **kw: calls.append(f.__qualname__) or orig(f, **kw)\n"
        "import renderer.render, renderer.integrator, renderer.shade\n"
        "import renderer.accel.bvh, renderer.accel.wide, renderer.accel.brute\n"
        "import renderer.accel.boxes, renderer.accel.traverse\n"
        "print(calls)\n")
    assert out == "[]"


def _count_up(n, step: int):
    """A symbolic loop under ``dr.syntax``: the first multiple of ``step`` at or above
    ``n``, per lane."""
    i = dr.zeros(type(n), dr.width(n))
    while i < n:
        i += step
    return i


def test_a_deferred_syntax_function_is_transformed_once_and_runs_as_dr_syntax(monkeypatch):
    from drjit.llvm import UInt32

    from renderer.device import syntax

    count_up = _count_up
    eager = dr.syntax(count_up)
    calls = []
    orig = dr.syntax
    monkeypatch.setattr(dr, "syntax", lambda f, **kw: calls.append(f) or orig(f, **kw))
    lazy = syntax(count_up)
    assert calls == [] and lazy.__name__ == "_count_up"
    n = UInt32(0, 5, 7, 10)
    assert lazy(n, 3).numpy().tolist() == eager(n, 3).numpy().tolist() == [0, 6, 9, 12]
    assert lazy(n, 2).numpy().tolist() == [0, 6, 8, 10]
    assert calls == [count_up]
