"""The ``whitted`` console entry point (and ``python -m whitted``): Ctrl-C at any moment of
start-up exits like Ctrl-C later on.

Importing the command line (``whitted.cli``: Dr.Jit, numpy, the renderer) takes most of a
second, during which Python's own SIGINT handler would raise ``KeyboardInterrupt`` inside
some import and print a traceback. ``main`` installs a handler first, with nothing heavy
imported yet: a SIGINT while starting prints one line and exits with 130
(``options.EXIT["interrupted"]``) at once; ``whitted.cli.main`` then takes SIGINT over for
the command itself.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

#: ``whitted.options.EXIT["interrupted"]`` (not imported: options imports the renderer).
INTERRUPTED = 130
STARTING_LINE = "interrupted: stopped while starting; nothing written"


def _interrupted_while_starting(signum, frame):
    try:
        sys.stderr.write(STARTING_LINE + "\n")
        sys.stderr.flush()
    finally:
        os._exit(INTERRUPTED)


def main(argv: list[str] | None = None) -> int:
    """Install the start-up SIGINT handler, import ``whitted.cli`` and run its ``main``."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _interrupted_while_starting)
    from .cli import main as cli_main
    return cli_main(argv)
