"""The viewer's frame rate, measured server-side: ``python -m evaluation.bench.viewer
--backend cuda --size 1280x720 --out DIR``.

For each scene (default: the seed scenes and the glass bunny) it starts the real viewer
server (``evaluation.view.server``) on a free loopback port, connects a websocket client
and sends camera messages (orbit drags of a few degrees, one at a time: the next message
leaves when the previous frame has arrived, so frames never merge), with the moving size
equal to ``--size`` so every frame is rendered at that size. The server records, per frame,
the time from the camera message's arrival to the image sent (``ViewServer.records``):
render (frozen frame and read-back), encode (sRGB, JPEG, base64, JSON) and send. The first
frame (the connection's, recording the kernels) and ``--warmup`` more are left out. Writes
``viewer-<backend>.json`` and ``.md`` (the device named, frames per second = 1000 / median
message-to-sent ms, the encode's share of it) and never replaces them without ``--force``.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from renderer.outputs import OutputError, check_output_file

from .. import SEED_SCENES, wxh
from . import device_info
from .part import jsonable, table, write_atomic

#: Scenes of the benchmark: the seed scenes and the glass bunny.
SCENES = tuple(SEED_SCENES) + ("glass_bunny",)


async def _drive(session, frames: int, step_px: float, timeout: float) -> list[dict]:
    """Run the server for ``session``, send ``frames`` camera messages one at a time, and
    return the server's records of the frames that answered them."""
    import aiohttp

    from evaluation.view.server import ViewServer, serve
    server = ViewServer(session, Path(os.devnull), log=lambda *a: None)
    port: list[int] = []
    done = asyncio.Event()
    task = asyncio.create_task(serve(session, host="127.0.0.1", port=0, out=Path(os.devnull),
                                     stop=done.is_set, on_ready=port.append, server=server))
    while not port:
        if task.done():
            task.result()
        await asyncio.sleep(0.01)
    try:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(f"http://127.0.0.1:{port[0]}/ws",
                                       max_msg_size=0) as ws:
                async def next_frame():
                    while True:
                        m = await asyncio.wait_for(ws.receive(), timeout)
                        if m.type != aiohttp.WSMsgType.TEXT:
                            raise RuntimeError(f"viewer closed the socket ({m.type})")
                        if json.loads(m.data).get("t") == "frame":
                            return
                await next_frame()                      # the first frame (still)
                for _ in range(frames):
                    await ws.send_str(json.dumps({"t": "drag", "kind": "orbit",
                                                  "dx": step_px, "dy": 0}))
                    await next_frame()
    finally:
        done.set()
        await task
    return [r for r in server.records if r["cause"] == "input"]


def bench_scene(path, *, backend: str, size, frames: int = 60, warmup: int = 3,
                step_px: float = 4.0, timeout: float = 600.0) -> dict:
    """One scene's row: medians of message-to-sent, render, encode and send ms over the
    frames after the first ``warmup + 1``, the frame rate, the encode's share, the
    recording frame's ms and the scene's facts."""
    from evaluation.view.session import ViewSession
    from renderer.scene import load_scene
    scene = load_scene(path)
    t0 = time.perf_counter()
    session = ViewSession(path, backend=backend, size=size, moving_size=size, scene=scene)
    upload_s = time.perf_counter() - t0
    load = os.getloadavg()
    # records[0]: the frame of the connection (it records the kernels); then one per message
    recs = asyncio.run(_drive(session, frames + warmup, step_px, timeout))
    first, timed = recs[0], recs[warmup + 1:]
    if not timed:
        raise RuntimeError(f"{scene.name}: no frame answered a camera message")

    def med(k):
        return float(np.median([r[k] for r in timed]))
    total = med("latency_ms")
    return {"scene": scene.name, "triangles": scene.face_count, "size": list(size),
            "frames": len(timed), "message_to_sent_ms": total, "fps": 1e3 / total,
            "render_ms": med("render_ms"), "encode_ms": med("encode_ms"),
            "send_ms": med("send_ms"), "encode_share": med("encode_ms") / total,
            "jpeg_bytes": med("bytes"), "first_frame_ms": first["latency_ms"],
            "recorded_after_first": sum(bool(r["recorded"]) for r in recs[1:]),
            "upload_s": upload_s, "effects": str(session.renderer().effects),
            "load_average": list(load)}


def markdown(result: dict) -> str:
    dev = result["device"]
    rows = [[r["scene"], f"{r['triangles']:,}", f"{r['size'][0]}x{r['size'][1]}",
             str(r["frames"]), f"{r['message_to_sent_ms']:.2f}", f"{r['fps']:.1f}",
             f"{r['render_ms']:.2f}", f"{r['encode_ms']:.2f}", f"{r['send_ms']:.2f}",
             f"{100 * r['encode_share']:.0f} %", f"{r['first_frame_ms']:.0f}",
             f"{r['load_average'][0]:.1f}"] for r in result["rows"]]
    lines = [f"<!-- command: {result['command']} -->"] if result.get("command") else []
    lines += [f"# Viewer frame rate ({dev['backend']}, {dev.get('device', '?')})", "",
             f"{result['date']}; host {dev.get('host')}; Dr.Jit {dev.get('drjit')}. "
             "Server-side, from the camera message's arrival to the image sent (median); "
             "encode = sRGB + JPEG + base64 + JSON; first = the frame that records the "
             "kernels. " + result.get("note", ""), ""]
    lines += table("Frames", ["scene", "triangles", "size", "frames", "msg→sent ms", "fps",
                        "render ms", "encode ms", "send ms", "encode share", "first ms",
                        "load"], "lrrrrrrrrrrr", rows)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="auto", choices=("auto", "cuda", "llvm"))
    ap.add_argument("--size", type=wxh, default=(1280, 720))
    ap.add_argument("--frames", type=int, default=60, help="timed frames per scene")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--scenes", default="scenes", help="folder of the scene files")
    ap.add_argument("--only", default="", help="comma-separated scene names (default: "
                                               + ", ".join(SCENES) + ")")
    ap.add_argument("--out", required=True)
    ap.add_argument("--note", default="")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    from renderer.device import types
    try:
        backend = types(args.backend).backend
    except (ValueError, RuntimeError) as e:
        ap.error(f"--backend: {e}")
    names = [n for n in (args.only.split(",") if args.only else SCENES) if n]
    missing = [n for n in names if not (Path(args.scenes) / f"{n}.toml").exists()]
    if missing:
        ap.error(f"--only: no scene {', '.join(missing)} in {args.scenes}/")
    stem = Path(args.out) / f"viewer-{backend}"
    try:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        for ext in (".json", ".md"):
            check_output_file(stem.with_suffix(ext), overwrite=args.force, flag="--force")
    except (OutputError, OSError) as e:
        print(f"viewer bench: {e}", file=sys.stderr)
        return 2
    command = shlex.join(
        ["python", "-m", "evaluation.bench.viewer", "--backend", backend, "--size",
         f"{args.size[0]}x{args.size[1]}", "--frames", str(args.frames)]
        + (["--warmup", str(args.warmup)] if args.warmup != 3 else [])
        + (["--scenes", args.scenes] if args.scenes != "scenes" else [])
        + (["--only", args.only] if args.only else []) + ["--out", args.out, "--force"])
    result = {"command": command, "device": device_info(backend),
              "date": time.strftime("%Y-%m-%d %H:%M:%S"), "note": args.note, "rows": []}
    for name in names:
        row = bench_scene(Path(args.scenes) / f"{name}.toml", backend=backend,
                          size=args.size, frames=args.frames, warmup=args.warmup)
        result["rows"].append(row)
        print(f"{name:16s} {row['size'][0]}x{row['size'][1]}  {row['fps']:7.1f} fps  "
              f"msg→sent {row['message_to_sent_ms']:.2f} ms (render {row['render_ms']:.2f}, "
              f"encode {row['encode_ms']:.2f} = {100 * row['encode_share']:.0f} %, send "
              f"{row['send_ms']:.2f})  load {row['load_average'][0]:.1f}", flush=True)
        write_atomic(stem.with_suffix(".json"), json.dumps(jsonable(result), indent=1))
        write_atomic(stem.with_suffix(".md"), markdown(result))
    print(f"wrote {stem}.json and .md", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
