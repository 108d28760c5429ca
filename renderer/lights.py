"""Lights on the device and the one query shading makes of them (pbrt's ``SampleLi``).

``upload_lights`` stores the scene's point lights once as ``DeviceLights``;
``sample_light(lights, i, p, t)`` answers, for light ``i`` seen from the points ``p``: the
unit direction towards the light, its distance, and the radiance arriving at ``p`` (the
intensity with the falloff applied), as a ``LightSample``. Shading reads lights only
through this function.

Lights with extent (docs/MODEL.md, "Lights with extent"): ``sample_light(..., u=(u1, u2))``
draws the point ``y`` of sample ``u`` (stratified by the caller): cone sampling for sphere
lights, area sampling for rectangle lights, and returns ``Li`` as the intensity that the
point-light formula takes for that sample (classic: ``I · att(dist)``, times the emission
factor ``g`` for a rectangle; physical: ``L_e / pdf_ω``). A light without extent takes the
point light's values bit for bit. ``sample_hash`` gives the samples' random numbers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr

from .device import Types, array3, normalize, rcp, rsqrt
from .scene import Scene


@dataclass
class DeviceLights:
    """Point lights on the device, width max(L, 1) (one unread dummy entry when L = 0).

    position, intensity: Array3f (world position or centre, RGB intensity);
    inverse_square: Bool (falloff ``1/dist²``, else none).
    Only read with soft shadows: kind: UInt32 (0 point, 1 sphere, 2 rectangle); radius:
    Float (sphere); edge_u, edge_v: Array3f (rectangle edges, else 0); two_sided: Bool;
    samples: UInt32 shadow rays per shading point (1 for a point light); weight: Float
    ``1 / samples``.
    """

    position: object = None
    intensity: object = None
    inverse_square: object = None
    kind: object = None
    radius: object = None
    edge_u: object = None
    edge_v: object = None
    two_sided: object = None
    samples: object = None
    weight: object = None


@dataclass
class LightSample:
    """Light ``i`` as seen from the shading points (arrays of the batch width).

    wi: Array3f unit direction from the point to the light; dist: Float distance to it;
    Li: Array3f radiance arriving at the point (intensity × falloff, before shadowing);
    p: Array3f position of the light (where a shadow ray ends).
    """

    wi: object = None
    dist: object = None
    Li: object = None
    p: object = None


def upload_lights(scene: Scene, t: Types) -> DeviceLights:
    """``scene.lights`` as DeviceLights of types ``t`` (evaluated)."""
    ls = scene.lights
    if not ls:
        z = array3(t, [0, 0, 0])
        return DeviceLights(z, z, t.Bool([False]), t.UInt32([0]), t.Float([0.0]), z, z,
                            t.Bool([False]), t.UInt32([1]), t.Float([1.0]))
    n = light_samples(scene)
    zero = [0.0, 0.0, 0.0]
    lights = DeviceLights(position=array3(t, [light.position for light in ls]),
                          intensity=array3(t, [light.intensity for light in ls]),
                          inverse_square=t.Bool([light.falloff == "inverse_square"
                                                 for light in ls]),
                          kind=t.UInt32([KINDS[light.shape] for light in ls]),
                          radius=t.Float([float(light.radius) for light in ls]),
                          edge_u=array3(t, [light.edge_u if light.edge_u is not None else zero
                                            for light in ls]),
                          edge_v=array3(t, [light.edge_v if light.edge_v is not None else zero
                                            for light in ls]),
                          two_sided=t.Bool([bool(light.two_sided) for light in ls]),
                          samples=t.UInt32(n),
                          weight=t.Float([1.0 / k for k in n]))
    dr.eval(lights)
    return lights


#: ``DeviceLights.kind`` of each light shape.
KINDS = {"point": 0, "sphere": 1, "rectangle": 2}


def light_samples(scene: Scene) -> list[int]:
    """Shadow rays per shading point of each light: ``settings.shadow_samples`` for a light
    with extent, 1 for a point light."""
    k = int(scene.settings.shadow_samples)
    return [k if light.extent else 1 for light in scene.lights]


def _lowbias32(x):
    """A 32-bit integer hash (Wellons' ``lowbias32``) of UInt32 ``x``."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def sample_hash(key, counter, t: Types):
    """A uniform Float in [0, 1) from the UInt32 ``key`` (the ray's number plus the seed)
    and the UInt32 ``counter`` (which draw of that ray): counter-based, so the same
    (key, counter) gives the same number in any batch or order."""
    h = _lowbias32(key ^ _lowbias32(counter * 0x9E3779B9 + 0x632BE5AB))
    return t.Float(h >> 8) * (1.0 / 16777216.0)


def _frame(w):
    """Two unit vectors completing the unit ``w`` to an orthonormal frame (Duff et al.)."""
    sign = dr.select(w[2] >= 0, 1.0, -1.0)
    a = -rcp(sign + w[2])
    b = w[0] * w[1] * a
    s1 = type(w)(1.0 + sign * w[0] * w[0] * a, sign * b, -sign * w[0])
    s2 = type(w)(b, sign + w[1] * w[1] * a, -w[1])
    return s1, s2


def sample_light(lights: DeviceLights, i, p, t: Types, *,
                 all_inverse_square: bool = False, u=None) -> LightSample:
    """Light ``i`` (UInt32 index, a literal or an array) seen from the points ``p``
    (Array3f).

    all_inverse_square: host constant; True when every light falls off as ``1/dist²``
        (physical shading guarantees it), so the per-light falloff flag is not read.
    u: None (point lights only: the light's position), or ``(u1, u2)`` Float in [0, 1]:
        the sample on a light with extent (docs/MODEL.md, "Lights with extent"); the
        physical estimate is taken when ``all_inverse_square`` (physical shading).
    """
    A3 = t.Array3f
    lp = dr.gather(A3, lights.position, i)
    intensity = dr.gather(A3, lights.intensity, i)
    to_light = lp - p
    dist2 = dr.squared_norm(to_light)
    inv_dist = rsqrt(dist2)
    if dr.hint(all_inverse_square, mode="scalar"):
        falloff = rcp(dist2)
        inverse_square = True
    else:
        inverse_square = dr.gather(t.Bool, lights.inverse_square, i)
        falloff = dr.select(inverse_square, rcp(dist2), 1.0)

    def att(d2):
        """The falloff at squared distance ``d2``."""
        return rcp(d2) if inverse_square is True else dr.select(inverse_square, rcp(d2), 1.0)
    point = LightSample(wi=to_light * inv_dist, dist=dist2 * inv_dist, Li=intensity * falloff,
                        p=lp)
    if u is None:
        return point
    kind = dr.gather(t.UInt32, lights.kind, i)
    sph = _sample_sphere(lights, i, SphereTarget(p=p, c=lp, to_c=to_light, dc2=dist2),
                         intensity, att, u, t, physical=all_inverse_square)
    rect = _sample_rectangle(lights, i, p, lp, intensity, att, u, t)

    def pick(name):
        a, b, c = getattr(point, name), getattr(sph, name), getattr(rect, name)
        return dr.select(kind == 1, b, dr.select(kind == 2, c, a))
    return LightSample(wi=pick("wi"), dist=pick("dist"), Li=pick("Li"), p=pick("p"))


@dataclass
class SphereTarget:
    """The shaded points ``p`` seen towards a sphere light's centre ``c``: ``to_c = c - p``
    and its squared length ``dc2``."""

    p: object
    c: object
    to_c: object
    dc2: object


def _sample_sphere(lights, i, target: SphereTarget, intensity, att, u, t: Types, *,
                   physical: bool) -> LightSample:
    """Cone sampling of sphere light ``i`` as seen from ``target.p`` (``target``)."""
    p, to_c, dc2 = target.p, target.to_c, target.dc2
    r = dr.gather(t.Float, lights.radius, i)
    r2 = r * r
    inv_dc = rsqrt(dc2)
    dc = dc2 * inv_dc
    w = to_c * inv_dc
    sin2_max = dr.minimum(r2 * rcp(dc2), 1.0)
    cos_max = dr.sqrt(1.0 - sin2_max)
    one_minus_cos_max = sin2_max * rcp(1.0 + cos_max)
    omc = u[0] * one_minus_cos_max                    # 1 - cosθ, without cancellation
    cos_t = 1.0 - omc
    sin_t = dr.sqrt(dr.maximum(omc * (2.0 - omc), 0.0))
    phi = (2.0 * math.pi) * u[1]
    s1, s2 = _frame(w)
    wi = normalize(s1 * (sin_t * dr.cos(phi)) + s2 * (sin_t * dr.sin(phi)) + w * cos_t)
    # near intersection of p + s wi with the sphere: s = dc cosθ - sqrt(r² - dc² sin²θ)
    dist = dc * cos_t - dr.sqrt(dr.maximum(r2 - dc2 * (sin_t * sin_t), 0.0))
    y = dr.fma(wi, dist, p)
    outside = dc2 > r2
    if physical:
        Li = intensity * (2.0 * rcp(dc2 * (1.0 + cos_max)))
    else:
        Li = intensity * att(dist * dist)
    return LightSample(wi=wi, dist=dist, Li=dr.select(outside, Li, 0.0), p=y)


def _sample_rectangle(lights, i, p, centre, intensity, att, u, t: Types
                      ) -> LightSample:
    """Area sampling of rectangle light ``i`` (both shading modes: ``I g att(dist)``)."""
    A3 = t.Array3f
    eu = dr.gather(A3, lights.edge_u, i)
    ev = dr.gather(A3, lights.edge_v, i)
    two = dr.gather(t.Bool, lights.two_sided, i)
    y = centre + eu * (u[0] - 0.5) + ev * (u[1] - 0.5)
    to_y = y - p
    d2 = dr.squared_norm(to_y)
    inv_d = rsqrt(d2)
    wi = to_y * inv_d
    n_l = normalize(dr.cross(eu, ev))
    cos_l = -dr.dot(wi, n_l)
    g = dr.select(two, dr.abs(cos_l), dr.maximum(cos_l, 0.0))
    Li = intensity * (g * att(d2))
    return LightSample(wi=wi, dist=d2 * inv_d, Li=Li, p=y)
