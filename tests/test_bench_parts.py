"""The timing study as a registry of parts: every part has a name, a result key and its own
markdown; the stored results render to the stored reports; a part measures what it says."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.bench import PARTS, markdown, run
from evaluation.bench.throughput import ray_throughput
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def test_parts_have_unique_names_and_keys_in_study_order():
    assert list(PARTS) == ["throughput", "seed", "whitted", "peer", "effects", "build"]
    assert [p.key for p in PARTS.values()] == ["throughput", "seed_table", "whitted", "peer",
                                               "effects", "build"]
    assert all(name == p.name for name, p in PARTS.items())


@pytest.mark.parametrize("stored", sorted(ROOT.glob("results/**/bench-*.json")),
                         ids=lambda p: str(p.parent.relative_to(ROOT / "results")))
def test_stored_results_render_to_the_stored_markdown(stored):
    assert markdown(json.loads(stored.read_text())) == stored.with_suffix(".md").read_text()


def test_build_part_renders_its_stored_rows():
    from evaluation.bench.build import markdown as build_markdown
    rows = json.loads((ROOT / "results/cpu/build/bench-llvm.json").read_text())["build"]
    text = "\n".join(build_markdown(rows))
    assert "Time to first image" in text and all(r["scene"] in text for r in rows)


def test_timed_processes_read_compiled_bytecode_even_where_it_is_turned_off(tmp_path,
                                                                            monkeypatch):
    """The time-to-first-image processes run as an installed package does, from bytecode:
    the environment they get writes it (to the part's own folder) although the caller's
    ``PYTHONDONTWRITEBYTECODE`` says not to."""
    import subprocess
    import sys

    from evaluation.bench.build import _process_env
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    env = _process_env(tmp_path / "cache", tmp_path / "pyc")
    assert env["WHITTED_CACHE"] == str(tmp_path / "cache")
    subprocess.run([sys.executable, "-c", "import evaluation.bench.part"], env=env,
                   cwd=ROOT, check=True)
    assert list((tmp_path / "pyc").rglob("part.*.pyc"))


def test_median_process_is_the_middle_run_with_its_own_breakdown():
    from evaluation.bench.build import _median_process
    runs = [(3.0, {"load": 3}), (1.0, {"load": 1}), (2.0, {"load": 2})]
    assert _median_process(runs) == (2.0, {"load": 2})


def test_unknown_part_is_refused_before_anything_runs(tmp_path):
    with pytest.raises(ValueError, match="unknown.*'sed'"):
        run(tmp_path / "out", backend="llvm", parts=("sed",))
    assert not (tmp_path / "out").exists()


def test_throughput_rays_agree_with_mitsuba_on_a_small_batch():
    res = ray_throughput(load_scene(ROOT / "scenes/cornell_box.toml"), backend="llvm",
                         width=40, height=24, repeats=1)
    assert res["rays"] == 40 * 24
    agree = res["primary_agreement"]
    assert agree["hits"] > res["rays"] // 2 and agree["hit_miss_agree"] > 0.99
    assert agree["same_triangle"] > 0.95 and agree["t_rel_1e-4"] > 0.99
    assert res["shadow_agreement"] > 0.95
    for k in ("ours_primary", "mitsuba_primary", "ours_shadow", "mitsuba_shadow"):
        assert res[k]["kernel_ms"] >= 0 and res[k]["repeats"] == 1
    # the incoherent and reflection batches: the same rays for both, closest and any hit
    for batch in ("incoherent", "reflection"):
        b = res["batches"][batch]
        assert b["rays"] > res["rays"] // 2
        assert b["closest"]["agreement"]["hit_miss_agree"] > 0.99
        assert b["closest"]["agreement"]["same_triangle"] > 0.95
        assert b["any"]["agreement"]["same_answer"] > 0.99
        assert set(b["closest"]["ms"]) == {"bvh", "bvh4", "bvh8", "bvh4+sort", "bvh4+refill",
                                           "bvh-ploc", "bvh4-ploc", "mitsuba"}
        assert all(b["closest"]["variants_bitwise_equal"].values())
    steps = res["batches"]["primary"]["closest"]["steps"]
    assert steps["bvh4"]["node"] < steps["bvh"]["node"]


def test_throughput_times_the_bvh_without_spatial_splits_where_they_cut(monkeypatch):
    """Where the default build cuts references (spatial splits), the ``bvh-nosplit``
    contender (a BVH built without them) runs on every batch and finds the same hits (t and
    face)."""
    import renderer.accel.bvh_build as bvh_build
    monkeypatch.setattr(bvh_build, "SPATIAL_MIN_TRIANGLES", 16)
    monkeypatch.setattr(bvh_build, "SPATIAL_MIN_REFS", 8)
    res = ray_throughput(load_scene(ROOT / "scenes/platonic_solids.toml"), backend="llvm",
                         width=32, height=20, repeats=1, steps=False)
    assert "bvh-nosplit" in res["variants"]
    assert res["build"]["references"] > res["triangles"]
    assert res["build"]["bvh-nosplit"]["references"] == res["triangles"]
    for batch, b in res["batches"].items():
        for q in ("closest", "any"):
            if q in b:
                assert "bvh-nosplit" in b[q]["ms"], (batch, q)
                assert b[q]["variants_bitwise_equal"]["bvh-nosplit"], (batch, q)


def test_throughput_reports_every_row_over_the_device_tree_too():
    """Every batch and query is timed over the PLOC tree as well (binary and 4-wide), with
    the same hits as the SAH tree's, and the part's markdown has the both-trees table with
    one line per row and the two trees' SAH costs."""
    from evaluation.bench.throughput import markdown
    res = ray_throughput(load_scene(ROOT / "scenes/platonic_solids.toml"), backend="llvm",
                         width=32, height=20, repeats=1, steps=False)
    res["scene"] = "platonic_solids"
    assert {"bvh-ploc", "bvh4-ploc"} <= set(res["variants"])
    assert res["build"]["ploc"]["sah_cost"] > 0
    rows = 0
    for batch, b in res["batches"].items():
        for q in ("closest", "any"):
            if q in b:
                rows += 1
                for v in ("bvh-ploc", "bvh4-ploc"):
                    assert b[q]["ms"][v]["mrays_per_s"] > 0, (batch, q, v)
                    assert b[q]["variants_bitwise_equal"][v], (batch, q, v)
    text = "\n".join(markdown([res]))
    both = text.split("Both trees, every row")[1].split("\n\n#")[0]
    lines = [ln for ln in both.splitlines() if ln.startswith("| platonic_solids")]
    assert len(lines) == rows == 7
    assert f"{res['build']['ploc']['sah_cost']:.2f}" in lines[0]


def test_interrupted_run_keeps_the_rows_saved_so_far(tmp_path, monkeypatch):
    """A part that saves a row and is then cut off (Ctrl-C, ``timeout -s INT``): the row is
    on disk as soon as it is saved (a run killed outright keeps it), and the result files
    hold it and say where the run was interrupted."""
    import evaluation.bench as bench
    from evaluation.bench.part import Part

    def cut_off(ctx):
        ctx.save_rows([{"n": 1}])
        on_disk = json.loads((tmp_path / "bench-llvm.json").read_text())
        assert on_disk["fake"] == [{"n": 1}] and "interrupted" not in on_disk
        raise KeyboardInterrupt

    fake = Part(name="fake", key="fake", run=cut_off,
                markdown=lambda rows: [f"rows: {len(rows)}", ""])
    monkeypatch.setattr(bench, "PARTS", {"fake": fake})
    monkeypatch.setattr(bench, "device_info", lambda backend: {"backend": backend})
    with pytest.raises(KeyboardInterrupt):
        bench.run(tmp_path, backend="llvm", parts=("fake",))
    saved = json.loads((tmp_path / "bench-llvm.json").read_text())
    assert saved["fake"] == [{"n": 1}] and saved["interrupted"] == "in part fake"
    md = (tmp_path / "bench-llvm.md").read_text()
    assert "Interrupted in part fake" in md and "rows: 1" in md


def _closest_float64(V, F, o, d):
    """float64 brute-force closest ``t`` (inf: miss) of rays (o, d) against triangles
    ``V[F]``: Möller–Trumbore without slack, hits with t > 0 (our (0, t_max) contract)."""
    P = V[F].astype(np.float64)
    o, d = o.astype(np.float64), d.astype(np.float64)
    best = np.full(len(o), np.inf)
    for p0, p1, p2 in P:
        e1, e2 = p1 - p0, p2 - p0
        p = np.cross(d, e2)
        det = p @ e1
        s = o - p0
        q = np.cross(s, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v, t = (s * p).sum(1) / det, (d * q).sum(1) / det, (q @ e2) / det
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        best = np.where(hit & (t < best), t, best)
    return best


def test_reflection_batch_hit_or_miss_is_the_float64_answer():
    """The throughput study's reflection batch of the Cornell box (40x24 primary hits,
    origins 1e-4 x diagonal off the surface): our hit/miss is the float64 answer for every
    ray, as Embree's default mode's is. 11 of these 576 rays truly hit an adjacent wall at
    t = 2e-7 ... 6e-7 (origins a float32 ulp from it); the watertight routine once dropped
    them (its t > 0 test used pbrt-v4's deltaT, which grows with the triangle's extent along
    the ray): 1.9 % disagreement. Mitsuba's robust Embree mode
    (``embree_use_robust_intersections``) differs by design on the rays whose origin lies
    exactly on a wall's plane (the ceiling's corner hit moved along the ceiling's normal):
    it reports a hit at t = 0 (its interval [tnear, tfar] is closed), ours and float64 keep
    t > 0; measured 9 rays."""
    import drjit as dr
    import mitsuba as mi

    from evaluation.bench.throughput import primary_rays_host, reflection_rays_host
    from reference import mitsuba_variant
    from reference.mitsuba_scene import rays
    from renderer.accel import Ray, build_accelerator
    from renderer.device import array3, types

    sc = load_scene(ROOT / "scenes/cornell_box.toml")
    t = types("llvm")
    acc = build_accelerator("bvh", sc, t)

    def ours(o, d):
        n = len(o)
        h = acc.intersect(Ray(o=array3(t, o), d=array3(t, d),
                              t_max=t.Float(np.full(n, np.inf, np.float32))),
                          dr.full(t.Bool, True, n))
        order = acc.tris.order.numpy().astype(np.int64)
        face = order[np.minimum(h.prim.numpy(), len(order) - 1)]
        return np.where(h.found.numpy(), h.t.numpy(), np.inf), face

    po, pd = primary_rays_host(sc, 40, 24, t)
    tp, fp = ours(po, pd)
    o, d = reflection_rays_host(sc, po, pd, tp, np.where(np.isfinite(tp), fp, 0))
    truth = np.isfinite(_closest_float64(sc.vertices, sc.faces, o, d))
    hit, _ = ours(o, d)
    assert 0.5 * len(o) < truth.sum() < len(o)
    assert np.array_equal(np.isfinite(hit), truth), f"{np.sum(np.isfinite(hit) != truth)} rays"

    mitsuba_variant("llvm_ad_rgb")
    mesh = mi.Mesh("all", sc.vertices.shape[0], sc.face_count)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(sc.vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(sc.faces, np.uint32).ravel())
    params.update()
    for robust in (False, True):
        ms = mi.load_dict({"type": "scene", "mesh": mesh,
                           "embree_use_robust_intersections": robust})
        pi = ms.ray_intersect_preliminary(rays(o, d), coherent=False)
        t_mi, prim = pi.t.numpy(), pi.prim_index.numpy()
        differ = np.isfinite(t_mi) != truth
        if not robust:
            assert not differ.any(), f"Embree's default mode: {differ.sum()} rays"
            continue
        # every difference: a hit at t = 0 on a plane the origin lies exactly on
        V = sc.vertices.astype(np.float64)
        P = V[sc.faces[prim[differ]]]
        ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        dist = np.einsum("ij,ij->i", o[differ] - P[:, 0], ng)
        assert differ.sum() > 0 and np.all(t_mi[differ] == 0) and np.all(dist == 0), (
            differ.sum(), t_mi[differ], dist)


def test_throughput_run_refuses_bad_input_in_one_line(tmp_path, capsys):
    """``evaluation.bench.throughput_run``: an existing result without --force is one line
    and exit 2 (the file kept); a bad --size or an unknown scene is argparse's one-line
    error (exit 2), before anything is measured."""
    from evaluation.bench import throughput_run
    (tmp_path / "bench-llvm-throughput.json").write_text("keep")
    assert throughput_run.main(["--out", str(tmp_path), "--scenes", str(ROOT / "scenes")]) == 2
    err = capsys.readouterr().err
    assert "exists (pass --force" in err and "Traceback" not in err
    assert (tmp_path / "bench-llvm-throughput.json").read_text() == "keep"
    for bad in (["--size", "64y3"], ["--only", "no_such_scene"]):
        with pytest.raises(SystemExit) as e:
            throughput_run.main(bad + ["--out", str(tmp_path / "new"),
                                       "--scenes", str(ROOT / "scenes")])
        assert e.value.code == 2
        assert bad[0] in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_interleaved_frames_time_each_scene_in_every_round():
    """The build part's frames: each tree's frozen frame timed once per round, the scenes
    in turn; each result is that scene's own image (not its neighbour's), equal to what
    ``frozen_frame_ms`` renders alone, and the median of its rounds."""
    from evaluation.bench.frames import frozen_frame_ms, interleaved_frame_ms
    box = load_scene(ROOT / "scenes/cornell_box.toml").with_size(24, 24)
    sphere = load_scene(ROOT / "scenes/cornell_sphere.toml").with_size(24, 24)
    got = interleaved_frame_ms({"box": box, "sphere": sphere}, backend="llvm", accel=None,
                               frames=2, warmup=1, rounds=3)
    assert list(got) == ["box", "sphere"]
    for label, sc in (("box", box), ("sphere", sphere)):
        r = got[label]
        alone = frozen_frame_ms(sc, backend="llvm", accel=None, frames=1, warmup=0)
        assert np.array_equal(r["image"], alone["image"]) and r["image"].max() > 0.05
        assert len(r["rounds_kernel_ms"]) == 3 and r["frozen_equals_traced"]
        assert r["frozen_kernel_ms"] == float(np.median(r["rounds_kernel_ms"]))
    assert not np.array_equal(got["box"]["image"], got["sphere"]["image"])
