"""The tie probe (``tie_break="other"``): another surface wins exactly where one is as near
as the nearest within the window and slack; nowhere else does the image change."""
from __future__ import annotations

import numpy as np
import pytest
from util import camera, diffuse_scene, light, make_scene, material, quad

from evaluation.gate.rules import tie_probe
from renderer.accel import ACCELERATORS, ROUTINES
from renderer.render import render


def _two_layers(gap: float):
    """Quad A (red, faces 0-1) at z = 0 over [-1, 1]^2, quad B (green, faces 2-3) at
    z = gap over [0, 2] x [-1, 1], both facing the camera at z = 3; ambient-lit only."""
    a = quad([-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0])
    b = quad([0, -1, gap], [2, -1, gap], [2, 1, gap], [0, 1, gap])
    cam = camera([0.5, 0, 3], [0.5, 0, 0], fov_y=60, width=24, height=12)
    return make_scene([(*a, 0), (*b, 1)],
                      materials=[material("red", ka=[1, 0, 0]), material("green", ka=[0, 1, 0])],
                      camera=cam, ambient=1.0)


@pytest.mark.parametrize("accel", sorted(ACCELERATORS))
def test_coplanar_overlap_is_a_tie(backend, accel):
    sc = _two_layers(0.0)
    low = render(sc, backend=backend, accel=accel).image
    other = render(sc, backend=backend, accel=accel, tie_break="other", tie_window=1e-6,
                   tie_slack=1e-6).image
    # lowest face index wins the exact tie: red everywhere A is
    assert (low[..., 0] == 1).sum() > 0 and (low[..., 1] == 1).sum() > 0
    both = (other != low).any(-1)
    # in the overlap the probe shows the other quad (green), elsewhere nothing changes
    assert both.sum() > 0
    assert np.all(other[both] == [0, 1, 0]) and np.all(low[both] == [1, 0, 0])
    assert np.array_equal(other[~both], low[~both])


@pytest.mark.parametrize("accel", sorted(ACCELERATORS))
def test_a_surface_behind_is_no_tie_unless_within_the_window(backend, accel):
    sc = _two_layers(-0.5)          # B half a unit behind A: never a tie at window 0.01
    low = render(sc, backend=backend, accel=accel).image
    near = render(sc, backend=backend, accel=accel, tie_break="other", tie_window=0.01,
                  tie_slack=0.01).image
    assert np.array_equal(near, low)
    far = render(sc, backend=backend, accel=accel, tie_break="other", tie_window=1.0,
                 tie_slack=0.01).image
    assert (far != low).any()


@pytest.mark.parametrize("routine", sorted(ROUTINES))
@pytest.mark.parametrize("accel", ["brute", "bvh8"])
def test_probe_works_with_either_triangle_routine(accel, routine):
    """The probe reads the edges of either packed layout (Möller–Trumbore's v0, e1, e2;
    the watertight test's p0, p1, p2, n): the coplanar overlap flips, only there, and the
    default tie-break gives the image of a render without the probe's fields."""
    sc = _two_layers(0.0)
    low = render(sc, backend="llvm", accel=accel, intersection=routine).image
    assert np.array_equal(low, render(sc, backend="llvm", accel=accel, intersection=routine,
                                      tie_break="lowest", tie_window=1.0, tie_slack=1.0).image)
    other = render(sc, backend="llvm", accel=accel, intersection=routine, tie_break="other",
                   tie_window=1e-6, tie_slack=1e-6).image
    both = (other != low).any(-1)
    assert both.sum() > 0 and np.all(other[both] == [0, 1, 0])
    assert np.array_equal(other[~both], low[~both])
    # a slack off the edge widens the inside test: the overlap's border pixels flip too
    wide = render(sc, backend="llvm", accel=accel, intersection=routine, tie_break="other",
                  tie_window=1e-6, tie_slack=0.3).image
    assert ((wide != low).any(-1)).sum() > both.sum()


def test_probe_images_agree_across_accelerators():
    sc = diffuse_scene()
    d = 1e-5 * sc.diagonal
    imgs = [render(sc, backend="llvm", accel=a, tie_break="other", tie_window=d,
                   tie_slack=d).image for a in sorted(ACCELERATORS)]
    for img in imgs[1:]:
        np.testing.assert_array_equal(img, imgs[0])


def test_shadow_grazing_an_edge_flips():
    """A floor lit past the edge of a blocker: with a slack wider than the pixels' distance
    from the shadow boundary, the probe flips shadow answers only along the boundary."""
    floor = quad([-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2])
    blocker = quad([-0.5, 1, -0.5], [0.5, 1, -0.5], [0.5, 1, 0.5], [-0.5, 1, 0.5])
    cam = camera([0, 3, 0.01], [0, 0, 0], fov_y=80, width=32, height=32, up=(0, 0, -1))
    sc = make_scene([(*floor, 0), (*blocker, 1)],
                    materials=[material("floor", kd=0.8), material("blocker", kd=0.2)],
                    lights=[light([0, 2, 0], 4.0, "none")], camera=cam)
    low = render(sc, backend="llvm").image
    other = render(sc, backend="llvm", tie_break="other", tie_window=0.0,
                   tie_slack=0.05).image
    # a shadow flip changes a pixel between lit and black; the diagonal shared by the
    # blocker's two triangles is a closest-hit tie too (the watertight routine's barycentrics
    # then differ in the last bit), which is not what this test is about
    changed = (np.abs(other - low) > 1e-3 * np.maximum(np.abs(low), 1.0)).any(-1)
    assert 0 < changed.sum() < 0.2 * changed.size
    lit = low.max(-1) > 0.1
    # every flipped pixel lies on the shadow's boundary (a lit/unlit neighbour pair)
    edge = np.zeros_like(lit)
    edge[1:-1, 1:-1] = np.any([lit[1 + dy:31 + dy, 1 + dx:31 + dx] != lit[1:-1, 1:-1]
                               for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    assert np.all(edge[changed])


def test_tie_probe_helper_and_bad_options():
    sc = _two_layers(0.0)
    img, ties = tie_probe(sc, 0, backend="llvm")
    assert np.array_equal(img, render(sc, backend="llvm").image)
    assert ties.shape == img.shape[:2] and ties.any()
    with pytest.raises(ValueError, match="tie_break"):
        render(sc, backend="llvm", tie_break="highest")
    with pytest.raises(ValueError, match="tie_window"):
        render(sc, backend="llvm", tie_break="other", tie_window=-1.0)


@pytest.mark.parametrize("routine", sorted(ROUTINES))
def test_probe_slack_is_a_world_space_distance_in_either_layout(routine):
    """A ray passing 0.1 outside an edge of a triangle far from the origin: the probe's
    inside test accepts it with a slack of 0.11 and rejects it with 0.09, whichever packed
    layout the routine reads (``traverse.edges_of``)."""
    import drjit as dr

    from renderer.accel.traverse import edges_of, probe_inside
    from renderer.accel.triangle import layout_of, load, pack, triangle_routine
    from renderer.device import types

    t = types("llvm", "float32")
    off = np.array([50.0, -30.0, 20.0])
    verts = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0]], float) + off
    layout = layout_of(routine)
    data = t.Float(pack(verts, np.array([[0, 1, 2]]), layout).astype(np.float32).reshape(-1))
    tri = load(t, data, t.UInt32(0), True, layout)
    e1, e2 = edges_of(tri, layout)
    # below the edge v0-v1 (y = 0) by 0.1, at x = 1; and well inside, for contrast
    o = t.Array3f([off[0] + 1, off[0] + 0.5], [off[1] - 0.1, off[1] + 0.5], [off[2] + 1] * 2)
    d = t.Array3f(0, 0, -1)
    th, u, v, _ = triangle_routine(routine)(o, d, *tri)
    near = probe_inside(th, u, v, e1, e2, 0.11).numpy()
    far = probe_inside(th, u, v, e1, e2, 0.09).numpy()
    # narrowed: the inner point is 0.5 from its nearest edge
    narrowed = [probe_inside(th, u, v, e1, e2, -s).numpy()[1] for s in (0.45, 0.55)]
    assert dr.width(th) == 2
    assert list(near) == [True, True] and list(far) == [False, True]
    assert narrowed == [True, False]


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_shadow_ray_blocked_at_its_origin_is_no_tie(precision):
    """A shadow ray that starts on a wall's edge and is blocked right there (a spawned ray
    re-hitting the surface it leaves, or one through its origin, as the Cornell box's
    floor did where its walls leaned by an ulp) stays blocked in the probe: no tie to
    excuse. A ray blocked by the same edge farther along is a graze, and flips."""
    from renderer.accel import build_accelerator
    from renderer.accel.base import Ray
    from renderer.device import types

    # a wall in the plane x = 1 over y in [0, 2], z in [-1, 1]
    wall = quad([1, 0, -1], [1, 2, -1], [1, 2, 1], [1, 0, 1])
    sc = make_scene([(*wall, 0)], materials=[material("w", kd=0.5)])
    t = types("llvm", precision)
    d = 1e-5 * 3.0
    probe = build_accelerator("bvh", sc, t, tie_break="other", tie_window=d, tie_slack=d)
    plain = build_accelerator("bvh", sc, t)
    u = 2.0 ** (-53 if precision == "float64" else -24)
    # from just behind the wall's bottom edge (x = 1 + 2u, y = 0) towards a light inside
    # the room: blocked at t ~ 2u, within the slack of the edge; and from 1 unit farther
    # out along the same line: blocked 1 unit along the ray, within the slack of the edge
    dirn = np.array([-0.5, 0.8, 0.2]) / np.linalg.norm([-0.5, 0.8, 0.2])
    starts = [np.array([1 + 2 * u, 0.0, 0.1]), np.array([1 + 2 * u, 0.0, 0.1]) - dirn]
    o = t.Array3f(*(t.Float([s[k] for s in starts]) for k in range(3)))
    ray = Ray(o=o, d=t.Array3f(*(float(c) for c in dirn)), t_max=t.Float(3.0))
    assert plain.intersect_p(ray).numpy().tolist() == [True, True]
    at_origin, graze = probe.intersect_p(ray).numpy().tolist()
    assert at_origin, "a ray blocked at its own origin was flipped as a tie"
    assert not graze, "an edge graze along the ray is a tie the probe flips"
