"""Command-line entry point: wires the Dr.Jit renderer and the Mitsuba reference harness."""
