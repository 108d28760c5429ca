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
over so few frames), built without PLOC's cuts of large triangles (``ploc.build_ploc``'s
``cuts``: they cost more build time than so few frames gain; "device" and "ploc" named
by the user make them), every other caller (a study, a bench, an unknown number of
frames) the SAH tree.

``tree_accelerator`` (``build_accelerator``'s way to a ``TREE_ACCELS`` accelerator) puts a
second entry in front of the tree: the arrays the accelerator uploads (``host_layout`` of
``bvh.BVH`` and ``wide.WideBVH``), keyed by ``layout_key`` (the tree's key and everything
else the upload reads). A hit checks dtypes, shapes and node references and uploads the
arrays as they were read; a miss gets the tree, makes the layout (on CUDA the triangles are
packed on a thread while the tree is got) and stores it.
"""
from __future__ import annotations

import threading
import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..scene.model import TREE_BUILDS, any_smooth, layout_inputs, triangles_digest
from .bvh_build import LEAF_SIZE, BVHArrays, build_bvh, raw_boxes
from .cache import CacheWarning, TreeCache, code_version, content_key
from .device_build import DeviceTree, build_device
from .layout import COUNT_SHIFT, DONE, FIRST_MASK, LEAF_BIT, MAX_LEAF
from .ploc import build_ploc, build_ploc_device
from .triangle import STRIDE, pad_extent, permuted, triangle_arrays
from .wide import record_words

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
    """The content hash of ``scene``'s triangles (float32 vertices, faces): the scene's
    ``model.triangles_digest``."""
    return triangles_digest(scene)


def tree_key(scene, build: str, leaf_size: int = LEAF_SIZE, triangles: str | None = None,
             cuts: bool = True) -> str:
    """The cache key of ``scene``'s tree from ``build`` (a value of ``BUILDS`` but "auto");
    ``triangles``: ``triangles_key(scene)`` when the caller has it (it hashes every
    vertex and face); ``cuts``: PLOC's ``cuts`` (the other builders have none)."""
    params = {"leaf_size": leaf_size}
    if builder(build) == "ploc":
        params["cuts"] = bool(cuts)
    return content_key(triangles or triangles_key(scene), builder(build), params,
                       code_version())


def binary_tree(scene, backend: str, *, build: str = "sah", cache: TreeCache | None = None,
                frames: int | None = None, progress=None, triangles: str | None = None,
                device: bool = False) -> tuple[BVHArrays | DeviceTree, TreeInfo]:
    """``scene``'s binary tree from ``build`` (a value of ``BUILDS``) on ``backend``, of
    the accelerators' leaf size (``LEAF_SIZE``), through ``cache`` (None: no cache).
    ``frames``: how many frames the caller renders
    (None: unknown), for "auto". ``progress(build, levels_done)``: None, or called after
    each level of the build that runs (at most ``MAX_LEVELS``). ``triangles``:
    ``triangles_key(scene)`` where the caller has it. ``device``: a tree PLOC builds may
    stay on the device (a ``DeviceTree``, copied back only for the cache entry)."""
    check_build(build)
    t0 = time.perf_counter()
    leaf_size = LEAF_SIZE
    keys = {}
    tri = (triangles or triangles_key(scene)) if cache is not None else None
    if cache is not None:
        keys["sah"] = tree_key(scene, "sah", leaf_size, tri)
        if build == "auto":
            got = cache.get("tree", keys["sah"])
            if got is not None:
                a = _from_entry(got, scene.face_count)
                if a is not None:
                    return a, TreeInfo("sah", True, time.perf_counter() - t0)
    chosen = resolve_build(build, scene.face_count, frames, False)
    cuts = build != "auto"        # "auto"'s device tree is for a first image: no cuts
    if cache is not None and not (build == "auto" and chosen == "sah"):
        keys[chosen] = keys.get(chosen) or tree_key(scene, chosen, leaf_size, tri, cuts)
        got = cache.get("tree", keys[chosen])
        if got is not None:
            a = _from_entry(got, scene.face_count)
            if a is not None:
                return a, TreeInfo(chosen, True, time.perf_counter() - t0)
    how = builder(chosen)
    if how == "ploc":
        a = (build_ploc_device if device else build_ploc)(
            scene.vertices, scene.faces, backend, leaf_size=leaf_size, cuts=cuts,
            progress=progress and (lambda k: progress(chosen, k)))
    elif how == "radix":
        a = build_device(scene.vertices, scene.faces, backend, leaf_size=leaf_size,
                         progress=progress and (lambda k: progress(chosen, k)), raw=True)
    else:
        a = build_bvh(scene.vertices, scene.faces, leaf_size=leaf_size,
                      progress=progress and (lambda k: progress("sah", k)))
    seconds = time.perf_counter() - t0
    if cache is not None:
        h = with_raw(a.host() if isinstance(a, DeviceTree) else a, scene)
        cache.put("tree", keys.get(chosen) or tree_key(scene, chosen, leaf_size, tri, cuts),
                  *_to_entry(h))
        if not isinstance(a, DeviceTree):
            a = h
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


#: Source files (relative to the ``renderer`` package) whose text is part of every layout
#: key besides ``CODE_MODULES``: the modules that compute what an accelerator uploads.
LAYOUT_MODULES = ("accel/triangle.py", "accel/bvh.py", "accel/wide.py", "accel/base.py",
                  "accel/layout.py", "accel/bvh_arrays.py", "scene/model.py")


@dataclass(frozen=True)
class LayoutRequest:
    """What an accelerator's uploaded layout depends on beyond its tree: the accelerator
    (``name``, the class ``cls`` with ``host_layout``/``from_layout``, its ``width``, 2 for
    the binary BVH), the precision of ``t`` and the triangle routine ``intersection``."""

    name: str
    cls: type
    width: int
    intersection: str


def layout_key(scene, tree: str, req: LayoutRequest, t, extent: float) -> str:
    """The cache key of the arrays ``req.cls.host_layout`` uploads for ``scene`` over the
    tree of key ``tree`` (``tree_key``) in the precision of ``t``: the tree, the
    accelerator and its width, the precision, the routine, the boxes' padding extent
    (``pad_extent``), the face materials and smooth flags, the vertex normals (where any
    face is smooth), the float64 vertices (float64 renders: the float32 ones are in the
    tree's key) and the code (``code_version`` of ``LAYOUT_MODULES``)."""
    parts = [tree, req.name, req.width, t.precision, req.intersection, float(extent),
             any_smooth(scene), layout_inputs(scene, t.is_double)]
    return content_key("layout", *parts, code_version(LAYOUT_MODULES))


def _refs_fit(refs: np.ndarray, nodes: int, faces: int) -> bool:
    """Whether every node reference of ``refs`` (uint32) is ``DONE``, an inner node below
    ``nodes`` or a leaf of triangle positions below ``faces`` (in 32-bit words, without
    copies of the references: a leaf's end stays below 2^28)."""
    r = refs.reshape(-1)
    if r.dtype != np.uint32:
        return False
    leaf = (r & np.uint32(LEAF_BIT)) != 0
    real_leaf = leaf & (r != np.uint32(DONE))
    if r.size and int(np.max(np.where(leaf, np.uint32(0), r))) >= nodes and (~leaf).any():
        return False
    end = (r & np.uint32(FIRST_MASK)) + ((r >> np.uint32(COUNT_SHIFT))
                                         & np.uint32(MAX_LEAF - 1)) + np.uint32(1)
    return not real_leaf.any() or int(np.max(np.where(real_leaf, end, np.uint32(0)))) <= faces


def _layout_fits(e: dict, req: LayoutRequest, scene, t) -> bool:
    """Whether the entry ``e`` can be ``req``'s layout of ``scene`` in the precision of
    ``t``: the arrays of ``host_layout`` with their dtypes and shapes, references inside
    the tree and the triangles, and an ``info`` of the same accelerator."""
    F = scene.face_count
    fdt = np.dtype(np.float64 if t.is_double else np.float32)
    try:
        info = e["meta"]["info"]
        normals = any_smooth(scene)
        ok = (info["accel"] == ("bvh" if req.width == 2 else f"bvh{req.width}")
              and info["intersection"] == req.intersection and info["triangles"] == F
              and e["tri_data"].dtype == fdt and e["tri_data"].shape == (F, STRIDE)
              and all(e[k].dtype == fdt and e[k].shape == (3, F)
                      for k in ("ng", "n0", "n1", "n2")[:4 if normals else 1])
              and normals == ("n0" in e)
              and e["material"].dtype == np.uint32 and e["material"].shape == (F,)
              and e["smooth"].dtype == np.bool_ and e["smooth"].shape == (F,)
              and e["order"].dtype == np.uint32 and e["order"].shape == (F,))
        ok = ok and (F == 0 or int(e["order"].max()) < F)
        nodes = e["nodes"]
        N = nodes.shape[0]
        if req.width == 2:
            refs = e["children"]
            ok = ok and nodes.dtype == fdt and nodes.shape == (N, 12)
            ok = ok and refs.dtype == np.uint32 and refs.shape == (N, 2)
        else:
            refs = e["refs"]
            shape = ((N, record_words(req.width)) if info["quantized"]
                     else (N, 6, req.width))
            ok = ok and info["width"] == req.width and nodes.shape == shape
            ok = ok and nodes.dtype == (np.uint32 if info["quantized"] else fdt)
            ok = ok and refs.dtype == np.uint32 and refs.shape == (N, req.width)
        return bool(ok and _refs_fit(refs, N, F))
    except (KeyError, TypeError, ValueError, AttributeError, IndexError):
        return False


def tree_accelerator(scene, t, req: LayoutRequest, build_request) -> object:
    """The accelerator ``req`` of ``scene`` on the tree ``build_request`` asks for (a
    ``BuildRequest``: ``build``, ``cache``, ``frames``, ``progress``). With a cache, the
    arrays it uploads are an entry of their own (``layout_key``): a hit uploads them as
    they are read (no tree read, no host work), after a check of their dtypes, shapes and
    references (a bad entry: one ``CacheWarning``, then the accelerator is made as
    without it); a miss gets the tree (``binary_tree``), makes the layout and stores it.
    ``acc.info`` names how the tree was got (``tree_build``, ``tree_cached``,
    ``tree_seconds``: for a layout hit, the seconds to the verified entry) and
    ``layout_cached``."""
    cache, build = build_request.cache, build_request.build
    t0 = time.perf_counter()
    tri = extent = None
    if cache is not None:
        tri = triangles_key(scene)
        extent = pad_extent(scene, req.intersection)
        chosen = resolve_build(build, scene.face_count, build_request.frames, False)
        for name in dict.fromkeys(["sah", chosen] if build == "auto" else [build]):
            key = layout_key(scene, tree_key(scene, name, LEAF_SIZE, tri, build != "auto"),
                             req, t, extent)
            got = cache.get("layout", key)
            if got is None:
                continue
            if not _layout_fits(got, req, scene, t):
                warnings.warn("cache entry does not hold an accelerator layout of this "
                              "scene; rebuilding", CacheWarning, stacklevel=3)
                continue
            seconds = time.perf_counter() - t0
            acc = req.cls.from_layout(t, got, got["meta"]["info"], own=True)
            acc.info.update(tree_build=name, tree_cached=True, tree_seconds=seconds,
                            layout_cached=True,
                            upload_seconds=time.perf_counter() - t0 - seconds)
            return acc
    packing = _Packing(scene, t, req.intersection) if (
        t.backend == "cuda" and scene.face_count >= OVERLAP_MIN_TRIANGLES) else None
    tree, how = binary_tree(scene, t.backend, build=build, cache=cache,
                            frames=build_request.frames, progress=build_request.progress,
                            triangles=tri, device=on_device(req, t))
    t1 = time.perf_counter()
    if isinstance(tree, DeviceTree):
        return _from_device_tree(scene, t, req, tree, how, packing, cache,
                                 (tri, extent, build != "auto"))
    kw = {} if req.width == 2 else {"width": req.width}
    tris = permuted(packing.result(), tree.order) if packing is not None else None
    arrays, info = req.cls.host_layout(scene, t, tree, intersection=req.intersection,
                                       extent=extent, triangles=tris, **kw)
    if cache is not None:
        key = layout_key(scene, tree_key(scene, how.build, LEAF_SIZE, tri, build != "auto"),
                         req, t, extent)
        cache.put("layout", key, arrays, {"info": info})
    t2 = time.perf_counter()
    acc = req.cls.from_layout(t, arrays, info)
    acc.info["upload_seconds"] = time.perf_counter() - t1
    acc.info.update(tree_build=how.build, tree_cached=how.cached, tree_seconds=how.seconds,
                    layout_cached=False, layout_seconds=t2 - t1)
    return acc


def on_device(req: LayoutRequest, t) -> bool:
    """Whether ``tree_accelerator`` makes ``req``'s accelerator from a tree left on the
    device (``device_build.DeviceTree``): the binary BVH in float32 (the wide layouts are
    collapsed on the host; float64 boxes are refitted there)."""
    return req.width == 2 and not t.is_double and hasattr(req.cls, "from_device_tree")


def _from_device_tree(scene, t, req: LayoutRequest, tree: DeviceTree, how: TreeInfo,
                      packing, cache, key_parts: tuple):
    """``tree_accelerator``'s accelerator from a tree on the device (``req.cls.
    from_device_tree``: the tree is not copied back for it). With a cache, the layout
    entry is the host layout of the tree's copy (``DeviceTree.host``, which the tree
    entry already read), made and written on the cache's writer thread."""
    t1 = time.perf_counter()
    tri, extent, cuts = key_parts
    tris = (packing.result() if packing is not None else   # face order, for both uses
            triangle_arrays(scene, False, None, routine=req.intersection))
    acc = req.cls.from_device_tree(scene, t, tree, intersection=req.intersection,
                                   extent=extent, triangles=tris)
    t2 = time.perf_counter()
    if cache is not None:
        key = layout_key(scene, tree_key(scene, how.build, LEAF_SIZE, tri, cuts), req, t,
                         extent)
        h = tree.host()

        def entry():
            arrays, info = req.cls.host_layout(
                scene, t, h, intersection=req.intersection, extent=extent,
                triangles=permuted(tris, h.order))
            return arrays, {"info": info}
        cache.put_made("layout", key, entry)
    acc.info["upload_seconds"] = t2 - t1
    acc.info.update(tree_build=how.build, tree_cached=how.cached, tree_seconds=how.seconds,
                    layout_cached=False, layout_seconds=0.0)
    return acc


#: ``tree_accelerator`` on CUDA packs the triangles (``triangle_arrays``, face order) on a
#: thread while the tree is got, for scenes of at least this many triangles (numpy
#: releases the GIL; the device builds meanwhile). On LLVM the build's kernels use every
#: core, so the packing waits for the tree there.
OVERLAP_MIN_TRIANGLES = 100000


class _Packing:
    """``triangle_arrays(scene, ...)`` in face order on a daemon thread; ``result()``
    waits for it (and raises what it raised)."""

    def __init__(self, scene, t, intersection: str):
        self._out = {}

        def run():
            try:
                self._out["arrays"] = triangle_arrays(scene, t.is_double, None,
                                                      routine=intersection)
            except BaseException as e:      # handed to result()
                self._out["error"] = e
        self._thread = threading.Thread(target=run, name="pack triangles", daemon=True)
        self._thread.start()

    def result(self) -> dict:
        self._thread.join()
        if "error" in self._out:
            raise self._out["error"]
        return self._out["arrays"]
