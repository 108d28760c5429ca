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
    from evaluation.executor import DaskExecutor
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
