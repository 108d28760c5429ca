"""The ``whitted`` command line: parse, call the renderer, the reference harness or the
evaluation, print, return an exit code (entry point ``whitted.entry.main``, which installs
the start-up Ctrl-C handling and runs ``whitted.cli.main``)."""
import time as _time

#: When the package was first imported (``whitted render`` reports its timing from here).
STARTED = _time.perf_counter()
