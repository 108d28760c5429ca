"""Per-object bounding boxes (the thesis's scheme).

One axis-aligned box per scene object (``Scene.objects`` face ranges); a ray tests each
object's box (Williams et al.) and, if it hits, the object's triangles. Triangles stay in
scene order (``tris.order`` is the identity).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from ..device import Types, host_array, syntax
from .base import Accelerator, DeviceTriangles, Ray, array_type, gather_floats
from .bvh_build import pad_boxes
from .query import Closest
from .traverse import (
    LeafTriangles,
    TraversalRay,
    cull_t,
    leaf_triangle_step,
    masked_step,
    probe_pad,
    setup,
    slab,
    traversal_result,
)
from .triangle import (
    DEFAULT_ROUTINE,
    bind_routine,
    origin_reach,
    pad_extent,
    triangle_routine,
    upload_triangles,
)


@dataclass
class ObjectBoxes(Accelerator):
    """Per-object boxes accelerator (see the module docstring).

    Build with ``ObjectBoxes.build(scene, t, intersection=DEFAULT_ROUTINE)``.
    boxes: Float (8 n_objects) lo xyz, pad, hi xyz, pad (of the precision in use, from
    ``Scene.positions``, grown by ``pad_boxes`` with the routine's ``box_reach``);
    ranges: UInt32 (2 n_objects) first face, face count; tri_data: Float (12 F) packed
    triangles; tris: DeviceTriangles; backend, precision: of the arrays (``types``);
    intersection: name of the triangle routine; info: ``stats()``.
    """

    boxes: object
    ranges: object
    tri_data: object
    tris: DeviceTriangles
    backend: str = "llvm"
    precision: str = "float32"
    intersection: str = DEFAULT_ROUTINE
    tie_break: str = "lowest"          # query.TIE_BREAKS; "other" only probes ties
    tie_window: float = 0.0            # t window (world units) of tie_break "other"
    tie_slack: float = 0.0             # edge slack (world units) of tie_break "other"
    info: dict = field(default_factory=dict, repr=False)
    reach: float = 0.0                 # origins the box padding covers (``traverse.box_ray``)

    @classmethod
    def build(cls, scene, t: Types, *, intersection: str = DEFAULT_ROUTINE) -> "ObjectBoxes":
        triangle_routine(intersection)
        t0 = time.perf_counter()
        F = scene.face_count
        objs = [(o.first_face, o.face_count) for o in scene.objects if o.face_count > 0]
        if not objs and F:
            objs = [(0, F)]
        fdt = np.float64 if t.is_double else np.float32
        boxes = np.full((max(len(objs), 1), 8), np.inf, fdt)
        ranges = np.zeros((max(len(objs), 1), 2), np.uint32)
        V = scene.positions(t.is_double).astype(fdt)
        ext = pad_extent(scene, intersection)
        for k, (f0, fc) in enumerate(objs):      # a loop over objects, not triangles
            p = V[scene.faces[f0:f0 + fc].reshape(-1)]
            boxes[k, 0:3], boxes[k, 4:7] = pad_boxes(p.min(axis=0), p.max(axis=0), ext)
            ranges[k] = (f0, fc)
        tri_data, tris = upload_triangles(scene, t, routine=intersection)
        out = cls(t.Float(host_array(boxes.reshape(-1))), t.UInt32(host_array(ranges.reshape(-1))),
                  tri_data, tris,
                  backend=t.backend, precision=t.precision,
                  intersection=intersection,
                  reach=origin_reach(scene, intersection))
        dr.eval(out.boxes, out.ranges, out.tri_data, out.tris)
        out.info = {"accel": "boxes", "intersection": intersection,
                    "build_seconds": time.perf_counter() - t0, "triangles": F,
                    "objects": len(objs),
                    "box_bytes_per_triangle": len(objs) * 8 * (8 if t.is_double else 4) / max(F, 1)}
        return out


    def _box_step(self, ray: TraversalRay, t_max, obj, first, end, active=True, pad=0.0):
        """Object ``obj``'s box where ``active``: on a hit its faces become the pending
        range ``[first, end)``; ``obj`` moves on to the next object."""
        t = self.types
        f = gather_floats(t, self.boxes, obj, 8, 8, active)
        if t.backend == "llvm":
            r0 = dr.gather(t.UInt32, self.ranges, obj * 2, active)
            r1 = dr.gather(t.UInt32, self.ranges, obj * 2 + 1, active)
        else:
            rng = dr.gather(array_type(t, "Array2u"), self.ranges, obj, active)
            r0, r1 = rng.x, rng.y
        lo, hi = t.Array3f(f[0], f[1], f[2]), t.Array3f(f[4], f[5], f[6])
        if pad:         # the tie probe's slack reaches beyond the padded boxes
            lo, hi = lo - pad, hi + pad
        hit, _ = slab(t, ray, lo, hi, t_max)
        if active is not True:
            hit &= active
        return (dr.select(hit, r0, first), dr.select(hit, r0 + r1, end),
                obj + 1 if active is True else dr.select(active, obj + 1, obj))

    @syntax
    def _traverse(self, ray: Ray, active, any_hit: bool, probe=None):
        t = self.types
        n_obj = dr.width(self.ranges) // 2
        r, active, n = setup(t, ray, active, self.reach)
        tris = LeafTriangles(t=t, routine=bind_routine(triangle_routine(self.intersection),
                                                       r.o, r.d),
                             data=self.tri_data, order=self.tris.order)
        active &= n_obj > 0
        obj = dr.zeros(t.UInt32, n)                 # next object to test
        first = dr.zeros(t.UInt32, n)               # pending triangles [first, end)
        end = dr.zeros(t.UInt32, n)
        rec = Closest.empty(t, r.t_max, n)          # closest hit so far

        while dr.hint(active, max_iterations=-1, label="boxes",
                      exclude=[self, t, tris, any_hit, probe]):
            # ---- box step: the next object's box, when no triangles are pending ---------
            cull = cull_t(rec, r.t_max, probe)   # boxes beyond it are skipped
            first, end, obj = masked_step(
                t, (first >= end) & (obj < n_obj),
                lambda first, end, obj, on, best_t=cull: self._box_step(
                    r, best_t, obj, first, end, on, probe_pad(probe)),
                (first, end, obj))

            # ---- triangle step -----------------------------------------------------------
            rec, first = leaf_triangle_step(tris, r, first, end, rec, any_hit, probe)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~rec.found

            active &= (first < end) | (obj < n_obj)

        return traversal_result(rec, any_hit)
