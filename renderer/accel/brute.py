"""Brute force: every ray tests every triangle (the reference accelerator)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr

from ..device import Types, syntax
from .base import Accelerator, DeviceTriangles, Ray
from .query import Closest
from .traverse import LeafTriangles, setup, traversal_result, triangle_step
from .triangle import DEFAULT_ROUTINE, bind_routine, triangle_routine, upload_triangles


@dataclass
class BruteForce(Accelerator):
    """Every ray tests every triangle, in scene order.

    tri_data: Float (12 F) packed triangles; tris: DeviceTriangles, in scene order;
    backend, precision: of the arrays (``types``); intersection: name of the triangle
    routine (``renderer.accel.triangle.ROUTINES``); info: ``stats()``.

    The candidate loop is a symbolic loop over triangle indices; each candidate goes through
    the shared ``traverse.triangle_step``. Rays start at their offset origin, so
    ``t_min = 0``.
    """

    tri_data: object
    tris: DeviceTriangles
    backend: str = "llvm"
    precision: str = "float32"
    intersection: str = DEFAULT_ROUTINE
    tie_break: str = "lowest"          # query.TIE_BREAKS; "other" only probes ties
    tie_window: float = 0.0            # t window (world units) of tie_break "other"
    tie_slack: float = 0.0             # edge slack (world units) of tie_break "other"
    info: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, scene, t: Types, *, intersection: str = DEFAULT_ROUTINE) -> "BruteForce":
        triangle_routine(intersection)
        t0 = time.perf_counter()
        tri_data, tris = upload_triangles(scene, t, routine=intersection)
        dr.eval(tri_data, tris)
        info = {"accel": "brute", "intersection": intersection,
                "build_seconds": time.perf_counter() - t0, "triangles": tris.count,
                "nodes": 0}
        return cls(tri_data, tris, backend=t.backend, precision=t.precision,
                   intersection=intersection, info=info)

    @syntax
    def _traverse(self, ray: Ray, active, any_hit: bool, probe=None):
        t = self.types
        count = self.tris.count
        r, active, n = setup(t, ray, active)
        tris = LeafTriangles(t=t, routine=bind_routine(triangle_routine(self.intersection),
                                                       r.o, r.d),
                             data=self.tri_data, order=self.tris.order)
        rec = Closest.empty(t, r.t_max, n)          # closest hit so far
        i = dr.zeros(t.UInt32, n)                   # next candidate triangle
        while dr.hint(active & (i < count), max_iterations=-1,
                      label="brute_force_any" if any_hit else "brute_force_closest",
                      exclude=[self, t, tris, count, any_hit, probe]):
            rec = triangle_step(tris, r, i, rec, any_hit, probe=probe)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~rec.found
            i += 1
        return traversal_result(rec, any_hit)
