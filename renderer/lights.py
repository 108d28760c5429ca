"""Lights on the device and the one query shading makes of them (pbrt's ``SampleLi``).

``upload_lights`` stores the scene's point lights once as ``DeviceLights``;
``sample_light(lights, i, p, t)`` answers, for light ``i`` seen from the points ``p``: the
unit direction towards the light, its distance, and the radiance arriving at ``p`` (the
intensity with the falloff applied), as a ``LightSample``. Shading reads lights only
through this function, so another light type (a spherical light) changes this file alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from .device import Types, array3, rcp, rsqrt
from .scene import Scene


@dataclass
class DeviceLights:
    """Point lights on the device, width max(L, 1) (one unread dummy entry when L = 0).

    position, intensity: Array3f (world position, RGB intensity);
    inverse_square: Bool (falloff ``1/dist²``, else none).
    """

    position: object = None
    intensity: object = None
    inverse_square: object = None


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
        return DeviceLights(array3(t, [0, 0, 0]), array3(t, [0, 0, 0]), t.Bool([False]))
    lights = DeviceLights(position=array3(t, [light.position for light in ls]),
                          intensity=array3(t, [light.intensity for light in ls]),
                          inverse_square=t.Bool([light.falloff == "inverse_square"
                                                 for light in ls]))
    dr.eval(lights)
    return lights


def sample_light(lights: DeviceLights, i, p, t: Types, *,
                 all_inverse_square: bool = False) -> LightSample:
    """Light ``i`` (UInt32 index, a literal or an array) seen from the points ``p``
    (Array3f).

    all_inverse_square: host constant; True when every light falls off as ``1/dist²``
        (physical shading guarantees it), so the per-light falloff flag is not read.
    """
    A3 = t.Array3f
    lp = dr.gather(A3, lights.position, i)
    intensity = dr.gather(A3, lights.intensity, i)
    to_light = lp - p
    dist2 = dr.squared_norm(to_light)
    inv_dist = rsqrt(dist2)
    if dr.hint(all_inverse_square, mode="scalar"):
        falloff = rcp(dist2)
    else:
        inverse_square = dr.gather(t.Bool, lights.inverse_square, i)
        falloff = dr.select(inverse_square, rcp(dist2), 1.0)
    return LightSample(wi=to_light * inv_dist, dist=dist2 * inv_dist, Li=intensity * falloff,
                       p=lp)
