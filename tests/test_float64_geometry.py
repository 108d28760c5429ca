"""float64 renders see float64 geometry (issue 25, "Numerics that the rules hid").

- At the origin: the Cornell box's walls are quads rotated upright by 90°; ``cos(90°)``
  from ``np.radians`` is 6e-17, so the walls leaned by an ulp, the floor poked through them
  and float64 shadow rays from the floor's edges were blocked (83 dark floor pixels at
  256², on two lines along the floor's edges; float32 rounds the ulp away). Right angles
  are exact now (``loader._sin_cos_degrees``).
- Far from the origin: the Cornell box moved by (1e7, 1e7, 1e7) *in its scene file*: the
  loader dropped the triangles that had no area on float32's grid (the mirror block's and
  the octahedron's) for float64 renders too, and averaged the float64 vertex normals from
  float32 face normals: 8.2 % of the pixels differed from the float64 render at the
  origin. Now a triangle is dropped only without area in both precisions (one with area in
  float64 only never hits in float32: ``triangle.pack``).
"""
from __future__ import annotations

import json
import tomllib
import warnings

import numpy as np
import pytest

from renderer.render import render
from renderer.scene import load_scene
from renderer.scene.loader import _rotation

SCENE = "scenes/cornell_box.toml"
SIZE = 96


def _toml_value(x) -> str:
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, str):
        return json.dumps(x)
    if isinstance(x, list):
        return "[" + ", ".join(_toml_value(i) for i in x) + "]"
    return repr(x)


def _toml(table: dict, prefix: str = "") -> list[str]:
    lines = []
    for k, v in table.items():
        if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict)):
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in table.items():
        name = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            lines += [f"[{name}]", *_toml(v, name)]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines += [f"[[{name}]]", *_toml(item, name)]
    return lines


def moved_scene_file(src, dst, shift: float):
    """``src`` with every object, view and light moved by ``(shift, shift, shift)`` in the
    file itself (the loader computes the moved vertices), written to ``dst``."""
    data = tomllib.loads(open(src, encoding="utf-8").read())
    move = lambda v: [float(x) + shift for x in v]   # noqa: E731
    for o in data["objects"]:
        o["translate"] = move(o.get("translate", [0.0, 0.0, 0.0]))
    for v in data["views"]:
        v["position"], v["target"] = move(v["position"]), move(v["target"])
    for li in data["lights"]:
        li["position"] = move(li["position"])
    dst.write_text("\n".join(_toml(data)) + "\n", encoding="utf-8")
    return dst


def _img(scene, precision):
    return render(scene.with_size(SIZE, SIZE), view=0, backend="llvm",
                  precision=precision).image


@pytest.mark.parametrize("deg", [[90.0, 0.0, 0.0], [0.0, -90.0, 0.0], [0.0, 0.0, 180.0],
                                 [270.0, 450.0, -180.0], [90.0, 90.0, 90.0]])
def test_right_angle_rotations_are_exact(deg):
    m = _rotation(np.array(deg))
    assert np.all(np.isin(m, (-1.0, 0.0, 1.0))), m
    assert np.array_equal(m @ m.T, np.eye(3))


def test_walls_meet_the_floor_exactly_in_float64():
    sc = load_scene(SCENE)
    V = sc.positions(True)
    for o in sc.objects[:5]:                       # floor, ceiling, back, left, right wall
        v = V[o.first_vertex:o.first_vertex + o.vertex_count]
        assert np.all(np.isin(v, (-1.0, 0.0, 1.0, 2.0))), (o.name, v)


def _edge_shadows(sc, precision: str, spawn: str, pts: np.ndarray) -> np.ndarray:
    import drjit as dr

    from renderer.accel import build_accelerator
    from renderer.device import types
    from renderer.shade import SurfacePoint, shadow_ray

    t = types("llvm", precision)
    acc = build_accelerator("bvh", sc, t)
    A3, n = t.Array3f, len(pts)
    p = A3(*(t.Float(pts[:, k]) for k in range(3)))
    sp = SurfacePoint(p=p, p_err=A3(dr.zeros(t.Float, n)), ng=A3(0.0, 1.0, 0.0),
                      ns=A3(0.0, 1.0, 0.0), material=dr.zeros(t.UInt32, n))
    light = A3(*(float(x) for x in sc.lights[0].position))
    return acc.intersect_p(shadow_ray(sp, light, t.is_double, None, spawn)).numpy()


@pytest.mark.parametrize("spawn", ["scale-free", "mitsuba"])
def test_float64_shadows_of_the_floor_edges_are_float32s(spawn):
    """Points on the floor's four edges: float64 shadow rays are blocked exactly where
    float32's are (by the mirror block and the tetrahedron; before the fix every point of
    the left and right edges was blocked by the leaning wall)."""
    sc = load_scene(SCENE)
    s = np.linspace(-0.99, 0.99, 199)
    one = np.ones_like(s)
    pts = np.concatenate([np.stack([x * one, 0 * s, s], 1) for x in (-1.0, 1.0)]
                         + [np.stack([s, 0 * s, z * one], 1) for z in (-1.0, 1.0)])
    b64 = _edge_shadows(sc, "float64", spawn, pts)
    b32 = _edge_shadows(sc, "float32", spawn, pts)
    assert b32.sum() < len(pts) / 4                      # the edges are mostly lit
    assert np.array_equal(b64, b32), f"{int((b64 != b32).sum())} of {len(pts)} differ, " \
                                     f"at {pts[b64 != b32][:3].tolist()}"


def test_float64_floor_lit_like_float32_at_origin():
    sc = load_scene(SCENE)
    a64, a32 = (render(sc.with_size(128, 128), view=0, backend="llvm", precision=p).image
                for p in ("float64", "float32"))
    # the floor's half of the image (at 128² no primary ray of either precision meets an
    # edge there, where the two could break the tie differently)
    dark = (a32 - a64)[64:].max(-1) > 0.05
    assert not dark.any(), f"{int(dark.sum())} pixels darker in float64 " \
                           f"(first {np.argwhere(dark)[:4].tolist()})"


def test_float64_far_from_origin_keeps_small_triangles(tmp_path):
    moved = moved_scene_file(SCENE, tmp_path / "moved.toml", 1e7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")             # no "dropped ... zero-area" warning
        far = load_scene(moved)
    near = load_scene(SCENE)
    assert far.face_count == near.face_count
    assert far.normals64 is not None
    assert np.allclose(far.normals_of(True), near.normals_of(True), atol=1e-8)


def test_float64_far_from_origin_matches_origin(tmp_path):
    moved = moved_scene_file(SCENE, tmp_path / "moved.toml", 1e7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        far = load_scene(moved)
    a, b = _img(load_scene(SCENE), "float64"), _img(far, "float64")
    diff = np.abs(a - b).max(-1)
    # the moved float64 scene rounds at 1e7 · 2^-53 ~ 1e-9: nothing visible may change
    assert float((diff > 1e-3).mean()) == 0.0, f"{float((diff > 1e-3).mean()):.2%} differ"
    assert float(diff.max()) < 1e-4
