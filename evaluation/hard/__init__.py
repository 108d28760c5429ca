"""The hard-case stress suite: cases where ray tracers usually crack, each with a measurable
criterion, run for every accelerator, triangle routine and precision.

The cases and their parameters are data (``cases.toml``, shipped with the package:
``cases.load_cases``); ``cases`` holds the records (``Config``: what a run covers; ``Row``:
case, variant, criterion, measured, pass); ``scenes`` builds the in-memory scenes; ``rays``
spawns and queries the rays (every spawned origin goes through ``rays.spawn_origin``, so a new
offset rule drops in without touching the cases); ``runners`` has one function per case,
registered in ``CASES`` under its table's name, and ``run_suite``; ``report`` writes the
table as markdown, JSON and an HTML page with each case's image (``write_report``).
``whitted hard-cases`` is the command line; ``tests/hard/test_*.py`` run the float32 LLVM
subset in CI.
"""
