"""Local light, shadows and the specular weights at a hit (docs/MODEL.md).

Materials and lights are uploaded once as device arrays (``DeviceMaterials``,
``renderer.lights.DeviceLights``) and gathered per hit, so their values are inputs of the
kernel, not literals baked into it. The scene on the device travels as one ``SceneArrays``
record and the host constants as ``TraceOptions``; the ``EffectSet`` is passed itself and
decides with ``dr.hint(..., mode="scalar")`` which terms are traced. Several lights are
summed in a device loop; a single light is straight-line code. Lights are read only through
``renderer.lights.sample_light``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np

from .accel import ClosestHit, Ray
from .accel.triangle import layout_of, unit_roundoff
from .accel.triangle import load as load_triangle
from .device import Types, array3, normalize, rcp, syntax
from .effects import EffectSet
from .lights import DeviceLights, sample_hash, sample_light
from .scene import Scene, validate_settings

INV_PI = 1.0 / np.pi
INV_TWO_PI = 0.5 / np.pi


# ---- the scene on the device -----------------------------------------------------------------
@dataclass
class DeviceMaterials:
    """Material table on the device, width M (materials), indexed by the triangles'
    ``material``.

    ka, kd, ks, k_refl, k_refr: Array3f; n, ior: Float; fresnel: Bool (combination).
    """

    ka: object = None
    kd: object = None
    ks: object = None
    n: object = None
    k_refl: object = None
    k_refr: object = None
    ior: object = None
    fresnel: object = None


def upload_materials(scene: Scene, t: Types) -> DeviceMaterials:
    """``scene.materials`` as DeviceMaterials of types ``t`` (evaluated); at least one
    material is required."""
    ms = scene.materials
    if not ms:
        raise ValueError(f"scene {scene.name!r}: materials: at least one material is required")
    m = DeviceMaterials(
        ka=array3(t, [x.ka for x in ms]), kd=array3(t, [x.kd for x in ms]),
        ks=array3(t, [x.ks for x in ms]), n=t.Float([float(x.n) for x in ms]),
        k_refl=array3(t, [x.k_refl for x in ms]), k_refr=array3(t, [x.k_refr for x in ms]),
        ior=t.Float([float(x.ior) for x in ms]),
        fresnel=t.Bool([x.combination == "fresnel" for x in ms]))
    dr.eval(m)
    return m


@dataclass
class SceneArrays:
    """Everything on the device a frame reads besides the camera.

    accel: the accelerator (``accel.tris`` holds the triangles' shading attributes);
    materials: DeviceMaterials; lights: DeviceLights; ambient, background: Array3f
    (width 1).
    """

    accel: object = None
    materials: DeviceMaterials = None
    lights: DeviceLights = None
    ambient: object = None
    background: object = None


@dataclass(frozen=True)
class TraceOptions:
    """Host-side constants of the kernel: n_lights (number of lights), max_depth
    (0..MAX_DEPTH_LIMIT, checked by ``validate_settings``), min_weight (branch pruning),
    eps (None: the offset rule ``spawn``; a float: the explicit absolute offset of a
    scene's ``ray_epsilon`` override), spawn (``SPAWN_RULES``: "scale-free", offsets from
    each hit's own rounding error, the default; "mitsuba", Mitsuba 3's rule), terminator
    (``TERMINATOR_FIXES``: "none"; "hanika", shadow rays of smooth faces from the lifted
    point ``SurfacePoint.p_shadow``), shadow_samples (``k²`` shadow rays per light with
    extent, read only with soft shadows)."""

    n_lights: int
    max_depth: int
    min_weight: float
    eps: float | None = None
    spawn: str = "scale-free"
    terminator: str = "none"
    shadow_samples: int = 1

    def __post_init__(self):
        validate_settings(max_depth=self.max_depth, spawn=self.spawn,
                          shadow_samples=self.shadow_samples)


# ---- Fresnel ---------------------------------------------------------------------------------
def fresnel(cos_theta_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric interface (same conventions as
    Mitsuba 3's ``fresnel()``).

    cos_theta_i: Float, cosine of the incident angle against the normal of the *outside*
        (positive: the ray arrives from outside).
    eta: Float, relative index of refraction inside / outside.
    Returns ``(F, cos_theta_t, eta_it, eta_ti)``: reflectance (1 under total internal
    reflection), signed cosine of the transmitted direction, and the relative indices.
    """
    outside = cos_theta_i >= 0
    rcp_eta = rcp(eta)
    eta_it = dr.select(outside, eta, rcp_eta)
    eta_ti = dr.select(outside, rcp_eta, eta)
    cos_t_sqr = dr.fma(-dr.fma(-cos_theta_i, cos_theta_i, 1.0), eta_ti * eta_ti, 1.0)
    cos_i_abs = dr.abs(cos_theta_i)
    cos_t_abs = dr.safe_sqrt(cos_t_sqr)
    index_matched = eta == 1
    special = index_matched | (cos_i_abs == 0)
    r_special = dr.select(index_matched, 0.0, 1.0)
    a_s = dr.fma(-eta_it, cos_t_abs, cos_i_abs) / dr.fma(eta_it, cos_t_abs, cos_i_abs)
    a_p = dr.fma(-eta_it, cos_i_abs, cos_t_abs) / dr.fma(eta_it, cos_i_abs, cos_t_abs)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    r = dr.select(special, r_special, r)
    cos_theta_t = dr.select(cos_theta_i >= 0, -cos_t_abs, cos_t_abs)
    return r, cos_theta_t, eta_it, eta_ti


# ---- geometry at a hit -----------------------------------------------------------------------
def gamma(n: int, double: bool) -> float:
    """Higham's ``γ_n = n u / (1 - n u)``: the relative error bound of ``n`` rounded
    operations (``u``: unit roundoff of float64 if ``double``, else float32)."""
    u = unit_roundoff(double)
    return n * u / (1.0 - n * u)


#: Rounded operations the hit-point error bound covers (docs/MODEL.md, "Ray offsets"). The
#: point ``v0 + u e1 + v e2`` itself takes 2 (two FMAs); Möller–Trumbore's own error in ``t``
#: for a ray starting near the plane is a few more of the same magnitude (``s = o - v0``, the
#: triple product), so the bound is taken with pbrt-v4's margin of 7 (its
#: ``Triangle::InteractionFromIntersection``), and the self-hit count of
#: tests/hard/test_offsets_reintersect.py is the measurement that it suffices.
POINT_ERROR_OPS = 7
#: Shadow rays end this many rounding errors (relative to their length) short of the light:
#: the light's position is exact, but ``|p_l - o'|``, the unit direction and the intersection
#: routine's ``t`` each round; 16 covers them with margin (float32: 9.5e-7 of the length).
SHADOW_END_OPS = 16


@dataclass
class SurfacePoint:
    """What shading needs at a hit (arrays of the batch width).

    p: Array3f position (``hit_point``);
    p_err: Array3f per-axis bound on the distance of ``p`` from the triangle's plane;
    ng: Array3f unit geometric normal (winding order);
    ns: Array3f unit shading normal (interpolated for smooth faces, else ``ng``);
    material: UInt32 material index;
    p_shadow, p_shadow_err: Array3f the start of shadow rays and its error bound
        (``terminator_point``), or None (then ``p``, ``p_err``).
    """

    p: object = None
    p_err: object = None
    ng: object = None
    ns: object = None
    material: object = None
    p_shadow: object = None
    p_shadow_err: object = None


def hit_point(accel, ray: Ray, hit: ClosestHit, ng, t: Types):
    """The hit point and a per-axis bound on its distance from the triangle's plane,
    ``(p, p_err)`` (Array3f each; ``ng`` the hit triangle's unit normal).

    Two estimates, each good at one thing: the barycentric point ``p_b`` (edges layout
    ``v0 + u e1 + v e2``, two FMAs; vertices layout ``(1-u-v) p0 + u p1 + v p2``, pbrt-v4)
    lies on the plane up to the rounding of that sum, whatever error ``u, v`` carry, with
    the bound ``γ_7 (|t0| + |t1| + |t2|)`` over its three terms (which grows with the
    coordinates the sum cancels, so a point near the origin on a huge triangle gets the
    larger offset its rays need); the ray's point ``o + t d`` is where along the plane the
    ray arrived (``u e1`` on a 1e5-wide floor is off by ulp(1e5) in the plane, ``o + t d``
    is not). ``p`` is the ray's point moved along ``N_g`` onto the plane through ``p_b``,
    so it keeps the ray's position in the plane and the barycentric bound off it, plus the
    roundings of the move (``γ_2 |p| + γ_5 |move|``)."""
    double = t.is_double
    layout = layout_of(accel.intersection)     # raw vertices p0, p1, p2 or v0, e1, e2
    a, b, c = load_triangle(t, accel.tri_data, hit.prim, hit.found, layout)[:3]
    if layout == "vertices":
        t0, t1, t2 = a * (1.0 - hit.u - hit.v), b * hit.u, c * hit.v
        p_b = t0 + t1 + t2
    else:
        t0, t1, t2 = a, b * hit.u, c * hit.v
        p_b = dr.fma(c, hit.v, dr.fma(b, hit.u, a))
    p_r = dr.fma(ray.d, hit.t, ray.o)
    move = dr.dot(p_b - p_r, ng)
    p = dr.fma(ng, move, p_r)
    p_err = (gamma(POINT_ERROR_OPS, double) * (dr.abs(t0) + dr.abs(t1) + dr.abs(t2))
             + gamma(2, double) * dr.abs(p) + gamma(5, double) * dr.abs(move))
    return p, p_err


def terminator_point(accel, hit: ClosestHit, p, p_err, normals, sm, t: Types):
    """Hanika's shadow-terminator point (Hanika 2021, "Hacking the shadow terminator", Ray
    Tracing Gems II ch. 4) of the hits on smooth faces ``sm``: ``p`` projected onto the
    tangent plane of each vertex ``P_k`` (normal ``n_k``) where it lies below it,
    ``p' = p - Σ b_k min(0, (p - P_k)·n_k) n_k`` with the barycentrics ``b_k``, so a shadow
    ray starts on the curved surface the vertex normals imply rather than on the flat
    triangle, and the low-polygon facets next to the terminator no longer shadow it. The
    point only moves outwards (to the side the vertex normals face). Returns ``(p',
    p_err')``, the bound grown by the rounding of the move and of the sum
    (``γ_6 (|p' - p| + |p'|)`` on top of ``p_err``)."""
    layout = layout_of(accel.intersection)
    a, b, c = load_triangle(t, accel.tri_data, hit.prim, hit.found & sm, layout)[:3]
    if layout == "edges":                    # v0, e1, e2: the vertices, rounded once
        b, c = a + b, a + c
    w = (1.0 - hit.u - hit.v, hit.u, hit.v)
    move = dr.zeros(type(p), dr.width(p))
    for pk, nk, wk in zip((a, b, c), normals, w):
        move -= nk * (wk * dr.minimum(dr.dot(p - pk, nk), 0.0))
    p_s = p + move
    err = p_err + gamma(6, t.is_double) * (dr.abs(move) + dr.abs(p_s))
    return dr.select(sm, p_s, p), dr.select(sm, err, p_err)


def surface_point(accel, ray: Ray, hit: ClosestHit, t: Types, fx: EffectSet,
                  terminator: str = "none") -> SurfacePoint:
    """Gather the hit triangle's data once (``accel``: the accelerator; its ``tri_data``
    packed triangles and ``tris`` shading attributes); the point and its error bound come
    from ``hit_point``. The normal interpolation is traced only with
    ``fx.smooth_normals``; with ``terminator`` "hanika" (and shadows traced) the shadow
    rays of smooth faces start from ``terminator_point``."""
    tris = accel.tris
    A3 = type(ray.o)
    UInt32 = type(hit.prim)
    m = hit.found
    ng = dr.gather(A3, tris.ng, hit.prim, m)
    p, p_err = hit_point(accel, ray, hit, ng, t)
    ns = ng
    p_s = p_s_err = None
    if dr.hint(fx.smooth_normals, mode="scalar"):
        sm = dr.gather(type(m), tris.smooth, hit.prim, m)
        w0 = 1.0 - hit.u - hit.v
        normals = tuple(dr.gather(A3, nk, hit.prim, m & sm)
                        for nk in (tris.n0, tris.n1, tris.n2))
        n_i = normals[0] * w0 + normals[1] * hit.u + normals[2] * hit.v
        ns = dr.select(sm, normalize(n_i), ng)
        if dr.hint(terminator == "hanika" and fx.shadows, mode="scalar"):
            p_s, p_s_err = terminator_point(accel, hit, p, p_err, normals, m & sm, t)
    mat = dr.gather(UInt32, tris.material, hit.prim, m)
    return SurfacePoint(p=p, p_err=p_err, ng=ng, ns=ns, material=mat, p_shadow=p_s,
                        p_shadow_err=p_s_err)


def _next_float_away(x, up):
    """The float next to ``x`` towards +inf where ``up``, else towards -inf (per lane;
    ±0 step to the smallest subnormal of the right sign)."""
    F = type(x)
    U = dr.uint_array_t(F)
    bits = dr.reinterpret_array(U, x)
    grow = (x > 0) == up                    # the magnitude grows: one ulp more
    stepped = dr.reinterpret_array(F, dr.select(grow, bits + 1, bits - 1))
    tiny = dr.reinterpret_array(F, dr.full(U, 1, dr.width(x)))   # smallest subnormal
    return dr.select(x == 0, dr.select(up, tiny, -tiny), stepped)


#: Mitsuba 3's ``math::RayEpsilon<float>`` (1500 · 2^-24): its ``spawn_ray`` moves an origin
#: ``(1 + max|p|)`` times this along ``N_g``; ``ShadowEpsilon`` is 10 times it. The goldens
#: are single-precision Mitsuba renders, so the "mitsuba" rule uses this value in float64 too.
MITSUBA_RAY_EPSILON = 1500.0 * 2.0 ** -24
MITSUBA_SHADOW_EPSILON = 10.0 * MITSUBA_RAY_EPSILON


def offset_origin(sp: SurfacePoint, direction, eps=None, spawn: str = "scale-free"):
    """The origin of a ray leaving the hit ``sp`` along ``direction`` (docs/MODEL.md, "Ray
    offsets"): ``p + δ N'`` with ``N' = ±N_g`` on the side ``direction`` leaves into.

    eps None, spawn "scale-free" (default): ``δ = dot(|N_g|, p_err)``, the hit's own error
    bound projected on the normal, and every coordinate that moved is rounded one more float
    away from ``p`` (pbrt-v4 ``OffsetRayOrigin``), so the offset survives the addition however
    small it is.
    eps None, spawn "mitsuba": ``δ = (1 + max|p|) · MITSUBA_RAY_EPSILON`` (Mitsuba 3's
    ``SurfaceInteraction::spawn_ray``).
    eps a float: the explicit override, ``δ = eps`` (absolute).
    """
    ng, p = sp.ng, sp.p
    F = type(p[0])
    sign = dr.select(dr.dot(direction, ng) >= 0, F(1.0), F(-1.0))
    if eps is not None:
        return dr.fma(ng, sign * eps, p)
    if spawn == "mitsuba":
        mag = (1.0 + dr.max(dr.abs(p))) * MITSUBA_RAY_EPSILON
        return dr.fma(ng, sign * mag, p)
    delta = dr.dot(dr.abs(ng), sp.p_err)
    off = ng * (sign * delta)
    po = p + off
    A3 = type(p)
    return A3(*(dr.select(off[k] == 0, po[k], _next_float_away(po[k], off[k] > 0))
                for k in range(3)))


def shadow_ray(sp: SurfacePoint, p_light, double: bool, eps=None,
               spawn: str = "scale-free") -> Ray:
    """The shadow ray from the hit ``sp`` to the point light at ``p_light`` (Array3f): from
    the offset origin ``o'`` (``offset_origin`` towards the light) along
    ``normalize(p_l - o')``, ending short of the light by ``γ_SHADOW_END_OPS`` of its length
    (scale-free), by ``MITSUBA_SHADOW_EPSILON`` of it (Mitsuba's ``spawn_ray_to``) or by
    ``eps`` (the override). Where ``sp.p_shadow`` is set the ray starts from it instead
    of ``sp.p`` (the shadow-terminator treatment)."""
    if sp.p_shadow is not None:
        sp = SurfacePoint(p=sp.p_shadow, p_err=sp.p_shadow_err, ng=sp.ng, ns=sp.ns,
                          material=sp.material)
    so = offset_origin(sp, p_light - sp.p, eps, spawn)
    sd = p_light - so
    s_len = dr.norm(sd)
    if eps is not None:
        t_max = s_len - eps
    elif spawn == "mitsuba":
        t_max = s_len * (1.0 - MITSUBA_SHADOW_EPSILON)
    else:
        t_max = s_len * (1.0 - gamma(SHADOW_END_OPS, double))
    return Ray(o=so, d=sd / s_len, t_max=t_max)


@dataclass
class ShadingContext:
    """A batch of hits as local shading sees them.

    sp: SurfacePoint; N: Array3f shading normal turned to face ``V``; V: Array3f unit
    direction to the viewer (``-d``); active: Bool lanes that hit a surface.
    key, hit: UInt32 the camera ray's random key and the number of this hit along its
    tree walk (the shadow samples' random numbers; None without soft shadows).
    """

    sp: SurfacePoint = None
    N: object = None
    V: object = None
    active: object = None
    key: object = None
    hit: object = None


def shading_context(sp: SurfacePoint, d, active, key=None, hit=None) -> ShadingContext:
    """The context of the hits ``sp`` of rays with unit directions ``d``."""
    V = -d
    N = dr.select(dr.dot(V, sp.ns) >= 0, sp.ns, -sp.ns)
    return ShadingContext(sp=sp, N=N, V=V, active=active, key=key, hit=hit)


# ---- local light -----------------------------------------------------------------------------
@dataclass
class PhongLobe:
    """The material's local-light coefficients at the hits: kd (Array3f), and with
    specular highlights ks (Array3f) and n (Float exponent), else None. In physical
    shading kd and ks already carry their normalisation (1/π, (n+2)/2π). The lobe
    ``(R·V)^n`` is evaluated by ``phong_power`` (guarded against Dr.Jit's float64 ``pow``
    returning -inf near the bottom of the double range)."""

    kd: object = None
    ks: object = None
    n: object = None


def phong_lobe(mats: DeviceMaterials, ctx: ShadingContext, t: Types, fx: EffectSet
               ) -> PhongLobe:
    """Gather kd (and ks, n with ``fx.specular``) of the hit materials."""
    A3 = t.Array3f
    mat, active = ctx.sp.material, ctx.active
    kd = dr.gather(A3, mats.kd, mat, active)
    ks = n_exp = None
    if dr.hint(fx.specular, mode="scalar"):
        ks = dr.gather(A3, mats.ks, mat, active)
        n_exp = dr.gather(t.Float, mats.n, mat, active)
    if dr.hint(fx.physical, mode="scalar"):
        kd = kd * INV_PI
        if dr.hint(fx.specular, mode="scalar"):
            ks = ks * ((n_exp + 2.0) * INV_TWO_PI)
    return PhongLobe(kd=kd, ks=ks, n=n_exp)


#: Below ``2^POWER_FLOOR_LOG2`` the Phong lobe ``(R·V)^n`` is taken as 0 in float64.
POWER_FLOOR_LOG2 = -1000.0


def phong_power(rv, n):
    """``rv^n`` for ``rv`` in [0, 1] and exponents ``n > 0`` (Float arrays), 0 where
    ``rv <= 0``. Guard: Dr.Jit 1.5's LLVM float64 ``dr.power`` (``exp2(n log2 rv)``) returns
    -inf for exp2 arguments in about [-1024, -1023.5) (``0.09386617626859929^300`` gives -inf,
    the true value is 5.7e-309); in float64 a result below ``2^POWER_FLOOR_LOG2`` (~1e-301,
    far under any pixel's resolution) is therefore set to 0. float32 needs no guard (its
    power underflows cleanly to 0 long before that exponent range) and stays bit-identical.
    """
    p = dr.power(rv, n)
    if dr.type_v(rv) == dr.VarType.Float64:
        p = dr.select(n * dr.log2(rv) > POWER_FLOOR_LOG2, p, 0.0)
    return dr.select(rv > 0, p, 0.0)


def _light_term(li, ctx: ShadingContext, lobe: PhongLobe, sa: SceneArrays, t: Types,
                fx: EffectSet, opt: TraceOptions, result):
    """``result`` plus light ``li``'s contribution (``li``: UInt32 index, a literal or an
    array), with a shadow ray through ``sa.accel.intersect_p`` when ``fx.shadows``; with
    ``fx.soft_shadows`` the mean over the light's shadow samples (``_soft_light_term``)."""
    if dr.hint(fx.soft_shadows, mode="scalar"):
        return _soft_light_term(li, ctx, lobe, sa, t, fx, opt, result)
    ls = sample_light(sa.lights, li, ctx.sp.p, t, all_inverse_square=fx.physical)
    return _sample_term(ls, ctx, lobe, sa, t, fx, opt, result)


def _sample_term(ls, ctx: ShadingContext, lobe: PhongLobe, sa: SceneArrays, t: Types,
                 fx: EffectSet, opt: TraceOptions, result):
    """``result`` plus the point-light term of the light sample ``ls`` (LightSample)."""
    sp, N = ctx.sp, ctx.N
    L = ls.wi
    cos_theta = dr.dot(L, N)
    lit = ctx.active & (cos_theta > 0)
    brdf = lobe.kd * cos_theta
    if dr.hint(fx.specular, mode="scalar"):
        R_l = dr.fma(N, 2.0 * cos_theta, -L)
        rv = dr.maximum(dr.dot(R_l, ctx.V), 0.0)
        spec = phong_power(rv, lobe.n)
        if dr.hint(fx.physical, mode="scalar"):
            spec = spec * cos_theta
        brdf = dr.fma(lobe.ks, spec, brdf)
    if dr.hint(fx.shadows, mode="scalar"):
        # no shadow ray where the light adds exactly nothing (brdf 0: a purely specular
        # surface outside its highlight, e.g. glass with kd = 0 and a sharp Phong lobe):
        # ``Li * 0 + result`` is ``result`` whether the light is blocked or not
        lit &= dr.max(brdf) > 0
        shadow = shadow_ray(sp, ls.p, t.is_double, opt.eps, opt.spawn)
        blocked = sa.accel.intersect_p(shadow, lit)
        lit &= ~blocked
    return dr.select(lit, dr.fma(ls.Li, brdf, result), result)


@syntax
def _soft_light_term(li, ctx: ShadingContext, lobe: PhongLobe, sa: SceneArrays, t: Types,
                     fx: EffectSet, opt: TraceOptions, result):
    """Light ``li``'s shadow samples (docs/MODEL.md, "Lights with extent"): a device loop
    over its ``samples`` (``k²`` for a light with extent, 1 for a point light), sample
    ``s = j k + i`` at ``((i + ξ1)/k, (j + ξ2)/k)``, each a point-light term with its own
    shadow ray and its intensity times ``1 / samples`` (exactly 1 for a point light, whose
    term is then the point light's bit for bit)."""
    k = math.isqrt(opt.shadow_samples)
    inv_k = 1.0 / k
    draws = 2 * opt.shadow_samples          # random numbers per light per hit
    n_s = dr.gather(t.UInt32, sa.lights.samples, li)
    w = dr.gather(t.Float, sa.lights.weight, li)
    base = (ctx.hit * opt.n_lights + li) * draws
    s = dr.zeros(t.UInt32, dr.width(ctx.active))
    while dr.hint(s < n_s, max_iterations=-1, label="shadow samples",
                  exclude=[ctx, lobe, sa, t, fx, opt, k, inv_k, w, base]):
        c = base + 2 * s
        row = s // k
        u1 = (t.Float(s - row * k) + sample_hash(ctx.key, c, t)) * inv_k
        u2 = (t.Float(row) + sample_hash(ctx.key, c + 1, t)) * inv_k
        ls = sample_light(sa.lights, li, ctx.sp.p, t, all_inverse_square=fx.physical,
                          u=(u1, u2))
        ls.Li = ls.Li * w
        result = _sample_term(ls, ctx, lobe, sa, t, fx, opt, result)
        s += 1
    return result


@syntax
def _light_loop(ctx: ShadingContext, lobe: PhongLobe, sa: SceneArrays, t: Types,
                fx: EffectSet, opt: TraceOptions, result):
    """The same sum as the unrolled one, as one device loop over the ``opt.n_lights``
    lights (in order, so the pixels are the same)."""
    li = dr.zeros(t.UInt32, dr.width(ctx.active))     # index of the current light
    while dr.hint(li < opt.n_lights, max_iterations=-1, label="lights",
                  exclude=[ctx, lobe, sa, t, fx, opt]):
        result = _light_term(li, ctx, lobe, sa, t, fx, opt, result)
        li += 1
    return result


def local_light(ctx: ShadingContext, sa: SceneArrays, t: Types, fx: EffectSet,
                opt: TraceOptions):
    """``I_local`` at the hits (Array3f): ambient·ka + Σ_l light contributions.

    With ``fx.many_lights`` the ``opt.n_lights`` lights are summed in a device loop,
    otherwise light 0 alone is straight-line code (only that light when ``many_lights`` is
    forced off in a scene with several). The other flags of ``fx`` drop untraced terms.
    """
    A3 = t.Array3f
    result = dr.zeros(A3)
    if dr.hint(fx.ambient, mode="scalar"):
        ka = dr.gather(A3, sa.materials.ka, ctx.sp.material, ctx.active)
        result = sa.ambient * ka
    if dr.hint(opt.n_lights == 0, mode="scalar"):
        return result
    lobe = phong_lobe(sa.materials, ctx, t, fx)
    if dr.hint(fx.many_lights or fx.soft_shadows, mode="scalar"):
        result = dr.zeros(A3, dr.width(ctx.active)) + result   # loop state of the batch width
    if dr.hint(fx.many_lights, mode="scalar"):
        return _light_loop(ctx, lobe, sa, t, fx, opt, result)
    return _light_term(t.UInt32(0), ctx, lobe, sa, t, fx, opt, result)


# ---- specular branches -----------------------------------------------------------------------
@dataclass
class Branches:
    """The two children of a hit (MODEL.md "Specular branches").

    R, T: Array3f unit reflected and refracted directions; w_refl, w_refr: Array3f their
    weights (``w_refr`` includes the physical-mode ``η²``; zero under total internal
    reflection). Without ``fx.refraction``, ``T`` and ``w_refr`` are None.
    """

    R: object = None
    w_refl: object = None
    T: object = None
    w_refr: object = None


def reflect(d, N):
    """``R = d - 2 (d·N) N``."""
    return dr.fma(N, -2.0 * dr.dot(d, N), d)


def specular_branches(sp: SurfacePoint, d, mats: DeviceMaterials, t: Types, fx: EffectSet,
                      active) -> Branches:
    """Directions and weights of the reflected and refracted children of the hits ``sp``
    of rays with unit directions ``d``."""
    A3 = t.Array3f
    mat = sp.material
    V = -d
    cos_s = dr.dot(V, sp.ns)
    N = dr.select(cos_s >= 0, sp.ns, -sp.ns)
    R = reflect(d, N)
    # ``reflection`` off happens only when forced for debugging (refraction implies it,
    # for total internal reflection): the reflected child then gets weight 0 (not traced).
    k_refl = dr.gather(A3, mats.k_refl, mat, active) if fx.reflection else dr.zeros(A3)
    if dr.hint(not fx.refraction, mode="scalar"):
        return Branches(R=R, w_refl=k_refl)
    k_refr = dr.gather(A3, mats.k_refr, mat, active)
    ior = dr.gather(t.Float, mats.ior, mat, active)
    entering = cos_s > 0
    eta = dr.select(entering, rcp(ior), ior)
    cos_i = dr.abs(cos_s)
    sin2_t = eta * eta * dr.fma(-cos_i, cos_i, 1.0)
    tir = sin2_t > 1.0
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    T = normalize(dr.fma(N, eta * cos_i - cos_t, eta * d))
    transmissive = dr.max(k_refr) > 0
    # constant weights (thesis eq. 14); TIR sends the refracted share along R
    w_refl = dr.select(tir, k_refl + k_refr, k_refl)
    w_refr = dr.select(tir, 0.0, k_refr)
    if dr.hint(fx.fresnel, mode="scalar"):
        use_f = dr.gather(t.Bool, mats.fresnel, mat, active) & transmissive
        F = fresnel(cos_s, ior)[0]
        F = dr.select(tir, 1.0, F)
        w_refl = dr.select(use_f, k_refl * F, w_refl)
        w_refr = dr.select(use_f, k_refr * (1.0 - F), w_refr)
    if dr.hint(fx.physical, mode="scalar"):
        w_refr = w_refr * (eta * eta)
    w_refr = dr.select(transmissive, w_refr, 0.0)
    if dr.hint(not fx.reflection, mode="scalar"):
        w_refl = dr.zeros(A3)
    return Branches(R=R, w_refl=w_refl, T=T, w_refr=w_refr)
