"""Far from the origin (case 16, ``far_snapped``): a scene moved by a large offset, our
render in each precision against our float64 render of the *same* vertices snapped to
float32's grid there, so the geometry's own snapping is not counted against float32's
arithmetic (``far_from_origin_criterion``); ``transformed``, ``snapped`` and ``compare``
are its parts (the ray-offset tests use them too)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from evaluation.gate.agreement import EDGE_TOL
from evaluation.gate.agreement import neighbour_range as _neighbour_range


def transformed(scene, scale: float = 1.0, shift=(0.0, 0.0, 0.0)):
    """``scene`` with every position mapped to ``scale · x + shift`` (geometry from its
    float32 vertices, cameras, lights), light intensities times ``scale²`` where they fall
    off as 1/dist², so the image is the same in exact arithmetic. Vertices are rounded to
    float32 once, as the loader does; the float64 positions (``Scene.positions(True)``, the
    loader's unrounded vertices) are mapped too and kept as ``vertices64``, so a float64
    render of the moved scene sees its exact geometry (without them ``Scene.__post_init__``
    drops the stale float64 array and float64 renders widen the float32 vertices, rounded
    to 1/128 at 1e5 and to 1 at 1e7)."""
    shift = np.asarray(shift, np.float64)
    V64 = scene.positions(True) * scale + shift
    V = V64.astype(np.float32)
    cams = [replace(c, position=c.position * scale + shift, target=c.target * scale + shift)
            for c in scene.cameras]
    lights = [replace(li, position=li.position * scale + shift,
                      intensity=li.intensity * (scale ** 2 if li.falloff == "inverse_square"
                                                else 1.0))
              for li in scene.lights]
    return replace(scene, vertices=V, vertices64=V64, cameras=cams, lights=lights)


def compare(ours: np.ndarray, ref: np.ndarray, *, bad_rel: float = 0.05) -> dict:
    """Pixel comparison of two renders of the same scene (H, W, 3).

    bad pixels: some channel off by more than ``bad_rel`` relative (floor 0.1 on |ref|) and
    not explained as an edge (a 3x3 neighbourhood allowance, either way
    round): acne, leaks, black glass. relMSE: mean over pixels and channels of
    ``(a - r)² / (r² + 1e-2)``. Non-finite pixels are bad."""
    a = np.nan_to_num(np.asarray(ours, np.float64), nan=1e30, posinf=1e30, neginf=-1e30)
    r = np.asarray(ref, np.float64)
    rel = (np.abs(a - r) / np.maximum(np.abs(r), 0.1)).max(-1)
    tol = EDGE_TOL * np.maximum(np.abs(r), 1.0)
    lo, hi = _neighbour_range(a)
    explained = np.all((r >= lo - tol) & (r <= hi + tol), -1)
    lo, hi = _neighbour_range(r)
    explained |= np.all((a >= lo - tol) & (a <= hi + tol), -1)
    bad = (rel > bad_rel) & ~explained
    rel_mse = float(np.mean((a - r) ** 2 / (r ** 2 + 1e-2)))
    diff = np.abs(a - r).max(-1)
    edge = (rel > bad_rel) & explained
    return dict(bad=int(bad.sum()), edge=int(edge.sum()), rel_mse=rel_mse,
                max_abs=float(diff.max()), max_abs_not_edge=float(diff[~edge].max(initial=0)),
                pixels=int(bad.size))


def snapped(scene, shift):
    """``scene`` moved by ``shift`` with its vertices snapped to float32's grid there, as a
    float32 render sees them: ``transformed``'s cameras and lights, and the float32
    vertices as the float64 ones too, so a float64 render sees the same snapped geometry."""
    moved = transformed(scene, shift=shift)
    return replace(moved, vertices64=moved.vertices.astype(np.float64), normals64=None)


def far_from_origin_criterion(scene, shift, precision: str, *, view: int = 0,
                              bad_rel: float = 0.05, backend: str = "llvm") -> dict:
    """The honest far-from-the-origin check: our render in ``precision`` of the
    scene moved by ``shift`` (``snapped``) against our float64 render of the *same snapped
    vertices*, so the geometry's own snapping to float32's grid is not counted against
    float32's arithmetic. Returns ``compare``'s dict plus ``shadow_pixels`` (pixels the
    reference's shadow rays darken: lit without shadows, more than ``bad_rel`` darker
    with them) and ``lost_shadow`` (of those, pixels ours leaves lit, off any edge the
    3x3 allowance explains): a shadow must survive wherever the snapped geometry still
    casts it. ``backend`` renders all three."""
    from renderer.effects import EffectSet
    from renderer.render import render

    sc = snapped(scene, shift)
    fx = EffectSet.from_scene(sc)
    ref = render(sc, view=view, backend=backend, precision="float64").image.astype(np.float64)
    lit = render(sc, view=view, backend=backend, precision="float64",
                 effects=fx.without("shadows")).image.astype(np.float64)
    ours = render(sc, view=view, backend=backend, precision=precision).image.astype(np.float64)
    res = compare(ours, ref, bad_rel=bad_rel)
    floor = np.maximum(np.abs(lit), 0.1)
    shadow = ((lit - ref) / floor).max(-1) > bad_rel
    ours_dark = ((lit - ours) / floor).max(-1) > bad_rel
    tol = EDGE_TOL * np.maximum(np.abs(ref), 1.0)
    lo, hi = _neighbour_range(ours)
    explained = np.all((ref >= lo - tol) & (ref <= hi + tol), -1)
    res.update(shadow_pixels=int(shadow.sum()),
               lost_shadow=int((shadow & ~ours_dark & ~explained).sum()))
    return res


def scene_file(name: str):
    """The bundled scene file ``name`` (its stem): ``scenes/`` of the repository, else the
    copy an installed wheel carries."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    for folder in (root / "scenes", root / "whitted" / "bundled" / "scenes"):
        if (folder / f"{name}.toml").is_file():
            return folder / f"{name}.toml"
    raise FileNotFoundError(f"far_snapped: scene {name!r}: no {name}.toml among the bundled "
                            f"scenes")


def case_far_snapped(cfg, spec: dict) -> list:
    """Case 16: ``spec["scene"]`` at ``size``² moved by (s, s, s) for every ``shifts`` s,
    in each precision of ``cfg``, against our float64 render of the same snapped vertices
    (``far_from_origin_criterion``): no bad pixel and no lost shadow pixel, and a float64
    render bit for bit its reference. float32 beyond ``float32_limit`` is the expected
    limit the table states (the camera's own rays round to 1/16 at 1e6): there the row
    holds iff the criterion *fails*, so the limit is measured on every run and a float32
    that starts to hold there turns the row red until the table says so."""
    import warnings

    from renderer.accel import DEFAULT_ROUTINE
    from renderer.scene import load_scene

    from .cases import Row
    from .runners import report_progress

    size = int(spec["size"])
    bad_rel = float(spec["bad_rel"])
    limit = float(spec["float32_limit"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")           # zero-area triangles of the snapped scene
        base = load_scene(scene_file(spec["scene"])).with_size(size, size)
        rows = []
        for prec in cfg.precisions:
            for s in (float(x) for x in spec["shifts"]):
                res = far_from_origin_criterion(base, (s, s, s), prec, bad_rel=bad_rel,
                                                backend=cfg.backend)
                holds = res["bad"] == 0 and res["lost_shadow"] == 0
                bound = "0 bad pixels, 0 lost shadow pixels"
                if prec == "float64":
                    holds = holds and res["max_abs"] == 0.0
                    bound += ", bitwise equal"
                measured = (f"{res['bad']} bad, {res['edge']} edge of {res['pixels']} pixels; "
                            f"{res['lost_shadow']} of {res['shadow_pixels']} shadow pixels "
                            f"lost; max abs {res['max_abs']:.3g}, relMSE {res['rel_mse']:.3g}")
                expected_limit = prec == "float32" and s > limit
                if expected_limit:
                    criterion = (f"expected limit: float32 beyond {limit:g} fails ({bound}); "
                                 f"the row holds while it does")
                    passed = not holds
                else:
                    criterion, passed = bound, holds
                rows.append(Row(case="16 far, snapped vertices",
                                variant=f"{spec['scene']} +{s:g}/bvh/{DEFAULT_ROUTINE}/{prec}",
                                criterion=criterion, measured=measured, passed=passed,
                                value=float(res["bad"] + res["lost_shadow"]),
                                info={**res, "shift": s, "expected_limit": expected_limit}))
                report_progress(cfg, rows[-1])
    return rows
