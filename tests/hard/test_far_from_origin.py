"""Far from the origin (issue 25), case 16 of the hard-case suite (``far_snapped``,
``evaluation.hard.far``): our render of the Cornell box moved by (s, s, s) against our
float64 render of the *same* vertices snapped to float32's grid there, so the geometry's own
snapping is not counted against float32's arithmetic: no bad pixel (off by > 5 % and not an
edge), and every shadow the snapped geometry casts survives; float64 bit for bit.

The table states float32's limit (``float32_limit = 1e5``, with the measured numbers): at
1e6 and 1e7 float32 fails the criterion, and those rows hold only while it does, so the
failure at 1e6 is also the proof that the criterion can fail.
"""
from __future__ import annotations

import pytest
from util_hard import CI, assert_green, rows_of

from evaluation.hard.cases import Config


@pytest.fixture(scope="module")
def float32_rows():
    return {r.info["shift"]: r for r in rows_of("far_snapped", CI)}


def test_float32_holds_to_its_limit_and_fails_beyond(float32_rows):
    rows = float32_rows
    assert sorted(rows) == [1e3, 1e4, 1e5, 1e6, 1e7]
    assert_green(rows.values())
    for s in (1e3, 1e4, 1e5):
        info = rows[s].info
        assert not info["expected_limit"] and info["shadow_pixels"] > 0, info
        assert info["bad"] == 0 and info["lost_shadow"] == 0, info
    # the check can fail: float32 rays from 1e6 away (ulp 1/16 against a room 2 across)
    info = rows[1e6].info
    assert info["expected_limit"] and info["bad"] > 0 and info["lost_shadow"] > 0, info
    assert "expected limit" in rows[1e6].criterion


def test_float64_is_bitwise_its_reference_at_every_shift():
    rows = rows_of("far_snapped", Config(backend="llvm", precisions=("float64",)),
                   shifts=[1e3, 1e7])
    assert_green(rows)
    assert [r.info["max_abs"] for r in rows] == [0.0, 0.0]
    assert rows[0].info["shadow_pixels"] > 0


def test_a_float32_that_held_beyond_its_limit_turns_the_row_red():
    """A table whose limit is stale (float32 declared to fail at 1e5, where it holds) gives
    a red row: the limit is measured, not assumed."""
    rows = rows_of("far_snapped", CI, shifts=[1e5], float32_limit=1e4)
    assert len(rows) == 1 and not rows[0].passed, rows[0]
