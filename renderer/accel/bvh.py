"""The BVH accelerator: device side of ``bvh_build``'s tree.

Node layout on the device (``load_node``): ``nodes`` Float, 12 per inner node (child A lo
xyz, hi xyz, child B lo xyz, hi xyz, as ``BVHArrays.boxes``), ``children`` UInt32, 2 per
inner node (the node references of ``renderer.accel.layout``).

Traversal is one symbolic loop per query with a per-ray stack of ``STACK_SIZE`` UInt32
(``dr.alloc_local``); the builder bounds the number of inner-node levels by
``MAX_LEVELS`` (at most ``STACK_SIZE``), so the stack cannot overflow. Each iteration does
a node step (when no leaf triangles are pending) and a triangle step (one pending leaf
triangle); each step is a real branch (``traverse.masked_step``). Traversal order
and culling never change which triangle wins (nearest ``t``, then smallest original face
index), so the hits are bitwise those of brute force.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from ..device import Types, syntax
from .base import (
    Accelerator,
    DeviceTriangles,
    Ray,
    array_type,
    as_pairs,
    device_pairs,
    gather_floats,
    gather_pairs,
    traversal_triangles,
    uses_pairs,
)
from .bvh_build import BINS, LEAF_SIZE, BVHArrays, build_bvh, pad_refit, refit_boxes
from .layout import DONE
from .query import Closest
from .traverse import (
    LeafTriangles,
    Stack,
    TraversalRay,
    cull_t,
    enter_leaf,
    leaf_triangle_step,
    masked_step,
    probe_pad,
    refill_lanes,
    refill_traversal,
    setup,
    slab,
    traversal_result,
)
from .triangle import (
    DEFAULT_ROUTINE,
    STRIDE,
    bind_routine,
    box_reach,
    device_triangles,
    host_source,
    origin_reach,
    pad_extent,
    triangle_arrays,
    triangle_routine,
)


def load_node(t: Types, nodes, children, cur, active=True):
    """Inner node(s) ``cur``: ``(a_lo, a_hi, b_lo, b_hi, ref_a, ref_b)``."""
    f = gather_floats(t, nodes, cur, 12, 12, active)
    if dr.type_v(children) == dr.VarType.UInt64:
        ref_a, ref_b = gather_pairs(t, children, cur, 2, 2, active)
    elif t.backend == "llvm":
        ref_a = dr.gather(t.UInt32, children, cur * 2, active)
        ref_b = dr.gather(t.UInt32, children, cur * 2 + 1, active)
    else:
        refs = dr.gather(array_type(t, "Array2u"), children, cur, active)
        ref_a, ref_b = refs.x, refs.y
    return (t.Array3f(f[0], f[1], f[2]), t.Array3f(f[3], f[4], f[5]),
            t.Array3f(f[6], f[7], f[8]), t.Array3f(f[9], f[10], f[11]), ref_a, ref_b)


def node_step(bvh: "BVH", ray: TraversalRay, t_max, stack: Stack, to_pop, active=True,
              pad: float = 0.0, any_hit: bool = False):
    """One inner node ``stack.cur`` of ``bvh`` where ``active``: test both child boxes
    (grown by ``pad``) against ``(0, t_max)``, push one hit child and go to the other: the
    near one first for closest hit, the far one first for any hit (``wide``'s module text).
    Returns ``(stack, to_pop)``, ``to_pop`` grown by the lanes where neither child was
    hit."""
    t, cur = bvh.types, stack.cur
    a_lo, a_hi, b_lo, b_hi, ref_a, ref_b = load_node(t, bvh.nodes, bvh.children, cur, active)
    if pad:             # the tie probe's slack reaches beyond the padded boxes
        a_lo, a_hi, b_lo, b_hi = a_lo - pad, a_hi + pad, b_lo - pad, b_hi + pad
    hit_a, tn_a = slab(t, ray, a_lo, a_hi, t_max)
    hit_b, tn_b = slab(t, ray, b_lo, b_hi, t_max)
    if active is not True:
        hit_a &= active
        hit_b &= active
    both = hit_a & hit_b
    b_first = (tn_b > tn_a) if any_hit else (tn_b < tn_a)
    near = dr.select(hit_a & ~(hit_b & b_first), ref_a, ref_b)
    far = dr.select(b_first, ref_a, ref_b)
    stack.push(far, both)
    missed = ~(hit_a | hit_b)
    if active is not True:
        missed &= active
    stack.cur = dr.select(hit_a | hit_b, near, cur)
    return stack, to_pop | missed


def traversal_boxes(a: BVHArrays, scene, t: Types, intersection: str,
                    extent: float | None = None) -> np.ndarray:
    """The node boxes of ``a`` that the traversal of ``intersection`` in precision ``t``
    needs: refitted (in float64 for float64 renders) and padded for the ray origins'
    reach (``pad_extent``); the build's own float32 boxes where no origin lies away from 0
    (``box_reach`` 0). A float32 traversal of a tree that carries its unpadded boxes
    (``BVHArrays.raw``: a cached tree) pads those (``pad_refit``): the same boxes.
    ``extent``: ``pad_extent(scene, intersection)`` where the caller has it."""
    if not (t.is_double or box_reach(scene, intersection) > 0):
        return a.boxes
    extent = pad_extent(scene, intersection) if extent is None else extent
    if not t.is_double and a.raw is not None and a.order.size:
        return pad_refit(a, a.raw, extent)
    fdt = np.float64 if t.is_double else np.float32
    return refit_boxes(a, scene.positions(t.is_double), scene.faces, fdt, extent)


def _info(scene, t: Types, intersection: str, tree: tuple) -> dict:
    """The BVH accelerator's ``info`` (JSON-able; ``reach`` included) for ``scene`` in the
    precision of ``t``, from its tree's ``(build_seconds, nodes, leaves, levels,
    sah_cost)``."""
    build_seconds, nodes, leaves, levels, sah_cost = tree
    fsize = 8 if t.is_double else 4
    return {
        "accel": "bvh", "intersection": intersection, "build_seconds": build_seconds,
        "triangles": scene.face_count, "nodes": nodes, "leaves": leaves, "levels": levels,
        "sah_cost": sah_cost, "leaf_size": LEAF_SIZE, "bins": BINS,
        "node_bytes_per_triangle": nodes * (12 * fsize + 8) / max(scene.face_count, 1),
        "traversal_triangle_bytes_per_triangle": STRIDE * fsize,
        "reach": origin_reach(scene, intersection),
    }


@dataclass
class BVH(Accelerator):
    """Bounding volume hierarchy accelerator (see the module docstring).

    Build with ``BVH.build(scene, t, intersection=DEFAULT_ROUTINE, leaf_size=2, bins=32)``.
    nodes: Float (12 N) child boxes; children: UInt32 (2 N) child references;
    tri_data: Float (12 F) packed triangles in BVH order; tris: DeviceTriangles in BVH order;
    backend, precision: of the arrays (``types``); intersection: name of the triangle
    routine; info: ``stats()``.
    """

    nodes: object
    children: object
    tri_data: object
    tris: DeviceTriangles
    backend: str = "llvm"
    precision: str = "float32"
    intersection: str = DEFAULT_ROUTINE
    tie_break: str = "lowest"          # query.TIE_BREAKS; "other" only probes ties
    tie_window: float = 0.0            # t window (world units) of tie_break "other"
    tie_slack: float = 0.0             # edge slack (world units) of tie_break "other"
    info: dict = field(default_factory=dict, repr=False)
    tri_trav: object = None
    refill: int = 0                    # rays per lane of ``traverse.refill_traversal``
    reach: float = 0.0                 # origins the box padding covers (``traverse.box_ray``)

    @classmethod
    def build(cls, scene, t: Types, *, intersection: str = DEFAULT_ROUTINE,
              leaf_size: int = LEAF_SIZE, bins: int = BINS, binary: BVHArrays | None = None,
              **build_options) -> "BVH":
        """``build_options`` go to ``build_bvh`` (root_bins, all_axes, sah_leaves,
        depth_first, sample); ``binary``: an existing build of ``scene`` to upload instead.
        The host arrays of ``host_layout``, uploaded by ``from_layout``."""
        triangle_routine(intersection)
        a = binary if binary is not None else build_bvh(
            scene.vertices, scene.faces, leaf_size=leaf_size, bins=bins, **build_options)
        t0 = time.perf_counter()
        arrays, info = cls.host_layout(scene, t, a, intersection=intersection)
        info.update(leaf_size=leaf_size, bins=bins)
        acc = cls.from_layout(t, arrays, info)
        acc.info["upload_seconds"] = time.perf_counter() - t0
        return acc

    @classmethod
    def host_layout(cls, scene, t: Types, a: BVHArrays, *,
                    intersection: str = DEFAULT_ROUTINE, extent: float | None = None,
                    triangles: dict | None = None) -> tuple[dict, dict]:
        """Everything the accelerator of tree ``a`` uploads, as host arrays in their device
        dtypes (``triangle_arrays``' and ``nodes`` (N, 12) the traversal's boxes,
        ``children`` uint32 (N, 2)), and its ``info`` (JSON-able; ``reach`` included).
        ``extent``: ``pad_extent`` where the caller has it; ``triangles``: the
        ``triangle_arrays`` of ``a.order`` where the caller has them."""
        extent = pad_extent(scene, intersection) if extent is None else extent
        arrays = dict(triangles or triangle_arrays(scene, t.is_double, a.order,
                                                   routine=intersection))
        fdt = np.float64 if t.is_double else np.float32
        arrays["nodes"] = np.ascontiguousarray(
            traversal_boxes(a, scene, t, intersection, extent), fdt)
        arrays["children"] = np.ascontiguousarray(a.children, np.uint32)
        return arrays, _info(scene, t, intersection, (a.build_seconds, a.node_count,
                                                      a.leaf_count, a.levels, a.sah_cost))

    @classmethod
    def from_layout(cls, t: Types, arrays: dict, info: dict, own: bool = False) -> "BVH":
        """The accelerator on the device from ``host_layout``'s ``arrays`` and ``info``
        (uploads only: no host work beyond aligned copies; ``own``: the arrays are this
        call's to hand over, as ``device_triangles``)."""
        tri_data, tris = device_triangles(t, arrays, own)
        boxes, children = arrays["nodes"], arrays["children"]
        put = host_source(t, own)
        if uses_pairs(t):
            nodes = as_pairs(t, boxes.view(np.uint32), copy=not own)
            children = as_pairs(t, children, copy=not own)
        else:
            nodes = t.Float(put(boxes.reshape(-1)))
            children = t.UInt32(put(children.reshape(-1)))
        tri_trav = traversal_triangles(t, tri_data)
        dr.eval(nodes, children, tri_data, tri_trav, tris)
        info = dict(info)
        return cls(nodes, children, tri_data, tris, backend=t.backend, precision=t.precision,
                   intersection=info["intersection"], info=info, tri_trav=tri_trav,
                   reach=float(info["reach"]))

    @classmethod
    def from_device_tree(cls, scene, t: Types, tree, *, intersection: str = DEFAULT_ROUTINE,
                         extent: float | None = None,
                         triangles: dict | None = None) -> "BVH":
        """The accelerator of a tree its builder left on the device
        (``device_build.DeviceTree``), made there in float32: the arrays ``from_layout``
        uploads for ``host_layout(scene, t, tree.host(), ...)``, bit for bit, without the
        tree's copy to the host. The nodes are the build's own boxes where no ray origin
        lies away from 0, else its unpadded boxes padded for ``extent`` on the device
        (``DeviceTree.padded``: ``traversal_boxes``' float32 rule); the triangles are
        ``triangle_arrays`` in face order (``triangles``: where the caller has them),
        uploaded and gathered into the tree's order there."""
        if t.is_double:
            raise ValueError("from_device_tree: a float32 accelerator (float64 refits its "
                             "boxes on the host)")
        triangle_routine(intersection)
        extent = pad_extent(scene, intersection) if extent is None else extent
        nodes = tree.padded(extent) if box_reach(scene, intersection) > 0 else tree.boxes
        arrays = triangles or triangle_arrays(scene, False, None, routine=intersection)
        face_data, face_tris = device_triangles(t, arrays)
        order = tree.order
        rows = dr.arange(t.UInt32, dr.width(order) * STRIDE)
        tri_data = dr.gather(t.Float, face_data,
                             dr.gather(t.UInt32, order, rows // STRIDE) * STRIDE
                             + rows % STRIDE)
        normals = ("n0" in arrays)
        gather3 = lambda v: dr.gather(t.Array3f, v, order)  # noqa: E731
        tris = DeviceTriangles(
            ng=gather3(face_tris.ng),
            n0=gather3(face_tris.n0) if normals else face_tris.n0,
            n1=gather3(face_tris.n1) if normals else face_tris.n1,
            n2=gather3(face_tris.n2) if normals else face_tris.n2,
            material=dr.gather(t.UInt32, face_tris.material, order),
            smooth=dr.gather(t.Bool, face_tris.smooth, order), order=t.UInt32(order))
        children = tree.children
        if uses_pairs(t):
            nodes, children = device_pairs(t, nodes), device_pairs(t, children)
        tri_trav = device_pairs(t, tri_data) if uses_pairs(t) else None
        dr.eval(nodes, children, tri_data, tri_trav, tris)
        leaf_count, sah, _ = tree.summary()
        info = _info(scene, t, intersection, (tree.build_seconds, tree.node_count, leaf_count,
                                              tree.levels, sah))
        return cls(nodes, children, tri_data, tris, backend=t.backend, precision=t.precision,
                   intersection=intersection, info=info, tri_trav=tri_trav,
                   reach=float(info["reach"]))

    def counts(self, ray: Ray, active=True, any_hit: bool = False):
        """The instrumented traversal (profiling): ``(node_steps, triangle_steps,
        iterations)`` UInt32 per ray, the same traversal as the query with counters."""
        return self._traverse(ray, active, any_hit, counting=True)

    def _leaf_triangles(self, routine) -> LeafTriangles:
        """The triangles as the traversal reads them (``tri_trav`` where the backend has
        one), with ``routine``."""
        return LeafTriangles(t=self.types, routine=routine, order=self.tris.order,
                             data=self.tri_data if self.tri_trav is None else self.tri_trav)

    def _traverse(self, ray: Ray, active, any_hit: bool, probe=None, counting: bool = False):
        if self.refill and not counting and probe is None:
            n = dr.width(ray.o, ray.d, ray.t_max, active)
            lanes = refill_lanes(n, self.refill)
            if lanes < n:
                return refill_traversal(
                    self._leaf_triangles(triangle_routine(self.intersection)),
                    lambda r, best_t, stack, to_pop: node_step(
                        self, r, best_t, stack, to_pop, any_hit=any_hit),
                    ray, active, any_hit, lanes, "bvh_refill", self.reach)
        return self._traverse_lanes(ray, active, any_hit, probe, counting)

    @syntax
    def _traverse_lanes(self, ray: Ray, active, any_hit: bool, probe=None,
                        counting: bool = False):
        t = self.types
        r, active, n = setup(t, ray, active, self.reach)
        tris = self._leaf_triangles(bind_routine(triangle_routine(self.intersection),
                                                 r.o, r.d))
        stack = Stack.start(t, active, n)                      # root = node 0
        first = dr.zeros(t.UInt32, n)                           # pending leaf triangles
        end = dr.zeros(t.UInt32, n)                             # [first, end)
        rec = Closest.empty(t, r.t_max, n)                      # closest hit so far
        n_node = dr.zeros(t.UInt32, n)                          # counters (``counts``)
        n_tri = dr.zeros(t.UInt32, n)
        n_iter = dr.zeros(t.UInt32, n)

        while dr.hint(active, max_iterations=-1,
                      label="bvh_llvm" if t.backend == "llvm" else "bvh",
                      exclude=[self, t, tris, any_hit, probe, counting]):
            # ---- node step: only when no leaf triangles are pending ---------------------
            is_leaf, is_inner, first, end = enter_leaf(stack.cur, first, end)
            if dr.hint(counting, mode="scalar"):
                n_node += dr.select(is_inner, 1, 0)
                n_tri += dr.select(first < end, 1, 0)
                n_iter += 1
            cull = cull_t(rec, r.t_max, probe)   # boxes beyond it are skipped
            stack, to_pop = masked_step(
                t, is_inner,
                lambda stack, to_pop, on, best_t=cull: node_step(
                    self, r, best_t, stack, to_pop, on, probe_pad(probe), any_hit),
                (stack, is_leaf | False))
            stack.pop(to_pop)

            # ---- triangle step: one pending leaf triangle ---------------------------------
            rec, first = leaf_triangle_step(tris, r, first, end, rec, any_hit, probe)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~rec.found

            active &= (first < end) | (stack.cur != DONE)

        return traversal_result(rec, any_hit, (n_node, n_tri, n_iter) if counting else None)
