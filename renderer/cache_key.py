"""Content keys of cached arrays: ``content_key`` hashes what went in, ``code_version`` the
source text of the code that made it (``renderer.accel.cache`` stores under these keys),
and ``CacheWarning``, the warning of an entry that could not be used or written.

Below both ``renderer.accel`` and ``renderer.scene``, so the scene loader keys its cached
arrays without importing the accelerators.
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

import numpy as np


class CacheWarning(UserWarning):
    """A cache entry that could not be used or written (the work is redone)."""


#: Modules of ``renderer/accel`` whose source text is part of every key (they decide what a
#: stored tree holds).
CODE_MODULES = ("bvh_build.py", "device_build.py", "optimize.py", "spatial.py",
                "traverse.py", "cache.py", "builders.py")


@lru_cache(maxsize=None)
def code_version(extra: tuple[str, ...] = ()) -> str:
    """SHA-256 (hex, 16 digits) of the source text of ``CODE_MODULES`` and of the files
    ``extra`` (paths relative to the ``renderer`` package)."""
    h = hashlib.sha256()
    package = Path(__file__).resolve().parent
    here = package / "accel"
    for name in CODE_MODULES:
        p = here / name
        h.update(name.encode() + b"\0" + (p.read_bytes() if p.exists() else b""))
    for rel in extra:
        p = package / rel
        h.update(rel.encode() + b"\0" + (p.read_bytes() if p.exists() else b""))
    return h.hexdigest()[:16]


def content_key(*parts) -> str:
    """SHA-256 (hex) of ``parts``: numpy arrays (dtype, shape and bytes), strings, numbers
    and JSON-able dicts, in order."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"array {a.dtype.str} {a.shape}\0".encode())
            h.update(a.reshape(-1).view(np.uint8).data if a.size else b"")
        elif isinstance(p, (bytes, bytearray)):
            h.update(b"bytes\0" + bytes(p))
        else:
            h.update(("json " + json.dumps(p, sort_keys=True, default=str) + "\0").encode())
    return h.hexdigest()
