"""Profile the steps before a first image (issue 24): scene load, tree, accelerator upload,
in one thread under cProfile. ``python lab/probes/ttfi_profile.py SCENE.toml [llvm|cuda]
[--no-cache] [--top N] [--accel A] [--cumulative] [--frame SIZE]``; prints each step's
seconds and the top functions of each (``--frame``: also the first frame at SIZE², with the
kernels it launched and whether each hit Dr.Jit's kernel cache)."""
from __future__ import annotations

import cProfile
import io
import pstats
import sys
import time

from renderer.accel.cache import TreeCache
from renderer.render import Renderer
from renderer.scene import load_scene

SORT = "cumulative" if "--cumulative" in sys.argv else "tottime"


def profiled(label, fn, top):
    pr = cProfile.Profile()
    t0 = time.perf_counter()
    pr.enable()
    out = fn()
    pr.disable()
    dt = time.perf_counter() - t0
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats(SORT).print_stats(top)
    print(f"== {label}: {dt:.3f} s")
    print("\n".join(s.getvalue().splitlines()[6:6 + top + 3]))
    return out


def main(argv):
    path = argv[0]
    backend = argv[1] if len(argv) > 1 and not argv[1].startswith("-") else "llvm"
    cache = None if "--no-cache" in argv else TreeCache()
    top = int(argv[argv.index("--top") + 1]) if "--top" in argv else 12
    scene = profiled("load", lambda: load_scene(path, cache=cache), top)
    if "--frame" in argv:
        size = int(argv[argv.index("--frame") + 1])
        scene = scene.with_size(size, size)
    accel = argv[argv.index("--accel") + 1] if "--accel" in argv else None
    r = profiled("renderer", lambda: Renderer(scene, backend=backend, build="auto", accel=accel,
                                              cache=cache, frames=1), top)
    print(r.arrays.accel.stats().get("tree_build"), r.arrays.accel.stats().get("tree_cached"))
    if "--frame" in argv:           # the first frame: which kernels compile or hit a cache
        import drjit as dr
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        res = profiled("first frame", lambda: r.render(0), top)
        hist = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        print(f"frame {res.seconds:.3f} s: {len(hist)} JIT kernels, "
              f"{sum(bool(k.get('cache_hit')) for k in hist)} cache hits "
              f"({sum(bool(k.get('cache_disk')) for k in hist)} from disk), codegen "
              f"{sum(k.get('codegen_time', 0) for k in hist):.1f} ms, backend "
              f"{sum(k.get('backend_time', 0) for k in hist):.1f} ms, execution "
              f"{sum(k.get('execution_time', 0) for k in hist):.1f} ms")
        for k in hist:
            print("  ", {x: k.get(x) for x in ("cache_hit", "cache_disk", "operation_count",
                                                "codegen_time", "backend_time",
                                                "execution_time")})


if __name__ == "__main__":
    main(sys.argv[1:])
