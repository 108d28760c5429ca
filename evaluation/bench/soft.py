"""Soft-shadow benchmark: frame time vs shadow samples, ours against the frozen Mitsuba peer.

    python -m evaluation.bench.soft --backend cuda --out DIR [--size 1024] [--samples 1 4 16 64]

For ``scenes/cornell_soft.toml`` (the Cornell box with a ceiling sphere light) at each
``shadow_samples`` value: our frozen frame (``frames.frozen_frame_ms``: median wall and
kernel ms of ``--frames`` frozen frames after warm-up, exact mode, one camera ray a pixel)
and the peer's (``reference.peer``: one kernel, frozen, the same scene translated, the area
emitter sampled by its own ``sample_direction`` the same number of times, stratified as
ours, in one symbolic loop) at the same depth (``--depth``, default 2: the peer's unrolled
tree does not compile much deeper, see ``evaluation/bench/peer.py``). Writes ``soft.json``
and ``soft.md`` (the table, speedup = peer ms / ours ms, and both image means, which agree
but for the box's creases, where the peer's fixed ray offset self-shadows) into ``--out``
atomically, a row at a time.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from renderer.outputs import check_output_dir, write_text
from renderer.scene import load_scene

from .frames import frozen_frame_ms
from .peer import _no_collection, peer_frame_ms

ROOT = Path(__file__).resolve().parents[2]
SCENE = "scenes/cornell_soft.toml"


def rows_for(backend: str, size: int, samples, depth: int, frames: int, warmup: int,
             on_row=None) -> list[dict]:
    """One row per shadow-sample count: ours and the peer, frozen frame ms."""
    rows = []
    for n in samples:
        sc = load_scene(ROOT / SCENE).with_overrides(shadow_samples=int(n), max_depth=depth,
                                                     size=(size, size))
        with _no_collection():
            ours = frozen_frame_ms(sc, backend=backend, accel=None, frames=frames,
                                   warmup=warmup)
        with _no_collection():
            peer = peer_frame_ms(sc, backend=backend, frames=frames, warmup=warmup)
        row = {"shadow_samples": int(n), "size": size, "depth": depth,
               "ours_ms": ours["frozen_ms"], "ours_kernel_ms": ours["frozen_kernel_ms"],
               "peer_ms": peer.get("frozen_ms"), "peer_kernel_ms": peer.get("frozen_kernel_ms"),
               # same estimator, different random numbers: the means agree, not the pixels
               "ours_mean": float(ours["image"].numpy().mean()) if hasattr(ours["image"],
                                                                           "numpy")
               else float(ours["image"].mean()),
               "peer_mean": float(peer["image"].mean())}
        row["speedup"] = (row["peer_ms"] / row["ours_ms"]
                          if row["peer_ms"] and row["ours_ms"] else None)
        rows.append(row)
        if on_row:
            on_row(rows)
    return rows


def markdown(rows: list[dict], device: str, command: str | None = None) -> str:
    """The table; ``command``: the command line that made it, as its first line."""
    out = [f"<!-- command: {command} -->"] if command else []
    out += [f"Soft shadows, {SCENE}, exact mode, frozen frames, {device}", "",
           "| shadow samples | size | depth | ours ms | peer ms | peer / ours | ours mean | "
           "peer mean |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sp = f"{r['speedup']:.2f}x" if r["speedup"] else "-"
        out.append(f"| {r['shadow_samples']} | {r['size']}² | {r['depth']} | "
                   f"{r['ours_ms']:.3g} | {r['peer_ms'] or float('nan'):.3g} | {sp} | "
                   f"{r['ours_mean']:.5f} | {r['peer_mean']:.5f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench.soft", description=__doc__
                                .split("\n")[0])
    p.add_argument("--backend", default="cuda", choices=("cuda", "llvm"))
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--samples", type=int, nargs="+", default=[1, 4, 16, 64])
    p.add_argument("--depth", type=int, default=2)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--force", action="store_true", help="replace an earlier run's files")
    a = p.parse_args(argv)
    check_output_dir(a.out)
    from . import device_info
    device = device_info(a.backend)["device"]

    command = " ".join([p.prog] + [str(x) for x in (sys.argv[1:] if argv is None else argv)])

    def save(rows):
        data = {"scene": SCENE, "backend": a.backend, "device": device, "command": command,
                "rows": rows}
        write_text(a.out / "soft.json", json.dumps(data, indent=1) + "\n", overwrite=True)
        write_text(a.out / "soft.md", markdown(rows, device, command), overwrite=True)
    rows = rows_for(a.backend, a.size, a.samples, a.depth, a.frames, a.warmup, save)
    print(markdown(rows, device))
    return 0


if __name__ == "__main__":
    sys.exit(main())
