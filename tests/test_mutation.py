"""The mutation check runs: a no-change control survives, planted bugs are caught.

The full list (``python -m evaluation.meta.mutation``) takes tens of minutes on 2 cores; here a
subset in CI: the control, a camera bug, the missing edge slack (cracks at the room's
corners that the old image-space edge rule passed) and the unweighted background (only the
case scenes have a non-black background); the reference plugin without η² (only the open
glass sheet sees it); and the rules' own mutants, each of which must fail more than one
test (``--count``: every selected test runs): a tie probe that excuses every pixel, a nudge
probe that does, and a converged t-test that always passes.
"""
from __future__ import annotations

import pytest

from evaluation.meta.mutation import BY_NAME, MUTANTS, module_file, patch_source, run, score


def test_every_mutant_applies_exactly_once():
    assert len(MUTANTS) >= 20
    for m in MUTANTS:
        patched = patch_source(module_file(m.module).read_text(), m)
        assert patched != module_file(m.module).read_text(), m.name


@pytest.mark.slow
def test_control_survives_and_planted_bugs_are_caught():
    names = ["control_no_change", "camera_half_pixel", "missing_edge_slack",
             "background_not_weighted", "reference_eta_squared_missing"]
    res = {r["name"]: r for r in run(names, progress=lambda s: None)}
    assert res["control_no_change"]["status"] == "survived", res["control_no_change"]
    for n in names[1:]:
        assert res[n]["status"] == "caught", res[n]
    assert score([res[n] for n in names[1:]])["score"] == 1.0
    assert set(names) <= set(BY_NAME)


@pytest.mark.slow
def test_each_rule_mutant_fails_several_tests():
    """Measured (LLVM): tie_probe_excuses_all fails 19 tests (the planted bugs of 5 scenes,
    the broken renderers, the crack and the patches), nudge_probe_excuses_all 10 (the
    planted bugs and the probe's rule test), t_test_always_passes 5 (4 planted bugs on 2
    scenes, the wrong ior)."""
    names = ["tie_probe_excuses_all", "nudge_probe_excuses_all", "t_test_always_passes"]
    res = {r["name"]: r for r in run(names, progress=lambda s: None, count=True)}
    for n in names:
        assert res[n]["status"] == "caught", res[n]
        assert res[n]["caught_by"] >= 2, (n, res[n]["failed_tests"])
        files = {t.split("::")[0] for t in res[n]["failed_tests"]}
        assert "tests/test_rules_must_fail.py" in files, (n, files)
    # different scenes' planted bugs, not one test's parameters only
    planted = [t for t in res["tie_probe_excuses_all"]["failed_tests"]
               if "exact_rule_fails_a_planted_bug" in t]
    assert len({t.split("[")[1].split("-")[0] for t in planted}) >= 4, planted
