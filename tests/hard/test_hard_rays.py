"""Hard cases 1, 2 and 15 (ray-count cases) in CI: float32, LLVM, every accelerator and
routine.

The full counts (10^8 rays, both precisions, CUDA) come from ``whitted hard-cases``; see
its module docstring for the command."""
from __future__ import annotations

import pytest
from util_hard import CI, assert_green, rows_of

import renderer.accel.bvh as bvh_module
import renderer.accel.triangle as triangle
from evaluation.hard.cases import Config
from renderer.accel import ACCELERATORS


@pytest.mark.slow
def test_closed_mesh_from_inside_has_no_miss():
    """~10^6 random interior rays through the BVH per routine (brute force and boxes 10^4),
    plus rays at every vertex and edge midpoint, tinybvh's ±0 axis directions and rays at a
    tessellated plane, all far from the origin: 0 misses for the default routine."""
    rows = rows_of("closed_mesh")
    assert_green(rows)
    assert {r.variant.split("/")[1] for r in rows} == set(triangle.ROUTINES)
    for r in rows:       # every routine, not only the default, is watertight here
        assert r.value == 0, r.measured


def test_closed_mesh_has_no_miss_through_wide_bvhs_in_float64():
    """The wide BVHs in float64 (their child boxes in the precision of the render, not
    rounded to float32: rounding a refitted float64 box to float32 shrank it, and 46-70 of
    6098 rays aimed at vertices and edges missed): 0 misses for both routines."""
    rows = rows_of("closed_mesh", Config(backend="llvm", precisions=("float64",),
                                         accels=("bvh4", "bvh8"), rays=2000))
    assert_green(rows)
    assert all(r.value == 0 for r in rows), [r.measured for r in rows]


def test_closed_mesh_catches_a_leaky_routine(monkeypatch):
    """The case can fail: Möller–Trumbore without its edge slack leaks at vertices and
    edges (measured: 341 of 26098 rays in float32)."""
    monkeypatch.setattr(triangle, "edge_slack", lambda double: 0.0)
    rows = rows_of("closed_mesh", Config(backend="llvm", precisions=("float32",),
                                         accels=("bvh",), routines=("moller_trumbore",),
                                         rays=2000))
    assert rows[0].value > 0
    assert rows[0].info["at vertices"]["misses"] + rows[0].info["at edge midpoints"][
        "misses"] > 0


def test_spawned_rays_never_rehit_their_triangle():
    """10^6 rays spawned from hits on 1000 triangles over 10^±8: 0 self-hits with the
    default (watertight) routine; Möller–Trumbore's count is reported (105 measured, which
    shows the case can fail)."""
    rows = rows_of("reintersect", CI)
    assert_green(rows)
    by = {r.variant: r for r in rows}
    assert by[f"{triangle.DEFAULT_ROUTINE}/float32"].value == 0
    assert by[f"{triangle.DEFAULT_ROUTINE}/float32"].info["triangles_hit"] >= 900
    assert by["moller_trumbore/float32"].value > 0


def test_far_origins_get_brute_force_hits():
    """Rays from 10^3..10^6 radii away at an icosphere's vertices, edge midpoints and random
    points (three quarters from beyond the reach its boxes are padded for): every
    accelerator and routine gives brute force's answers, closest and any hit, here (LLVM,
    float32) and on the H200 in both precisions (``results/h200/hard-cases/``; Möller–Trumbore
    in float64 differed there at 4-5 vertex rays while CUDA's float64 reciprocal was
    approximate, ``renderer.device.rcp``)."""
    rows = rows_of("far_origin")
    assert_green(rows)
    assert {r.variant.split("/")[1] for r in rows} == set(triangle.ROUTINES)
    assert {r.variant.split("/")[0] for r in rows} == set(ACCELERATORS) - {"brute"}
    assert all(r.value == 0 and sum(v["hits"] for v in r.info.values()) > 4000 for r in rows)


def test_far_origin_case_sees_boxes_that_do_not_reach(monkeypatch):
    """The case can fail: the binary BVH told that its padding covers every origin
    (``reach`` infinite, so no ray enters every box) loses hits (measured: 1-2 rays of
    6562 per routine, in either form of the slab test)."""
    monkeypatch.setattr(bvh_module, "origin_reach", lambda scene, routine: float("inf"))
    rows = rows_of("far_origin", Config(backend="llvm", precisions=("float32",),
                                        accels=("bvh",)))
    assert sum(r.value for r in rows) > 0
