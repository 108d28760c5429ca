"""Scene files: the bundled scenes, every validation error class, transforms, normals."""
import warnings
from pathlib import Path

import numpy as np
import pytest

from renderer.scene import SceneError, load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"

# name: (triangles, objects) -- the thesis's counts for its three scenes (SUMMARY.md).
BUNDLED = {"cornell_box": (34, 8), "cornell_sphere": (970, 8), "platonic_solids": (1342, 20),
           "analytic_quad": (2, 1)}


@pytest.mark.parametrize("name", BUNDLED)
@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_bundled_scenes_load_with_stated_counts(name, shading):
    s = load_scene(SCENES / f"{name}.toml", shading=shading)
    tris, objs = BUNDLED[name]
    assert (s.face_count, len(s.objects)) == (tris, objs)
    assert s.name == name and s.settings.shading == shading
    assert len(s.cameras) == 3 and len({c.name for c in s.cameras}) == 3
    assert s.source_files[0] == (SCENES / f"{name}.toml").resolve()
    assert s.vertices.dtype == np.float32 and s.faces.dtype == np.int32
    assert s.normals.dtype == np.float32 and np.all(np.isfinite(s.normals))
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1, atol=1e-6)
    # Contiguous object ranges covering everything.
    assert sum(o.face_count for o in s.objects) == s.face_count
    assert sum(o.vertex_count for o in s.objects) == len(s.vertices)
    for k, o in enumerate(s.objects):
        fr = slice(o.first_face, o.first_face + o.face_count)
        assert np.all(s.face_object[fr] == k) and np.all(s.face_material[fr] == o.material)
        assert s.faces[fr].min() >= o.first_vertex
        assert s.faces[fr].max() < o.first_vertex + o.vertex_count
    for light in s.lights:
        assert light.falloff == ("none" if shading == "classic" else "inverse_square")


@pytest.mark.parametrize("name", ["cornell_box", "cornell_sphere", "platonic_solids"])
def test_seed_scenes_have_closed_glass_and_mirrors_and_free_lights(name):
    s = load_scene(SCENES / f"{name}.toml")
    assert any(m.reflective and not m.transmissive for m in s.materials)
    glass = [o for o in s.objects if s.materials[o.material].transmissive]
    assert glass
    for o in glass:                             # closed: every edge used twice
        f = s.faces[o.first_face:o.first_face + o.face_count]
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        # weld by position (flat objects may repeat positions)
        pos = s.vertices[e.reshape(-1)].reshape(-1, 2, 3)
        key = np.unique(pos.reshape(len(pos), 6), axis=0, return_counts=True)[1]
        assert np.all(key == 2), f"{o.name} is not closed"
    # Lights are at least 1e-3 away from every triangle (closest point on the triangle).
    v = s.vertices.astype(np.float64)
    for light in s.lights:
        assert min_distance_to_triangles(light.position, v[s.faces]) > 1e-3


def min_distance_to_triangles(p, tri):
    """Exact distance from point p (3,) to the nearest of triangles tri (F, 3, 3)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("ij,ij->i", p - a, n)
    q = p - h[:, None] * n                       # projection onto each plane
    inside = np.ones(len(tri), bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, q - u), n) >= 0
    d = np.where(inside, np.abs(h), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):      # otherwise: nearest point on an edge
        e = v - u
        t = np.clip(np.einsum("ij,ij->i", p - u, e) / np.einsum("ij,ij->i", e, e), 0, 1)
        d = np.minimum(d, np.linalg.norm(u + t[:, None] * e - p, axis=1))
    return float(d.min())


def test_point_triangle_distance_helper():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    assert np.isclose(min_distance_to_triangles(np.array([0.2, 0.2, 0.5]), tri), 0.5)
    assert np.isclose(min_distance_to_triangles(np.array([2.0, 0.0, 0.0]), tri), 1.0)
    assert np.isclose(min_distance_to_triangles(np.array([1.0, 1.0, 0.0]), tri), np.sqrt(0.5))


def test_physical_table_scales_lights_and_replaces_ambient():
    classic = load_scene(SCENES / "cornell_box.toml")
    physical = load_scene(SCENES / "cornell_box.toml", shading="physical")
    np.testing.assert_allclose(physical.lights[0].intensity, classic.lights[0].intensity * 7.0)
    assert np.all(classic.ambient > 0) and np.all(physical.ambient == 0)


# ---- validation ------------------------------------------------------------------------------
BASE = """
ambient = 0.1
[render]
max_depth = 5
[camera]
fov_y = 40.0
resolution = [16, 16]
[[views]]
name = "front"
position = [0.0, 1.0, 4.0]
target = [0.0, 0.0, 0.0]
[[lights]]
position = [0.0, 2.0, 0.0]
intensity = 1.0
[materials.white]
kd = 0.5
[materials.glass]
k_refr = 0.9
ior = 1.5
[[objects]]
name = "floor"
shape = "quad"
material = "white"
scale = 2.0
[[objects]]
name = "ball"
shape = "sphere"
frequency = 2
material = "glass"
translate = [0.0, 1.0, 0.0]
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def edit(old, new):
    assert old in BASE, old
    return BASE.replace(old, new, 1)


TRI_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
BAD_CASES = {   # id: (scene text, extra files, field named, words expected in the message)
    "toml_syntax": (BASE + "\n[render\n", {}, "line", "TOML syntax"),
    "unknown_top_key": ("ambiant = 1\n" + BASE, {}, "ambiant", "did you mean 'ambient'"),
    "unknown_render_key": (edit("max_depth = 5", "max_dept = 5"), {}, "render.max_dept",
                           "max_depth"),
    "unknown_material_key": (edit("kd = 0.5", "kdd = 0.5"), {}, "materials.white.kdd", "'kd'"),
    "unknown_object_key": (edit('scale = 2.0', 'scael = 2.0'), {}, "objects[0].scael", "scale"),
    "unknown_view_key": (edit('name = "front"', 'nmae = "front"'), {}, "views[0].nmae", "name"),
    "unknown_light_key": (edit("intensity = 1.0", "intensity = 1.0\npower = 2"), {},
                          "lights[0].power", "unknown key"),
    "unknown_shape_param": (edit('shape = "quad"', 'shape = "quad"\nfrequency = 2'), {},
                            "objects[0].frequency", "unknown key"),
    "wrong_type_colour": (edit("kd = 0.5", 'kd = "white"'), {}, "materials.white.kd",
                          "number or an array of 3"),
    "wrong_length_vector": (edit("position = [0.0, 2.0, 0.0]", "position = [0.0, 2.0]"), {},
                            "lights[0].position", "array of 3"),
    "bool_as_number": (edit("max_depth = 5", "max_depth = true"), {}, "render.max_depth",
                       "integer"),
    "missing_material": (edit('material = "white"\n', ""), {}, "objects[0].material", "missing"),
    "missing_position": (edit("position = [0.0, 1.0, 4.0]\n", ""), {}, "views[0].position",
                         "missing"),
    "missing_intensity": (edit("intensity = 1.0\n", ""), {}, "lights[0].intensity", "missing"),
    "mesh_and_shape": (edit('shape = "quad"', 'shape = "quad"\nmesh = "m.obj"'), {},
                       "objects[0]", "exactly one"),
    "missing_mesh_file": (edit('shape = "quad"', 'mesh = "nope.obj"'), {}, "objects[0].mesh",
                          "not found"),
    "unsupported_mesh_format": (edit('shape = "quad"', 'mesh = "m.stl"'), {"m.stl": "solid"},
                                "objects[0].mesh", "unsupported mesh format"),
    "mesh_index_out_of_range": (edit('shape = "quad"', 'mesh = "m.obj"'),
                                {"m.obj": TRI_OBJ + "f 1 2 9\n"}, "objects[0].mesh", "m.obj:5"),
    "mesh_nan": (edit('shape = "quad"', 'mesh = "m.obj"'),
                 {"m.obj": "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}, "objects[0].mesh",
                 "non-finite"),
    "nan_in_scene": (edit("kd = 0.5", "kd = nan"), {}, "materials.white.kd", "finite"),
    "inf_in_vector": (edit("translate = [0.0, 1.0, 0.0]", "translate = [0.0, inf, 0.0]"), {},
                      "objects[1].translate[1]", "finite"),
    "fov_zero": (edit("fov_y = 40.0", "fov_y = 0.0"), {}, "camera.fov_y", "> 0"),
    "fov_180": (edit("fov_y = 40.0", "fov_y = 180"), {}, "camera.fov_y", "< 180"),
    "resolution_zero": (edit("resolution = [16, 16]", "resolution = [16, 0]"), {},
                        "camera.resolution[1]", ">= 1"),
    "resolution_shape": (edit("resolution = [16, 16]", "resolution = 16"), {},
                         "camera.resolution", "[width, height]"),
    "ior_zero": (edit("ior = 1.5", "ior = 0.0"), {}, "materials.glass.ior", "> 0"),
    "negative_coefficient": (edit("kd = 0.5", "kd = [0.5, -0.1, 0.5]"), {},
                             "materials.white.kd", "non-negative"),
    "negative_intensity": (edit("intensity = 1.0", "intensity = -1.0"), {},
                           "lights[0].intensity", "non-negative"),
    "n_zero": (edit("kd = 0.5", "kd = 0.5\nn = 0"), {}, "materials.white.n", "> 0"),
    "unknown_material_ref": (edit('material = "white"', 'material = "whit"'), {},
                             "objects[0].material", "did you mean 'white'"),
    "unknown_shape": (edit('shape = "quad"', 'shape = "torus"'), {}, "objects[0].shape",
                      "expected one of"),
    "unknown_shading": (edit("max_depth = 5", 'shading = "phong"'), {}, "render.shading",
                        "'classic', 'physical'"),
    "unknown_falloff": (edit("intensity = 1.0", 'intensity = 1.0\nfalloff = "linear"'), {},
                        "lights[0].falloff", "inverse_square"),
    "unknown_combination": (edit("ior = 1.5", 'ior = 1.5\ncombination = "schlick"'), {},
                            "materials.glass.combination", "fresnel"),
    "spp_not_square": (edit("max_depth = 5", "spp = 8"), {}, "render.spp", "perfect square"),
    "exact_with_spp": (edit("max_depth = 5", "spp = 4\nexact = true"), {}, "render.exact",
                       "spp = 4"),
    "negative_depth": (edit("max_depth = 5", "max_depth = -1"), {}, "render.max_depth", ">= 0"),
    "unknown_spawn": (edit("max_depth = 5", 'spawn = "pbrt"'), {}, "render.spawn",
                      "'scale-free', 'mitsuba'"),
    "spawn_with_ray_epsilon": (edit("max_depth = 5", 'spawn = "mitsuba"\nray_epsilon = 1e-4'),
                               {}, "render.spawn", "exclude each other"),
    "scale_free_with_ray_epsilon": (edit("max_depth = 5",
                                         'spawn = "scale-free"\nray_epsilon = 1e-4'),
                                    {}, "render.spawn", "exclude each other"),
    "sphere_frequency_past_memory": (edit("frequency = 2", "frequency = 1000000"),
                                     {}, "objects[1].frequency", "2e+13 triangles, about"),
    "sphere_subdivisions_past_memory": (edit("frequency = 2",
                                             "subdivisions = 40"),
                                        {}, "objects[1].subdivisions", "GB to render"),
    "subdivide_past_memory": (edit("frequency = 2",
                                   "frequency = 300\nsubdivide = 4"), {}, "objects[1].subdivide",
                              "subdivide = 4 of 1,800,000 triangles makes"),
    "singular_scale": (edit("scale = 2.0", "scale = [2.0, 0.0, 2.0]"), {}, "objects[0].scale",
                       "singular"),
    "singular_matrix": (edit("scale = 2.0", "matrix = [[1,0,0,0],[0,0,0,0],[0,0,1,0],[0,0,0,1]]"),
                        {}, "objects[0].matrix", "singular"),
    "projective_matrix": (edit("scale = 2.0", "matrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,1,0,1]]"),
                          {}, "objects[0].matrix[3]", "affine"),
    "matrix_and_scale": (edit("scale = 2.0",
                              "scale = 2.0\nmatrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"),
                         {}, "objects[0].matrix", "not both"),
    "all_degenerate": (edit('shape = "quad"', 'mesh = "m.obj"'),
                       {"m.obj": "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"}, "objects[0]",
                       "no triangles"),
    "physical_with_none": (edit("intensity = 1.0", 'intensity = 1.0\nfalloff = "none"')
                           .replace("max_depth = 5", 'shading = "physical"'), {},
                           "lights[0].falloff", "inverse_square"),
    "duplicate_object_name": (edit('name = "ball"', 'name = "floor"'), {}, "objects[1].name",
                              "duplicate"),
    "up_parallel": (edit('name = "front"', 'name = "front"\nup = [0.0, -1.0, -4.0]'), {},
                    "views[0].up", "parallel"),
    "views_not_tables": (BASE.replace("[[views]]", "[views.x]"), {}, "views",
                         "array of tables"),
}


@pytest.mark.parametrize("case", BAD_CASES)
def test_malformed_scene_raises_one_clear_error(tmp_path, case):
    text, files, fieldname, words = BAD_CASES[case]
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    p = write(tmp_path, text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SceneError) as e:
            load_scene(p)
    msg = str(e.value)
    assert msg.startswith(str(p)), msg
    assert fieldname in msg and words in msg, msg


def test_base_scene_is_valid(tmp_path):
    s = load_scene(write(tmp_path, BASE))
    assert s.face_count == 2 + 80 and s.settings.exact and s.settings.spp == 1
    assert s.cameras[0].width == 16 and s.cameras[0].fov_y == 40.0
    assert s.objects[1].smooth and not s.objects[0].smooth     # spheres default smooth


def test_spawn_setting_reaches_the_render_settings(tmp_path):
    assert load_scene(write(tmp_path, BASE)).settings.spawn == "scale-free"
    p = write(tmp_path, edit("max_depth = 5", 'spawn = "mitsuba"'), "m.toml")
    assert load_scene(p).settings.spawn == "mitsuba"


def test_spp_implies_converged_mode(tmp_path):
    s = load_scene(write(tmp_path, edit("max_depth = 5", "spp = 16")))
    assert s.settings.spp == 16 and not s.settings.exact


def test_scene_without_lights_is_allowed(tmp_path):
    text = BASE.replace("[[lights]]\nposition = [0.0, 2.0, 0.0]\nintensity = 1.0\n", "")
    assert load_scene(write(tmp_path, text)).lights == []


def test_degenerate_triangles_dropped_with_warning(tmp_path):
    (tmp_path / "m.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 1 0 0\n"
        "f 1 2 3\nf 1 2 4\nf 2 5 3\nf 1 3 3\n")   # collinear, coincident corners, repeated index
    p = write(tmp_path, edit('shape = "quad"', 'mesh = "m.obj"'))
    with pytest.warns(UserWarning, match=r"objects\[0\].*'floor'.*dropped 3 zero-area"):
        s = load_scene(p)
    o = s.objects[0]
    assert o.face_count == 1 and o.vertex_count == 3     # unused vertices compacted away
    assert np.all(np.isfinite(s.normals))
    assert (tmp_path / "m.obj").resolve() in s.source_files


def test_views_inherit_camera_defaults_and_override(tmp_path):
    text = BASE + '\n[[views]]\nname = "side"\nposition = [4.0, 1.0, 0.0]\n' \
                  'target = [0.0, 0.0, 0.0]\n' \
                  'resolution = [32, 8]\n'
    s = load_scene(write(tmp_path, text))
    assert [c.name for c in s.cameras] == ["front", "side"]
    assert (s.cameras[0].width, s.cameras[0].height) == (16, 16)
    assert (s.cameras[1].width, s.cameras[1].height) == (32, 8)
    assert s.cameras[1].fov_y == 40.0
    np.testing.assert_array_equal(s.cameras[1].up, [0, 1, 0])


# ---- transforms ------------------------------------------------------------------------------
def one_object(tmp_path, transform, shape="box", extra=""):
    text = f"""
[camera]
position = [0.0, 0.0, 5.0]
target = [0.0, 0.0, 0.0]
[materials.m]
kd = 0.5
[[objects]]
shape = "{shape}"
material = "m"
{transform}
{extra}
"""
    return load_scene(write(tmp_path, text))


def test_transform_scale_then_rotate_then_translate(tmp_path):
    s = one_object(tmp_path, "scale = [2.0, 1.0, 1.0]\nrotate = [0.0, 0.0, 90.0]\n"
                             "translate = [10.0, 0.0, 0.0]")
    lo, hi = s.bounds()
    # x-extent 2 rotated by 90 deg about z becomes the y-extent, then shifted by +10 in x.
    np.testing.assert_allclose(lo, [9.5, -1.0, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi, [10.5, 1.0, 0.5], atol=1e-6)


def test_rotation_order_is_x_then_y_then_z(tmp_path):
    # The quad's normal +y: 90 about x -> +z, then 90 about y -> +x, then 90 about z -> +y.
    for rot, expected in [([90, 0, 0], [0, 0, 1]), ([90, 90, 0], [1, 0, 0]),
                          ([90, 90, 90], [0, 1, 0]), ([0, 0, 90], [-1, 0, 0])]:
        s = one_object(tmp_path, f"rotate = {rot}", shape="quad")
        v = s.vertices[s.faces[0]].astype(np.float64)
        n = np.cross(v[1] - v[0], v[2] - v[0])
        np.testing.assert_allclose(n / np.linalg.norm(n), expected, atol=1e-6)


def test_matrix_matches_translate_rotate_scale(tmp_path):
    a = np.radians(30)
    m = [[2 * np.cos(a), 0, 2 * np.sin(a), 1], [0, 2, 0, 2], [-2 * np.sin(a), 0, 2 * np.cos(a), 3],
         [0, 0, 0, 1]]
    s1 = one_object(tmp_path, f"matrix = {np.array(m).tolist()}")
    s2 = one_object(tmp_path, "scale = 2.0\nrotate = [0.0, 30.0, 0.0]\ntranslate = [1.0, 2.0, 3.0]")
    np.testing.assert_allclose(s1.vertices, s2.vertices, atol=1e-5)


def signed_volume(s):
    v = s.vertices.astype(np.float64)
    f = s.faces
    return np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6


def test_mirroring_keeps_winding_outward_and_flip_normals_reverses(tmp_path):
    assert np.isclose(signed_volume(one_object(tmp_path, "scale = [-1.0, 2.0, 3.0]")), 6, rtol=1e-5)
    flipped = one_object(tmp_path, "scale = 2.0", extra="flip_normals = true")
    assert np.isclose(signed_volume(flipped), -8, rtol=1e-5)


def test_smooth_sphere_normals_are_radial(tmp_path):
    s = one_object(tmp_path, "scale = 3.0\ntranslate = [1.0, 2.0, 3.0]", shape="sphere",
                   extra="frequency = 3")
    radial = s.vertices.astype(np.float64) - [1, 2, 3]
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", radial, s.normals)
    assert cos.min() > 0.995       # averaged face normals of a geodesic sphere


def test_vertex_normals_weld_duplicate_positions(tmp_path):
    # Two triangles forming a tent, with the ridge vertices duplicated (unwelded seam).
    (tmp_path / "m.obj").write_text(
        "v 0 0 0\nv 0 0 1\nv -1 -1 0\nv 0 0 0\nv 0 0 1\nv 1 -1 0\n"
        "f 1 2 3\nf 5 4 6\n")
    text = ("[camera]\nposition = [0.0, 0.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\n"
            "[materials.m]\nkd = 0.5\n[[objects]]\nmesh = \"m.obj\"\nmaterial = \"m\"\n")
    s = load_scene(write(tmp_path, text))
    n = s.normals.astype(np.float64)
    fn = []
    for f in s.faces:
        v = s.vertices[f].astype(np.float64)
        c = np.cross(v[1] - v[0], v[2] - v[0])
        fn.append(c / np.linalg.norm(c))
    ridge = (n[s.faces[0, 0]] + 0)          # shared-position vertex: average of both faces
    expected = (fn[0] + fn[1]) / np.linalg.norm(fn[0] + fn[1])
    np.testing.assert_allclose(ridge, expected, atol=1e-6)
    np.testing.assert_allclose(n[s.faces[0, 2]], fn[0], atol=1e-6)   # corner: own face only
