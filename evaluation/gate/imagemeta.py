"""Image metadata: what an image was rendered from, and what differs between two images'.

Every EXR this project writes (``whitted render``, the images ``check`` and the pytest plugin
write, and goldens) carries string attributes ``whitted:<field>`` in its header
(``renderer.film.write_exr(metadata=)``). The fields, in the order they are printed
(``FIELDS``):

============  ===============================================================================
field         value
============  ===============================================================================
renderer      ``whitted <version>`` (ours) or ``mitsuba <version> (<variant>)`` (a golden)
scene         the scene's name (its file stem)
scene_key     sha256 of the scene's content: its parsed file without ``[check]`` and its
              meshes' bytes (``reference.golden.scene_key``); equal for ours and the golden
              of the same scene
view          the view's name
resolution    ``<width>x<height>``
shading       ``classic`` or ``physical``
mode          ``exact`` (one ray per pixel centre) or ``converged``
spp           samples per pixel
max_depth     the specular depth limit
backend       ``llvm`` or ``cuda``
precision     ``float32`` or ``float64``
batches       a converged golden's number of independent batches (its ``var`` layer is the
              variance of one batch); converged goldens only
content_key   a golden's lookup key (``reference.golden.content_key``); goldens only
============  ===============================================================================

``image_metadata(path)`` reads them: the EXR's header, else (a golden written before its EXR
carried metadata) its sidecar JSON beside it (``reference.golden.golden_metadata``); a PNG
has none. ``differences(a, b)`` lists the fields whose values differ, one phrase each, which
``whitted check`` and ``whitted diff`` print under a verdict that is not PASS.
"""
from __future__ import annotations

import json
from importlib import metadata as _pkg
from pathlib import Path

from reference import golden as golden_store
from renderer.film import EXR_MAGIC, read_exr_metadata

#: Every field, in the order ``differences`` lists them.
FIELDS = ("renderer", "scene", "scene_key", "view", "resolution", "shading", "mode", "spp",
          "max_depth", "backend", "precision", "batches", "content_key")


def renderer_version() -> str:
    """``whitted <version>`` of the installed package (``whitted unknown`` when it is run
    from a source tree that was never installed)."""
    try:
        return f"whitted {_pkg.version('whitted')}"
    except _pkg.PackageNotFoundError:
        return "whitted unknown"


def scene_key_of(scene) -> str | None:
    """``reference.golden.scene_key`` of a scene loaded from a file (None without one)."""
    if scene.path is None:
        return None
    files = [Path(f) for f in scene.source_files] or [Path(scene.path)]
    return golden_store.scene_key({"scene": golden_store.scene_content_hash(scene.path),
                                   "meshes": [golden_store.file_hash(f) for f in files[1:]]})


def ours_metadata(scene, view: int, *, backend: str, precision: str,
                  exact: bool | None = None, spp: int | None = None) -> dict[str, str]:
    """The metadata of our render of ``scene.cameras[view]`` as ``scene`` stands (its size,
    shading and settings): ``backend`` the backend that ran (``llvm`` / ``cuda``, not
    ``auto``), ``precision``; ``exact`` / ``spp`` when the render's differ from the scene's
    settings (``check`` renders exact goldens' comparisons at 1 spp)."""
    s = scene.settings
    cam = scene.cameras[view]
    exact = s.exact if exact is None else exact
    out = {"renderer": renderer_version(), "scene": scene.name,
           "scene_key": scene_key_of(scene), "view": cam.name,
           "resolution": f"{cam.width}x{cam.height}", "shading": s.shading,
           "mode": "exact" if exact else "converged",
           "spp": 1 if exact else (spp if spp is not None else s.spp),
           "max_depth": s.max_depth, "backend": backend, "precision": precision}
    return {k: str(v) for k, v in out.items() if v is not None}


def _sidecar_metadata(path: Path) -> dict[str, str]:
    side = path.with_suffix(".json")
    if not side.is_file():
        return {}
    try:
        meta = json.loads(side.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    if not isinstance(meta, dict) or "content_key" not in meta:
        return {}
    try:
        return golden_store.golden_metadata(meta)
    except (TypeError, ValueError, AttributeError):
        return {}


def image_metadata(path) -> dict[str, str]:
    """The metadata of the image file ``path``: an EXR's header fields, else the golden
    sidecar beside it (``<stem>.json``), else {} (a PNG, another tool's EXR). Reading errors
    of the EXR are ``renderer.film.read_exr_metadata``'s."""
    path = Path(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    found = read_exr_metadata(path) if magic == EXR_MAGIC else {}
    return found or _sidecar_metadata(path)


def differences(a: dict, b: dict, names=("A", "B"), ignore=()) -> list[str]:
    """The fields whose values differ between metadata ``a`` and ``b``, in ``FIELDS`` order
    (then any other field), one phrase each: ``spp 1 (A) vs 16 (B)``; a field only one side
    has is listed as ``absent`` on the other; keys are shown by their first 12 hex digits.
    Nothing when either side has no metadata. The
    scene's name is not listed when both have the same ``scene_key`` (same content, another
    file name); a golden's ``content_key`` only when both have one."""
    if not a or not b:
        return []
    keys = [k for k in FIELDS if k in a or k in b]
    keys += sorted((set(a) | set(b)) - set(FIELDS))
    out = []
    for k in keys:
        if k in ignore or a.get(k) == b.get(k):
            continue
        if k == "scene" and a.get("scene_key") and a.get("scene_key") == b.get("scene_key"):
            continue        # a file name; the content is the same
        if k == "content_key" and (k not in a or k not in b):
            continue        # a golden's lookup key: absent from ours by design
        out.append(f"{k} {_shown(k, a)} ({names[0]}) vs {_shown(k, b)} ({names[1]})")
    return out


def _shown(key: str, meta: dict) -> str:
    value = meta.get(key, "absent")
    return value[:12] if key in ("scene_key", "content_key") else value


def format_differences(diff: list[str]) -> str:
    """One indented line for a verdict's metadata differences ('' when there are none)."""
    return f"        metadata differs: {'; '.join(diff)}" if diff else ""
