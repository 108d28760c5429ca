"""The command line the probes share (``probe_parser``) and the loop that runs one over its
scenes and writes its rows (``run_probe``). Run a probe from the repository root:
``PYTHONPATH=. python lab/probes/NAME.py ...``."""
from pathlib import Path

from evaluation.bench.part import jsonable, write_atomic


def probe_parser(doc: str, scenes, backend: str = "cuda"):
    """The command line every probe (``lab/probes/probe_*.py``) shares: ``--backend``,
    ``--scenes`` (comma-separated, default ``scenes``), ``--out`` (default ``$OUT`` or
    ``out``) and ``--force``; the probe adds its own options to the parser returned."""
    import argparse
    import os
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--backend", default=backend, choices=("cuda", "llvm"))
    ap.add_argument("--scenes", default=",".join(scenes))
    ap.add_argument("--out", default=os.environ.get("OUT", "out"))
    ap.add_argument("--force", action="store_true", help="replace an existing result")
    return ap


def run_probe(out_file, force: bool, names: list[str], probe_scene, header: dict) -> int:
    """The command line of a probe (``lab/probes/probe_*.py``): refuse an existing
    ``out_file`` without ``--force`` and a scene name with no ``scenes/NAME.toml`` (one line
    on stderr, exit 2) before anything runs; then ``probe_scene(name)`` (a list of rows) per
    scene, the rows so far written atomically (``header`` plus ``rows``) after each one;
    Ctrl-C stops cleanly (one line, exit 130, the rows of the finished scenes kept)."""
    import json
    import sys

    from renderer.outputs import OutputError, check_output_file
    from renderer.scene.model import SceneError

    out_file = Path(out_file)
    try:
        out_file.parent.mkdir(parents=True, exist_ok=True)
        check_output_file(out_file, overwrite=force, flag="--force")
        missing = [n for n in names if not Path(f"scenes/{n}.toml").is_file()]
        if missing:
            raise SceneError(f"--scenes: no scenes/{missing[0]}.toml")
    except (OutputError, SceneError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    rows = []
    try:
        for name in names:
            rows += probe_scene(name)
            write_atomic(out_file, json.dumps(jsonable(dict(header, rows=rows)), indent=1))
    except KeyboardInterrupt:
        print(f"interrupted: {out_file} holds the scenes finished before", file=sys.stderr)
        return 130
    print(f"wrote {out_file}", flush=True)
    return 0
