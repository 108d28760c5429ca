"""The mutation check runs: a no-change control survives, planted bugs are caught.

The full list (``python -m evaluation.meta.mutation``) takes tens of minutes on 2 cores; here a
subset in CI: the control, a camera bug, the missing edge slack (cracks at the room's
corners that the old image-space edge rule passed) and the unweighted background (only the
case scenes have a non-black background).
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
             "background_not_weighted"]
    res = {r["name"]: r for r in run(names, progress=lambda s: None)}
    assert res["control_no_change"]["status"] == "survived", res["control_no_change"]
    for n in names[1:]:
        assert res[n]["status"] == "caught", res[n]
    assert score([res[n] for n in names[1:]])["score"] == 1.0
    assert set(names) <= set(BY_NAME)
