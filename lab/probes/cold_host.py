"""Cold host set-up of a first image (issue 24) against the host thread pool's size: for each
scene, the load (``load_scene``, no cache) and the accelerator set-up (``Renderer``: the
tree, then the upload with its host arrays; no cache) with ``renderer.parallel.threads(n)``
for each ``n`` of ``--threads``, median of ``--repeat`` runs (after one warm-up run that
compiles the device kernels), and the check that every array the loader and the
accelerator give is the same bit for bit for every thread count.

    PYTHONPATH=. python lab/probes/cold_host.py --backend cuda
    PYTHONPATH=. python lab/probes/cold_host.py --backend llvm --threads 1 2 --repeat 1
    PYTHONPATH=. python lab/probes/cold_host.py --out a.json      # hashes, for --against
    PYTHONPATH=. python lab/probes/cold_host.py --against a.json  # another build's hashes

Prints one row per scene and thread count: load, tree, upload (``upload_seconds``: the host
arrays and their upload after the tree), load + upload (the host's share), and the whole
set-up. Exits 1 when any array differs between thread counts (or from ``--against``).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import statistics
import sys
import time
from pathlib import Path

import drjit as dr
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from renderer.render import Renderer  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

try:                                      # a build without the pool: one row, its own
    from renderer import parallel  # noqa: E402
except ImportError:
    parallel = None

SCENE_FIELDS = ("vertices", "normals", "vertices64", "normals64", "faces", "face_material",
                "face_object")
ACCEL_FIELDS = ("nodes", "children", "refs", "tri_data", "tri_trav")
TRIS_FIELDS = ("ng", "n0", "n1", "n2", "material", "smooth", "order")


def _digest(x) -> str:
    """SHA-256 prefix of a host array or of a Dr.Jit array's bytes (an Array3f: its three
    components)."""
    if isinstance(x, np.ndarray):
        return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()[:20]
    if not dr.is_array_v(x):
        return repr(x)
    parts = [x.x, x.y, x.z] if dr.size_v(x) == 3 else [x]
    return hashlib.sha256(b"".join(np.ascontiguousarray(np.asarray(p.numpy())).tobytes()
                                   for p in parts)).hexdigest()[:20]


def _hashes(scene, acc) -> dict:
    out = {}
    for f in SCENE_FIELDS:
        a = getattr(scene, f)
        out[f"scene.{f}"] = "none" if a is None else f"{a.dtype} {a.shape} {_digest(a)}"
    for f in ACCEL_FIELDS:
        v = getattr(acc, f, None)
        if v is not None:
            out[f"accel.{f}"] = _digest(v)
    for f in TRIS_FIELDS:
        out[f"tris.{f}"] = _digest(getattr(acc.tris, f))
    return out


def once(path: Path, backend: str, accel: str | None, check: bool):
    """One cold load and set-up: (seconds dict, hashes or None)."""
    t0 = time.perf_counter()
    scene = load_scene(path)
    t1 = time.perf_counter()
    r = Renderer(scene, backend=backend, build="auto", accel=accel, frames=1)
    t2 = time.perf_counter()
    acc = r.arrays.accel
    info = acc.stats()
    s = {"load": t1 - t0, "tree": float(info.get("tree_seconds", float("nan"))),
         "upload": float(info.get("upload_seconds", float("nan"))), "setup": t2 - t1}
    return s, (_hashes(r.scene, acc) if check else None)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="llvm", choices=("llvm", "cuda"))
    ap.add_argument("--accel", default=None, help="accelerator (default: the renderer's)")
    ap.add_argument("--scenes", nargs="+", default=["bunny_1m", "conference"])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2, 4, 8, 16])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", help="write the arrays' hashes (JSON)")
    ap.add_argument("--against", help="compare the arrays' hashes with this JSON")
    a = ap.parse_args()
    hashes, differ = {}, []
    if parallel is None:
        a.threads = [0]
        print(f"backend {a.backend}, no renderer.parallel (threads 0: numpy's own); "
              f"seconds, median of {a.repeat}")
    else:
        print(f"backend {a.backend}, {parallel.thread_count()} threads by default "
              f"(MAX_THREADS {parallel.MAX_THREADS}); seconds, median of {a.repeat}")
    print("| scene | threads | load | tree | upload | load + upload | set-up |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in a.scenes:
        path = ROOT / "scenes" / f"{name}.toml"
        once(path, a.backend, a.accel, False)                  # warm-up: device kernels
        first = None
        for n in a.threads:
            with parallel.threads(n) if parallel else contextlib.nullcontext():
                runs, h = [], None
                for k in range(max(a.repeat, 1)):
                    s, got = once(path, a.backend, a.accel, k == 0)
                    runs.append(s)
                    h = got if got is not None else h
            med = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
            print(f"| {name} | {n} | {med['load']:.3f} | {med['tree']:.3f} | "
                  f"{med['upload']:.3f} | {med['load'] + med['upload']:.3f} | "
                  f"{med['setup']:.3f} |", flush=True)
            if first is None:
                first = h
                hashes.update({f"{name}/{k}": v for k, v in h.items()})
            differ += [f"{name}/{k} ({n} threads)" for k in first if h.get(k) != first[k]]
    if a.out:
        Path(a.out).write_text(json.dumps(hashes, indent=1, sort_keys=True) + "\n")
    if a.against:
        ref = json.loads(Path(a.against).read_text())
        differ += [f"{k} (against {a.against})" for k in sorted(ref)
                   if k in hashes and hashes[k] != ref[k]]
    print(f"{len(hashes)} arrays per thread count, {len(differ)} differ")
    for d in differ:
        print("DIFFERS", d)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
