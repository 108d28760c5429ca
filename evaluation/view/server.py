"""The viewer's server: one page and one websocket (aiohttp) in front of a ``ViewSession``.

Why not viser: its client draws with WebGL (three.js) and owns the camera in its own
conventions; here the image is the renderer's own and the camera is the scene's pinhole
camera, so a plain ``<img>`` and a few lines of script do the job with one dependency
(aiohttp), run in a headless browser without a GPU, take native key events (W/S/A/D/Q/E and
the arrows) and reach a remote host through one forwarded port.

Protocol (JSON text messages). Browser -> server: ``{"t": "key", "key": "w"}``,
``{"t": "drag", "kind": "orbit"|"pan", "dx": .., "dy": ..}``, ``{"t": "wheel", "dy": ..}``,
``{"t": "set", "name": <ViewSettings field>, "value": ..}``,
``{"t": "effect", "name": .., "on": bool}``, ``{"t": "preset", "name": ..}``,
``{"t": "save"}``, ``{"t": "viewtable", "name": ..}``, ``{"t": "sbs", "on": bool}``.
Server -> browser: ``init`` (the menus), ``frame`` (a base64 JPEG and the overlay: frame,
render and encode times, rays/s, the effect set, the camera), ``msg`` (one line: a
recompile, a saved file, an error) and ``sbs`` (ours | Mitsuba | heat map, the verdict and
the pixel counts, or the one line saying why there is none).

The session's Dr.Jit work runs in one worker thread, one frame at a time; input that
arrives meanwhile is applied at once and the next frame shows all of it. While input keeps
coming (within ``STILL_SECONDS``) frames are rendered at the moving size; then one frame at
full size follows. Every frame's time from the first camera message it answers to the image
sent is measured server-side (``latency_ms`` in the next overlay; ``ViewServer.records``
keeps each frame's: message to sent, render, encode (JPEG, base64, JSON), send).
"""
from __future__ import annotations

import asyncio
import base64
import collections
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .page import PAGE
from .session import MitsubaMissing, ViewSession

#: Seconds without input after which the camera counts as still (a full-size frame).
STILL_SECONDS = 0.25


def one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


class ViewServer:
    """The aiohttp application around ``session``; ``out`` is where saved views go."""

    def __init__(self, session: ViewSession, out: Path, log=print):
        self.session = session
        self.out = Path(out)
        self.log = log
        self.sockets: set = set()
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="whitted-view")
        self.dirty = asyncio.Event()
        self.last_input = 0.0
        self.pending_since: float | None = None
        self.last_latency_ms: float | None = None
        self.sbs_on = False
        self.sbs_dirty = False
        self.frames = 0
        self.rendering = False
        self.pending_cause = "input"
        #: The last frames' server-side timings (``frame_record``), newest last.
        self.records: collections.deque = collections.deque(maxlen=10000)

    # ---- aiohttp --------------------------------------------------------------------------
    def app(self):
        from aiohttp import web
        app = web.Application()
        app.router.add_get("/", self.index)
        app.router.add_get("/ws", self.websocket)
        app.on_startup.append(self._start_loop)
        app.on_shutdown.append(self._close_sockets)
        return app

    async def index(self, request):
        from aiohttp import web
        return web.Response(text=PAGE, content_type="text/html")

    async def _start_loop(self, app):
        self.task = asyncio.get_running_loop().create_task(self.render_loop())

    async def _close_sockets(self, app):
        for ws in list(self.sockets):
            await ws.close()

    async def run_in_worker(self, fn, *args):
        return await asyncio.get_running_loop().run_in_executor(self.pool, fn, *args)

    async def websocket(self, request):
        from aiohttp import WSMsgType, web
        ws = web.WebSocketResponse(heartbeat=20)
        await ws.prepare(request)
        self.sockets.add(ws)
        await ws.send_str(json.dumps({"t": "init", **self.session.options()}))
        self.touch(still=True)
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    await self.handle(json.loads(msg.data))
                except (ValueError, KeyError, TypeError) as e:
                    await self.say(f"error: {one_line(e)}")
        finally:
            self.sockets.discard(ws)
        return ws

    # ---- input ----------------------------------------------------------------------------
    def touch(self, still: bool = False) -> None:
        """A camera or settings change: the next frame is due (``still``: at full size)."""
        now = time.perf_counter()
        if not still:
            self.last_input = now
        if self.pending_since is None:
            self.pending_since = now
            self.pending_cause = "input"
        self.sbs_dirty = self.sbs_on
        self.dirty.set()

    async def handle(self, m: dict) -> None:
        s = self.session
        t = m.get("t")
        if t == "key":
            if s.key(str(m["key"]), int(m.get("repeat", 1))):
                self.touch()
        elif t == "drag":
            dx, dy = float(m["dx"]), float(m["dy"])
            (s.pan if m.get("kind") == "pan" else s.orbit)(dx, dy)
            self.touch()
        elif t == "wheel":
            s.zoom(float(m["dy"]))
            self.touch()
        elif t == "preset":
            s.preset(m["name"])
            self.touch(still=True)
        elif t in ("set", "effect"):
            await self.change(m)
        elif t == "save":
            exr, png = await self.run_in_worker(s.save_view, self.out)
            self.log(f"view: saved {exr} and {png}")
            await self.say(f"saved {exr} and {png}")
        elif t == "viewtable":
            text = s.view_table(str(m.get("name") or "viewer"))
            path = await self.run_in_worker(s.save_view_table, self.out,
                                            str(m.get("name") or "viewer"))
            self.log(f"view: camera table ({path}):\n{text}")
            await self.broadcast({"t": "viewtable", "text": text, "path": str(path)})
        elif t == "sbs":
            self.sbs_on = bool(m.get("on"))
            if self.sbs_on:
                self.sbs_dirty = True
                self.dirty.set()
        else:
            raise ValueError(f"unknown message type {t!r}")

    async def change(self, m: dict) -> None:
        """A menu: the new settings' Renderer is built in the worker (a new accelerator
        or kernel may take a moment, and says so); a setting that cannot render is
        refused with one line and the old one stays."""
        s = self.session
        what = f"{m['name']} = {m.get('value', m.get('on'))}"
        await self.say(f"{what}: building (the first frame records the kernels once)")
        try:
            if m["t"] == "set":
                await self.run_in_worker(s.set_option, str(m["name"]), m["value"])
            else:
                await self.run_in_worker(s.set_effect, str(m["name"]), bool(m["on"]))
        except Exception as e:  # noqa: BLE001 - SceneError, DeviceError, ValueError: one line
            await self.say(f"error: {what}: {one_line(e)}")
            await self.broadcast({"t": "init", **s.options()})
            return
        await self.broadcast({"t": "init", **s.options()})
        self.touch(still=True)

    # ---- output ---------------------------------------------------------------------------
    async def broadcast(self, obj) -> None:
        """Send ``obj`` (a dict, or its JSON text) to every page."""
        text = obj if isinstance(obj, str) else json.dumps(obj)
        for ws in list(self.sockets):
            try:
                await ws.send_str(text)
            except (ConnectionError, RuntimeError):
                self.sockets.discard(ws)

    async def say(self, text: str) -> None:
        await self.broadcast({"t": "msg", "text": text})

    async def render_loop(self) -> None:
        """Render while frames are due: moving size while input keeps coming, then one
        full-size frame; the side-by-side comparison after a still frame when it is on."""
        loop = asyncio.get_running_loop()
        while True:
            await self.dirty.wait()
            self.dirty.clear()
            if not self.sockets:
                continue
            moving = time.perf_counter() - self.last_input < STILL_SECONDS
            if self.session.needs_compile(moving):
                w, h = self.session._size(moving)
                await self.say(f"recording the frame's kernels for {w}x{h} (once)")
            since, cause = self.pending_since, self.pending_cause
            self.pending_since = None
            self.rendering = True
            try:
                f = await self.run_in_worker(self.session.frame, moving)
            except Exception as e:  # noqa: BLE001 - the viewer keeps running
                await self.say(f"error: frame: {one_line(e)}")
                continue
            finally:
                self.rendering = False
            self.frames += 1
            cam = self.session.camera.as_dict()
            overlay = {
                "frame_ms": f.render_ms + f.encode_ms, "render_ms": f.render_ms,
                "encode_ms": f.encode_ms, "rays_per_s": f.rays_per_s,
                "latency_ms": self.last_latency_ms, "effects": f.effects,
                "size": [f.width, f.height], "moving": f.moving, "recorded": f.recorded,
                "seq": self.frames}
            t0 = time.perf_counter()
            text = json.dumps({"t": "frame", "img": base64.b64encode(f.jpeg).decode(),
                               "overlay": overlay, "camera": cam})
            t1 = time.perf_counter()
            await self.broadcast(text)
            t2 = time.perf_counter()
            if since is not None:
                self.last_latency_ms = (t2 - since) * 1e3
                self.records.append({
                    "cause": cause, "latency_ms": self.last_latency_ms,
                    "render_ms": f.render_ms, "encode_ms": f.encode_ms + (t1 - t0) * 1e3,
                    "send_ms": (t2 - t1) * 1e3, "width": f.width, "height": f.height,
                    "moving": f.moving, "recorded": f.recorded, "bytes": len(f.jpeg)})
            if f.moving:
                loop.call_later(STILL_SECONDS, self._maybe_still, self.frames)
            elif self.sbs_on and self.sbs_dirty and not self.dirty.is_set():
                self.sbs_dirty = False
                await self.side_by_side()

    def _maybe_still(self, seq: int) -> None:
        """After a moving frame ``seq``: when no frame came after it and no input for
        ``STILL_SECONDS``, the full-size frame is due."""
        if self.rendering or self.frames != seq or self.dirty.is_set():
            return
        if time.perf_counter() - self.last_input >= STILL_SECONDS - 1e-3:
            if self.pending_since is None:
                self.pending_since = time.perf_counter()
                self.pending_cause = "still"
            self.dirty.set()

    async def side_by_side(self) -> None:
        await self.say("side by side: rendering the current view with Mitsuba")
        try:
            sb = await self.run_in_worker(self.session.side_by_side)
        except MitsubaMissing as e:
            self.log(f"warning: {e}")
            await self.broadcast({"t": "sbs", "error": str(e)})
            return
        except Exception as e:  # noqa: BLE001 - the viewer keeps running
            await self.broadcast({"t": "sbs", "error": f"side by side: {one_line(e)}"})
            return
        await self.broadcast({"t": "sbs", "img": base64.b64encode(sb.jpeg).decode(),
                              "status": sb.status, "reason": sb.reason,
                              "excused": sb.excused, "failing": sb.failing,
                              "pixels": sb.pixels, "mitsuba_s": sb.mitsuba_seconds,
                              "note": sb.note})
        await self.say(f"side by side: {sb.status} ({sb.reason})")


async def serve(session: ViewSession, *, host: str, port: int, out: Path, stop,
                on_ready=None, log=print, server: ViewServer | None = None) -> None:
    """Serve ``session`` on ``host:port`` until ``stop()`` is true (checked every 0.1 s).
    Raises OSError when the port cannot be bound. ``on_ready(port)`` is called once the
    socket listens (the port actually bound, for ``port`` 0). ``server``: the
    ``ViewServer`` to run (default: a new one; a benchmark passes its own to read its
    ``records``)."""
    from aiohttp import web
    server = server or ViewServer(session, out, log=log)
    runner = web.AppRunner(server.app(), handle_signals=False, access_log=None)
    await runner.setup()
    try:
        site = web.TCPSite(runner, host, port, reuse_address=False)
        await site.start()
        bound = site._server.sockets[0].getsockname()[1] if site._server else port
        if on_ready is not None:
            on_ready(bound)
        while not stop():
            await asyncio.sleep(0.1)
    finally:
        await runner.cleanup()
        server.pool.shutdown(wait=False, cancel_futures=True)
        sys.stdout.flush()
