"""Scenes from other tools: the Cornell box OBJ + MTL as shipped (Intel's Embree copy), an MTL
with every ``illum`` model, OBJ ``vn`` normals and smoothing groups, PLY normals and colours,
and Mitsuba XML written the way its tutorials write it, rendered by stock Mitsuba from the
same file and compared with ours under the exact rule."""
from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from renderer.scene import SceneError, load_scene
from renderer.scene.objmtl import ILLUM, read_mtl

# the shared meshes lie beside the repository, as tests/data/imports/*.xml name them
MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"
CORNELL = MESHES / "cornell_box" / "cornell_box.obj"
TEAPOT = MESHES / "utah_teapot" / "teapot.obj"
DATA = Path(__file__).resolve().parent / "data" / "imports"


def _load(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path, **kw)
    return scene, [str(w.message) for w in caught]


# ---- OBJ + MTL -------------------------------------------------------------------------------
def test_cornell_box_obj_gets_its_mtl_materials_object_names_camera_and_light():
    scene, notes = _load(CORNELL)
    names = [o.name for o in scene.objects]
    assert names == ["floor", "light", "ceiling", "back_wall", "green_wall", "red_wall",
                     "short_block", "tall_block"]       # front_wall's faces are commented out
    mats = {m.name: m for m in scene.materials}
    assert set(mats) == {"white", "red", "green", "blue", "light"}
    np.testing.assert_array_equal(mats["red"].kd, [1, 0, 0])
    np.testing.assert_array_equal(mats["light"].ka, [20, 20, 20])
    assert scene.materials[scene.objects[names.index("green_wall")].material].name == "green"
    assert scene.face_count == 36 and not any(o.smooth for o in scene.objects)
    assert sorted(scene.source_files) == sorted([CORNELL.resolve(),
                                                 CORNELL.with_suffix(".mtl").resolve()])
    # the box is open towards -z: the framed camera looks in through the opening
    cam = scene.cameras[0]
    lo, hi = scene.bounds()
    assert cam.position[2] < lo[2] and np.allclose(cam.target, (lo + hi) / 2)
    assert len(scene.lights) == 1 and np.allclose(scene.lights[0].position, cam.position)
    assert any("no camera" in n for n in notes) and any("no light" in n for n in notes)


def test_cornell_box_obj_renders_its_wall_colours():
    from renderer.render import render
    scene = load_scene(CORNELL).with_size(48, 48)
    img = render(scene).image
    red = (img[..., 0] > 5 * img[..., 1]) & (img[..., 0] > 0.05)
    green = (img[..., 1] > 5 * img[..., 0]) & (img[..., 1] > 0.05)
    # seen from -z through the opening: the red wall on the left, the green one on the right
    assert red[:, :16].sum() > 40 and red[:, 32:].sum() == 0
    assert green[:, 32:].sum() > 40 and green[:, :16].sum() == 0
    assert img[24, 24].min() > 0.1                                  # the white back wall
    assert (img.max(-1) > 0).mean() > 0.9          # framed: the box fills the image


MTL_ALL = """# one material per illum model
newmtl m0\nillum 0\nKd 0.5 0.5 0.5
newmtl m1\nillum 1\nKa 0.1 0.1 0.1\nKd 0.5 0.4 0.3\nKs 0.9 0.9 0.9
newmtl m2\nillum 2\nKd 0.5 0.4 0.3\nKs 0.2 0.2 0.2\nNs 50
newmtl m3\nillum 3\nKd 0.1 0.1 0.1\nKs 0.8 0.8 0.8
newmtl m4\nillum 4\nKs 0.1 0.1 0.1\nTf 0.9 0.9 0.9\nNi 1.33
newmtl m5\nillum 5\nKs 0.7 0.7 0.7
newmtl m6\nillum 6\nKs 0.1 0.1 0.1\nd 0.25\nNi 1.5
newmtl m7\nillum 7\nKs 1 1 1\nNi 1.6
newmtl m8\nillum 8\nKs 0.5 0.5 0.5
newmtl m9\nillum 9\nKs 0.2 0.2 0.2\nNi 1.4
newmtl none\nKd 0.2 0.3 0.4\nmap_Kd wood.png
"""


def test_every_illum_model_maps_as_the_table_says(tmp_path):
    p = tmp_path / "all.mtl"
    p.write_text(MTL_ALL)
    mats, notes = read_mtl(p)
    m = {k: (v.kd.tolist(), v.ks.tolist(), v.k_refl.tolist(), v.k_refr.tolist(), v.ior,
             v.combination) for k, v in mats.items()}
    assert m["m0"] == ([0.5] * 3, [0] * 3, [0] * 3, [0] * 3, 1.5, "constant")
    assert m["m1"][1] == [0] * 3 and mats["m1"].ka.tolist() == [0.1] * 3    # no highlight
    assert m["m2"][:2] == ([0.5, 0.4, 0.3], [0.2] * 3) and mats["m2"].n == 50
    assert m["m3"][2] == [0.8] * 3 and m["m3"][3] == [0] * 3
    assert m["m4"][2:] == ([0.1] * 3, [0.9] * 3, 1.33, "constant")
    assert m["m5"][2] == [0.7] * 3 and m["m5"][3] == [0] * 3
    assert m["m6"][3] == [0.75] * 3                       # 1 - d without Tf
    assert m["m7"][2:] == ([1] * 3, [1] * 3, 1.6, "fresnel")
    assert m["m8"][2] == [0.5] * 3 and m["m9"][3] == [1] * 3
    assert m["none"][1] == [0] * 3                        # no illum, no Ks: illum 1
    approximated = {n.split("'")[1] for n in notes if "approximated" in n}
    assert approximated == {f"m{k}" for k, (what, _) in ILLUM.items()
                            if what == "approximates"}
    line = MTL_ALL.splitlines().index("map_Kd wood.png") + 1
    assert any(f"{p}:{line}: 'map_Kd' ignored" in n for n in notes), notes


def test_illum_10_is_refused_with_file_and_line(tmp_path):
    p = tmp_path / "bad.mtl"
    p.write_text("newmtl ok\nKd 1 1 1\nnewmtl ghost\nKd 1 1 1\nillum 10\n")
    with pytest.raises(Exception, match=r"bad\.mtl:5: material 'ghost': illum 10"):
        read_mtl(p)


@pytest.mark.parametrize("mtl, where", [
    ("newmtl a\nKd 1 x 1\n", ":2:"),
    ("Kd 1 1 1\n", ":1:"),
    ("newmtl a\nNs\n", ":2:"),
    ("newmtl a\nKd -1 0 0\n", ":2:"),
    ("newmtl a\nillum 2.5\n", ":2:"),
])
def test_malformed_mtl_lines_name_file_and_line(tmp_path, mtl, where):
    (tmp_path / "m.mtl").write_text(mtl)
    obj = tmp_path / "m.obj"
    obj.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n")
    with pytest.raises(SceneError, match=rf"m\.mtl{where}"):
        load_scene(obj)


def test_missing_mtllib_names_the_obj_line(tmp_path):
    obj = tmp_path / "m.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nmtllib gone.mtl\nf 1 2 3\n")
    with pytest.raises(SceneError, match=r"m\.obj:4: mtllib gone\.mtl: file not found"):
        load_scene(obj)


def test_obj_vn_normals_and_smoothing_groups_are_honoured(tmp_path):
    obj = tmp_path / "n.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                   "vn 0 0 2\nvn 0.6 0 0.8\n"
                   "o with_vn\nf 1//1 2//2 3//2\n"
                   "o smooth\ns 1\nf 1 2 3\ns off\no flat\nf 1 3 4\n")
    scene, _ = _load(obj)
    by = {o.name: o for o in scene.objects}
    assert by["with_vn"].smooth and by["smooth"].smooth and not by["flat"].smooth
    o = by["with_vn"]
    n = scene.normals64[o.first_vertex:o.first_vertex + o.vertex_count]
    v = scene.vertices64[o.first_vertex:o.first_vertex + o.vertex_count]
    for p, expect in (([0, 0, 0], [0, 0, 1]), ([1, 0, 0], [0.6, 0, 0.8])):
        k = int(np.argwhere(np.all(v == p, axis=1))[0, 0])
        np.testing.assert_allclose(n[k], expect, atol=1e-12)


def test_ignored_obj_statements_are_one_warning_each_with_the_line(tmp_path):
    obj = tmp_path / "w.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nl 1 2\nf 1 2 3\nbogus 1\n")
    _, notes = _load(obj)
    assert any(f"{obj}:4: 'vt' ignored (and 1 more)" in n for n in notes), notes
    assert any(f"{obj}:6: 'l' ignored" in n for n in notes)
    assert any(f"{obj}:8: 'bogus' ignored" in n for n in notes)


# ---- PLY -------------------------------------------------------------------------------------
#: A float32 unit normal that normalising in float64 and rounding would move by one ulp.
KEPT = (-0.7905711531639099, 0.5492416620254517, 0.27079683542251587)


def _ply_with_normals_and_colours(path: Path) -> None:
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
            "property float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    rows = [(0, 0, 0, 0, 0, 1, 255, 0, 0), (1, 0, 0, *KEPT, 255, 0, 0),
            (0, 1, 0, 0, 0, 3, 0, 0, 255)]
    body = b"".join(struct.pack("<6f3B", *r) for r in rows) + struct.pack("<B3i", 3, 0, 1, 2)
    path.write_bytes(head.encode() + body)


def test_ply_normals_are_used_and_colours_averaged(tmp_path):
    p = tmp_path / "tri.ply"
    _ply_with_normals_and_colours(p)
    scene, notes = _load(p)
    assert scene.objects[0].smooth
    np.testing.assert_allclose(scene.normals_of(True), [[0, 0, 1], KEPT, [0, 0, 1]], atol=1e-7)
    # a file normal that is unit in float32 keeps its bits (an export read back renders
    # the same image)
    assert scene.normals[1].tolist() == list(KEPT)
    np.testing.assert_allclose(scene.materials[0].kd, [2 / 3, 0, 1 / 3])
    assert any("vertex colours averaged" in n for n in notes)


# ---- Mitsuba XML -----------------------------------------------------------------------------
def test_tutorial_xml_matches_stock_mitsuba_on_the_same_file_under_the_exact_rule():
    """The teapot scene as Mitsuba's tutorials write it (direct integrator, one point light,
    diffuse BSDFs, an OBJ, a rectangle and a cube with to_world transforms, ref ids,
    $parameters): stock Mitsuba's render of the same file, one ray per pixel centre,
    against ours with Mitsuba's spawn rule."""
    pytest.importorskip("mitsuba")
    from evaluation.gate.rules import EXACT_THRESHOLDS, check_exact
    from reference.stock import render_file_exact
    from renderer.render import render
    xml = DATA / "teapot_direct.xml"
    defines = {"teapot": str(TEAPOT), "res": "40"}
    scene, _ = _load(xml, defines=defines)
    assert scene.settings.shading == "physical" and scene.settings.max_depth == 0
    assert [o.name for o in scene.objects] == ["teapot", "floor", "box"]
    assert (scene.cameras[0].width, scene.cameras[0].height) == (40, 40)
    ours = render(scene.with_settings(spawn="mitsuba")).image
    ref = render_file_exact(xml, defines)
    res = check_exact(ours, ref, {k: (t.value,) for k, t in EXACT_THRESHOLDS.items()})
    assert ref.mean() > 0.02 and res["ok"], {k: res[k] for k in ("mean_rel", "max_rel")}


def test_xml_fov_axes_and_matrix_sensor_agree_with_lookat(tmp_path):
    base = (DATA / "teapot_direct.xml").read_text()
    scene_y = _load(DATA / "teapot_direct.xml", defines={"teapot": str(TEAPOT)})[0]
    cam = scene_y.cameras[0]
    # fov 35 on x of a square film is fov_y 35
    assert cam.fov_y == pytest.approx(35.0)
    diag = tmp_path / "d.xml"
    diag.write_text(base.replace('value="x"', 'value="diagonal"').replace(
        "../../../../shared/data/meshes/utah_teapot/teapot.obj", str(TEAPOT)))
    d = _load(diag)[0].cameras[0]
    assert np.tan(np.radians(d.fov_y) / 2) == pytest.approx(np.tan(np.radians(35) / 2)
                                                            / np.sqrt(2))
    # the same view as Mitsuba's look-at matrix (columns left, up, dir, origin)
    left = np.cross([0, 1, 0], cam.target - cam.position)
    m = np.eye(4)
    m[:3, 0] = left / np.linalg.norm(left)
    m[:3, 2] = (cam.target - cam.position) / np.linalg.norm(cam.target - cam.position)
    m[:3, 1], m[:3, 3] = np.cross(m[:3, 2], m[:3, 0]), cam.position
    matrix = tmp_path / "m.xml"
    matrix.write_text(diag.read_text().replace('value="diagonal"', 'value="x"').replace(
        '<lookat origin="1, 5, 11" target="0.2, 1.3, 0" up="0, 1, 0"/>',
        f'<matrix value="{" ".join(map(repr, m.reshape(-1).tolist()))}"/>'))
    mc = _load(matrix)[0].cameras[0]
    np.testing.assert_allclose(mc.position, cam.position)
    d0 = (cam.target - cam.position) / np.linalg.norm(cam.target - cam.position)
    np.testing.assert_allclose(mc.target - mc.position, d0, atol=1e-12)
    np.testing.assert_allclose(np.cross(mc.up, d0), np.cross(cam.up, d0) /
                               np.linalg.norm(np.cross(cam.up, d0)), atol=1e-12)


@pytest.mark.parametrize("edit, message", [
    (("<integrator type=\"direct\"/>", "<integrator type=\"direct\">"), "XML syntax error"),
    (("$teapot", "nope.obj"), "filename: file not found"),
    (("value=\"$res\"", "value=\"$resolution\""), "$resolution: parameter has no value"),
    (("<ref id=\"clay\"/>\n    </shape>", "<ref id=\"loop\"/>\n    </shape>\n"
      "    <bsdf type=\"twosided\" id=\"loop\"><ref id=\"loop2\"/></bsdf>\n"
      "    <bsdf type=\"twosided\" id=\"loop2\"><ref id=\"loop\"/></bsdf>"),
     "a cycle of references"),
    (("<emitter type=\"point\">", "<emitter type=\"area\">"),
     "an area emitter belongs inside a <shape>"),
    (("<integrator type=\"direct\"/>", "<integrator type=\"path\"/>"),
     "refused (with --approximate"),
    (("<rgb name=\"reflectance\" value=\"0.8\"/>",
      "<texture type=\"bitmap\" name=\"reflectance\"/>"), "textures are not supported"),
    (("<ref id=\"clay\"/>", "<ref id=\"clai\"/>"), "no object with that id"),
])
def test_bad_xml_is_one_line_with_file_and_line(tmp_path, edit, message):
    text = (DATA / "teapot_direct.xml").read_text().replace(
        "../../../../shared/data/meshes/utah_teapot/teapot.obj", str(TEAPOT))
    assert edit[0] in text
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(SceneError) as e:
        _load(bad)
    line = str(e.value)
    assert line.startswith(f"{bad}:") and line.split(":")[1].isdigit(), line
    assert message in line and "\n" not in line


def test_path_integrator_renders_as_an_approximation_on_request(tmp_path):
    text = (DATA / "teapot_direct.xml").read_text().replace(
        "<integrator type=\"direct\"/>",
        "<integrator type=\"path\"><integer name=\"max_depth\" value=\"4\"/></integrator>")
    p = tmp_path / "path.xml"
    p.write_text(text)
    scene, notes = _load(p, defines={"teapot": str(TEAPOT)}, approximate=True)
    assert scene.settings.max_depth == 2
    line = next(k for k, t in enumerate(text.splitlines(), 1) if "type=\"path\"" in t)
    assert any(f"{p}:{line}: <integrator type=\"path\"> approximated" in n
               for n in notes), notes


# ---- every format: one entry point, goldens keyed by every file ------------------------------
def test_camera_auto_frames_any_scene():
    scene = load_scene("scenes/bunny.toml", camera="auto")
    assert [c.name for c in scene.cameras] == ["auto"]
    lo, hi = scene.bounds()
    assert np.allclose(scene.cameras[0].target, (lo + hi) / 2)


def test_golden_key_of_an_imported_scene_covers_its_mtl(tmp_path):
    from reference.golden import content_key, golden_inputs
    obj, mtl = tmp_path / "box.obj", tmp_path / "cornell_box.mtl"
    obj.write_text(CORNELL.read_text())
    mtl.write_text(CORNELL.with_suffix(".mtl").read_text())
    scene, _ = _load(obj)
    key = content_key(golden_inputs(scene, view=0, shading="classic", mode="exact"))
    mtl.write_text(mtl.read_text().replace("Kd 1 0 0", "Kd 0.9 0 0"))
    scene2, _ = _load(obj)
    inputs = golden_inputs(scene2, view=0, shading="classic", mode="exact")
    assert content_key(inputs) != key
    assert "renderer/scene/objmtl.py" in inputs["code"]


# ---- scene files naming other tools' files ---------------------------------------------------
def test_scene_file_names_an_obj_with_its_mtl_and_a_ply_with_its_normals(tmp_path):
    for f in ("cornell_box.obj", "cornell_box.mtl"):
        (tmp_path / f).write_bytes((CORNELL.parent / f).read_bytes())
    _ply_with_normals_and_colours(tmp_path / "tri.ply")
    toml = tmp_path / "mixed.toml"
    toml.write_text("""
[camera]
position = [278, 273, -800]
target = [278, 273, 0]
[[lights]]
position = [278, 500, 200]
intensity = 1.0
[materials.grey]
kd = 0.5
[[objects]]
name = "box"
mesh = "cornell_box.obj"
materials = "mtl"
[[objects]]
name = "tri"
mesh = "tri.ply"
material = "grey"
normals = "file"
translate = [278, 100, 200]
""")
    scene, _ = _load(toml)
    direct, _ = _load(tmp_path / "cornell_box.obj")
    box = [o for o in scene.objects if o.name.startswith("box.")]
    assert [o.name for o in box] == [f"box.{o.name}" for o in direct.objects]
    assert [scene.materials[o.material].name for o in box] == \
        [direct.materials[o.material].name for o in direct.objects]
    n = len(direct.vertices)
    np.testing.assert_array_equal(scene.vertices[:n], direct.vertices)
    tri = scene.objects[-1]
    assert tri.name == "tri" and tri.smooth
    np.testing.assert_allclose(scene.normals_of(True)[-3:], [[0, 0, 1], KEPT, [0, 0, 1]],
                               atol=1e-7)
    assert (tmp_path / "cornell_box.mtl").resolve() in scene.source_files
    averaged = toml.read_text().replace('normals = "file"', 'normals = "averaged"')
    toml.write_text(averaged)
    flat = _load(toml)[0]
    np.testing.assert_allclose(flat.normals64[-3:], [[0, 0, 1]] * 3, atol=1e-12)


def test_normals_from_a_file_without_normals_is_one_clear_error(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    toml = tmp_path / "s.toml"
    toml.write_text('[camera]\nposition = [0, 0, 3]\ntarget = [0, 0, 0]\n'
                    '[materials.a]\nkd = 1\n[[objects]]\nmesh = "m.obj"\nmaterial = "a"\n'
                    'normals = "file"\n')
    with pytest.raises(SceneError, match=r"s\.toml: objects\[0\]\.normals: .*'vn'"):
        load_scene(toml)


# ---- round trips -----------------------------------------------------------------------------
def _face_materials(scene) -> np.ndarray:
    """float (F, 17): every face's material parameters (ka, kd, ks, n, k_refl, k_refr, ior,
    fresnel?)."""
    rows = np.array([[*m.ka, *m.kd, *m.ks, m.n, *m.k_refl, *m.k_refr, m.ior,
                      m.combination == "fresnel"] for m in scene.materials])
    return rows[scene.face_material]


@pytest.mark.parametrize("name,shading", [("cornell_box", "classic"),
                                          ("cornell_box", "physical"),
                                          ("cornell_sphere", "classic"),
                                          ("platonic_solids", "physical"),
                                          ("analytic_quad", "classic")])
def test_export_then_import_renders_the_bundled_scene_bit_for_bit(tmp_path, name, shading):
    """``whitted export`` then ``load_scene`` of the XML: the same lights, materials,
    settings and float32 geometry, and the same image bit for bit (the last view: an
    oblique one, whose camera a float32 look-at matrix would not give back exactly)."""
    pytest.importorskip("mitsuba")
    import re

    from renderer.render import render
    from whitted.cli import main
    toml = tmp_path / "s.toml"
    toml.write_text(re.sub(r"resolution = \[\d+, \d+\]", "resolution = [20, 16]",
                           Path(f"scenes/{name}.toml").read_text()))
    scene = load_scene(toml, shading=shading)
    view = len(scene.cameras) - 1
    assert (scene.cameras[view].width, scene.cameras[view].height) == (20, 16)
    xml = tmp_path / "s.xml"
    args = ["export", str(toml), "--mitsuba-xml", str(xml), "--view", str(view)]
    if shading == "physical":
        args += ["--shading", "physical"]
    assert main(args) == 0
    back, _ = _load(xml)
    assert back.settings.shading == shading and back.settings.max_depth == \
        scene.settings.max_depth
    np.testing.assert_array_equal(back.vertices, scene.vertices)
    np.testing.assert_array_equal(back.faces, scene.faces)
    np.testing.assert_array_equal(_face_materials(back), _face_materials(scene))
    a, b = render(scene, view=view).image, render(back).image
    assert a.max() > 0 and np.array_equal(a, b)


@pytest.mark.parametrize("source", ["cornell", "xml", "ply"])
def test_convert_writes_a_toml_that_renders_the_same(tmp_path, capsys, source):
    from renderer.render import render
    from whitted.cli import main
    if source == "cornell":
        src, extra = CORNELL, []
    elif source == "ply":
        src, extra = tmp_path / "tri.ply", []
        _ply_with_normals_and_colours(src)
    else:
        src, extra = DATA / "teapot_direct.xml", ["-D", f"teapot={TEAPOT}", "-D", "res=24"]
    out = tmp_path / "conv.toml"
    assert main(["convert", str(src), str(out), *extra]) == 0
    scene = _load(src, defines=dict(e.split("=", 1) for e in extra[1::2]) or None)[0]
    back = _load(out)[0]
    np.testing.assert_array_equal(back.vertices, scene.vertices)
    np.testing.assert_array_equal(back.normals, scene.normals)
    a = render(scene.with_size(24, 24)).image
    b = render(back.with_size(24, 24)).image
    assert a.max() > 0 and np.array_equal(a, b)
    # nothing replaced without --force
    before = out.read_bytes()
    capsys.readouterr()
    assert main(["convert", str(src), str(out), *extra]) == 4
    assert "--force" in capsys.readouterr().err and out.read_bytes() == before
