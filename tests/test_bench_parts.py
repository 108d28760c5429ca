"""The timing study as a registry of parts: every part has a name, a result key and its own
markdown; the stored results render to the stored reports; a part measures what it says."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from evaluation.bench import PARTS, markdown, run
from evaluation.bench.throughput import ray_throughput
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def test_parts_have_unique_names_and_keys_in_study_order():
    assert list(PARTS) == ["throughput", "seed", "whitted", "peer", "effects"]
    assert [p.key for p in PARTS.values()] == ["throughput", "seed_table", "whitted", "peer",
                                               "effects"]
    assert all(name == p.name for name, p in PARTS.items())


@pytest.mark.parametrize("stored", sorted(ROOT.glob("results/*/bench-*.json")),
                         ids=lambda p: p.parent.name)
def test_stored_results_render_to_the_stored_markdown(stored):
    assert markdown(json.loads(stored.read_text())) == stored.with_suffix(".md").read_text()


def test_unknown_part_is_refused_before_anything_runs(tmp_path):
    with pytest.raises(ValueError, match="unknown.*'sed'"):
        run(tmp_path / "out", backend="llvm", parts=("sed",))
    assert not (tmp_path / "out").exists()


@pytest.mark.xfail(strict=True, reason=(
    "open (issue 10/12): with the watertight default, ours and Mitsuba/Embree disagree on "
    "hit or miss for 1.9 % of the Cornell box's incoherent rays at 40x24 (0.981 against "
    "0.99; Moller-Trumbore agrees on > 99 %); which side is right is not yet found"))
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
                                           "mitsuba"}
        assert all(b["closest"]["variants_bitwise_equal"].values())
    steps = res["batches"]["primary"]["closest"]["steps"]
    assert steps["bvh4"]["node"] < steps["bvh"]["node"]


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
