"""Image files of a comparison: the two images and their difference, for a person to look at.

``difference(a, b)`` is the per-channel absolute difference ``|a - b|`` (linear, float32
(H, W, 3)); ``difference_png(a, b)`` the same scaled so that the largest difference is white
(8-bit, no sRGB curve: grey levels are proportional to the difference; black: equal). For an
exact-mode comparison ``rules.exact_overlay`` adds the rule's own view (hard pixels red,
excused yellow, the rest of the tie mask magenta).

``write_case_images(folder, verdict)`` writes, for a verdict that kept its images
(``check_scene(keep_images=True)``): ``ours.exr`` / ``ours.png``, ``golden.exr`` /
``golden.png``, ``diff.exr`` / ``diff.png`` and, in exact mode, ``rule.png``; the EXRs carry
the verdict's image metadata (``evaluation.gate.imagemeta``). These names, and only these,
are replaced on every run (``CASE_FILES``); ``clear_case_images`` removes them again (a case
that passes now leaves no images of an earlier failure).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from renderer.film import srgb_encode, write_exr
from renderer.outputs import atomic_path, check_output_dir

#: The files ``write_case_images`` writes into a case's folder.
CASE_FILES = ("ours.exr", "ours.png", "golden.exr", "golden.png", "diff.exr", "diff.png",
              "rule.png")


def difference(a, b) -> np.ndarray:
    """``|a - b|`` per channel, float32 (H, W, 3) (NaN where either is NaN)."""
    return np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).astype(np.float32)


def difference_png(a, b) -> tuple[np.ndarray, float]:
    """``difference(a, b)`` divided by its largest finite value: (uint8 (H, W, 3), that
    value). Non-finite differences are white; identical images are black (scale 0)."""
    d = np.asarray(difference(a, b), np.float64)
    finite = np.isfinite(d)
    scale = float(d[finite].max(initial=0.0))
    out = np.where(finite, d / scale if scale > 0 else 0.0, 1.0)
    return np.round(np.clip(out, 0.0, 1.0) * 255).astype(np.uint8), scale


def save_png(path, rgb: np.ndarray, *, overwrite: bool = True) -> Path:
    """uint8 (H, W, 3) ``rgb`` as a PNG (atomic, ``renderer.outputs``)."""
    from PIL import Image

    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        Image.fromarray(np.ascontiguousarray(rgb, np.uint8), "RGB").save(tmp, format="PNG")
    return path


def write_case_images(folder, verdict) -> dict[str, Path]:
    """The images of ``verdict`` (which kept ``ours`` and ``ref``) into ``folder`` (made if
    missing): name -> path of every file written (``CASE_FILES``). Raises ``OSError``."""
    folder = check_output_dir(folder)
    ours, ref = verdict.ours, verdict.ref
    meta = verdict.metadata or {}
    out = {"ours.exr": write_exr(folder / "ours.exr", ours, overwrite=True,
                                 metadata=meta.get("ours")),
           "ours.png": save_png(folder / "ours.png", srgb_encode(ours)),
           "golden.exr": write_exr(folder / "golden.exr", ref, overwrite=True,
                                   metadata=meta.get("golden")),
           "golden.png": save_png(folder / "golden.png", srgb_encode(ref))}
    if np.shape(ours) == np.shape(ref):
        out["diff.exr"] = write_exr(folder / "diff.exr", difference(ours, ref),
                                    overwrite=True)
        out["diff.png"] = save_png(folder / "diff.png", difference_png(ours, ref)[0])
        if verdict.mode == "exact" and verdict.thresholds:
            from .rules import exact_overlay

            th = {k: (t["value"],) for k, t in verdict.thresholds.items()}
            out["rule.png"] = save_png(folder / "rule.png",
                                       exact_overlay(ours, ref, th, verdict.ties))
    return out


def clear_case_images(folder) -> None:
    """Remove the ``CASE_FILES`` of ``folder`` (nothing else), and the folder if it is then
    empty."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    for name in CASE_FILES:
        (folder / name).unlink(missing_ok=True)
    try:
        folder.rmdir()
    except OSError:
        pass
