"""``whitted``: one entry point, one subcommand per job.

    whitted render  SCENE.toml   render with the Dr.Jit tracer → EXR + PNG
    whitted compare SCENE.toml   ours vs Mitsuba's golden → verdict, HTML side-by-side report
    whitted check   SCENE...     regression gate: one verdict per view, idiff exit codes
    whitted diff    A B          two images (EXR or PNG) judged by check's rules
    whitted reference SCENE...   (re)render Mitsuba golden images
    whitted export  SCENE.toml --mitsuba-xml OUT.xml [--portable]
    whitted convert SCENE OUT.toml   an OBJ + MTL, PLY or Mitsuba XML scene as a TOML file
    whitted bench   ...          timing study (kernel times, frozen frames, vs Mitsuba)
    whitted study   ...          accuracy-vs-time study (error vs time, Pareto front)
    whitted data    DIR          copy the bundled scenes and meshes out of the package
    whitted hard-cases --out DIR  hard-case stress suite → table; exit 0 iff all pass
    whitted view    SCENE        interactive viewer in the browser, Mitsuba side by side

Each subcommand lives in its own module (``whitted/render.py``, ``compare.py``,
``check.py``, ``diff.py``, ``reference.py``, ``convert.py``, ``bench.py``, ``study.py``,
``data.py``, ``hard_cases.py``, ``view.py``)
with ``register(subparsers)``, which sets ``func``; the options they share are in
``whitted/options.py``. Mitsuba is imported only by the subcommands that run it, when they
run, so ``render`` works with only the core dependencies installed.

Exit codes: one table for every command, ``options.EXIT``, defined from the verdict codes
``evaluation.gate.verdict.EXIT_CODES`` (OpenImageIO ``idiff``'s style: 0 pass, 1 warn, 2 fail or
bad request, 3 size, 4 missing/stale golden or file error, 130 Ctrl-C);
``options.EXIT_CODE_HELP`` is the table ``whitted --help`` shows. ``check``, ``compare`` and
``diff`` exit with the largest code of their verdicts.

Every error is one ``error:`` line on stderr, never a traceback; warnings are one
``warning:`` line. The command runs in a worker thread while the main thread waits, so
Ctrl-C takes effect at once even in the middle of a long kernel: temporary files of the
atomic writer (``renderer.outputs``) are removed and the process exits with 130.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import signal
import sys
import threading
import warnings

from renderer.device import DeviceError
from renderer.outputs import OutputError, remove_live_temporaries
from renderer.scene import SceneError

from . import (
    bench,
    check,
    compare,
    convert,
    data,
    diff,
    hard_cases,
    reference,
    render,
    study,
    view,
)
from .options import EXIT, EXIT_CODE_HELP, CliError
from .progress import STOP

#: Modules that add subcommands, in the order ``--help`` lists them.
COMMANDS = (render, compare, check, diff, reference, convert, bench, study, hard_cases, view, data)


def version() -> str:
    """The installed distribution's version (``0+unknown`` when run from a bare tree)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version
    try:
        return dist_version("whitted")
    except PackageNotFoundError:
        return "0+unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="whitted", description=__doc__.split("\n")[0],
                                     epilog=EXIT_CODE_HELP,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"whitted {version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.register(sub)
    return parser


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` of the CLI: ``warning: <message> (<Category>)``, one line,
    no source line."""
    text = " ".join(str(message).split())
    print(f"warning: {text} ({category.__name__})", file=sys.stderr if file is None else file)


def error_code(e: BaseException) -> tuple[int, str] | None:
    """The exit code and the one-line message of an error the CLI reports without a
    traceback; None for any other exception (a bug: its traceback is shown)."""
    if isinstance(e, CliError):
        return e.code, str(e)
    if isinstance(e, (SceneError, DeviceError)):
        return EXIT["fail"], str(e)
    if isinstance(e, (OutputError, FileExistsError, FileNotFoundError, IsADirectoryError,
                      NotADirectoryError, PermissionError)):
        return EXIT["file"], str(e)
    from reference.golden import GoldenError  # no Mitsuba import: golden imports it lazily
    if isinstance(e, GoldenError):
        return EXIT["file"], str(e)
    return None


def _run(args: argparse.Namespace, box: dict, done: threading.Event) -> None:
    try:
        box["code"] = args.func(args) or 0
    except BaseException as e:  # noqa: BLE001 - handed to the main thread as it is
        box["error"] = e
    finally:
        done.set()


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, run the subcommand in a worker thread, return its exit code."""
    args = build_parser().parse_args(argv)
    STOP.clear()
    if threading.current_thread() is threading.main_thread():
        # A shell starts background jobs with SIGINT ignored; `timeout -s INT whitted ... &`
        # in a script must still stop the command cleanly.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    box: dict = {}
    # The worker's end is an Event, not Thread.join: a KeyboardInterrupt inside join() can
    # mark a running thread stopped (CPython's bpo-45274 handling), and the interpreter
    # would then shut down under a running kernel.
    done = threading.Event()
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning
        worker = threading.Thread(target=_run, args=(args, box, done), daemon=True,
                                  name=f"whitted {args.command}")
        worker.start()
        try:
            while not done.wait(0.05):
                pass
        except KeyboardInterrupt:
            return interrupted(done, worker)
    if "error" not in box:
        return box["code"]
    e = box["error"]
    if isinstance(e, KeyboardInterrupt):       # stopped from within (STOP), no signal
        return interrupted(done, None)
    known = error_code(e)
    if known is None:
        raise e
    code, message = known
    print(f"error: {message}", file=sys.stderr)
    return code


#: Seconds Ctrl-C gives the command to stop on its own (a bench saving what it measured)
#: before the process exits anyway.
GRACE_SECONDS = 0.5


def interrupted(done: threading.Event, worker: threading.Thread | None) -> int:
    """Ctrl-C (``worker`` given) or a stop from within (``worker`` None).

    Ctrl-C: set ``STOP`` and raise ``KeyboardInterrupt`` inside the worker too, which takes
    effect at its next Python line (an atomic write then removes its temporary file; a
    bench writes the rows it measured), wait up to ``GRACE_SECONDS`` for it, remove any
    temporary file still open, print one line and exit with 130 at once (``os._exit``: the
    worker may be inside a kernel, which cannot be cancelled, and the interpreter's
    shutdown would wait for it). A stop from within returns 130."""
    STOP.set()
    if worker is not None and not done.is_set():
        ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(worker.ident),
                                                   ctypes.py_object(KeyboardInterrupt))
        done.wait(GRACE_SECONDS)
    remove_live_temporaries()
    print("interrupted: stopped; no partial file written", file=sys.stderr)
    if worker is None:
        return EXIT["interrupted"]
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(EXIT["interrupted"])


if __name__ == "__main__":
    raise SystemExit(main())
