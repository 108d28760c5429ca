"""Hard case 14 in CI (LLVM, float32): ours against Mitsuba 3 with Embree in its fast
(default) and robust (``embree_use_robust_intersections``) modes
(``evaluation.hard.runners.case_mitsuba_parity``).

Measured: rays aimed at case 1's vertices and edge midpoints far from the origin: ours and
robust Embree miss 0, fast Embree 200 of 12840 and 937 of 19200 (random interior rays 4 of
10^5). Renders with ``spawn = "mitsuba"``: every pixel over 1e-3 from robust Embree is an
edge tie, but on coplanar faces with other vertices, where all 221 are pixels that Embree
shows green (its t rounded per triangle) and ours red (the plane's t, the lower face)."""
from __future__ import annotations

from util_hard import assert_green, rows_of


def test_mitsuba_parity_on_hard_cases():
    rows = rows_of("mitsuba_parity")
    assert_green(rows)
    rays = {r.variant: r.info for r in rows if r.variant.startswith("closed mesh rays")}
    assert set(rays) == {"closed mesh rays at vertices", "closed mesh rays at edge midpoints",
                         "closed mesh rays random interior"}
    # the check sees leaks: Embree's fast mode is not watertight on the aimed rays
    assert rays["closed mesh rays at vertices"]["fast"] > 0
    assert rays["closed mesh rays at edge midpoints"]["fast"] > 0
    renders = {r.variant.split("/")[0]: r.info for r in rows if "spawn mitsuba" in r.variant}
    assert len(renders) == 8
    tie = renders["coplanar faces, other vertices"]
    assert tie["vs_robust"][0] > 0
    assert tie["embree_green_ours_red"] == tie["vs_robust"][0] and tie["ours_green"] == 0
