"""The exit code of each verdict status (idiff's convention; a run exits with the largest),
in a module of its own so the command line reads it without importing the gate."""

EXIT_CODES = {"PASS": 0, "WARN": 1, "FAIL": 2, "SIZE": 3, "MISSING": 4, "STALE": 4, "ERROR": 4}
