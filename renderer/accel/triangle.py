"""Ray/triangle intersection routines and the one packed triangle layout.

Routines (one function each) take the ray (origin ``o``, direction ``d``: Array3f) and the
triangle as the Array3f its layout holds (the function's ``layout`` attribute, "edges"
when absent; ``layout_of``), and return
``(t, u, v, hit)``: the ray parameter, the barycentrics of ``v1`` and ``v2``, and a Bool
mask. ``hit`` already includes ``t > t_min``; callers compare ``t`` against their own
``t_max``. The types follow the inputs, so float64 works unchanged. A routine may have a
``bind(o, d)`` attribute returning the same test with its per-ray part computed once for the
rays ``(o, d)``; traversal loops call it through ``bind_routine`` before the loop.

- ``moller_trumbore`` reads the first vertex ``v0`` and the edge vectors ``e1 = v1 - v0``,
  ``e2 = v2 - v0`` (precomputed on the host at load, as in the thesis): layout "edges".
- ``watertight`` (Woop, Benthin, Wald 2013; pbrt-v4 ``IntersectTriangle``) reads the raw
  vertices ``p0, p1, p2`` and the unit normal ``n``: layout "vertices". Watertightness needs
  the exact shared vertex values (``v0 + e1`` rounded does not give back ``p1``), so the two
  routines cannot share one set of vectors.

Packed layout (``pack`` on the host, ``load`` on the device): 12 floats per triangle,
three quads: "edges" is ``v0, e1, e2`` and 3 floats of padding; "vertices" is ``p0, p1, p2,
n`` (the padding holds the unit normal, so a CUDA packet gather loads it for free). This
module is the one owner of it.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from .. import parallel
from ..device import Types, host_array, host_view, rcp
from ..device import unit_roundoff as unit_roundoff
from ..scene.model import vertex_reach
from .base import DeviceTriangles, gather_floats

#: Floats per packed triangle.
STRIDE = 12


def edge_slack(double: bool) -> float:
    """Barycentric slack of Möller–Trumbore's inside test: 16 units of roundoff (2^-20 in
    float32). The test is not watertight: a ray through a shared edge can miss both
    triangles by a rounding error (seen on CUDA, where products are contracted into FMAs, as
    black pixels along a quad's diagonal). Accepting ``u, v >= -slack`` and
    ``u + v <= 1 + slack`` closes those cracks; the closest-hit tie-break (lowest original
    face index) keeps the choice deterministic, and the boxes of the accelerators are padded
    far more than this (``renderer.accel.bvh_build.pad_boxes``)."""
    return 16.0 * unit_roundoff(double)


def moller_trumbore(o, d, v0, e1, e2, t_min=0.0):
    """Möller–Trumbore (thesis eqs. 1-5), with ``edge_slack`` on the inside test.
    Two-sided; parallel rays never hit."""
    slack = edge_slack(dr.type_v(o) == dr.VarType.Float64)
    p = dr.cross(d, e2)
    det = dr.dot(e1, p)
    inv_det = rcp(det)
    s = o - v0
    u = dr.dot(s, p) * inv_det
    q = dr.cross(s, e1)
    v = dr.dot(d, q) * inv_det
    t = dr.dot(e2, q) * inv_det
    hit = ((det != 0) & (u >= -slack) & (v >= -slack) & (u + v <= 1 + slack)
           & (t > t_min))
    return t, u, v, hit


def difference_of_products(a, b, c, d):
    """``a*b - c*d`` by Kahan's algorithm (pbrt-v4 ``DifferenceOfProducts``): relative
    error <= 2 units of roundoff, so the sign is exact (0 exactly when ``a*b == c*d``) and
    swapping the two products negates the result's sign exactly, FMA contraction or not."""
    cd = c * d
    dop = dr.fma(a, b, -cd)
    err = dr.fma(-c, d, cd)
    return dop + err


def _gamma(n: int, double: bool) -> float:
    u = unit_roundoff(double)
    return n * u / (1 - n * u)


def _edges_float64(xy, e):
    """The three edge functions recomputed in float64 from the float32 sheared vertices
    ``xy = (x0, y0, x1, y1, x2, y2)``: the products are exact there, so the one rounding
    of the difference keeps the sign. ``e``: the float32 edge functions (unused)."""
    x0, y0, x1, y1, x2, y2 = xy
    Float = type(x0)
    F64 = dr.float64_array_t(Float)
    X0, Y0, X1, Y1, X2, Y2 = (F64(c) for c in (x0, y0, x1, y1, x2, y2))
    return (Float(X1 * Y2 - Y1 * X2), Float(X2 * Y0 - Y2 * X0), Float(X0 * Y1 - Y0 * X1))


def _edges_as_they_are(xy, e):
    return e


def _rotate(v, zx, zy):
    """``v`` rotated so that its x (where ``zx``), y (where ``zy``) or else z component
    comes last: ``(v[kx], v[ky], v[kz])`` with ``kz`` that axis, ``kx = kz + 1``,
    ``ky = kz + 2`` (mod 3)."""
    return (dr.select(zx, v.y, dr.select(zy, v.z, v.x)),
            dr.select(zx, v.z, dr.select(zy, v.x, v.y)),
            dr.select(zx, v.x, dr.select(zy, v.y, v.z)))


def watertight(o, d, p0, p1, p2, n, t_min=0.0):
    """Watertight ray/triangle test (Woop, Benthin, Wald 2013; pbrt-v4's
    ``IntersectTriangle``): translate the vertices to the ray origin, permute the axes so
    that the ray's largest direction component is z, shear the ray onto +z, and test the
    signs of the three 2-D edge functions of the projected triangle. A shared edge's edge
    function is computed from the same transformed vertices in both triangles with exactly
    opposite sign (``difference_of_products``), so a ray through an edge or a vertex cannot
    pass between two triangles. In float32 an edge function that comes out exactly 0 is
    recomputed in float64 (products of floats are exact there). A hit is accepted only
    where the sign of ``t`` is certain under the rounding of its own formula (the bound in
    the code), so a ray spawned from a triangle never re-hits it at t ~ 0. Two-sided;
    edge-on triangles never hit.

    The distance is the plane's, ``t = (p0 - o)·n / d·n`` with ``n`` the unit normal
    rounded once on the host: for an axis-aligned plane ``n`` is exactly a unit axis, so
    every triangle of the plane gets the same ``t`` for a ray, and coplanar overlapping
    faces tie exactly (the lowest face index wins, in either precision) instead of
    z-fighting on the rounding of the edge functions.

    A traversal binds the test to its rays once (``bind_routine``, ``_watertight_bind``):
    the rotation and shear are the same for every triangle a ray meets."""
    return _watertight_bind(o, d)(o, d, p0, p1, p2, n, t_min)


def _watertight_bind(o, d):
    """``watertight`` for the rays ``(o, d)`` of one traversal (``bind_routine``): the
    per-ray part of the test (the axis rotation that puts the largest ``|d|`` component
    last, and the shear) computed once, before the traversal loop, instead of at every
    triangle. The rotation is cyclic (``kx = kz + 1``, ``ky = kz + 2`` mod 3), chosen by
    two Bools, so a vertex is rotated with two selects per component. Both are bitwise the
    same test as selects on integer axis indices at every test, and cheaper on CUDA
    (``lab/notes/accel-decisions.md``)."""
    double = dr.type_v(o) == dr.VarType.Float64
    ad = dr.abs(d)
    zx = (ad.x > ad.y) & (ad.x > ad.z)           # largest |d| component: x
    zy = ~(ad.x > ad.y) & (ad.y > ad.z)          # y (else z)
    dx, dy, dz = _rotate(d, zx, zy)
    inv_dz = 1.0 / dz
    sx, sy = -dx * inv_dz, -dy * inv_dz

    def bound(o_, d_, p0, p1, p2, n, t_min=0.0):
        # ---- translate, rotate (largest |d| component to z), shear ------------------------
        a0, a1, a2 = p0 - o_, p1 - o_, p2 - o_
        x0, y0, z0 = _rotate(a0, zx, zy)
        x1, y1, z1 = _rotate(a1, zx, zy)
        x2, y2, z2 = _rotate(a2, zx, zy)
        x0, y0 = dr.fma(sx, z0, x0), dr.fma(sy, z0, y0)
        x1, y1 = dr.fma(sx, z1, x1), dr.fma(sy, z1, y1)
        x2, y2 = dr.fma(sx, z2, x2), dr.fma(sy, z2, y2)
        return _watertight_tail((a0, a1, a2), n, d_, (x0, y0, x1, y1, x2, y2), double,
                                t_min)
    bound.layout = "vertices"
    return bound


def bind_routine(routine, o, d):
    """``routine`` for the rays ``(o, d)`` of one traversal loop: ``routine.bind(o, d)``
    where the routine has one (its per-ray set-up hoisted out of the loop; the result
    takes the same arguments, and ``o``, ``d`` must be the rays it was bound to), else
    ``routine`` itself. A loop whose lanes change rays (``refill_traversal``) calls the
    routine unbound."""
    bind = getattr(routine, "bind", None)
    return routine if bind is None else bind(o, d)


def _watertight_tail(a, n, d, xy, double, t_min):
    """The rest of ``watertight`` from the translated vertices ``a = (a0, a1, a2)``,
    ``a_k = p_k - o``, and the sheared 2-D vertices ``xy = (x0, y0, x1, y1, x2, y2)``."""
    a0, a1, a2 = a
    x0, y0, x1, y1, x2, y2 = xy
    # ---- edge functions (exact sign), float64 where one is exactly 0 in float32 ----------
    e0 = difference_of_products(x1, y2, y1, x2)
    e1 = difference_of_products(x2, y0, y2, x0)
    e2 = difference_of_products(x0, y1, y0, x1)
    if not double:
        # a symbolic branch: the float64 products are a large part of the test when
        # evaluated on every lane, and an exactly-zero edge function is rare
        e0, e1, e2 = dr.if_stmt((xy, (e0, e1, e2)), (e0 == 0) | (e1 == 0) | (e2 == 0),
                                _edges_float64, _edges_as_they_are)
    mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0))
    det = e0 + e1 + e2
    # ---- distance: the plane's, with a conservative sign -------------------------------
    inv_det = 1.0 / det
    u = e1 * inv_det
    v = e2 * inv_det
    num = dr.dot(a0, n)                      # (p0 - o)·n
    den = dr.dot(d, n)
    t = num / den
    # ``t > 0`` is trusted only where the signs of ``num`` and ``den`` are exact: the ray
    # meets the triangle at ``q = Σ b_k p_k`` where ``t (d·n) = (q - o)·n = Σ b_k N_k``,
    # ``N_k = (p_k - o)·n`` exactly (any ``n``), so the true ``t`` has ``num``'s sign when
    # ``|num|`` exceeds the spread of the three ``N_k`` (the triangle's tilt against the
    # rounded ``n``) plus twice their rounding (``a_k = p_k - o`` and the dot product:
    # γ4 Σ|a_k||n|). This bound scales with the distances from the origin to the vertices
    # along ``n``, not with the triangle's extent along the ray (pbrt-v4's deltaT, for its
    # own ``t = Σ e_k z_k / det``, grows with that extent: on a floor 4e5 wide it
    # rejected true hits up to t ≈ 2, so shadows and glass in front of it changed); for an
    # axis-aligned triangle (``n`` a unit axis) the spread and the rounding are exactly 0.
    an = dr.abs(n)
    n1, n2 = dr.dot(a1, n), dr.dot(a2, n)
    spread = dr.maximum(dr.abs(n1 - num), dr.abs(n2 - num))
    s_max = dr.maximum(dr.maximum(dr.dot(dr.abs(a0), an), dr.dot(dr.abs(a1), an)),
                       dr.dot(dr.abs(a2), an))
    g3, g4 = _gamma(3, double), _gamma(4, double)
    num_ok = dr.abs(num) > (spread + 2.0 * g4 * s_max) * (1.0 + g4)
    den_ok = dr.abs(den) > g3 * dr.dot(dr.abs(d), an)
    hit = (~mixed & (det != 0) & num_ok & den_ok & dr.isfinite(t) & (t > 0)
           & (t > t_min))
    return t, u, v, hit


#: Routines by name, so the intersection test is a render parameter.
ROUTINES = {"moller_trumbore": moller_trumbore, "watertight": watertight}

#: The routine a render uses unless told otherwise (re-exported by ``renderer.accel``;
#: the measurements behind the choice are in its docstring there).
DEFAULT_ROUTINE = "watertight"

moller_trumbore.layout = "edges"
watertight.layout = "vertices"
watertight.bind = _watertight_bind

#: Array3f per triangle of each layout (what ``load`` returns).
LAYOUT_VECTORS = {"edges": 3, "vertices": 4}


def layout_of(routine) -> str:
    """The packed layout ("edges" or "vertices") the routine (a name of ``ROUTINES`` or the
    function) reads: its ``layout`` attribute, "edges" when it has none."""
    fn = triangle_routine(routine) if isinstance(routine, str) else routine
    return getattr(fn, "layout", "edges")


def triangle_routine(name: str):
    """The routine registered as ``name`` in ``ROUTINES``; ValueError listing the choices."""
    try:
        return ROUTINES[name]
    except KeyError:
        raise ValueError(f"intersection: expected one of {sorted(ROUTINES)}, "
                         f"got {name!r}") from None


def box_reach(scene, routine: str) -> float:
    """What ``pad_boxes`` adds to the scene's extent: the largest coordinate magnitude a ray
    origin of ``scene`` has (cameras, lights, the geometry itself), for every ``routine``.
    The watertight test decides on vertices translated to the ray origin, which moves them
    by up to a few units of roundoff of ``|p - o|`` (pbrt's conservative traversal: the
    slab test never rejects a ray the triangle test would accept); and the slab test's FMA
    form moves its planes by up to a unit of roundoff of ``|o|`` (``traverse.box_ray``,
    where origins beyond the reach enter every box), whichever routine the boxes serve."""
    mags = [vertex_reach(scene)]
    mags += [float(np.max(np.abs(c.position))) for c in scene.cameras]
    mags += [float(np.max(np.abs(li.position))) for li in scene.lights]
    return max(mags)


def pad_extent(scene, routine: str) -> float:
    """The extent the accelerators pad their boxes with (``bvh_build.pad_boxes``): the
    scene's size plus ``box_reach`` (0 without triangles)."""
    if not scene.face_count:
        return 0.0
    lo, hi = scene.bounds()
    return float(np.max(hi - lo)) + box_reach(scene, routine)


def origin_reach(scene, routine: str) -> float:
    """An accelerator's ``reach``: ray origins of coordinates up to it in magnitude are
    covered by its boxes' padding (``pad_extent``); from farther away rays enter every box
    (``traverse.box_ray``). Infinite without triangles: there is nothing to miss."""
    return pad_extent(scene, routine) if scene.face_count else float("inf")


def pack(vertices: np.ndarray, faces: np.ndarray, layout: str = "edges") -> np.ndarray:
    """float64 (F, STRIDE) packed rows of the triangles ``faces`` (int (F, 3)) of
    ``vertices`` (float (V, 3)); the caller casts to the precision in use. ``layout``
    (``layout_of``): "edges" stores ``v0, v1 - v0, v2 - v0`` (the edges are differences of
    float64 vertices, rounded once by that cast; zero for a triangle without area, which
    then never hits); "vertices" stores ``p0, p1, p2`` and the unit normal
    ``normalize((p1 - p0) x (p2 - p0))`` (zero for a triangle without area: never hits)."""
    if layout not in ("edges", "vertices"):
        raise ValueError(f"layout: expected 'edges' or 'vertices', got {layout!r}")
    faces = np.asarray(faces)
    packed = np.zeros((faces.shape[0], STRIDE), np.float64)
    fc = [np.ascontiguousarray(faces[:, c], np.intp) for c in range(3)]
    _pack_rows(_columns(vertices), fc, layout, {"tri_data": packed})
    return packed


def _columns(a: np.ndarray, dtype=np.float64) -> list[np.ndarray]:
    """The three columns of ``a`` (N, 3) as contiguous ``dtype`` arrays (threads)."""
    a = np.asarray(a)
    return parallel.run(lambda k: np.ascontiguousarray(a[:, k], dtype), range(3))


def _corners(vc: list, f: list):
    """``(p, n, length)`` of the triangles of corner indices ``f`` (three index columns)
    over the vertices ``vc`` (three float64 columns): the corners ``p[c][k]`` (float64
    columns), the cross product ``(p1 - p0) x (p2 - p0)`` (three columns, ``np.cross``'s
    operations in its order) and its length (``np.linalg.norm``'s ``sqrt((x² + y²) +
    z²)``), computed once for both the packed rows and the geometric normals."""
    p = [[np.take(vc[k], f[c], mode="clip") for k in range(3)] for c in range(3)]
    a = [p[1][k] - p[0][k] for k in range(3)]
    b = [p[2][k] - p[0][k] for k in range(3)]
    n = [a[(k + 1) % 3] * b[(k + 2) % 3] - a[(k + 2) % 3] * b[(k + 1) % 3] for k in range(3)]
    length = np.sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2])
    return p, a, b, n, length


def _pack_rows(vc: list, f: list, layout: str, out: dict) -> None:
    """``pack``'s rows of the faces ``f`` (three index columns) over ``vc`` (three float64
    columns), written into ``out["tri_data"]`` (its dtype: each value rounded once, as the
    float64 rows cast to it), and where ``out`` has them the unit geometric normals
    ``out["ng"]`` (3, F); elementwise over spans of faces."""
    packed, ng = out["tri_data"], out.get("ng")

    def span(lo, hi):
        p, a, b, n, length = _corners(vc, [c[lo:hi] for c in f])
        rows = packed[lo:hi]
        if layout == "edges":
            # a triangle without area in these vertices (kept for the other precision,
            # where it has some) gets zero edges: det = 0, so it never hits
            flat = length == 0
            for k in range(3):
                rows[:, k] = p[0][k]
                rows[:, 3 + k] = np.where(flat, 0.0, a[k])
                rows[:, 6 + k] = np.where(flat, 0.0, b[k])
        else:
            pos = length > 0
            safe = np.where(pos, length, 1.0)
            for k in range(3):
                rows[:, k], rows[:, 3 + k], rows[:, 6 + k] = p[0][k], p[1][k], p[2][k]
                rows[:, 9 + k] = np.where(pos, n[k] / safe, 0.0)
        if ng is not None:
            floor = np.maximum(length, 1e-300)
            for k in range(3):
                ng[k, lo:hi] = n[k] / floor
    parallel.for_spans(len(f[0]), span)


def load(t, data, i, active=True, layout: str = "edges"):
    """The Array3f of packed triangle(s) ``i`` (UInt32) of ``data`` in ``layout``:
    ``(v0, e1, e2)`` or ``(p0, p1, p2, n)``."""
    k = LAYOUT_VECTORS[layout]
    f = gather_floats(t, data, i, STRIDE, 3 * k, active)
    return tuple(t.Array3f(f[3 * j], f[3 * j + 1], f[3 * j + 2]) for j in range(k))


def triangle_arrays(scene, double: bool, order: np.ndarray | None = None,
                    with_normals: bool | None = None, *, routine: str) -> dict:
    """The host arrays ``upload_triangles`` uploads, in their device dtypes (float64 for a
    ``double`` render, else float32): ``tri_data`` (F, STRIDE) the packed geometry of
    ``pack`` in the layout ``routine`` reads, ``ng`` (3, F) the unit geometric normals,
    ``n0``/``n1``/``n2`` (3, F) the vertex normals at the corners (only ``with_normals``,
    default: when any object is smooth), ``material`` uint32 (F,), ``smooth`` bool (F,) and
    ``order`` uint32 (F,), all permuted by ``order`` (int (F,); None: face order). The
    vertices are those of the precision (``Scene.positions``); corners, cross products and
    their lengths are computed once for the packed rows and the unit geometric normals,
    elementwise over spans of faces on ``renderer.parallel``'s threads."""
    order = (np.arange(scene.face_count, dtype=np.int64) if order is None
             else np.asarray(order, np.int64))
    F = order.size                        # references: a face may appear more than once
    fdt = np.float64 if double else np.float32
    faces, material, smooth = scene.faces, scene.face_material, scene.face_smooth
    cols = parallel.run(lambda c: np.ascontiguousarray(faces[:, c], np.intp), range(3))
    f = [np.empty(F, np.intp) for _ in range(3)]
    out = {"tri_data": np.zeros((F, STRIDE), fdt), "ng": np.empty((3, F), fdt)}
    tail = {"material": np.empty(F, np.uint32), "smooth": np.empty(F, bool),
            "order": np.empty(F, np.uint32)}

    def gather_span(lo, hi):
        o = order[lo:hi]
        for c in range(3):
            np.take(cols[c], o, out=f[c][lo:hi], mode="clip")
        tail["material"][lo:hi] = np.take(material, o, mode="clip")
        np.take(smooth, o, out=tail["smooth"][lo:hi], mode="clip")
        tail["order"][lo:hi] = o
    parallel.for_spans(F, gather_span)
    _pack_rows(_columns(scene.positions(double)), f, layout_of(routine), out)
    if with_normals is None:
        with_normals = bool(tail["smooth"].any())
    if with_normals:
        nc = _columns(scene.normals_of(double), fdt)
        for k in range(3):
            out[f"n{k}"] = np.empty((3, F), fdt)

        def normals_span(lo, hi):
            for k in range(3):
                for j in range(3):
                    np.take(nc[j], f[k][lo:hi], out=out[f"n{k}"][j, lo:hi], mode="clip")
        parallel.for_spans(F, normals_span)
    out.update(tail)
    return out


def permuted(arrays: dict, order: np.ndarray) -> dict:
    """``triangle_arrays`` made in face order, permuted by ``order`` (int (F,)): the
    arrays ``triangle_arrays`` gives for ``order`` (each row's values depend on its face
    only), by gathers over spans of rows."""
    order = np.asarray(order, np.int64)
    F = order.size
    cols = [k for k in ("ng", "n0", "n1", "n2") if k in arrays]
    src = {k: arrays[k] for k in cols + ["tri_data", "material", "smooth", "order"]}
    out = {k: np.empty((3, F) if k in cols else (F,) + v.shape[1:], v.dtype)
           for k, v in src.items()}

    def span(lo, hi):
        o = order[lo:hi]
        for k in cols:
            for j in range(3):
                np.take(src[k][j], o, out=out[k][j, lo:hi], mode="clip")
        np.take(src["tri_data"], o, axis=0, out=out["tri_data"][lo:hi], mode="clip")
        for k in ("material", "smooth", "order"):
            np.take(src[k], o, out=out[k][lo:hi], mode="clip")
    parallel.for_spans(F, span)
    return out


def host_source(t: Types, own: bool):
    """How a host array becomes the source of a device array of ``t``: on CUDA the array
    as it is where C-contiguous of the dtype (the upload copies it to the device, so its
    address enters no kernel), on LLVM ``device.host_view`` (``own``) or
    ``device.host_array`` (aligned: the traced kernel does not depend on the address)."""
    if t.backend == "cuda":
        return lambda a, dtype=None: np.ascontiguousarray(a, dtype)
    return host_view if own else host_array


def device_triangles(t: Types, arrays: dict, own: bool = False):
    """``(tri_data, tris)`` on the device from ``triangle_arrays``'s ``arrays`` (of the
    precision of ``t``): the packed geometry as a Float and the ``DeviceTriangles``
    (width-1 zero vertex normals where ``arrays`` has none). ``own``: the arrays are
    this call's to hand over (a cache hit's views): aligned ones become the device
    arrays' memory on LLVM (``device.host_view``) instead of being copied."""
    fdt = np.float64 if t.is_double else np.float32
    put = host_source(t, own)
    cols = lambda a: t.Array3f(*(t.Float(put(a[k], fdt)) for k in range(3)))  # noqa: E731
    if "n0" in arrays:
        n0, n1, n2 = (cols(arrays[f"n{k}"]) for k in range(3))
    else:
        n0 = n1 = n2 = t.Array3f(0, 0, 0)
    tri_data = t.Float(put(arrays["tri_data"].reshape(-1), fdt))
    tris = DeviceTriangles(
        ng=cols(arrays["ng"]), n0=n0, n1=n1, n2=n2,
        material=t.UInt32(put(arrays["material"], np.uint32)),
        smooth=t.Bool(put(arrays["smooth"], bool)),
        order=t.UInt32(put(arrays["order"], np.uint32)))
    return tri_data, tris


def upload_triangles(scene, t: Types, order: np.ndarray | None = None,
                     with_normals: bool | None = None, *, routine: str):
    """Upload ``scene``'s triangles, optionally permuted by ``order`` (int (F,)): returns
    ``(tri_data, tris)``, the packed geometry of ``pack`` (in the layout ``routine``
    reads) as a Float and the ``DeviceTriangles`` (``triangle_arrays``, then
    ``device_triangles``). Normals are uploaded when ``with_normals`` (default: when any
    object is smooth)."""
    return device_triangles(t, triangle_arrays(scene, t.is_double, order, with_normals,
                                               routine=routine))


def columns3(t: Types, rows: np.ndarray):
    """``t.Array3f`` of host rows (N, 3) of any float dtype, each column cast once to the
    precision in use (as ``device.array3``, without its float64 copy)."""
    fdt = np.float64 if t.is_double else np.float32
    return t.Array3f(*(t.Float(host_array(rows[:, k], fdt)) for k in range(3)))
