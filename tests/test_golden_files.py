"""Golden files: a missing or stale golden is refused with the command that renders it, an
up-to-date one is not rendered again, a stale one is replaced only with force, and the
committed converged goldens carry their variance layer."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from reference import mitsuba_variant
from reference.golden import GoldenError, load_golden, render_goldens
from renderer.scene import load_scene


def test_missing_and_stale_goldens_name_the_command(tmp_path):
    src = tmp_path / "scenes"
    src.mkdir()
    path = src / "analytic_quad.toml"
    shutil.copy("scenes/analytic_quad.toml", path)
    root = tmp_path / "goldens"
    scene = load_scene(path)
    with pytest.raises(GoldenError,
                       match=r"no golden.*whitted reference --goldens .*analytic_quad\.toml"):
        load_golden(scene, view=0, shading="classic", mode="exact", root=root)
    render_goldens([path], size=16, modes=("exact",), shadings=("classic",), root=root,
                   progress=False)
    g = load_golden(scene, view=0, shading="classic", mode="exact", root=root)
    assert g.image.shape == (16, 16, 3) and g.meta["variant"] == mitsuba_variant()
    assert json.loads(g.path.with_suffix(".json").read_text())["spp"] == 1
    assert render_goldens([path], size=16, modes=("exact",), shadings=("classic",), root=root,
                          progress=False) == []         # up to date: nothing rendered
    path.write_text(path.read_text().replace("\nkd = 0.5", "\nkd = 0.4"))
    with pytest.raises(GoldenError, match=r"stale \(changed since it was rendered: "
                       r"materials\.diffuse\.kd 0\.5 -> 0\.4\).*"
                       r"whitted reference --goldens .* --force"):
        load_golden(load_scene(path), view=0, shading="classic", mode="exact", root=root)
    with pytest.raises(GoldenError, match="pass --force"):
        render_goldens([path], size=16, modes=("exact",), shadings=("classic",), root=root,
                       progress=False)


def test_committed_converged_golden_has_its_variance():
    scene = load_scene("scenes/cornell_box.toml")
    g = load_golden(scene, view=0, shading="classic", mode="converged")
    h, w = g.meta["resolution"][1], g.meta["resolution"][0]
    assert g.image.shape == g.var.shape == (h, w, 3)
    assert g.image.dtype == g.var.dtype == np.float32
    assert np.all(g.var >= 0) and g.var.max() > 0
    assert load_golden(scene, view=0, shading="classic", mode="exact").var is None
