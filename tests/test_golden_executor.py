"""Golden rendering through the study's executor (issue 13): the same jobs on Dask worker
processes write the same files, byte for byte, as in this process."""
from __future__ import annotations

import json
import shutil

import pytest

from reference.golden import golden_jobs, render_goldens


def _scene(tmp_path):
    src = tmp_path / "scenes"
    src.mkdir()
    path = src / "analytic_quad.toml"
    shutil.copy("scenes/analytic_quad.toml", path)
    return path


def test_jobs_are_plain_picklable_specs(tmp_path):
    import pickle
    jobs = golden_jobs([_scene(tmp_path)], size=8, converged_size=4,
                       modes=("exact", "converged"), shadings=("classic",), root=tmp_path / "g")
    views = len({j["view"] for j in jobs})          # analytic_quad has several views
    assert views > 1
    assert [j["mode"] for j in jobs] == ["exact"] * views + ["converged"] * views
    assert [j["height"] for j in jobs] == [8] * views + [4] * views
    assert len({j["out"] for j in jobs}) == len(jobs)
    assert pickle.loads(pickle.dumps(jobs)) == jobs
    assert all(type(v) in (str, int, bool) for j in jobs for v in j.values())


def test_dask_workers_write_byte_identical_goldens(tmp_path):
    pytest.importorskip("dask.distributed")
    from evaluation.gate.executor import DaskExecutor
    path = _scene(tmp_path)
    kw = dict(size=16, converged_size=8, spp=8, batches=2, modes=("exact", "converged"),
              shadings=("classic",), progress=False)
    here = render_goldens([path], root=tmp_path / "here", **kw)
    with DaskExecutor(workers=2) as ex:
        there = render_goldens([path], root=tmp_path / "there", executor=ex, **kw)
    assert [p.relative_to(tmp_path / "here") for p in here] == \
        [p.relative_to(tmp_path / "there") for p in there]
    jobs = golden_jobs([path], root=tmp_path / "x", **{k: v for k, v in kw.items()
                                                       if k != "progress"})
    assert len(here) == len(jobs) > 2
    for a, b in zip(here, there):
        assert a.read_bytes() == b.read_bytes(), a.name
        ma, mb = (json.loads(p.with_suffix(".json").read_text()) for p in (a, b))
        ma.pop("date"), mb.pop("date")
        assert ma == mb


class _Recording:
    """An executor (``.map`` yielding ``(index, result)``, out of order like Dask's
    ``as_completed``) that records what it was given; the jobs go through pickle as they
    would to a worker process."""

    name = "recording"

    def __init__(self):
        self.jobs = []

    def map(self, fn, items):
        import pickle
        items = [pickle.loads(pickle.dumps(j)) for j in items]
        self.jobs += items
        for i in reversed(range(len(items))):
            yield i, fn(items[i])


def test_executor_jobs_go_through_the_store_logic(tmp_path):
    """Only what is missing or stale in the chosen store becomes a job; a stale golden is
    refused without force before anything renders and replaced with it; the files are
    format-2 sidecars that the gate's lookup finds."""
    from reference.golden import BUNDLED_STORE, FORMAT, GoldenError, find_golden
    from renderer.scene import load_scene
    path = _scene(tmp_path)
    root = tmp_path / "store"
    kw = dict(size=16, modes=("exact",), shadings=("classic",), progress=False, root=root)
    ex = _Recording()
    written = render_goldens([path], executor=ex, **kw)
    scene = load_scene(path)
    assert len(written) == len(ex.jobs) == len(scene.cameras) > 1
    for v, p in enumerate(written):                    # in job order despite the executor
        assert p == root / scene.name / f"{scene.cameras[v].name}_classic_exact.exr"
        meta = json.loads(p.with_suffix(".json").read_text())
        assert meta["format"] == FORMAT == 2 and meta["content_key"] == ex.jobs[v]["content_key"]
        found = find_golden(scene, view=v, shading="classic", mode="exact", stores=[root])
        assert found.status == "ok" and found.path == p
    assert golden_jobs([path], **{k: v for k, v in kw.items() if k != "progress"}) == []
    assert render_goldens([path], executor=(ex2 := _Recording()), **kw) == []
    assert ex2.jobs == []                              # up to date: nothing sent to workers

    before = {p: p.read_bytes() for p in written}
    path.write_text(path.read_text().replace("\nkd = 0.5", "\nkd = 0.4"))
    with pytest.raises(GoldenError, match="pass --force"):
        render_goldens([path], executor=(ex3 := _Recording()), **kw)
    assert ex3.jobs == [] and all(p.read_bytes() == b for p, b in before.items())
    again = render_goldens([path], executor=(ex4 := _Recording()), force=True, **kw)
    assert again == written and {j["status"] for j in ex4.jobs} == {"stale"}
    assert any(p.read_bytes() != before[p] for p in again)     # kd changed the pixels
    for v in range(len(scene.cameras)):
        assert find_golden(load_scene(path), view=v, shading="classic", mode="exact",
                           stores=[root]).status == "ok"

    with pytest.raises(GoldenError, match="bundled golden store .* read-only"):
        render_goldens([path], executor=(ex5 := _Recording()), size=16, modes=("exact",),
                       shadings=("classic",), progress=False, root=BUNDLED_STORE)
    assert ex5.jobs == []
    with pytest.raises(GoldenError, match="read-only"):
        golden_jobs([path], root=BUNDLED_STORE)


def test_a_job_refuses_a_scene_changed_since_it_was_planned(tmp_path):
    from reference.golden import BUNDLED_STORE, GoldenError, render_golden_job
    path = _scene(tmp_path)
    job = golden_jobs([path], size=8, modes=("exact",), shadings=("classic",),
                      root=tmp_path / "g")[0]
    path.write_text(path.read_text().replace("\nkd = 0.5", "\nkd = 0.4"))
    with pytest.raises(GoldenError, match="changed since the goldens were planned"):
        render_golden_job(job)
    assert not list((tmp_path / "g").rglob("*.exr"))
    bundled = dict(job, root=str(BUNDLED_STORE))
    with pytest.raises(GoldenError, match="read-only"):
        render_golden_job(bundled)
