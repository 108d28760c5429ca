"""The hard-case table and its records: the cases and their parameters are data
(``cases.toml`` beside this module, shipped with the package, ``load_cases``); ``Config`` says
what a run covers (backend, precisions, accelerators, routines); ``Row`` is one line of the
result, with its criterion and whether it holds."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from renderer.accel import ACCELERATORS, ROUTINES

#: The case table, package data beside this module (in the repository and in a wheel).
CASES_FILE = Path(__file__).resolve().parent / "cases.toml"
PRECISIONS = ("float32", "float64")


# ---- records -----------------------------------------------------------------------------
@dataclass
class Row:
    """One line of the table. variant: "accel/routine/precision" or what the case varies;
    criterion: the bound in words; measured: the value in words; value: the number compared
    (None when the row only reports); passed: the criterion holds; image: PNG path
    relative to the report folder, or None; info: extra numbers (JSON)."""

    case: str
    variant: str
    criterion: str
    measured: str
    passed: bool
    value: float | None = None
    image: str | None = None
    info: dict = field(default_factory=dict)


@dataclass
class Config:
    """What a run covers. backend: "llvm" | "cuda"; precisions, accels, routines: the
    variants; rays: case 1's ray count per BVH variant (None: the table's); out: report
    folder (images are written there) or None; seed: of every random batch; chunk: rays
    per device batch; progress: print one line per finished row to stderr."""

    backend: str = "llvm"
    precisions: tuple = PRECISIONS
    accels: tuple = tuple(ACCELERATORS)
    routines: tuple = tuple(ROUTINES)
    rays: int | None = None
    out: Path | None = None
    seed: int = 1
    chunk: int = 1 << 20
    progress: bool = False


def load_cases(path: Path = CASES_FILE) -> dict:
    """The case table (``CASES_FILE`` unless ``path`` is given)."""
    with open(path, "rb") as f:
        return tomllib.load(f)


def variants(cfg: Config):
    """(accel, routine, precision) of every variant ``cfg`` asks for."""
    for p in cfg.precisions:
        for r in cfg.routines:
            for a in cfg.accels:
                yield a, r, p


# ---- helpers -----------------------------------------------------------------------------
#: Case 2 spawns with the explicit ``ray_epsilon`` override (fraction of the triangle's
#: diagonal), to compare the routines under one fixed offset; the default scale-free spawn
#: (``renderer.shade.offset_origin``) has its own re-intersection test in
#: ``tests/hard/test_offsets_reintersect.py``.
OVERRIDE_EPSILON = 1e-4


#: Render cases whose differences from Mitsuba are ties by design: coplanar faces with
#: other vertices, where our routine gives every face the plane's ``t`` (the lowest face
#: index wins) and Embree's ``t`` rounds per triangle.
PARITY_TIES_BY_DESIGN = ("coplanar faces, other vertices",)
