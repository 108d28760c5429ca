"""Golden images: Mitsuba renders of a scene's views, keyed by the content they depend on.

**Stores.** A golden store is any folder. Inside it a golden is two files,
``<scene>/<view>_<shading>_<mode>.exr`` (linear RGB, float32, ZIP compressed; converged
goldens also hold a ``var`` layer, channels ``var.R/G/B``: the per-pixel variance of one
``batch_spp`` estimate, see ``render_converged_with_variance``; its header carries the image
metadata of ``golden_metadata``) and its JSON sidecar ``.json``.
The folder names are only for people: a golden is *found* by its key. The bundled store
(``reference/goldens``, ``BUNDLED_STORE``) is read-only to the command line; re-rendering a
bundled golden is a developer action (``python -m reference.golden --bundled ...``, with the
reason in the commit).

**Keys.** ``golden_inputs`` lists everything a golden depends on: the scene file's content
(its parsed TOML without the ``[check]`` table, so thresholds and comments can change without
re-rendering; the bytes of an OBJ, PLY or Mitsuba XML scene file), the bytes of every mesh
(and MTL) file it reads, how a Mitsuba XML file was read (its ``-D`` defines and
``--approximate``, when given: ``Scene.read``), the view (index and name), shading, mode, the
source of the reference harness, the scene loader and shapes (``HARNESS_FILES``, the bytes of
each file), and the Mitsuba version. ``content_key`` is the sha256 of
those inputs without the Mitsuba version; ``key`` adds the version. No path enters a key, so
an identical copy of a bundled scene anywhere finds its bundled golden; sidecars store no
absolute path.

**Size.** A golden is rendered at the scene's own resolution (each view's), unless the
scene's ``[check]`` table sets ``size = [w, h]`` (and, for converged goldens,
``converged_size``) or the command gives a height (``golden_size``); the sidecar's
``resolution`` records it, and ``check`` renders ours at that size, so pixel coordinates in
verdicts are the golden's. ``[check]`` is not part of the key: after the size there changes,
``check`` still uses the golden it finds, while ``render_goldens`` (``whitted reference``)
calls that golden stale (its size) and replaces it with ``force``.

**Lookup** (``find_golden``): the stores in order, the first golden whose ``content_key``
matches wins (with Mitsuba installed, its version must match too). Otherwise, a golden of the
same scene name, view, shading and mode is *stale* and the message says exactly which inputs
changed (the scene fields by TOML path with their old and new values, as the sidecar's
``scene_fields`` records them; a mesh by file name; a harness file; the Mitsuba version) and
the command that re-renders it; with neither it is *missing*.

**Writing** (``render_goldens``): only what is missing or stale is rendered; a stale file is
replaced only with ``force``; every file is written to a temporary name in its folder and
renamed (atomic). The work is a list of picklable jobs (``golden_jobs``: only what is missing
or stale, each carrying its store and content key), each rendered and written by
``render_golden_job`` in this process or on an executor's workers (``render_goldens(...,
executor=)``, ``whitted reference --workers N``); the files are the same either way.
"""
from __future__ import annotations

import datetime
import functools
import hashlib
import json
import os
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from renderer.film import read_exr_layers, write_exr
from renderer.outputs import OutputError, check_output_dir, write_text
from renderer.scene import SHADING_MODES, Scene, load_scene
from renderer.scene.importers import IMPORT_KINDS

from . import MODES

ROOT = Path(__file__).resolve().parent.parent
BUNDLED_STORE = Path(__file__).resolve().parent / "goldens"
GOLDEN_DIR = BUNDLED_STORE           # the name older callers use
#: Converged goldens: total spp and the number of independent batches (variance estimate).
CONVERGED_SPP = 64
CONVERGED_BATCHES = 16
#: Sidecar format: 2 = content keys (``key``, ``content_key``, ``inputs``).
FORMAT = 2
#: Source files whose code decides what a golden holds (package-relative to the project root).
HARNESS_FILES = (
    "reference/mitsuba_scene.py", "reference/plugins.py",
    "renderer/scene/loader.py", "renderer/scene/shapes.py", "renderer/scene/meshio.py",
    "renderer/scene/subdivide.py", "renderer/parallel.py",
)
#: The readers of other tools' scene files (``renderer.scene.load_scene``): part of the key
#: of a golden of an OBJ, PLY or Mitsuba XML scene only, so TOML scenes' keys do not change
#: with them.
IMPORT_FILES = (
    "renderer/scene/importers.py", "renderer/scene/objmtl.py",
    "renderer/scene/mitsuba_xml.py", "renderer/scene/plyattrs.py", "renderer/scene/parts.py",
)
#: Environment variable naming the user's golden store.
STORE_ENV = "WHITTED_GOLDENS"


class GoldenError(RuntimeError):
    """A golden image is missing, stale or unreadable, or a store cannot be written."""


@dataclass
class Golden:
    image: np.ndarray            # float32 (H, W, 3) linear RGB
    var: np.ndarray | None       # float32 (H, W, 3) variance of one batch_spp estimate
    meta: dict
    path: Path


@dataclass
class Lookup:
    """The outcome of ``find_golden``: status "ok" (``golden`` set), "stale" (``path`` is the
    outdated golden, ``changes`` what differs) or "missing"; ``message`` says it in one line,
    ``command`` re-renders it."""

    status: str
    golden: Golden | None = None
    path: Path | None = None
    changes: list[str] = field(default_factory=list)
    message: str = ""
    command: str = ""


# ---- stores ---------------------------------------------------------------------------------
def is_bundled(store) -> bool:
    return Path(store).resolve() == BUNDLED_STORE


def configured_store(cwd=None) -> tuple[Path | None, str]:
    """The user's golden store when none is given on the command line: ``$WHITTED_GOLDENS``,
    else ``goldens`` of a ``[tool.whitted]`` table in the nearest ``pyproject.toml`` upward from
    ``cwd`` (relative to that file's folder). Returns (store or None, where it came from)."""
    env = os.environ.get(STORE_ENV)
    if env:
        return Path(env), f"${STORE_ENV}"
    here = Path(cwd or Path.cwd()).resolve()
    for folder in (here, *here.parents):
        py = folder / "pyproject.toml"
        if not py.is_file():
            continue
        try:
            data = tomllib.loads(py.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            reason = " ".join(str(e).split())[:160]
            raise GoldenError(f"{py}: cannot read [tool.whitted]: {reason}") from None
        tool = data.get("tool", {})
        table = tool.get("whitted") if isinstance(tool, dict) else None
        if table is None:
            return None, ""                   # the nearest pyproject.toml decides
        if not isinstance(table, dict) or not isinstance(table.get("goldens", ""), str):
            raise GoldenError(f"{py}: tool.whitted.goldens: expected a folder name (string)")
        if "goldens" in table:
            return folder / table["goldens"], f"{py} [tool.whitted] goldens"
        return None, ""
    return None, ""


def search_stores(user_store=None, *, cwd=None) -> list[Path]:
    """The stores ``check`` and ``compare`` search, in order: the user's (``user_store``, else
    ``configured_store``), then the bundled one."""
    store = Path(user_store) if user_store else configured_store(cwd)[0]
    stores = [store] if store is not None else []
    if store is None or not is_bundled(store):
        stores.append(BUNDLED_STORE)
    return stores


def golden_path(scene_name: str, view_name: str, shading: str, mode: str,
                root: Path = BUNDLED_STORE) -> Path:
    return Path(root) / scene_name / f"{view_name}_{shading}_{mode}.exr"


def _display(p: Path) -> str:
    """``p`` relative to the working folder or the project when inside them (for messages);
    the bundled store by that name."""
    p = Path(p)
    if is_bundled(p):
        return "the bundled store"
    for base in (Path.cwd(), ROOT):
        try:
            return str(p.resolve().relative_to(base.resolve()))
        except ValueError:
            pass
    return str(p)


def regenerate_command(scene_path, store=None) -> str:
    """The command that (re-)renders the goldens of ``scene_path`` into ``store``."""
    scene = _display(Path(scene_path))
    if store is None or is_bundled(store):
        return f"python -m reference.golden --bundled --force {scene}"
    return f"whitted reference --goldens {_display(Path(store))} --force {scene}"


# ---- keys -----------------------------------------------------------------------------------
def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def file_hash(path: Path) -> str:
    """sha256 of a file's bytes (cached while its size and modification time stay)."""
    st = Path(path).stat()
    return _file_hash(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=64)
def _file_hash(path: str, mtime_ns: int, size: int) -> str:
    return _sha(Path(path).read_bytes())


def code_hash(path: Path) -> str:
    st = Path(path).stat()
    return _code_hash(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=64)
def _code_hash(path: str, mtime_ns: int, size: int) -> str:
    """sha256 of a Python file's bytes (line endings normalised). Not of its tokens: token
    numbers and f-string tokens differ between Python versions (3.12 split f-strings), and a
    key must not change with the interpreter that checks it."""
    return _sha(Path(path).read_bytes().replace(b"\r\n", b"\n"))


def harness_hashes() -> dict[str, str]:
    """``code_hash`` of every file in ``HARNESS_FILES``."""
    return {f: code_hash(ROOT / f) for f in HARNESS_FILES}


def import_hashes() -> dict[str, str]:
    """``code_hash`` of every file in ``IMPORT_FILES`` (keys of imported scenes' goldens)."""
    return {f: code_hash(ROOT / f) for f in IMPORT_FILES}


def is_imported(path) -> bool:
    """Whether a scene file is another tool's format (OBJ, PLY, Mitsuba XML), not TOML."""
    return Path(path).suffix.lower() != ".toml"


def scene_content_hash(path) -> str:
    """sha256 of the scene file's parsed TOML without its ``[check]`` table (canonical JSON);
    for an imported scene (OBJ, PLY, XML) the sha256 of its bytes."""
    if is_imported(path):
        return file_hash(Path(path))
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    data.pop("check", None)
    return _sha(json.dumps(data, sort_keys=True, separators=(",", ":")).encode())


#: A scene field whose value is longer than this (as JSON) is recorded by its sha256 only.
FIELD_VALUE_CHARS = 120
#: At most this many changed scene fields are named in a STALE message.
FIELDS_NAMED = 4


def _leaves(value, where: str, out: dict) -> None:
    if isinstance(value, dict):
        for k in sorted(value):
            _leaves(value[k], f"{where}.{k}" if where else str(k), out)
    elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        for i, v in enumerate(value):                  # an array of tables: [[lights]]
            _leaves(v, f"{where}[{i}]", out)
    else:                                              # TOML dates and times: as text
        text = json.dumps(value, sort_keys=True, default=str)
        out[where] = json.loads(text) if len(text) <= FIELD_VALUE_CHARS else \
            {"sha256": _sha(text.encode())}


def scene_fields(path) -> dict | None:
    """The scene file's fields without ``[check]``, flattened to dotted TOML paths
    (``materials.white.kd``, ``lights[0].position``, ``render.spp``) -> value (a long value:
    ``{"sha256": ...}``), as a golden's sidecar records them so that a STALE line can name
    the fields that changed. None for an imported scene (OBJ, PLY, XML: bytes only)."""
    if is_imported(path):
        return None
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    data.pop("check", None)
    out: dict = {}
    _leaves(data, "", out)
    return out


def _show(value) -> str:
    if isinstance(value, dict) and set(value) == {"sha256"}:
        return "(a long value)"
    return json.dumps(value, default=str)


def describe_fields(old: dict, new: dict) -> list[str]:
    """The fields that differ between two ``scene_fields``, one phrase each
    (``materials.white.kd 0.5 -> 0.4``, ``lights[1] added``), at most ``FIELDS_NAMED``
    and a count of the rest."""
    out = []
    for key in sorted(set(old) | set(new)):
        if key not in old:
            out.append(f"{key} added ({_show(new[key])})")
        elif key not in new:
            out.append(f"{key} removed (was {_show(old[key])})")
        elif json.dumps(old[key], sort_keys=True) != json.dumps(new[key], sort_keys=True):
            out.append(f"{key} {_show(old[key])} -> {_show(new[key])}")
    if len(out) > FIELDS_NAMED:
        out = out[:FIELDS_NAMED] + [f"{len(out) - FIELDS_NAMED} more scene fields"]
    return out


def mitsuba_version() -> str | None:
    """The installed Mitsuba's version (without importing it), or None."""
    from importlib import metadata
    try:
        return metadata.version("mitsuba")
    except metadata.PackageNotFoundError:
        return None


def golden_inputs(scene: Scene, *, view: int, shading: str, mode: str,
                  mitsuba: str | None = None) -> dict:
    """Everything the golden of ``scene`` (loaded from a file) for one view, shading and mode
    depends on; ``mitsuba``: the version (default: the installed one)."""
    if scene.path is None:
        raise GoldenError(f"scene {scene.name!r} has no file; goldens exist only for files")
    files = [Path(f) for f in scene.source_files] or [Path(scene.path)]
    imported = is_imported(scene.path) or any(o.kind in IMPORT_KINDS for o in scene.objects)
    return {
        "scene": scene_content_hash(scene.path),
        "meshes": [file_hash(f) for f in files[1:]],
        "view": view, "view_name": scene.cameras[view].name,
        "shading": shading, "mode": mode,
        "code": {**harness_hashes(), **(import_hashes() if imported else {})},
        **({"read": scene.read} if scene.read else {}),     # -D defines, --approximate
        "mitsuba_version": mitsuba or mitsuba_version(),
    }


def content_key(inputs: dict) -> str:
    """sha256 of ``inputs`` without the Mitsuba version."""
    body = {k: v for k, v in inputs.items() if k != "mitsuba_version"}
    return _sha(json.dumps(body, sort_keys=True).encode())


def full_key(inputs: dict) -> str:
    """sha256 of ``inputs`` including the Mitsuba version."""
    return _sha(json.dumps(inputs, sort_keys=True).encode())


def scene_key(inputs: dict) -> str:
    """sha256 of the scene's own content in ``inputs`` (``golden_inputs``: the scene file's
    ``scene_content_hash`` and its meshes' bytes), without view, mode or code: equal for
    every image of the same scene content, ours or a golden (image metadata)."""
    body = {"scene": inputs.get("scene"), "meshes": list(inputs.get("meshes", []))}
    return _sha(json.dumps(body, sort_keys=True).encode())


def golden_metadata(meta: dict) -> dict[str, str]:
    """The image metadata of a golden (``renderer.film.write_exr(metadata=)``'s fields) from
    its sidecar ``meta``: who rendered it, the scene's ``scene_key``, view, resolution and
    settings, and the backend and precision of its Mitsuba variant. A golden written
    before its EXR carried metadata is described by its sidecar through this too."""
    inputs = meta.get("inputs") if isinstance(meta.get("inputs"), dict) else {}
    variant = str(meta.get("variant", ""))
    out = {"renderer": f"mitsuba {meta.get('mitsuba_version')} ({variant or '?'})",
           "scene": meta.get("scene_name"), "scene_key": scene_key(inputs) if inputs else None,
           "view": meta.get("view_name"),
           "resolution": "x".join(str(int(x)) for x in meta.get("resolution", []))
           if isinstance(meta.get("resolution"), list) else None,
           "shading": meta.get("shading"), "mode": meta.get("mode"), "spp": meta.get("spp"),
           "max_depth": meta.get("max_depth"),
           "backend": variant.split("_")[0] if variant else None,
           "precision": "float64" if "double" in variant else "float32" if variant else None,
           "batches": meta.get("batches") if meta.get("mode") == "converged" else None,
           "content_key": meta.get("content_key")}
    return {k: str(v) for k, v in out.items() if v is not None}


def _read_text(inputs: dict) -> str:
    read = inputs.get("read", {})
    parts = [f"-D {k}={v}" for k, v in sorted(read.get("defines", {}).items())]
    return " ".join(parts + (["--approximate"] if read.get("approximate") else [])) or "none"


def describe_changes(old: dict, new: dict, mesh_files=(), old_fields=None,
                     new_fields=None) -> list[str]:
    """What differs between two ``golden_inputs``, one phrase each: the scene fields that
    changed (``describe_fields``, when both ``scene_fields`` are given; else "scene file
    content"), a mesh by its file name (``mesh_files``: the new scene's mesh files, in
    ``meshes`` order), the view, shading or mode, a harness file by its path, the Mitsuba
    version."""
    out = []
    names = [Path(f).name for f in mesh_files]
    if old.get("scene") != new.get("scene"):
        fields = describe_fields(old_fields, new_fields) \
            if isinstance(old_fields, dict) and isinstance(new_fields, dict) else []
        out += fields or ["scene file content"]
    om, nm = old.get("meshes", []), new.get("meshes", [])
    if len(om) != len(nm):
        out.append(f"mesh count {len(om)} -> {len(nm)}")
    else:
        out += [f"mesh {names[i] if i < len(names) else i} (its bytes)"
                for i, (a, b) in enumerate(zip(om, nm)) if a != b]
    for k in ("view", "view_name", "shading", "mode"):
        if old.get(k) != new.get(k):
            out.append(f"{k} {old.get(k)!r} -> {new.get(k)!r}")
    if old.get("read", {}) != new.get("read", {}):
        out.append(f"how the file is read (-D, --approximate) {_read_text(old)} -> "
                   f"{_read_text(new)}")
    oc, nc = old.get("code", {}), new.get("code", {})
    out += [f"harness file {f}" for f in sorted(set(oc) | set(nc)) if oc.get(f) != nc.get(f)]
    ov, nv = old.get("mitsuba_version"), new.get("mitsuba_version")
    if nv is not None and ov != nv:
        out.append(f"Mitsuba version {ov} -> {nv}")
    return out


# ---- reading --------------------------------------------------------------------------------
def _sidecars(store: Path):
    if Path(store).is_dir():
        yield from sorted(Path(store).glob("*/*.json"))


def _read_meta(side: Path) -> dict:
    """A golden's sidecar JSON; ``GoldenError`` (one line naming the file and key) for
    one that cannot be read, is not UTF-8 JSON, is not an object or has a key of the
    wrong type."""
    try:
        meta = json.loads(side.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        reason = " ".join(str(e).split())[:160]
        raise GoldenError(f"{_display(side)}: unreadable golden sidecar: {reason}") from None
    if not isinstance(meta, dict):
        raise GoldenError(f"{_display(side)}: golden sidecar: expected a JSON object, got "
                          f"{type(meta).__name__}")
    for key, kind in (("content_key", str), ("inputs", dict)):
        if key in meta and not isinstance(meta[key], kind):
            raise GoldenError(f"{_display(side)}: golden sidecar key {key!r}: expected "
                              f"{'a string' if kind is str else 'an object'}, got "
                              f"{type(meta[key]).__name__}")
    return meta


def _load(exr: Path, meta: dict) -> Golden:
    try:
        layers = read_exr_layers(exr)
    except (OSError, ValueError) as e:
        raise GoldenError(f"{_display(exr)}: unreadable golden: {e}") from None
    return Golden(layers[""], layers.get("var"), meta, exr)


def find_golden(scene: Scene, *, view: int, shading: str, mode: str, stores) -> Lookup:
    """Look the golden of ``scene`` up in ``stores`` (in order) by content (module docstring).
    Raises ``GoldenError`` only for an unreadable file."""
    inputs = golden_inputs(scene, view=view, shading=shading, mode=mode)
    want = content_key(inputs)
    stores = [Path(s) for s in stores]
    stale = None
    for store in stores:
        for side in _sidecars(store):
            meta = _read_meta(side)
            if meta.get("content_key") != want:
                continue
            have = meta.get("inputs", {}).get("mitsuba_version")
            if inputs["mitsuba_version"] is not None and have != inputs["mitsuba_version"]:
                stale = stale or (side, meta)
                continue
            return Lookup("ok", golden=_load(side.with_suffix(".exr"), meta),
                          path=side.with_suffix(".exr"))
    name = golden_path(scene.name, scene.cameras[view].name, shading, mode, Path("."))
    if stale is None:
        for store in stores:
            side = (store / name).with_suffix(".json")
            if side.is_file():
                stale = (side, _read_meta(side))
                break
    if stale is not None:
        side, meta = stale
        store = side.parent.parent
        old = meta.get("inputs")
        exr = _display(side.with_suffix(".exr"))
        if not old:
            cmd = (f"python -m reference.golden --bundled --rekey {_display(scene.path)}"
                   if is_bundled(store) else regenerate_command(scene.path, store))
            return Lookup("stale", path=side.with_suffix(".exr"), command=cmd,
                          changes=["sidecar format 1 (keyed by path)"],
                          message=f"golden {exr} has a sidecar without content keys "
                                  f"(format 1); re-key or re-render it with `{cmd}`")
        fields = scene_fields(scene.path) if "scene_fields" in meta else None
        changes = describe_changes(old, inputs, [Path(f) for f in scene.source_files][1:],
                                   meta.get("scene_fields"), fields) or ["its key"]
        cmd = regenerate_command(scene.path, store)
        return Lookup("stale", path=side.with_suffix(".exr"), changes=changes, command=cmd,
                      message=f"golden {exr} is stale (changed since it was rendered: "
                              f"{'; '.join(changes)}); re-render it with `{cmd}`")
    users = [s for s in stores if not is_bundled(s)]
    cmd = (f"whitted reference --goldens {_display(users[0]) if users else 'DIR'} "
           f"{_display(Path(scene.path))}")
    where = " or ".join(_display(s) for s in stores) or "no store"
    return Lookup("missing", command=cmd,
                  message=f"no golden of {scene.name}/{name.stem} in {where}; render it with "
                          f"`{cmd}`")


def load_golden(scene: Scene, *, view: int, shading: str, mode: str, root=None,
                stores=None) -> Golden:
    """The golden of ``scene`` for one view/shading/mode from ``stores`` (default: ``root``
    alone, else the bundled store). Raises ``GoldenError`` naming the command that renders it
    when it is missing or stale."""
    if stores is None:
        stores = [root if root is not None else BUNDLED_STORE]
    found = find_golden(scene, view=view, shading=shading, mode=mode, stores=stores)
    if found.status != "ok":
        raise GoldenError(found.message)
    return found.golden


# ---- rendering ------------------------------------------------------------------------------
def golden_size(scene: Scene, mode: str, size: int | None = None,
                converged_size: int | None = None) -> tuple[int, int] | None:
    """(width, height) of the goldens of ``scene`` in ``mode``, or None for the scene's own
    resolution (each view's). In order: a height given here (``converged_size`` for a
    converged golden, else ``size``; the width follows the aspect of the scene's first
    view), else the scene's ``[check]`` ``converged_size`` (converged goldens) or ``size``,
    else None."""
    height = converged_size if mode == "converged" and converged_size is not None else size
    if height is not None:
        cam = scene.cameras[0]
        return max(1, int(round(height * cam.width / cam.height))), int(height)
    check = scene.check or {}
    wh = check.get("converged_size") if mode == "converged" else None
    wh = wh or check.get("size")
    return (int(wh[0]), int(wh[1])) if wh else None


def _sized(scene: Scene, size) -> Scene:
    """``scene`` with every view ``size`` = (width, height) pixels (None: unchanged)."""
    return scene if size is None else scene.with_size(int(size[0]), int(size[1]))


def _progress_bar(total: int, enabled: bool):
    state = {"done": 0}

    def step(label: str = ""):
        state["done"] += 1
        if not enabled:
            return
        n = state["done"]
        bar = "#" * int(30 * n / max(total, 1))
        sys.stderr.write(f"\r[{bar:<30}] {n}/{total} {label[:50]:<50}")
        if n == total:
            sys.stderr.write("\n")
        sys.stderr.flush()
    return step


def plan_goldens(scene_paths, *, root, modes=MODES, shadings=SHADING_MODES,
                 size: int | None = None, converged_size: int | None = None,
                 read: dict | None = None):
    """For each scene x shading x mode x view: (scene_path, shading, mode, view, Lookup in
    ``root`` alone). A golden whose key matches but whose size is not the one asked for
    (``golden_size``; the view's resolution by default) is stale, its change the size.
    read: how the files are read (``load_scene``'s ``defines`` and ``approximate``).
    Raises ``SceneError`` for a bad scene file."""
    plan = []
    for scene_path in scene_paths:
        for shading in shadings:
            scene = load_scene(scene_path, shading=shading, **(read or {}))
            for mode in modes:
                wh = golden_size(scene, mode, size, converged_size)
                for v, cam in enumerate(scene.cameras):
                    found = find_golden(scene, view=v, shading=shading, mode=mode,
                                        stores=[root])
                    want = list(wh) if wh else [cam.width, cam.height]
                    have = found.golden.meta.get("resolution") if found.golden else None
                    if found.status == "ok" and have != want:
                        found = _resized_lookup(found, scene_path, root, have, want)
                    plan.append((scene_path, shading, mode, v, found))
    return plan


def _resized_lookup(found: Lookup, scene_path, root, have, want) -> Lookup:
    """The stale ``Lookup`` of an up-to-date golden of another size than ``want``."""
    change = f"size {'x'.join(map(str, have or ['?']))} -> {want[0]}x{want[1]}"
    cmd = regenerate_command(scene_path, root)
    return Lookup("stale", path=found.path, changes=[change], command=cmd,
                  message=f"golden {_display(found.path)} is stale ({change}: the size asked "
                          f"for); re-render it with `{cmd}`")


def _check_store(root: Path, bundled: bool) -> None:
    """Refuse the bundled store unless ``bundled``, and a file where the store should be."""
    if is_bundled(root) and not bundled:
        raise GoldenError(f"the bundled golden store {_display(root)} is read-only; give a "
                          "store of your own (--goldens DIR, $WHITTED_GOLDENS or "
                          "[tool.whitted] goldens in pyproject.toml)")
    if Path(root).exists() and not Path(root).is_dir():
        raise GoldenError(f"golden store {root}: exists and is not a folder")


def golden_jobs(scene_paths, *, spp: int = CONVERGED_SPP, batches: int = CONVERGED_BATCHES,
                size: int | None = None, converged_size: int | None = None,
                modes=MODES, shadings=SHADING_MODES, root: Path = BUNDLED_STORE,
                bundled: bool = False, force: bool = False, plan=None,
                read: dict | None = None) -> list[dict]:
    """The goldens of every scene x shading x mode x view that are missing or stale in the
    store ``root``, one picklable spec each (a plain dict of str / int / bool): what
    ``render_golden_job`` needs to render and write that golden in any process, the sidecar's
    content key included (the job checks it against the scene it loads).

    An up-to-date golden gets no job; a stale one is a ``GoldenError`` unless ``force``;
    the bundled store is refused unless ``bundled``. size / converged_size: image heights
    (``golden_size``; None: the scene's ``[check]`` size, else its own resolution). plan:
    ``plan_goldens``'s answer when the caller already has it (else it is made here). read:
    how the scene files are read (``plan_goldens``; a job carries it as JSON text)."""
    root = Path(root)
    _check_store(root, bundled)
    if plan is None:
        plan = plan_goldens(scene_paths, root=root, modes=modes, shadings=shadings,
                            size=size, converged_size=converged_size, read=read)
    stale = [p for p in plan if p[4].status == "stale"]
    if stale and not force:
        lines = "; ".join(p[4].message.split("; re-render")[0] for p in stale[:3])
        more = f" (and {len(stale) - 3} more)" if len(stale) > 3 else ""
        raise GoldenError(f"{lines}{more}; pass --force to replace "
                          f"{'it' if len(stale) == 1 else 'them'}")
    jobs = []
    for scene_path, shading, mode, v, found in plan:
        if found.status == "ok":
            continue
        scene = load_scene(scene_path, shading=shading, **(read or {}))
        wh = golden_size(scene, mode, size, converged_size)
        scene = _sized(scene, wh)
        out = golden_path(scene.name, scene.cameras[v].name, shading, mode, root)
        replaces = found.path if found.status == "stale" and found.path else None
        jobs.append({
            "scene": str(scene_path), "shading": shading, "mode": mode, "view": v,
            "width": wh[0] if wh else 0, "height": wh[1] if wh else 0,   # 0: the view's own
            "spp": spp, "batches": batches, "read": json.dumps(read or {}, sort_keys=True),
            "root": str(root), "bundled": bool(bundled), "out": str(out),
            "status": found.status,
            "replaces": str(replaces) if replaces is not None and replaces != out else "",
            "content_key": content_key(golden_inputs(scene, view=v, shading=shading,
                                                     mode=mode)),
        })
    return jobs


def render_golden_job(job: dict, step=None) -> str:
    """Render one golden (a ``golden_jobs`` spec) with Mitsuba and write its EXR, then its
    format-2 sidecar (both atomic, ``renderer.outputs``); a stale golden of the same key
    under another name is removed afterwards. Returns the EXR path. ``step(label)`` is
    called per unit of work (one per batch of a converged golden). The executor task of
    ``render_goldens``; raises ``GoldenError`` when the scene's inputs no longer match the
    planned content key (it changed since the plan) or the store is the bundled one and
    the job does not say ``bundled``."""
    import mitsuba as mi

    from . import mitsuba_variant
    from .mitsuba_scene import render_converged_with_variance, render_mitsuba

    root = Path(job["root"])
    _check_store(root, job.get("bundled", False))
    variant = mitsuba_variant()
    step = step or (lambda label="": None)
    scene_path, v, mode, batches = job["scene"], job["view"], job["mode"], job["batches"]
    shading = job["shading"]
    read = json.loads(job.get("read") or "{}")
    scene = _sized(load_scene(scene_path, shading=shading, **read),
                   (job["width"], job["height"]) if job["height"] else None)
    cam = scene.cameras[v]
    out = Path(job["out"])
    inputs = golden_inputs(scene, view=v, shading=shading, mode=mode, mitsuba=mi.__version__)
    if content_key(inputs) != job["content_key"]:
        raise GoldenError(f"{_display(Path(scene_path))}: its inputs changed since the goldens "
                          f"were planned ({out.name}); run the command again")
    label = f"{scene.name}/{out.name}"
    var, b_spp = None, 1
    if mode == "exact":
        img = render_mitsuba(scene, view=v, mode="exact")
        step(label)
        used_spp = 1
    else:
        img, var, b_spp = render_converged_with_variance(
            scene, view=v, spp=job["spp"], batches=batches,
            progress=lambda label=label: step(label))
        used_spp = job["spp"]
    meta = sidecar(scene, inputs, resolution=[cam.width, cam.height], spp=used_spp,
                   batch_spp=b_spp, batches=batches if mode == "converged" else 1,
                   variant=variant)
    # the image first, its sidecar last: an interrupted run leaves no sidecar that vouches
    # for a missing image (both writes are atomic: renderer.outputs)
    write_exr(out, img, layers=None if var is None else {"var": var}, overwrite=True,
              metadata=golden_metadata(meta))
    write_text(out.with_suffix(".json"), json.dumps(meta, indent=1) + "\n", overwrite=True)
    if job.get("replaces"):
        old = Path(job["replaces"])
        old.unlink(missing_ok=True)
        old.with_suffix(".json").unlink(missing_ok=True)
    return str(out)


def render_goldens(scene_paths, *, force: bool = False, spp: int = CONVERGED_SPP,
                   batches: int = CONVERGED_BATCHES, size: int | None = None,
                   converged_size: int | None = None, modes=MODES,
                   shadings=SHADING_MODES, progress: bool = True,
                   root: Path = BUNDLED_STORE, bundled: bool = False,
                   report=None, executor=None, read: dict | None = None) -> list[Path]:
    """Render the goldens of every scene x view x shading x mode into the store ``root`` that
    are missing there or stale; an up-to-date golden is kept, a stale one is replaced only
    with ``force`` (else ``GoldenError`` before anything is rendered).

    spp: converged samples per pixel in total (``batches`` independent renders of
    ``spp // batches`` each, for the per-pixel variance). size: image height in pixels (width
    follows the camera's aspect); converged_size: the same for converged goldens (None:
    ``size``); with neither, the scene's ``[check]`` ``size`` / ``converged_size``, else its
    own resolution (``golden_size``). bundled: allow ``root`` to be the bundled store (a
    developer action). report: called with one line per golden kept or written. executor: an
    ``evaluation.gate.executor`` object (``.map(fn, items)`` yielding ``(index, result)``, e.g.
    Dask workers, one GPU each) to render the jobs (``golden_jobs``) on; None: here, one
    after another. The files are the same either way. read: how the scene files are read
    (``load_scene``'s ``defines`` and ``approximate``; part of the key). Returns the
    written EXR paths (in job order).
    """
    root = Path(root)
    _check_store(root, bundled)
    plan = plan_goldens(scene_paths, root=root, modes=modes, shadings=shadings, size=size,
                        converged_size=converged_size, read=read)
    jobs = golden_jobs(scene_paths, spp=spp, batches=batches, size=size,
                       converged_size=converged_size, modes=modes, shadings=shadings,
                       root=root, bundled=bundled, force=force, plan=plan, read=read)
    for p in plan:
        if p[4].status == "ok" and report:
            report(f"up to date: {_display(p[4].path)}")
    try:
        check_output_dir(root)
    except OutputError as e:
        raise GoldenError(f"golden store {e}") from None

    def done(job, path):
        if report and not progress:         # with a progress bar, the bar names each file
            report(f"{'replaced' if job['status'] == 'stale' else 'wrote'}: {_display(path)}")
        return path

    units = [batches if j["mode"] == "converged" else 1 for j in jobs]
    step = _progress_bar(sum(units), progress)
    if executor is None:
        return [done(job, Path(render_golden_job(job, step))) for job in jobs]
    written = [None] * len(jobs)
    for i, path in executor.map(render_golden_job, jobs):
        written[i] = done(jobs[i], Path(path))
        for _ in range(units[i]):
            step(Path(path).name)
    return written


#: The reference's spawn rule for every golden (``reference.mitsuba_scene.to_mitsuba_dict``'s
#: default); recorded in the sidecars.
GOLDEN_SPAWN = "mitsuba"


def sidecar(scene: Scene, inputs: dict, *, resolution, spp: int, batch_spp: int, batches: int,
            variant: str, date: str | None = None) -> dict:
    """The JSON sidecar of a golden: its keys, its inputs and how it was rendered (no
    absolute path). ``spawn``: how the reference spawned secondary and shadow rays (always
    Mitsuba's own ``spawn_ray`` / ``spawn_ray_to``: "mitsuba"); a check renders ours with
    that rule (``renderer.scene.SPAWN_RULES``) so both trace the same rays."""
    return {
        "format": FORMAT, "key": full_key(inputs), "content_key": content_key(inputs),
        "scene_name": scene.name, "scene_file": Path(scene.path).name,
        "view": inputs["view"], "view_name": inputs["view_name"],
        "shading": inputs["shading"], "mode": inputs["mode"],
        "spp": spp, "batch_spp": batch_spp, "batches": batches,
        "resolution": list(resolution), "mitsuba_version": inputs["mitsuba_version"],
        "variant": variant, "max_depth": scene.settings.max_depth, "spawn": GOLDEN_SPAWN,
        "inputs": inputs, "scene_fields": scene_fields(scene.path),
        "date": date or datetime.datetime.now(datetime.timezone.utc).isoformat(
            timespec="seconds"),
    }


# ---- developer harness: the bundled store -------------------------------------------------
def rekey(scene_paths, *, root: Path = BUNDLED_STORE, verify=MODES,
          report=print) -> list[Path]:
    """Give the existing goldens of ``scene_paths`` in ``root`` the keys of the current code
    (e.g. after a harness change that does not change a pixel), keeping their EXRs.
    verify: the modes whose goldens are first re-rendered: an exact golden must come out
    bit-identical, a converged one (re-rendered with its seeds) within 1e-6 relative;
    otherwise it is left stale and reported. The sidecar's ``rekeyed`` records the
    ``content_key`` it had (``from``) and whether it was verified. Returns the sidecars
    rewritten."""
    import mitsuba as mi

    from . import mitsuba_variant
    from .mitsuba_scene import render_converged_with_variance, render_mitsuba

    mitsuba_variant()
    done = []
    for scene_path in scene_paths:
        for shading in SHADING_MODES:
            base = load_scene(scene_path, shading=shading)
            for v, cam in enumerate(base.cameras):
                for mode in MODES:
                    exr = golden_path(base.name, cam.name, shading, mode, root)
                    side = exr.with_suffix(".json")
                    if not side.is_file():
                        continue
                    meta = _read_meta(side)
                    w, h = meta["resolution"]
                    scene = base.with_size(w, h)
                    g = _load(exr, meta)
                    checked = mode in verify
                    if checked:
                        if mode == "exact":
                            img = render_mitsuba(scene, view=v, mode="exact")
                            same = np.array_equal(img, g.image)
                        else:
                            img, _, _ = render_converged_with_variance(
                                scene, view=v, spp=meta["spp"], batches=meta["batches"])
                            same = np.allclose(img, g.image, rtol=1e-6, atol=1e-7)
                        if not same:
                            report(f"differs, left stale: {_display(exr)} (max abs "
                                   f"{float(np.abs(img - g.image).max()):.3g})")
                            continue
                    inputs = golden_inputs(scene, view=v, shading=shading, mode=mode,
                                           mitsuba=mi.__version__)
                    new = sidecar(scene, inputs, resolution=[w, h], spp=meta["spp"],
                                  batch_spp=meta["batch_spp"], batches=meta["batches"],
                                  variant=meta["variant"], date=meta["date"])
                    # the key it had (its harness is in the history) and whether a
                    # re-render confirmed its pixels
                    new["rekeyed"] = {"from": meta.get("content_key"), "verified": checked}
                    write_text(side, json.dumps(new, indent=1) + "\n", overwrite=True)
                    report(f"rekeyed: {_display(side)}")
                    done.append(side)
    return done


def main(argv=None) -> int:
    """``python -m reference.golden --bundled [--force] [--rekey] SCENE...``: the developer
    harness that renders (or re-keys) goldens in the bundled store."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m reference.golden",
                                description="Developer harness: render goldens into the "
                                "bundled store (reference/goldens). Say why in the commit.")
    p.add_argument("scenes", nargs="+", type=Path)
    p.add_argument("--bundled", action="store_true", required=True,
                   help="required: confirms that the bundled store is to be written")
    p.add_argument("--force", action="store_true", help="replace stale goldens")
    p.add_argument("--rekey", action="store_true",
                   help="re-key existing goldens to the current code after verifying that a "
                        "re-render gives the same pixels")
    p.add_argument("--verify", nargs="*", choices=MODES, default=list(MODES),
                   help="with --rekey: the modes whose goldens are re-rendered and compared "
                        "first (default both; converged re-renders are slow)")
    p.add_argument("--size", type=int, default=None,
                   help="image height (default: the scene's [check] size, else its own "
                        "resolution)")
    p.add_argument("--converged-size", type=int, default=None,
                   help="image height of converged goldens (default: --size, else the "
                        "scene's [check] converged_size or size, else its resolution)")
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    p.add_argument("--shadings", nargs="+", default=list(SHADING_MODES), choices=SHADING_MODES)
    args = p.parse_args(argv)
    for name in ("size", "converged_size"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')}: expected a height >= 1, got "
                    f"{getattr(args, name)}")
    try:
        if args.rekey:
            rekey(args.scenes, verify=tuple(args.verify))
        else:
            render_goldens(args.scenes, force=args.force, size=args.size,
                           converged_size=args.converged_size, modes=tuple(args.modes),
                           shadings=tuple(args.shadings), bundled=True, report=print)
    except GoldenError as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
