"""``whitted export``: a mesh folder of its own per export, no overwrite without --force,
and ``--portable`` XML that plain Mitsuba (no plugin of ours registered) loads and renders
to the same image as the harness's built-ins-only translation."""
from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from renderer.scene import load_scene
from whitted.cli import main

mi = pytest.importorskip("mitsuba")

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"

# A fresh interpreter: nothing of ours imported, no plugin registered.
PLAIN_MITSUBA = """
import sys, numpy as np, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_file(sys.argv[1])
np.save(sys.argv[2], np.array(mi.render(scene, seed=0), np.float32)[..., :3])
"""


def _plain_mitsuba_render(xml: Path, tmp_path: Path) -> np.ndarray:
    out = tmp_path / "plain.npy"
    run = subprocess.run([sys.executable, "-c", PLAIN_MITSUBA, str(xml), str(out)],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    return np.load(out)


def test_two_exports_in_one_folder_keep_their_own_meshes(tmp_path, capsys):
    a, b = tmp_path / "box.xml", tmp_path / "sphere.xml"
    assert main(["export", str(SCENES / "cornell_box.toml"), "--mitsuba-xml", str(a)]) == 0
    box_meshes = {p.name: p.read_bytes() for p in (tmp_path / "box_meshes").iterdir()}
    assert main(["export", str(SCENES / "cornell_sphere.toml"), "--mitsuba-xml", str(b)]) == 0
    assert {p.name: p.read_bytes() for p in (tmp_path / "box_meshes").iterdir()} == box_meshes
    assert 'filename" value="box_meshes/obj0.ply"' in a.read_text()
    assert 'filename" value="sphere_meshes/obj0.ply"' in b.read_text()
    # refused without --force, before anything is written
    xml_before = a.read_bytes()
    capsys.readouterr()
    assert main(["export", str(SCENES / "cornell_sphere.toml"), "--mitsuba-xml", str(a)]) == 4
    assert "--force" in capsys.readouterr().err
    assert a.read_bytes() == xml_before
    assert {p.name: p.read_bytes() for p in (tmp_path / "box_meshes").iterdir()} == box_meshes
    assert main(["export", str(SCENES / "cornell_sphere.toml"), "--mitsuba-xml", str(a),
                 "--force"]) == 0


def test_export_of_a_view_that_does_not_exist_is_a_usage_error(tmp_path, capsys):
    assert main(["export", str(SCENES / "cornell_box.toml"), "--view", "99",
                 "--mitsuba-xml", str(tmp_path / "x.xml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --view") and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_portable_refuses_a_scene_that_needs_our_plugins_and_names_the_parts(tmp_path,
                                                                               capsys):
    assert main(["export", str(SCENES / "glass_bunny.toml"), "--portable",
                 "--mitsuba-xml", str(tmp_path / "g.xml")]) == 2
    err = capsys.readouterr().err
    assert "settings.shading 'classic'" in err and "ambient" in err
    assert "settings.background" in err and "Phong lobe" in err
    assert not any(tmp_path.iterdir())


def test_portable_diffuse_scene_renders_in_plain_mitsuba_like_the_builtin_dict(tmp_path):
    """The XML carries everything: plain Mitsuba renders it to the image of the harness's
    built-ins translation (the same stock plugins, loaded from a dict), and that image
    agrees with ours (converged, same spp) to Monte Carlo error."""
    from reference.mitsuba_scene import render_mitsuba
    from renderer.render import render
    xml = tmp_path / "quad.xml"
    assert main(["export", str(SCENES / "analytic_quad.toml"), "--shading", "physical",
                 "--view", "oblique", "--portable", "--mitsuba-xml", str(xml)]) == 0
    text = xml.read_text()
    assert "whitted" not in text and 'type="direct"' in text and 'type="diffuse"' in text
    plain = _plain_mitsuba_render(xml, tmp_path)
    scene = load_scene(SCENES / "analytic_quad.toml", shading="physical")
    ref = render_mitsuba(scene, view=1, mode="converged", spp=16, seed=0, builtins=True)
    assert plain.shape == ref.shape == (64, 64, 3) and ref.mean() > 0.01
    np.testing.assert_allclose(plain, ref, rtol=1e-5, atol=1e-7)
    ours = render(scene, view=1, backend="llvm", exact=False, spp=16).image
    lit = ref.sum(-1) > 0.01
    assert abs(ours[lit].mean() / ref[lit].mean() - 1) < 0.01


def test_portable_mirror_and_glass_map_to_conductor_dielectric_and_path(tmp_path):
    """Mirrors and Fresnel glass have stock BSDFs; the Whitted tree has no stock
    integrator, so the export uses 'path' and says how that differs."""
    from reference.mitsuba_scene import export_xml, portable_integrator, portable_problems
    from renderer.render import render
    s = load_scene(SCENES / "cornell_box.toml", shading="physical").with_size(48, 48)
    z = np.zeros(3)
    mats = []
    for m in s.materials:
        if m.name == "mirror":
            m = replace(m, kd=z, ks=z, ka=z)
        elif m.name == "glass":
            m = replace(m, kd=z, ks=z, ka=z, k_refl=np.ones(3), k_refr=np.ones(3),
                        combination="fresnel")
        else:
            m = replace(m, ks=z, ka=z)
        mats.append(m)
    s = replace(s, materials=mats, ambient=z).with_settings(background=z)
    assert portable_problems(s) == []
    integrator, note = portable_integrator(s)
    assert integrator["type"] == "path" and "indirect diffuse light" in note
    xml = export_xml(s, tmp_path / "box.xml", spp=16, mode="converged", portable=True)
    text = xml.read_text()
    assert "whitted" not in text
    assert 'type="conductor"' in text and 'type="dielectric"' in text
    plain = _plain_mitsuba_render(xml, tmp_path)
    ours = render(s, backend="llvm", exact=False, spp=16).image
    assert np.all(np.isfinite(plain)) and plain.mean() > 0.01
    # the path tracer adds indirect light: brighter on average, never much darker
    assert plain.mean() > ours.mean()
