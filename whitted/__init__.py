"""The ``whitted`` command line: parse, call the renderer, the reference harness or the
evaluation, print, return an exit code (entry point ``whitted.cli.main``)."""
