"""What the ray/triangle routine costs: closest-hit throughput of every routine in
``renderer.accel.ROUTINES`` through the same BVH on the throughput bench's identical primary
and incoherent batches, kernel time (median of repeats after warm-up), plus how often the
routines pick the same triangle. The measurement behind ``DEFAULT_ROUTINE``.

    PYTHONPATH=. python lab/probes/routine_cost.py --backend cuda --out DIR    (JSON + markdown)
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import drjit as dr
import numpy as np

from evaluation import wxh
from evaluation.bench.throughput import incoherent_rays_host, primary_rays_host
from renderer.accel import ROUTINES, Ray, build_accelerator
from renderer.device import array3, types
from renderer.outputs import write_text
from renderer.scene import load_scene
from renderer.stats import kernel_ms

SCENES = ("cornell_box", "platonic_solids", "bunny", "sponza", "conference", "bunny_1m")


def measure(scene, backend: str, width: int, height: int, repeats: int) -> list[dict]:
    t = types(backend)
    batches = {"primary": primary_rays_host(scene, width, height, t),
               "incoherent": incoherent_rays_host(scene, width * height)}
    accs = {r: build_accelerator("bvh", scene, t, intersection=r) for r in ROUTINES}
    rows = []
    for name, (o_h, d_h) in batches.items():
        o, d = array3(t, o_h), array3(t, d_h)
        n = o_h.shape[0]
        ray = Ray(o=o, d=d, t_max=dr.full(t.Float, dr.inf, n))
        on = dr.full(t.Bool, True, n)
        prims, row = {}, {"scene": scene.name, "batch": name, "rays": n}
        for r, acc in accs.items():
            def query(acc=acc, ray=ray, on=on):
                h = acc.intersect(ray, on)
                dr.eval(h.t, h.prim, h.found)
            tm = kernel_ms(query, warmup=2, repeats=repeats)
            h = acc.intersect(ray, on)
            order = acc.tris.order.numpy().astype(np.int64)
            prims[r] = np.where(h.found.numpy(), order[h.prim.numpy()], -1)
            row[r] = n / (tm["kernel_ms"] * 1e-3) / 1e6
        ref = prims[next(iter(prims))]
        row["same_triangle"] = min(float(np.mean(p == ref)) for p in prims.values())
        rows.append(row)
    return rows


def markdown(rows: list[dict], device: str) -> str:
    rs = list(ROUTINES)
    lines = [f"# Ray/triangle routine cost on {device}", "",
             "Closest hit through the binary BVH, M rays/s from kernel time (median of repeats).",
             "", "| scene | batch | " + " | ".join(rs) + " | ratio | same triangle |",
             "| --- | --- | " + " | ".join("---:" for _ in rs) + " | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['batch']} | "
                     + " | ".join(f"{r[x]:,.0f}" for x in rs)
                     + f" | {r[rs[-1]] / r[rs[0]]:.2f} | {r['same_triangle']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="lab/probes/routine_cost.py")
    p.add_argument("--backend", default="auto")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", type=wxh, default=(1920, 1080), help="batch WxH")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--scenes", default=",".join(SCENES))
    a = p.parse_args(argv)
    w, h = a.size
    backend = types(a.backend).backend
    from evaluation.bench import device_info
    device = device_info(backend).get("device", backend)
    rows = []
    for name in a.scenes.split(","):
        rows += measure(load_scene(f"scenes/{name}.toml"), backend, w, h, a.repeats)
        print(markdown(rows, device).splitlines()[-1], flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    write_text(a.out / "routine-cost.json", json.dumps({"device": device, "rows": rows},
                                                        indent=1), overwrite=True)
    write_text(a.out / "routine-cost.md", markdown(rows, device), overwrite=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
