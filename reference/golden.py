"""Golden images: Mitsuba renders of every scene × view × shading mode × mode, with settings.

Layout: ``reference/goldens/<scene>/<view>_<shading>_<mode>.exr`` (linear RGB, float32, ZIP
compressed) and a JSON sidecar ``.json`` beside each (Mitsuba version, variant, spp, mode,
shading, view, resolution, sha256 of the scene file and of every mesh in
``Scene.source_files``, date). Converged goldens also hold a ``var`` layer (channels
``var.R/var.G/var.B``, float32: smooth pixels have variances far below half's range): the
per-pixel variance of one ``batch_spp`` estimate (see ``render_converged_with_variance``).
The files are read and written by ``renderer.film`` (``write_exr`` / ``read_exr_layers``).

Goldens change only through ``render_goldens(..., force=True)`` / ``whitted reference
--force``; ``load_golden`` refuses a missing or stale (hash mismatch) golden and says the
exact command that regenerates it.
"""
from __future__ import annotations

import datetime
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from renderer.film import read_exr_layers, write_exr
from renderer.scene import SHADING_MODES, Scene, load_scene

from . import MODES

ROOT = Path(__file__).resolve().parent.parent
GOLDEN_DIR = Path(__file__).resolve().parent / "goldens"
#: Converged goldens: total spp and the number of independent batches (variance estimate).
CONVERGED_SPP = 64
CONVERGED_BATCHES = 16
DEFAULT_SIZE = 256
#: Converged goldens are rendered at this height (2 CPU cores: 16 x 4 spp at 256² is slow).
CONVERGED_SIZE = 128


class GoldenError(RuntimeError):
    """A golden image is missing or does not match its scene files."""


@dataclass
class Golden:
    image: np.ndarray            # float32 (H, W, 3) linear RGB
    var: np.ndarray | None       # float32 (H, W, 3) variance of one batch_spp estimate
    meta: dict
    path: Path


def _rel(p: Path) -> str:
    try:
        return str(Path(p).resolve().relative_to(ROOT))
    except ValueError:
        return str(p)


def regenerate_command(scene_path) -> str:
    return f"whitted reference --force {_rel(Path(scene_path))}"


def source_hashes(scene: Scene) -> dict[str, str]:
    """sha256 of the scene file and every mesh it uses, keyed by repo-relative path."""
    files = list(scene.source_files) or ([scene.path] if scene.path else [])
    out = {}
    for f in files:
        out[_rel(Path(f))] = hashlib.sha256(Path(f).read_bytes()).hexdigest()
    return out


def golden_path(scene_name: str, view_name: str, shading: str, mode: str,
                root: Path = GOLDEN_DIR) -> Path:
    return Path(root) / scene_name / f"{view_name}_{shading}_{mode}.exr"


# ---- rendering ----------------------------------------------------------------------------
def _resize(scene: Scene, size: int | None) -> Scene:
    """``scene`` with every view ``size`` pixels high, the width following the aspect of
    the scene's resolution (None: unchanged)."""
    if size is None:
        return scene
    cam = scene.cameras[0]
    return scene.with_size(max(1, int(round(size * cam.width / cam.height))), int(size))


def _progress_bar(total: int, enabled: bool):
    state = {"done": 0}

    def step(label: str = ""):
        state["done"] += 1
        if not enabled:
            return
        n = state["done"]
        bar = "#" * int(30 * n / total)
        sys.stderr.write(f"\r[{bar:<30}] {n}/{total} {label[:50]:<50}")
        if n == total:
            sys.stderr.write("\n")
        sys.stderr.flush()
    return step


def render_goldens(scene_paths, *, force: bool = False, spp: int = CONVERGED_SPP,
                   batches: int = CONVERGED_BATCHES, size: int = DEFAULT_SIZE,
                   converged_size: int | None = CONVERGED_SIZE, modes=MODES,
                   shadings=SHADING_MODES, progress: bool = True,
                   root: Path = GOLDEN_DIR) -> list[Path]:
    """Render every scene × view × shading × mode with Mitsuba into ``root``.

    spp: converged samples per pixel in total (``batches`` independent renders of
    ``spp // batches`` each, for the per-pixel variance). size: image height in pixels
    (width follows the camera's aspect); converged_size: the same for converged goldens
    (None: ``size``). Existing goldens are kept unless ``force``.
    Returns the written EXR paths.
    """
    import mitsuba as mi

    from . import mitsuba_variant
    from .mitsuba_scene import render_converged_with_variance, render_mitsuba

    variant = mitsuba_variant()
    jobs = []
    for scene_path in scene_paths:
        for shading in shadings:
            name = Path(scene_path).stem
            for mode in modes:
                h = size if mode == "exact" or converged_size is None else converged_size
                scene = _resize(load_scene(scene_path, shading=shading), h)
                for v, cam in enumerate(scene.cameras):
                    jobs.append((scene_path, name, scene, v, cam, shading, mode))
    units = sum(batches if j[6] == "converged" else 1 for j in jobs)
    step = _progress_bar(units, progress)
    written = []
    for scene_path, name, scene, v, cam, shading, mode in jobs:
        out = golden_path(name, cam.name, shading, mode, root)
        label = f"{name}/{out.name}"
        if out.exists() and not force:
            raise GoldenError(f"{_rel(out)} exists; pass force=True "
                              f"({regenerate_command(scene_path)}) to overwrite it")
        var, b_spp = None, 1
        if mode == "exact":
            img = render_mitsuba(scene, view=v, mode="exact")
            step(label)
            used_spp = 1
        else:
            img, var, b_spp = render_converged_with_variance(
                scene, view=v, spp=spp, batches=batches, progress=lambda label=label: step(label))
            used_spp = spp
        write_exr(out, img, layers=None if var is None else {"var": var}, overwrite=True)
        meta = {
            "scene": _rel(Path(scene_path)), "view": v, "view_name": cam.name, "shading": shading,
            "mode": mode, "spp": used_spp, "batch_spp": b_spp,
            "batches": batches if mode == "converged" else 1,
            "resolution": [cam.width, cam.height], "mitsuba_version": mi.__version__,
            "variant": variant, "max_depth": scene.settings.max_depth,
            "spawn": "mitsuba",           # secondary/shadow rays: si.spawn_ray(_to)
            "sources": source_hashes(scene),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        }
        out.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
        written.append(out)
    return written


def load_golden(scene: Scene, *, view: int, shading: str, mode: str,
                root: Path = GOLDEN_DIR) -> Golden:
    """The golden of ``scene`` (its path names it) for one view/shading/mode. Raises
    ``GoldenError`` naming the regeneration command when missing or stale."""
    scene_path = scene.path
    if scene_path is None:
        raise GoldenError(f"scene {scene.name!r} has no path; goldens exist only for files")
    cam = scene.cameras[view]
    out = golden_path(Path(scene_path).stem, cam.name, shading, mode, root)
    side = out.with_suffix(".json")
    if not out.exists() or not side.exists():
        raise GoldenError(f"golden {_rel(out)} is missing; render it with "
                          f"`{regenerate_command(scene_path)}`")
    meta = json.loads(side.read_text())
    now = source_hashes(scene)
    if meta.get("sources") != now:
        changed = sorted(k for k in set(now) | set(meta.get("sources", {}))
                         if now.get(k) != meta.get("sources", {}).get(k))
        raise GoldenError(f"golden {_rel(out)} is stale ({', '.join(changed)} changed since "
                          f"it was rendered); regenerate it with "
                          f"`{regenerate_command(scene_path)}`")
    layers = read_exr_layers(out)
    return Golden(layers[""], layers.get("var"), meta, out)
