"""The ``whitted`` console entry point (and ``python -m whitted``): Ctrl-C at any moment of
start-up exits like Ctrl-C later on.

Importing the command line (``whitted.cli``: Dr.Jit, numpy, the renderer) takes most of a
second, during which Python's own SIGINT handler would raise ``KeyboardInterrupt`` inside
some import and print a traceback. ``main`` installs a handler first, with nothing heavy
imported yet: a SIGINT while starting prints one line and exits with 130
(``options.EXIT["interrupted"]``) at once; ``whitted.cli.main`` then takes SIGINT over for
the command itself. Until the handler is in place the module imports only what the
interpreter has loaded already (``os``, ``sys``) and ``signal``: a module-level import of
``tempfile`` or ``threading`` (shutil, zlib, random: some milliseconds) would leave a
window in which a Ctrl-C prints a traceback.

Dr.Jit prints its own complaints about an unusable libLLVM while it is imported (two lines,
then a ``TypeError`` or an LLVM abort at the first kernel); the entry point imports it with
stderr captured and drops those lines, and ``renderer.device.types`` refuses the LLVM
backend in one line with the fix (``llvm_problem``) before any kernel.
"""
from __future__ import annotations

import os
import signal
import sys

#: ``whitted.options.EXIT["interrupted"]`` (not imported: options imports the renderer).
INTERRUPTED = 130
STARTING_LINE = "interrupted: stopped while starting; nothing written"


#: Dr.Jit's own lines when it cannot load a libLLVM it can use (printed while it is
#: imported): ``renderer.device.llvm_problem`` says the same in one line with the fix, when a
#: command needs the backend.
LLVM_NOISE = ("jit_find_library():", "jitc_llvm_init():", "jit_llvm_init():")
#: The file descriptor the start-up Ctrl-C line goes to (stderr, also while it is captured).
_stderr_fd = 2


def _interrupted_while_starting(signum, frame):
    try:
        os.write(_stderr_fd, (STARTING_LINE + "\n").encode())
    finally:
        os._exit(INTERRUPTED)


def _import_drjit_quietly() -> None:
    """Import Dr.Jit with the process's stderr captured, then pass on what it printed except
    its libLLVM complaints (``LLVM_NOISE``)."""
    global _stderr_fd
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except OSError:                      # no stderr to capture
        import drjit  # noqa: F401
        return
    import tempfile  # after the handler: it imports shutil, zlib, random

    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        _stderr_fd = saved
        try:
            import drjit  # noqa: F401
        finally:
            os.dup2(saved, 2)
            _stderr_fd = 2
            os.close(saved)
        tmp.seek(0)
        text = tmp.read().decode("utf-8", "replace")
    kept = [line for line in text.splitlines() if not line.startswith(LLVM_NOISE)]
    if kept:
        print("\n".join(kept), file=sys.stderr)


#: Commands whose process ends at once when the command has returned (``os._exit`` after
#: flushing stdout and stderr): a render has written its files (atomically) and its cache
#: entries (``TreeCache.flush``) by then, and the interpreter's own shutdown (Dr.Jit's and
#: the device's teardown) would add a fifth of a second or more to the time it takes.
#: Commands that start other processes (a study's Dask workers) or serve (the viewer)
#: exit through the interpreter.
QUICK_EXIT = ("render",)


def main(argv: list[str] | None = None) -> int:
    """Install the start-up SIGINT handler, import Dr.Jit (``_import_drjit_quietly``) and
    ``whitted.cli``, and run its ``main``; a ``QUICK_EXIT`` command run as the process
    (``argv`` None) ends it with its exit code."""
    try:
        signal.signal(signal.SIGINT, _interrupted_while_starting)
    except ValueError:                   # not the main thread: its caller owns SIGINT
        pass
    _import_drjit_quietly()
    from .cli import main as cli_main
    code = cli_main(argv)
    words = sys.argv[1:] if argv is None else []
    if words and words[0] in QUICK_EXIT:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code
