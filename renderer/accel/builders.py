"""Which builder makes the binary tree, and the cache in front of both.

``BUILDS``: "sah" (``bvh_build.build_bvh``: binned SAH on the host, spatial splits,
reinsertion: the better tree), "ploc" (``ploc.build_ploc``: locally-ordered clustering by
Dr.Jit on the render's backend), "radix" (``device_build.build_device``: the Morton radix
tree by Dr.Jit: the fastest build, the slowest tree), "device" (the device builder of
choice, ``DEVICE_BUILD``), "auto" (``resolve_build``). "device" and the builder it stands
for share their cache entries.

``binary_tree(scene, backend, build=..., cache=...)`` answers a ``BVHArrays`` and how it
was got: from the ``TreeCache`` when an entry for the same triangles, builder, parameters
and code is there (verified: a bad entry is rebuilt with one warning), else built and
stored. The "auto" rule, measured (``lab/notes/device-build.md``): an SAH tree already in
the cache is taken (it costs nothing and traces fastest); otherwise a caller that renders
at most ``AUTO_MAX_FRAMES`` frames of a scene of at least ``AUTO_MIN_TRIANGLES`` triangles
gets the device tree (its much faster build outweighs its slower traversal
over so few frames), every other caller (a study, a bench, an unknown number of frames)
the SAH tree.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..scene.model import TREE_BUILDS
from .bvh_build import LEAF_SIZE, BVHArrays, build_bvh, raw_boxes
from .cache import CacheWarning, TreeCache, code_version, content_key
from .device_build import build_device
from .ploc import build_ploc
from .traverse import LEAF_BIT

BUILDS = TREE_BUILDS
#: The builder "device" (and "auto"'s device choice) runs: PLOC, whose trees trace nearly as
#: fast as the SAH tree's at a few times the radix tree's build time
#: (``lab/notes/device-build.md``).
DEVICE_BUILD = "ploc"
#: ``resolve_build``: "auto" takes the device build for at most this many frames ...
AUTO_MAX_FRAMES = 4
#: ... of scenes of at least this many triangles (smaller ones build by SAH in < 0.1 s).
AUTO_MIN_TRIANGLES = 20000


def check_build(build: str) -> str:
    if build not in BUILDS:
        raise ValueError(f"build: expected one of {list(BUILDS)}, got {build!r}")
    return build


def resolve_build(build: str, face_count: int, frames: int | None, sah_cached: bool) -> str:
    """The builder "auto" stands for (see the module docstring); others unchanged."""
    check_build(build)
    if build != "auto":
        return build
    if sah_cached:
        return "sah"
    if frames is not None and frames <= AUTO_MAX_FRAMES and face_count >= AUTO_MIN_TRIANGLES:
        return "device"
    return "sah"


@dataclass
class TreeInfo:
    """How ``binary_tree`` got its tree: the builder, whether the cache answered, the
    seconds spent (building, or reading the entry)."""

    build: str
    cached: bool
    seconds: float


def builder(build: str) -> str:
    """The builder that makes ``build``'s tree: "sah", "ploc" or "radix"."""
    check_build(build)
    if build == "auto":
        raise ValueError("build: 'auto' stands for a builder only through resolve_build")
    return DEVICE_BUILD if build == "device" else build


def triangles_key(scene) -> str:
    """The content hash of ``scene``'s triangles (float32 vertices, faces)."""
    return content_key(np.asarray(scene.vertices, np.float32), np.asarray(scene.faces))


def tree_key(scene, build: str, leaf_size: int = LEAF_SIZE, triangles: str | None = None
             ) -> str:
    """The cache key of ``scene``'s tree from ``build`` (a value of ``BUILDS`` but "auto");
    ``triangles``: ``triangles_key(scene)`` when the caller has it (it hashes every
    vertex and face)."""
    return content_key(triangles or triangles_key(scene), builder(build),
                       {"leaf_size": leaf_size}, code_version())


def binary_tree(scene, backend: str, *, build: str = "sah", cache: TreeCache | None = None,
                frames: int | None = None, leaf_size: int = LEAF_SIZE, progress=None
                ) -> tuple[BVHArrays, TreeInfo]:
    """``scene``'s binary tree from ``build`` (a value of ``BUILDS``) on ``backend``,
    through ``cache`` (None: no cache). ``frames``: how many frames the caller renders
    (None: unknown), for "auto". ``progress(build, levels_done)``: None, or called after
    each level of the build that runs (at most ``MAX_LEVELS``)."""
    check_build(build)
    t0 = time.perf_counter()
    keys = {}
    tri = triangles_key(scene) if cache is not None else None
    if cache is not None:
        keys["sah"] = tree_key(scene, "sah", leaf_size, tri)
        if build == "auto":
            got = cache.get("tree", keys["sah"])
            if got is not None:
                a = _from_entry(got, scene.face_count)
                if a is not None:
                    return a, TreeInfo("sah", True, time.perf_counter() - t0)
    chosen = resolve_build(build, scene.face_count, frames, False)
    if cache is not None and not (build == "auto" and chosen == "sah"):
        keys[chosen] = keys.get(chosen) or tree_key(scene, chosen, leaf_size, tri)
        got = cache.get("tree", keys[chosen])
        if got is not None:
            a = _from_entry(got, scene.face_count)
            if a is not None:
                return a, TreeInfo(chosen, True, time.perf_counter() - t0)
    how = builder(chosen)
    if how == "ploc":
        a = build_ploc(scene.vertices, scene.faces, backend, leaf_size=leaf_size,
                       progress=progress and (lambda k: progress(chosen, k)))
    elif how == "radix":
        a = build_device(scene.vertices, scene.faces, backend, leaf_size=leaf_size,
                         progress=progress and (lambda k: progress(chosen, k)), raw=True)
    else:
        a = build_bvh(scene.vertices, scene.faces, leaf_size=leaf_size,
                      progress=progress and (lambda k: progress("sah", k)))
    seconds = time.perf_counter() - t0
    if cache is not None:
        a = with_raw(a, scene)
        cache.put("tree", keys.get(chosen) or tree_key(scene, chosen, leaf_size, tri),
                  *_to_entry(a))
    return a, TreeInfo(chosen, False, seconds)


def with_raw(a: BVHArrays, scene) -> BVHArrays:
    """``a`` with its unpadded float32 child boxes (``BVHArrays.raw``) of ``scene``'s
    vertices, which a cache entry keeps so a cached tree's upload only pads them."""
    if a.raw is not None or a.order.size == 0:
        return a
    return replace(a, raw=raw_boxes(a, scene.vertices, scene.faces, np.float32))


def _to_entry(a: BVHArrays) -> tuple[dict, dict]:
    arrays = {"boxes": a.boxes, "children": a.children, "order": a.order,
              "bounds_lo": np.asarray(a.bounds[0], np.float64),
              "bounds_hi": np.asarray(a.bounds[1], np.float64)}
    if a.raw is not None:
        arrays["raw"] = a.raw
    if a.cells is not None:
        arrays["cell_lo"], arrays["cell_hi"] = a.cells
    meta = {"levels": a.levels, "leaf_count": a.leaf_count, "sah_cost": a.sah_cost,
            "build_seconds": a.build_seconds, "optimize_seconds": a.optimize_seconds}
    return arrays, meta


def _raw_fits(raw: np.ndarray, boxes: np.ndarray) -> bool:
    """Whether ``raw`` can be a tree's unpadded child boxes: float32 of the boxes' shape,
    inside the (padded) boxes wherever those are finite."""
    if raw.dtype != np.float32 or raw.shape != boxes.shape:
        return False
    with np.errstate(invalid="ignore"):
        fin = np.isfinite(boxes)
        lo = np.zeros(boxes.shape[1], bool)
        lo[[0, 1, 2, 6, 7, 8]] = True
        inside = np.where(lo, raw >= boxes, raw <= boxes)
    return bool(np.all(inside | ~fin))


def _from_entry(e: dict, face_count: int) -> BVHArrays | None:
    """The tree of a verified entry, or None (a ``CacheWarning``) when its arrays do not
    make a tree over ``face_count`` triangles."""
    try:
        boxes, children, order = e["boxes"], e["children"], e["order"]
        meta = e["meta"]
        n = boxes.shape[0]
        ok = (boxes.dtype == np.float32 and boxes.shape == (n, 12)
              and children.dtype == np.uint32 and children.shape == (n, 2)
              and order.dtype == np.int64 and order.ndim == 1 and order.size >= face_count)
        if ok and order.size:
            ok = int(order.min()) >= 0 and int(order.max()) < face_count
        ref = children.astype(np.int64)
        inner = ref[(ref & LEAF_BIT) == 0]
        ok = ok and (inner.size == 0 or int(inner.max()) < n)
        cells = (e["cell_lo"], e["cell_hi"]) if "cell_lo" in e else None
        raw = e.get("raw")
        ok = ok and (raw is None or _raw_fits(raw, boxes))
        a = BVHArrays(boxes, children, order, int(meta["levels"]), int(meta["leaf_count"]),
                      float(meta["sah_cost"]), float(meta["build_seconds"]),
                      (e["bounds_lo"], e["bounds_hi"]), cells,
                      float(meta.get("optimize_seconds", 0.0)), raw)
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        warnings.warn("cache entry does not hold a tree of this scene; rebuilding",
                      CacheWarning, stacklevel=3)
        return None
    return a
