"""The float64 oracle (tests/oracle.py): its own correctness, and how close our exact-mode
renders and the Mitsuba goldens come to it.

The oracle's own tests need no Dr.Jit backend. The comparisons render each seed scene's
views once on LLVM (float32, exact mode) and share them through ``_compared``.

Bounds (measured on 200 sampled pixels per view; half of them on specular objects,
so glass and mirrors are over-represented against a full image):

- With the fixed offset override on both sides (``report.FIXED_RAY_EPSILON``) the oracle
  is the renderer's
  model in float64: every sampled pixel of every seed view agrees with ours within 1e-3, and
  at least 97 % within 1e-5 relative (the rest: float32 rounding amplified through glass
  and mirror bounces, and rays through shared edges).
- With offsets → 0 (the oracle's default) ours and the Mitsuba goldens (which spawn rays
  with our offset rule) differ from the oracle where the offset of 1e-4 × diagonal moves a
  reflected or refracted ray: its hit point shifts by about the offset, a change of order
  offset / distance in the radiance it brings back (1e-3 relative in bright physical
  mirror pixels), and through glass far more. Pixels lit directly agree to float32
  precision (1e-5 relative); the fraction within 1e-3 over all pixels is asserted at the
  measured minimum rounded down (``MIN_WITHIN``).
"""
from __future__ import annotations

import types

import numpy as np
import oracle
import oracle_report as report
import pytest

N_PIXELS = 200
SEED = 0


# =========================================================================================
# The oracle on its own
# =========================================================================================

def _all_pixels(cam):
    ys, xs = np.mgrid[0:cam.height, 0:cam.width]
    return np.stack([xs.ravel(), ys.ravel()], 1)


@pytest.mark.parametrize("shading", ["classic", "physical"])
@pytest.mark.parametrize("view", [0, 1, 2])
def test_analytic_quad_closed_form(view, shading):
    """scenes/analytic_quad.toml's docstring: at a floor point (px, 0, pz),
    d² = px² + 1 + pz², cosθ = 1/d; classic L = 0.5 cosθ, physical L = cosθ / d² · 0.5/π;
    misses are black. Every pixel of every view agrees to float64 rounding."""
    scene = report.load("analytic_quad", shading)
    cam = scene.cameras[view]
    px = _all_pixels(cam)
    img = oracle.render_pixels(scene, view, px)
    o, d = oracle.camera_rays(cam, px)
    t = -o[:, 1] / d[:, 1]
    x = o + t[:, None] * d
    inside = (t > 0) & (np.abs(x[:, 0]) < 1) & (np.abs(x[:, 2]) < 1)
    margin = np.minimum(1 - np.abs(x[:, 0]), 1 - np.abs(x[:, 2]))
    clear = np.abs(margin) > 1e-9          # pixel centres not on the quad's border
    d2 = x[:, 0] ** 2 + 1 + x[:, 2] ** 2
    cos = 1 / np.sqrt(d2)
    want = 0.5 * cos if shading == "classic" else cos / d2 * 0.5 / np.pi
    want = np.where(inside, want, 0.0)
    assert inside.sum() > 300 and clear.all()
    np.testing.assert_allclose(img, np.repeat(want[:, None], 3, 1), rtol=0, atol=1e-14)


def test_fresnel_dielectric():
    f = oracle.fresnel_dielectric
    assert f(np.array(1.0), 1 / 1.5) == pytest.approx(0.04, abs=1e-15)
    assert f(np.array(1.0), 1.5) == pytest.approx(0.04, abs=1e-15)
    # Reciprocity: entering at θi and leaving at the refracted θt reflect the same.
    ci = np.linspace(0.05, 1.0, 20)
    ct = np.sqrt(1 - (1 / 1.5) ** 2 * (1 - ci ** 2))
    np.testing.assert_allclose(f(ci, 1 / 1.5), f(ct, 1.5), atol=1e-14)
    # Total internal reflection past the critical angle.
    crit = np.sqrt(1 - (1 / 1.5) ** 2)
    assert f(np.array(crit * 0.999), 1.5) == 1.0
    assert f(np.array(crit * 1.001), 1.5) < 1.0


def test_vertex_normals_match_the_loader():
    """The oracle recomputes vertex normals in float64 from MODEL.md's rule; the loader's
    float32 normals must be the same to float32 precision."""
    for name in ("cornell_sphere", "glass_bunny"):
        scene = report.load(name, "classic")
        geo = oracle.Geometry.from_scene(scene)
        smooth = geo.smooth
        theirs = np.asarray(scene.normals, np.float64)[np.asarray(scene.faces)][smooth]
        assert smooth.any()
        assert np.abs(geo.vn[smooth] - theirs).max() < 1e-6


def _toy(vertices, faces):
    vertices = np.asarray(vertices, np.float32)
    faces = np.asarray(faces, np.int32)
    return types.SimpleNamespace(vertices=vertices, faces=faces,
                                 face_smooth=np.zeros(len(faces), bool),
                                 face_material=np.zeros(len(faces), np.int32))


def test_coplanar_duplicates_go_to_the_lowest_face():
    quad = [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]
    faces = [[0, 1, 2]] * 3 + [[0, 2, 3]] * 3
    geo = oracle.Geometry.from_scene(_toy(quad, faces))
    s = np.linspace(-0.95, 0.95, 2001)
    o = np.stack([s, np.ones_like(s), 0.3 * s[::-1]], 1)
    d = np.tile([0.0, -1.0, 0.0], (len(s), 1))
    t, face, _, _ = geo.closest(o, d)
    assert (face >= 0).all() and np.all(t == 1.0)
    assert set(np.unique(face)) <= {0, 3}


def test_closed_mesh_does_not_leak_at_vertices_and_edges():
    """Rays from inside the glass sphere aimed exactly at every vertex and at every edge
    midpoint (where two triangles meet) all hit the sphere."""
    scene = report.load("cornell_sphere", "classic")
    obj = next(o for o in scene.objects if o.name == "glass_sphere")
    F = np.asarray(scene.faces)[obj.first_face:obj.first_face + obj.face_count]
    V = np.asarray(scene.vertices, np.float64)
    centre = V[np.unique(F)].mean(0)
    targets = np.concatenate([V[np.unique(F)]] + [(V[F[:, i]] + V[F[:, (i + 1) % 3]]) / 2
                                                  for i in range(3)])
    rng = np.random.default_rng(1)
    origins = centre + rng.normal(scale=0.05, size=(len(targets), 3))
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    geo = oracle.Geometry.from_scene(scene)
    _, face, _, _ = geo.closest(origins, d)
    assert (face >= obj.first_face).all() and (face < obj.first_face + obj.face_count).all()


def test_offset_limit_is_reached():
    """The oracle's ε (OFFSET_REL = 1e-10) is close enough to the limit: ten times smaller
    changes no sampled pixel of the glass bunny (depth 8, the most offset-sensitive scene)
    by more than 1e-3, and 95 % of them by no more than 1e-6 (paths through glass amplify
    the origin's shift, so the image moves in proportion to ε)."""
    scene = report.load("glass_bunny", "classic")
    px = oracle.sample_pixels(scene, 0, 60, seed=3)
    a = oracle.render_pixels(scene, 0, px)
    saved = oracle.OFFSET_REL
    try:
        oracle.OFFSET_REL = saved / 10
        b = oracle.render_pixels(scene, 0, px)
    finally:
        oracle.OFFSET_REL = saved
    assert np.isfinite(a).all()
    e = np.abs(a - b).max(1)
    assert e.max() <= 1e-3 and np.mean(e <= 1e-6) >= 0.95


def test_sample_pixels():
    scene = report.load("cornell_sphere", "classic")
    px = oracle.sample_pixels(scene, 1, 100, seed=0)
    assert px.shape == (100, 2) and len({tuple(p) for p in px}) == 100
    assert (px[:, 0] < scene.cameras[1].width).all() and (px[:, 1] < 256).all()
    np.testing.assert_array_equal(px, oracle.sample_pixels(scene, 1, 100, seed=0))


# =========================================================================================
# Ours and the Mitsuba goldens against the oracle (LLVM)
# =========================================================================================

VIEWS = [(name, shading, v) for name in report.GOLDEN_SCENES for shading in report.SHADINGS
         for v in range(3)]
# Lowest fraction within 1e-3 measured (seed 0, 200 pixels per view, lab/notes/data/
# issue10-ray-offsets/oracle_golden_scenes.md), rounded down. Ours (scale-free offsets,
# ~1e-7): 1.000 on every view. Mitsuba (si.spawn_ray, offset (1 + max|x|) x 8.9e-5):
# cornell_box 1.000, cornell_sphere 0.980, platonic_solids 0.975 (physical "low" and "left":
# physical radiance is larger, so the same shift crosses 1e-3 more often).
MIN_WITHIN = {
    "ours_float32": {"cornell_box": 0.995, "cornell_sphere": 0.995, "platonic_solids": 0.995,
                     "analytic_quad": 1.0},
    "mitsuba": {"cornell_box": 0.99, "cornell_sphere": 0.97, "platonic_solids": 0.97,
                "analytic_quad": 1.0},
}

_cache: dict = {}


def _compared(name, shading, view):
    key = (name, shading, view)
    if key not in _cache:
        scene = report.at_golden_size(report.load(name, shading), view)
        px = oracle.sample_pixels(scene, view, N_PIXELS, SEED)
        _cache[key] = report.compare(scene, view, px)
    return _cache[key]


@pytest.mark.parametrize("name,shading,view", VIEWS)
def test_model_epsilon_oracle_matches_ours(name, shading, view):
    """Same offset rule on both sides: the oracle is the renderer's model."""
    c = _compared(name, shading, view)
    e = c["err"]["model_eps"]
    rel = e / np.maximum(1.0, np.abs(c["oracle"]).max(1))
    assert np.all(e <= 1e-3), f"{np.sum(e > 1e-3)} pixels off by more than 1e-3"
    assert np.mean(rel <= 1e-5) >= 0.97


@pytest.mark.parametrize("source", ["ours_float32", "mitsuba"])
@pytest.mark.parametrize("name,shading,view", VIEWS)
def test_against_the_offset_limit(name, shading, view, source):
    """Pixels lit directly (no reflected or refracted ray in their tree) agree with the
    oracle to float32 precision: at least 97 % within 1e-5 relative and all within 1e-4
    (measured: 100 % within 1e-5 on every view but platonic_solids/physical/left, 97.4 %
    there, largest 1.9e-5). Pixels with specular rays move with the spawn offset (ours
    ~1e-7, Mitsuba's ~1e-4); the share of all pixels within 1e-3 is bounded by
    MIN_WITHIN."""
    c = _compared(name, shading, view)
    e = c["err"][source]
    within = e <= report.TOL
    direct = ~c["specular"]
    share = lambda m: f"{within[m].mean():.3f}" if m.any() else "-"
    print(f"{name} {shading} view {view} {source}: {within.mean():.3f} within 1e-3 "
          f"({direct.sum()} direct pixels: {share(direct)}; "
          f"{c['glass'].sum()} glass pixels: {share(c['glass'])})")
    rel = e / np.maximum(1.0, np.abs(c["oracle"]).max(1))
    assert np.mean(rel[direct] <= 1e-5) >= 0.97 and np.all(rel[direct] <= 1e-4)
    assert within.mean() >= MIN_WITHIN[source][name]


@pytest.mark.parametrize("name,shading,view", VIEWS)
def test_ours_closer_to_the_oracle_than_mitsuba_on_glass(name, shading, view):
    """Issue 10's goal, pixel for pixel on glass: the share of glass pixels where Mitsuba's
    golden is closer to the oracle than ours by more than 1e-5 is at most 2 % (measured 0 on
    all 24 views; ours closer on up to 84 %)."""
    c = _compared(name, shading, view)
    g = c["glass"]
    if not g.any():
        pytest.skip("no glass pixel sampled")
    d = c["err"]["ours_float32"][g] - c["err"]["mitsuba"][g]
    assert np.mean(d > 1e-5) <= 0.02, f"Mitsuba closer on {np.mean(d > 1e-5):.1%}"


@pytest.mark.slow
@pytest.mark.parametrize("shading", report.SHADINGS)
def test_glass_bunny_against_the_oracle(shading):
    """The shipped Fresnel glass bunny (depth 8, no golden). With MODEL.md's offset the
    oracle and our float32 render agree within 1e-3 on at least 95 % of sampled pixels
    (measured 97-99 %: float32 rounding amplified along paths through glass). Against the
    offset → 0 limit (scale-free offsets) ours is within 1e-3 on 97.0 % (classic) and
    97.5 % (physical) of the sampled pixels (71 % / 73 % with the old fixed offset);
    asserted ≥ 95 %."""
    scene = report.load("glass_bunny", shading)
    px = oracle.sample_pixels(scene, 0, N_PIXELS, SEED)
    c = report.compare(scene, 0, px, with_golden=False)     # its golden is 64 px only
    assert np.mean(c["err"]["model_eps"] <= report.TOL) >= 0.95
    assert np.mean(c["err"]["ours_float32"] <= report.TOL) >= 0.95


def test_non_square_film():
    """tan_x = tan_y · width / height: a 160 x 100 film agrees with ours under MODEL.md's
    offset on every sampled pixel."""
    scene = report.load("cornell_sphere", "classic").with_size(160, 100)
    px = oracle.sample_pixels(scene, 1, 150, SEED)
    c = report.compare(scene, 1, px, with_golden=False)
    assert np.all(c["err"]["model_eps"] <= report.TOL)
