"""The mesh-edit twin of the material-edit STALE test (tests/test_check.py): a golden is
looked up by the meshes' bytes too, so moving one vertex of the bunny makes its golden
STALE, and the line names the mesh by its file name."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_moved_vertex_makes_the_golden_stale_naming_the_mesh(tmp_path, capsys):
    pytest.importorskip("mitsuba")
    (tmp_path / "meshes" / "stanford_bunny").mkdir(parents=True)
    ply = tmp_path / "meshes" / "stanford_bunny" / "bun_zipper.ply"
    shutil.copy(ROOT / "scenes" / "meshes" / "stanford_bunny" / "bun_zipper.ply", ply)
    scene = tmp_path / "bunny.toml"
    shutil.copy(ROOT / "scenes" / "bunny.toml", scene)
    store = tmp_path / "goldens"
    pick = ["--view", "front", "--shadings", "classic", "--modes", "exact"]
    assert main(["reference", str(scene), "--goldens", str(store), "--size", "8", "--quiet",
                 *pick[2:]]) == 0
    assert main(["check", str(scene), "--goldens", str(store), *pick]) in (0, 1)
    capsys.readouterr()
    text = ply.read_text()
    head, _, body = text.partition("end_header\n")
    first, _, rest = body.partition("\n")
    x, y, z, *more = first.split()
    moved = " ".join([f"{float(x) + 1e-3:g}", y, z, *more])
    ply.write_text(head + "end_header\n" + moved + "\n" + rest)
    assert main(["check", str(scene), "--goldens", str(store), *pick]) == 4
    stale = [line for line in capsys.readouterr().out.splitlines()
             if line.startswith("STALE")]
    assert len(stale) == 1
    assert "bun_zipper.ply" in stale[0] and "scene file content" not in stale[0]
