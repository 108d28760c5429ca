"""Local light, shadows and the specular weights (docs/MODEL.md).

Materials and lights are uploaded once as device arrays (``DeviceMaterials``,
``DeviceLights``) and gathered per hit, so their values are inputs of the kernel, not
literals baked into it. Several lights are summed in a device loop; a single light is
straight-line code.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .accel import Ray
from .device import Types
from .scene import Scene

INV_PI = 1.0 / np.pi
INV_TWO_PI = 0.5 / np.pi


@dataclass
class DeviceMaterials:
    """Material table on the device, width M (materials), indexed by ``DeviceTriangles.material``.

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
    DRJIT_STRUCT = {"ka": object, "kd": object, "ks": object, "n": object, "k_refl": object,
                    "k_refr": object, "ior": object, "fresnel": object}


@dataclass
class DeviceLights:
    """Point lights on the device, width max(L, 1).

    position, intensity: Array3f; inverse_square: Bool (falloff ``1/dist²``).
    """

    position: object = None
    intensity: object = None
    inverse_square: object = None
    DRJIT_STRUCT = {"position": object, "intensity": object, "inverse_square": object}


def _a3(t: Types, rows) -> object:
    x = np.asarray(rows, np.float64).reshape(-1, 3)
    return t.Array3f(t.Float(x[:, 0]), t.Float(x[:, 1]), t.Float(x[:, 2]))


def upload_materials(scene: Scene, t: Types) -> DeviceMaterials:
    ms = scene.materials
    if not ms:
        raise ValueError(f"scene {scene.name!r}: materials: at least one material is required")
    m = DeviceMaterials(
        ka=_a3(t, [x.ka for x in ms]), kd=_a3(t, [x.kd for x in ms]),
        ks=_a3(t, [x.ks for x in ms]), n=t.Float([float(x.n) for x in ms]),
        k_refl=_a3(t, [x.k_refl for x in ms]), k_refr=_a3(t, [x.k_refr for x in ms]),
        ior=t.Float([float(x.ior) for x in ms]),
        fresnel=t.Bool([x.combination == "fresnel" for x in ms]))
    dr.eval(m)
    return m


def upload_lights(scene: Scene, t: Types) -> DeviceLights:
    ls = scene.lights
    if not ls:  # a dummy entry keeps the struct well formed; never read
        return DeviceLights(_a3(t, [0, 0, 0]), _a3(t, [0, 0, 0]), t.Bool([False]))
    lt = DeviceLights(position=_a3(t, [l.position for l in ls]),
                      intensity=_a3(t, [l.intensity for l in ls]),
                      inverse_square=t.Bool([l.falloff == "inverse_square" for l in ls]))
    dr.eval(lt)
    return lt


# ---- Fresnel --------------------------------------------------------------------------------
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
    rcp_eta = dr.rcp(eta)
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


# ---- geometry at a hit ----------------------------------------------------------------------
@dataclass
class SurfacePoint:
    """What shading needs at a hit (arrays of the batch width).

    p: Array3f position; ng: Array3f unit geometric normal (winding order);
    ns: Array3f unit shading normal (interpolated for smooth faces, else ``ng``);
    material: UInt32 material index.
    """

    p: object = None
    ng: object = None
    ns: object = None
    material: object = None


def surface_point(tris, hit, o, d, smooth_normals: bool) -> SurfacePoint:
    """Gather the hit triangle's data once. ``smooth_normals`` (Python bool) traces the
    normal interpolation only when some object is smooth."""
    A3 = type(o)
    UInt32 = type(hit.prim)
    m = hit.found
    p = dr.fma(d, hit.t, o)
    ng = dr.gather(A3, tris.ng, hit.prim, m)
    ns = ng
    if dr.hint(smooth_normals, mode="scalar"):
        sm = dr.gather(type(m), tris.smooth, hit.prim, m)
        w0 = 1.0 - hit.u - hit.v
        n_i = (dr.gather(A3, tris.n0, hit.prim, m & sm) * w0
               + dr.gather(A3, tris.n1, hit.prim, m & sm) * hit.u
               + dr.gather(A3, tris.n2, hit.prim, m & sm) * hit.v)
        ns = dr.select(sm, dr.normalize(n_i), ng)
    mat = dr.gather(UInt32, tris.material, hit.prim, m)
    return SurfacePoint(p=p, ng=ng, ns=ns, material=mat)


def offset_origin(p, ng, direction, eps):
    """``p + ε N'`` with ``N' = ±N_g`` on the side ``direction`` leaves into."""
    side = dr.select(dr.dot(direction, ng) >= 0, eps, -eps)
    return dr.fma(ng, side, p)


# ---- local light -----------------------------------------------------------------------------
def _light_term(li, sp: SurfacePoint, N, V, lights: DeviceLights, accel, t: Types, kd, ks,
                n_exp, result, *, physical: bool, shadows: bool, specular: bool, eps: float,
                active):
    """``result`` plus light ``li``'s contribution (``li``: UInt32 index, a literal or an
    array)."""
    A3 = t.Array3f
    lp = dr.gather(A3, lights.position, li)
    li_int = dr.gather(A3, lights.intensity, li)
    to_light = lp - sp.p
    dist2 = dr.squared_norm(to_light)
    inv_dist = dr.rsqrt(dist2)
    L = to_light * inv_dist
    cos_theta = dr.dot(L, N)
    lit = active & (cos_theta > 0)
    if dr.hint(physical, mode="scalar"):
        att = dr.rcp(dist2)
    else:
        inv_sq = dr.gather(t.Bool, lights.inverse_square, li)
        att = dr.select(inv_sq, dr.rcp(dist2), 1.0)
    if dr.hint(shadows, mode="scalar"):
        so = offset_origin(sp.p, sp.ng, L, eps)
        sd = lp - so
        s_len = dr.norm(sd)
        blocked = accel.intersect_p(Ray(so, sd / s_len, s_len - eps), lit)
        lit &= ~blocked
    brdf = kd * cos_theta
    if dr.hint(specular, mode="scalar"):
        R_l = dr.fma(N, 2.0 * cos_theta, -L)
        rv = dr.maximum(dr.dot(R_l, V), 0.0)
        spec = dr.select(rv > 0, dr.power(rv, n_exp), 0.0)
        if dr.hint(physical, mode="scalar"):
            spec = spec * cos_theta
        brdf = dr.fma(ks, spec, brdf)
    return dr.select(lit, dr.fma(li_int * att, brdf, result), result)


@dr.syntax
def _light_loop(sp, N, V, lights, accel, t: Types, kd, ks, n_exp, result, *, n_lights: int,
                physical: bool, shadows: bool, specular: bool, eps: float, active):
    """The same sum as the unrolled one, as one device loop over the ``n_lights`` lights
    (in order, so the pixels are the same)."""
    li = dr.zeros(t.UInt32, dr.width(active))          # index of the current light
    while dr.hint(li < n_lights, max_iterations=-1, label="lights",
                  exclude=[sp, N, V, lights, accel, t, kd, ks, n_exp, n_lights, physical,
                           shadows, specular, eps, active]):
        result = _light_term(li, sp, N, V, lights, accel, t, kd, ks, n_exp, result,
                             physical=physical, shadows=shadows, specular=specular, eps=eps,
                             active=active)
        li += 1
    return result


def local_light(sp: SurfacePoint, N, V, mats: DeviceMaterials, lights: DeviceLights,
                accel, t: Types, *, n_lights: int, ambient, physical: bool,
                shadows: bool, ambient_on: bool, specular: bool, eps: float, active,
                many_lights: bool = True):
    """``I_local`` at ``sp`` (Array3f): ambient·ka + Σ_l light contributions, with shadow
    rays through ``accel.intersect_p``. N: shading normal facing ``V = -d``.
    ``n_lights`` (Python int) is the number of lights; with ``many_lights`` they are summed
    in a device loop, otherwise light 0 alone is straight-line code (only that light when
    ``many_lights`` is forced off in a scene with several). The flags drop untraced terms."""
    A3 = t.Array3f
    mat = sp.material
    result = dr.zeros(A3)
    if dr.hint(ambient_on, mode="scalar"):
        ka = dr.gather(A3, mats.ka, mat, active)
        result = ambient * ka
    if dr.hint(n_lights == 0, mode="scalar"):
        return result
    kd = dr.gather(A3, mats.kd, mat, active)
    ks = n_exp = None
    if dr.hint(specular, mode="scalar"):
        ks = dr.gather(A3, mats.ks, mat, active)
        n_exp = dr.gather(t.Float, mats.n, mat, active)
    if dr.hint(physical, mode="scalar"):
        kd = kd * INV_PI
        if dr.hint(specular, mode="scalar"):
            ks = ks * ((n_exp + 2.0) * INV_TWO_PI)
    flags = dict(physical=physical, shadows=shadows, specular=specular, eps=eps, active=active)
    if dr.hint(many_lights, mode="scalar"):
        result = dr.zeros(A3, dr.width(active)) + result   # loop state of the batch width
        return _light_loop(sp, N, V, lights, accel, t, kd, ks, n_exp, result,
                           n_lights=n_lights, **flags)
    return _light_term(t.UInt32(0), sp, N, V, lights, accel, t, kd, ks, n_exp, result, **flags)


# ---- specular branches ------------------------------------------------------------------------
def reflect(d, N):
    """``R = d - 2 (d·N) N``."""
    return dr.fma(N, -2.0 * dr.dot(d, N), d)


def specular_weights(sp: SurfacePoint, d, mats: DeviceMaterials, t: Types, *,
                     reflection: bool, refraction: bool, fresnel_on: bool, physical: bool,
                     active):
    """Directions and weights of the two children (MODEL.md "Specular branches").

    Returns ``(R, w_refl, T, w_refr)``: Array3f unit directions and Array3f weights
    (``w_refr`` includes the physical-mode ``η²``; zero under TIR). With ``refraction``
    off, ``T``/``w_refr`` are None.
    """
    A3 = t.Array3f
    mat = sp.material
    V = -d
    cos_s = dr.dot(V, sp.ns)
    N = dr.select(cos_s >= 0, sp.ns, -sp.ns)
    R = reflect(d, N)
    # ``reflection`` off happens only when forced for debugging (refraction implies it,
    # for total internal reflection): the reflected child then gets weight 0 (not traced).
    k_refl = dr.gather(A3, mats.k_refl, mat, active) if reflection else dr.zeros(A3)
    if dr.hint(not refraction, mode="scalar"):
        return R, k_refl, None, None
    k_refr = dr.gather(A3, mats.k_refr, mat, active)
    ior = dr.gather(t.Float, mats.ior, mat, active)
    entering = cos_s > 0
    eta = dr.select(entering, dr.rcp(ior), ior)
    cos_i = dr.abs(cos_s)
    sin2_t = eta * eta * dr.fma(-cos_i, cos_i, 1.0)
    tir = sin2_t > 1.0
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    T = dr.normalize(dr.fma(N, eta * cos_i - cos_t, eta * d))
    transmissive = dr.max(k_refr) > 0
    # constant weights (thesis eq. 14); TIR sends the refracted share along R
    w_refl = dr.select(tir, k_refl + k_refr, k_refl)
    w_refr = dr.select(tir, 0.0, k_refr)
    if dr.hint(fresnel_on, mode="scalar"):
        use_f = dr.gather(t.Bool, mats.fresnel, mat, active) & transmissive
        F = fresnel(cos_s, ior)[0]
        F = dr.select(tir, 1.0, F)
        w_refl = dr.select(use_f, k_refl * F, w_refl)
        w_refr = dr.select(use_f, k_refr * (1.0 - F), w_refr)
    if dr.hint(physical, mode="scalar"):
        w_refr = w_refr * (eta * eta)
    w_refr = dr.select(transmissive, w_refr, 0.0)
    if dr.hint(not reflection, mode="scalar"):
        w_refl = dr.zeros(A3)
    return R, w_refl, T, w_refr
