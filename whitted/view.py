"""``whitted view SCENE``: move through a scene live in the browser.

    whitted view SCENE [--backend auto|cuda|llvm] [--port N] [--host H] [--size WxH]
                       [--moving-size WxH] [--view N|NAME] [--out DIR]

Serves a page on ``http://HOST:PORT/`` (``evaluation.view``): the image is rendered with
frozen frames (``dr.freeze``: a moved camera replays the recorded kernels), at the moving
size while the camera moves and at ``--size`` when it stops. Keys W/S/A/D/Q/E and the arrows,
mouse orbit/pan/zoom, the scene's views as presets, menus for the render mode, effects,
accelerator, triangle routine, precision, spawn rule, spp and shading; a toggle renders the
current view with Mitsuba and shows ours | Mitsuba | the error, with the exact rule's
verdict. Saved views and camera tables go to ``--out`` (default ``out/view/<scene>``),
never replacing a file. On a remote host, the printed ssh command forwards the port.
Ctrl-C stops it.
"""
from __future__ import annotations

import argparse
import asyncio
import errno
import getpass
import socket
from pathlib import Path

from evaluation import wxh
from renderer.scene import load_scene

from .data import scene_arg
from .options import (
    EXIT,
    CliError,
    add_backend_option,
    add_read_options,
    read_options,
    select_views,
)
from .progress import STOP


def register(subparsers) -> None:
    """Add the ``view`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser("view", help="interactive viewer in the browser, with Mitsuba "
                                           "side by side", description=__doc__.split("\n")[0])
    p.add_argument("scene", type=scene_arg,
                   help="scene file (.toml), or a bundled scene's name (whitted data)")
    add_backend_option(p)
    p.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; "
                                                          "0: any free port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1; reach a remote host "
                        "through the printed ssh tunnel)")
    p.add_argument("--size", type=wxh, help="image size when the camera is still "
                                            "(default: the first view's)")
    p.add_argument("--moving-size", type=wxh,
                   help="image size while the camera moves (default: --size halved)")
    p.add_argument("--view", default="0", help="view to start from (index or name)")
    p.add_argument("--out", type=Path, help="folder for saved views and camera tables "
                                            "(default out/view/<scene>)")
    add_read_options(p)
    p.set_defaults(func=cmd_view)


def tunnel_command(port: int) -> str:
    """The ssh command that forwards ``port`` of this host to the same local port."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = "USER"
    return f"ssh -N -L {port}:localhost:{port} {user}@{socket.gethostname()}"


def cmd_view(args: argparse.Namespace) -> int:
    try:
        import aiohttp  # noqa: F401
    except ImportError:
        raise CliError("whitted view needs aiohttp: pip install 'whitted[view]'") from None
    from evaluation.view.server import serve
    from evaluation.view.session import ViewSession

    if not 0 <= args.port <= 65535:
        raise CliError(f"--port: expected 0..65535, got {args.port}")
    scene = load_scene(args.scene, **read_options(args))
    start = select_views(scene, args.view)[0]
    session = ViewSession(args.scene, backend=args.backend, size=args.size,
                          moving_size=args.moving_size, scene=scene)
    session.preset(start)
    out = args.out or Path("out") / "view" / scene.name
    r = session.renderer()
    print(f"{scene.name}: {scene.face_count} triangles, backend {r.t.backend}, "
          f"{session.size[0]}x{session.size[1]} still, {session.moving_size[0]}x"
          f"{session.moving_size[1]} moving; effects: {r.effects}")

    def ready(port: int) -> None:
        print(f"view: open http://{args.host}:{port}/  (Ctrl-C stops)")
        print(f"view: from another machine: {tunnel_command(port)}  then open "
              f"http://localhost:{port}/", flush=True)

    try:
        asyncio.run(serve(session, host=args.host, port=args.port, out=out,
                          stop=STOP.is_set, on_ready=ready))
    except OSError as e:
        if e.errno in (errno.EADDRINUSE, errno.EACCES, errno.EADDRNOTAVAIL):
            why = str(e.strerror or e).rsplit(": ", 1)[-1]
            raise CliError(f"--port {args.port}: cannot listen on {args.host}:{args.port} "
                           f"({why}); pick another with --port",
                           code=EXIT["usage"]) from None
        raise
    return EXIT["interrupted"] if STOP.is_set() else EXIT["ok"]
