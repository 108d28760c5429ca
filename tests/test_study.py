"""The accuracy-vs-time study (evaluation.study) on a tiny sweep: the facts its plots rest on.

One tiny sweep (cornell_box at 16 x 16, spp 1/4/16 and every accelerator, 5 seeds) is
run once in-process; the other tests check facts of it, re-run it (resumed, on Dask) and
compare, or render single points.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

# ---- project imports (the one block to rename at merge) ------------------------------------
from evaluation import study
from evaluation.gate.executor import InProcess, make_executor
from renderer.accel import ACCELERATORS
from renderer.render import Renderer

ROOT = Path(__file__).resolve().parents[1]
TINY = replace(study.PROFILES["tiny"], factors=("spp", "accel"), grid=False)
SCENES = ["scenes/cornell_box.toml"]


def _spec(**changes) -> dict:
    spec = {"scene": "scenes/cornell_box.toml", "offset": 0.0, "label": "cornell_box",
            "shading": "classic", "view": 0, "size": 16, "backend": "llvm", "spp": 4,
            "max_depth": 5, "min_weight": 0.01, "precision": "float32",
            "combination": "scene", "intersection": "moller_trumbore", "accel": "bvh",
            "effects": "auto", "seeds": [0, 1, 2, 3, 4]}
    spec.update(changes)
    return spec


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    data = study.run_study(SCENES, out, profile=TINY, show_progress=False, outputs=True,
                           log=lambda *a: None)
    return out, data


def test_sweep_is_complete_and_written(tiny):
    out, data = tiny
    assert not data["meta"]["missing"]
    # default (4 spp, bvh), spp 1 and 16, and every other accelerator
    assert len(data["points"]) == 3 + len(ACCELERATORS) - 1
    for name in ("study.json", "study.md", "index.html", "cornell_box.png", "cornell_box.svg"):
        assert (out / name).exists(), name
    p = next(iter(data["points"].values()))
    assert len(p["seeds"]) >= 5 and p["device"]["backend"] == "llvm"
    for ref in study.REFS:
        assert set(p["errors"][ref]) == set(study.METRICS)
    for k in ("kernel_ms", "frozen_wall_ms", "compile_ms", "first_frame_ms"):
        assert p["timing"][k] >= 0
    assert p["facts"]["frozen_equals_traced"]


def test_more_spp_never_raises_golden_error(tiny):
    _, data = tiny
    line = study.factor_line(data, "cornell_box", "spp")
    assert [p["settings"]["spp"] for p in line] == [1, 4, 16]
    for a, b in zip(line, line[1:]):
        ea, eb = a["errors"]["golden"]["rmse"], b["errors"]["golden"]["rmse"]
        spread = max(ea["max"] - ea["min"], eb["max"] - eb["min"])
        assert eb["mean"] <= ea["mean"] + spread, (a["settings"]["spp"], b["settings"]["spp"])
    assert line[-1]["errors"]["own"]["rmse"]["mean"] < line[0]["errors"]["own"]["rmse"]["mean"]


def test_accelerators_give_the_same_image(tiny):
    _, data = tiny
    line = study.factor_line(data, "cornell_box", "accel")
    assert {p["settings"]["accel"] for p in line} == set(ACCELERATORS)
    assert len({tuple(p["image_sha256"]) for p in line}) == 1


def test_pareto_front_and_tables(tiny):
    _, data = tiny
    pts = study.scene_points(data, "cornell_box")
    front = study.pareto(pts, "own")
    for p in pts:             # nothing on the front is beaten in both time and error
        for q in front:
            assert not (study.time_of(p) < study.time_of(q)
                        and study.err_of(p, "own") < study.err_of(q, "own"))
    default = data["scenes"]["cornell_box"]["default"]
    rows = study.equal_time_rows(pts, default, "own")
    assert rows and all(r["kernel_ms"] <= r["budget_ms"] for r in rows)
    errs = [r["relmse"] for r in rows]
    assert errs == sorted(errs, reverse=True)
    assert "spp" in study.factor_sentences(data, "cornell_box")
    # README block: the device named, one sentence per factor; on LLVM the cost is CPU time
    lines = study.summary_sentences(data)
    assert any(x.startswith("4× spp") and "CPU time" in x for x in lines)
    block = study.readme_section(data, "results/study/x")
    assert data["meta"]["device"]["device"] in block and block.count("\n- ") == len(lines)


def test_load_warning_only_beyond_the_studys_own_threads(tiny):
    """The README block and study.md call the machine shared only when the load average
    exceeds what the study's own render threads make (the core count plus half a core)."""
    import copy
    _, data = tiny
    cores = data["meta"]["device"].get("cores") or 1
    for load, shared in ((cores + 0.1, False), (cores + 2.0, True)):
        d = copy.deepcopy(data)
        for p in d["points"].values():
            p["timing"]["loadavg_1m"] = load
        block = study.readme_section(d, "results/study/x")
        assert ("the machine was shared" in block) == shared
        assert ("Measured under load" in study.markdown(d)) == shared


def test_resumed_sweep_equals_uninterrupted(tiny, tmp_path):
    _, full = tiny
    part = study.run_study(SCENES, tmp_path, profile=TINY, max_points=2, show_progress=False,
                           outputs=False, log=lambda *a: None)
    assert len(part["points"]) == 2 and len(part["meta"]["missing"]) == len(full["points"]) - 2
    resumed = study.run_study(SCENES, tmp_path, profile=TINY, show_progress=False,
                              outputs=False, log=lambda *a: None)
    assert study.strip_timings(resumed) == study.strip_timings(full)
    on_disk = json.loads((tmp_path / "study.json").read_text())
    assert study.strip_timings(on_disk) == study.strip_timings(full)


def test_dask_local_cluster_gives_the_same_json(tiny, tmp_path):
    pytest.importorskip("dask.distributed")
    _, full = tiny
    data = study.run_study(SCENES, tmp_path, profile=TINY, workers=2, show_progress=False,
                           outputs=False, log=lambda *a: None)
    assert data["meta"]["executor"]["workers"] == 2
    assert len({p["pid"] for p in data["points"].values()}) >= 1
    assert study.strip_timings(data) == study.strip_timings(full)


def test_depth_beyond_reachable_changes_nothing(tmp_path):
    # cornell_box without transmission: the mirror block is a closed convex mirror, the only
    # reflector, so nothing is reachable past depth 1.
    text = (ROOT / "scenes/cornell_box.toml").read_text()
    text = text.replace("k_refl = 0.1\nk_refr = 0.85", "k_refl = 0.0\nk_refr = 0.0")
    path = tmp_path / "mirror_box.toml"
    path.write_text(text)
    images = {d: study.render_seeds(_spec(scene=str(path), max_depth=d, seeds=[0, 1]))
              for d in (0, 1, 2, 8)}
    assert images[1][1]["reachable_depth"] == 1
    for d in (2, 8):
        for a, b in zip(images[1][0], images[d][0]):
            assert np.array_equal(a, b), d
    assert not np.array_equal(images[0][0][0], images[1][0][0])


def test_float64_beats_float32_far_from_the_origin():
    errs = {}
    for prec in ("float32", "float64"):
        spec = _spec(offset=1e4, size=32, precision=prec, seeds=[0, 1, 2, 3, 4])
        golden, _ = study.golden_for(spec)
        images, _ = study.render_seeds(spec)
        errs[prec] = np.mean([study.error_metrics(i, golden)["rmse"] for i in images])
    assert errs["float64"] <= errs["float32"]


def test_seed_is_the_settings_seed():
    spec = _spec(seeds=[3])
    images, _ = study.render_seeds(spec)
    sc = study.prepare_scene(spec)
    sc = replace(sc, settings=replace(sc.settings, seed=3))
    img = Renderer(sc, backend="llvm", accel="bvh",
                   intersection=spec["intersection"]).render(0).image
    assert np.array_equal(images[0], img)


def test_golden_box_reduction_and_metrics():
    g = np.random.default_rng(0).random((8, 8, 3))
    small = study.block_mean(g, 2, 2)
    assert small.shape == (2, 2, 3) and np.allclose(small[0, 0], g[:4, :4].mean(axis=(0, 1)))
    m = study.error_metrics(g, g)
    assert m["rmse"] == 0 and m["relmse"] == 0 and m["de2000_mean"] == 0


def test_executors_map_everything():
    items = list(range(5))
    with InProcess() as ex:
        assert sorted(ex.map(abs, items)) == [(i, i) for i in items]
    assert isinstance(make_executor(0), InProcess)


def test_de2000_is_skipped_with_a_note_without_colour_science(monkeypatch):
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "colour" else real(name, *a))
    have, notes = study.metrics_available()
    assert "de2000_mean" not in have and "rmse" in have
    assert len(notes) == 1 and "colour" in notes[0]
    g = np.random.default_rng(1).random((8, 8, 3))
    m = study.error_metrics(g, g * 0.5)
    assert "de2000_mean" not in m and m["rmse"] > 0
    md = study.markdown({"meta": {"metric_notes": notes}, "scenes": {}, "points": {}})
    assert "de2000_mean skipped" in md


def test_gpu_assignment_one_gpu_per_worker_rank():
    from evaluation.gate.executor import gpu_for_worker, visible_gpus
    smi = "GPU 0: NVIDIA H200 (UUID: a)\nGPU 1: NVIDIA H200 (UUID: b)\n" \
          "GPU 2: NVIDIA H200 (UUID: c)\nGPU 3: NVIDIA H200 (UUID: d)\n"
    assert visible_gpus({}, smi) == ["0", "1", "2", "3"]
    assert visible_gpus({}, "") == []
    assert visible_gpus({"CUDA_VISIBLE_DEVICES": "2,5"}, smi) == ["2", "5"]
    assert visible_gpus({"CUDA_VISIBLE_DEVICES": ""}, smi) == []
    gpus = visible_gpus({}, smi)
    assert [gpu_for_worker(r, gpus) for r in range(4)] == ["0", "1", "2", "3"]
    assert [gpu_for_worker(r, ["2", "5"]) for r in range(4)] == ["2", "5", "2", "5"]
    with pytest.raises(ValueError):
        gpu_for_worker(0, [])


def test_dask_workers_each_see_their_own_gpu():
    # No GPU here: fake two and check what each worker process sees before any task runs.
    pytest.importorskip("dask.distributed")
    from evaluation.gate.executor import DaskExecutor
    with DaskExecutor(workers=2, gpus=["0", "1"]) as ex:
        env = ex.worker_env()
        assert sorted(env.items()) == [(0, "0"), (1, "1")]
        assert ex.describe()["gpus"] == ["0", "1"]
        assert sorted(r for _, r in ex.map(_cuda_env, range(2))) in (["0", "1"], ["0", "0"],
                                                                   ["1", "1"])


def _cuda_env(_):
    import os
    return os.environ.get("CUDA_VISIBLE_DEVICES")


def test_report_carries_the_study_page(tiny, tmp_path):
    from evaluation.gate.report import ReportEntry, write_report
    out, _ = tiny
    img = np.zeros((4, 4, 3), np.float32)
    index = write_report(tmp_path / "rep", [ReportEntry("box / front", img, img)], title="t",
                         studies=[out, tmp_path / "not-a-study"])
    text = index.read_text()
    name = out.name
    assert f'href="study/{name}/index.html"' in text and "Accuracy vs time" in text
    for f in ("index.html", "study.json", "study.md", "cornell_box.png", "cornell_box.svg"):
        assert (tmp_path / "rep" / "study" / name / f).read_bytes() == (out / f).read_bytes()
    assert not (tmp_path / "rep" / "study" / name / "cache").exists()
    assert "not-a-study" not in text
    plain = write_report(tmp_path / "rep2", [ReportEntry("x", img, img)], title="t")
    assert "Accuracy vs time" not in plain.read_text()


def test_readme_block_is_replaced_in_place(tiny):
    _, data = tiny
    mark = study.readme_marker("results/study/x")
    text = f"# T\n\nbefore\n{mark}\nold paragraph\nstill old\n\n- old\n  wrapped\n- old\n\nafter\n"
    new = study.update_readme(text, data, "results/study/x")
    assert new.startswith(f"# T\n\nbefore\n{mark}\n") and new.endswith("\n\nafter\n")
    assert "old" not in new and study.readme_section(data, "results/study/x") in new
    assert study.update_readme(new, data, "results/study/x") == new     # idempotent
    with pytest.raises(ValueError):
        study.update_readme("no marker\n", data, "results/study/x")


def test_boxes_are_skipped_on_scenes_with_one_huge_object():
    prof = replace(TINY, factors=("accel",), boxes_max_object_faces=1000)
    specs, scenes = study.build_sweep(["glass_bunny", "cornell_box"], prof)
    accels = {(s["label"], s["accel"]) for s in specs}
    assert ("glass_bunny", "boxes") not in accels and ("cornell_box", "boxes") in accels
    assert any("accel=boxes" in x for x in scenes["glass_bunny"]["skipped"])
