"""Ray/triangle intersection routines (one function each, same signature).

All take the ray (origin ``o``, direction ``d``: Array3f) and the triangle as its first vertex
``v0`` and the edge vectors ``e1 = v1 - v0``, ``e2 = v2 - v0`` (precomputed on the host at
load, as in the thesis), and return ``(t, u, v, hit)``: the ray parameter, the barycentrics
of ``v1`` and ``v2``, and a Bool mask. ``hit`` already includes ``t > t_min``; callers compare
``t`` against their own ``t_max``. The types follow the inputs, so float64 works unchanged.
"""
from __future__ import annotations

import drjit as dr


#: Barycentric slack of Möller–Trumbore's inside test. The test is not watertight: a ray
#: through a shared edge can miss both triangles by a rounding error (seen on CUDA, where
#: products are contracted into FMAs, as black pixels along a quad's diagonal). Accepting
#: ``u, v >= -EDGE_SLACK`` and ``u + v <= 1 + EDGE_SLACK`` closes those cracks; the closest-
#: hit tie-break (lowest original face index) keeps the choice deterministic, and the
#: BVH's boxes are padded far more than this.
EDGE_SLACK = 2.0 ** -20


def moller_trumbore(o, d, v0, e1, e2, t_min=0.0):
    """Möller–Trumbore (thesis eqs. 1-5), with ``EDGE_SLACK`` on the inside test.
    Two-sided; parallel rays never hit."""
    p = dr.cross(d, e2)
    det = dr.dot(e1, p)
    inv_det = dr.rcp(det)
    s = o - v0
    u = dr.dot(s, p) * inv_det
    q = dr.cross(s, e1)
    v = dr.dot(d, q) * inv_det
    t = dr.dot(e2, q) * inv_det
    hit = ((det != 0) & (u >= -EDGE_SLACK) & (v >= -EDGE_SLACK) & (u + v <= 1 + EDGE_SLACK)
           & (t > t_min))
    return t, u, v, hit


#: Routines by name, so the intersection test is a render parameter.
ROUTINES = {"moller_trumbore": moller_trumbore}
