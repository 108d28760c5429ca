"""The Whitted integrator (docs/MODEL.md, "The Whitted tree").

The whole tree of reflected and refracted rays up to ``max_depth`` is walked depth-first
without recursion (to ``EffectSet.depth``, the deepest bounce the scene can reach, at most
``max_depth``). Each lane carries its current ray, the ray's accumulated weight and
depth, and a small stack of pending branches (origin, direction, weight, depth) in
``dr.alloc_local`` arrays; at a hit with both children the refracted one is pushed and the
reflected one followed. A branch is created only if ``depth + 1 <= max_depth`` and its
accumulated weight (max over RGB) is ``>= min_weight`` and its own weight is nonzero (a
zero-weight child adds nothing, so ``min_weight = 0`` does not trace rays off diffuse hits).

What gets traced is decided by the ``EffectSet`` before tracing: no secondary rays means no
loop at all (one closest hit and local shading); reflection without refraction is a chain
(no stack); the stack exists only with refraction.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from .accel import Ray
from .device import Types, syntax
from .effects import EffectSet
from .shade import (
    SceneArrays,
    TraceOptions,
    local_light,
    offset_origin,
    shading_context,
    specular_branches,
    surface_point,
)


@dataclass
class ShadowDraw:
    """The shadow samples' random ``key`` (UInt32 per ray) and ``hit_no`` (the hit's number
    along the ray's tree walk); both None without soft shadows."""

    key: object = None
    hit_no: object = None


def _shade_hit(sa: SceneArrays, ray: Ray, hit, t: Types, fx: EffectSet, opt: TraceOptions,
               active, draw: ShadowDraw):
    """Surface point and I_local (Array3f) at the closest hits ``hit`` of ``ray``
    (``draw``: the shadow samples' random key and hit number, soft shadows only)."""
    sp = surface_point(sa.accel, ray, hit, t, fx, opt.terminator)
    ctx = shading_context(sp, ray.d, active, draw.key, draw.hit_no)
    I_local = local_light(ctx, sa, t, fx, opt)
    return sp, I_local


def _no_secondary(sa: SceneArrays, o, d, t: Types, fx: EffectSet, opt: TraceOptions,
                  key=None):
    """Depth 0 only: one closest hit, local light or the background."""
    active = dr.full(t.Bool, True, dr.width(d))
    ray = Ray(o=o, d=d, t_max=t.Float(dr.inf))
    hit = sa.accel.intersect(ray, active)
    hit_no = dr.zeros(t.UInt32, dr.width(d)) if fx.soft_shadows else None
    sp, I_local = _shade_hit(sa, ray, hit, t, fx, opt, hit.found, ShadowDraw(key, hit_no))
    return dr.select(hit.found, I_local, t.Array3f(sa.background))


@syntax
def trace(sa: SceneArrays, o, d, t: Types, fx: EffectSet, opt: TraceOptions, key=None):
    """Radiance along the rays ``(o, d)`` (Array3f, ``d`` unit) through the Whitted tree.

    Returns Array3f radiance of the batch width. ``fx`` (which effects are traced) and
    ``opt`` (``max_depth`` checked when it was made) are host constants. ``key``: UInt32
    per ray, the random key of its shadow samples (required with ``fx.soft_shadows``,
    ``camera.ray_keys``); the hits along a ray's tree walk are numbered 0, 1, ... so each
    draws its own numbers.
    """
    if dr.hint(fx.soft_shadows and key is None, mode="scalar"):
        raise ValueError("trace: soft shadows need the rays' random keys (key=...)")
    if dr.hint(not fx.secondary, mode="scalar"):
        return _no_secondary(sa, o, d, t, fx, opt, key)

    n = dr.width(d)
    A3, Float, UInt32 = t.Array3f, t.Float, t.UInt32
    max_depth = min(fx.depth, opt.max_depth)   # deepest reachable bounce (host constant)
    use_stack = fx.refraction                  # pending branches exist only with refraction

    # ---- stack of pending branches (one slot per level) --------------------------------------
    cap = st_o = st_d = st_w = st_depth = None
    if dr.hint(use_stack, mode="scalar"):
        cap = max_depth
        st_o = [dr.alloc_local(Float, cap) for _ in range(3)]   # pending origins
        st_d = [dr.alloc_local(Float, cap) for _ in range(3)]   # pending directions
        st_w = [dr.alloc_local(Float, cap) for _ in range(3)]   # pending weights
        st_depth = dr.alloc_local(UInt32, cap)                  # pending depths

    # ---- loop state --------------------------------------------------------------------------
    ray_o = A3(o)                          # origin of the current ray
    ray_d = A3(d)                          # direction of the current ray (unit)
    weight = dr.full(A3, 1.0, n)           # accumulated weight of the current ray
    depth = dr.zeros(UInt32, n)            # depth of the current ray (camera ray = 0)
    sp_top = dr.zeros(UInt32, n)           # number of pending branches on the stack
    radiance = dr.zeros(A3, n)             # result
    active = dr.full(t.Bool, True, n)      # lane still has a ray to trace
    hit_no = None                          # number of the hit along the walk (soft shadows)
    if dr.hint(fx.soft_shadows, mode="scalar"):
        hit_no = dr.zeros(UInt32, n)

    # host objects and local buffers are read inside the loop but are not loop state
    while dr.hint(active, max_iterations=-1, label="whitted",
                  exclude=[sa, t, fx, opt, n, A3, Float, UInt32, max_depth, use_stack, cap,
                           st_o, st_d, st_w, st_depth, key]):
        # ---- closest hit, or the background --------------------------------------------------
        ray = Ray(o=ray_o, d=ray_d, t_max=Float(dr.inf))
        hit = sa.accel.intersect(ray, active)
        missed = active & ~hit.found
        radiance = dr.select(missed, dr.fma(weight, sa.background, radiance), radiance)
        on_surface = active & hit.found

        # ---- local light ---------------------------------------------------------------------
        sp, I_local = _shade_hit(sa, ray, hit, t, fx, opt, on_surface,
                                 ShadowDraw(key, hit_no))
        if dr.hint(fx.soft_shadows, mode="scalar"):
            hit_no += 1
        radiance = dr.select(on_surface, dr.fma(weight, I_local, radiance), radiance)

        # ---- children: follow the reflected one ----------------------------------------------
        br = specular_branches(sp, ray_d, sa.materials, t, fx, on_surface)
        can_branch = on_surface & (depth < max_depth)
        child_depth = depth + 1
        w_r = weight * br.w_refl
        go_r = can_branch & (dr.max(w_r) >= opt.min_weight) & (dr.max(br.w_refl) > 0)
        next_o = offset_origin(sp, br.R, opt.eps, opt.spawn)
        next_d = br.R
        next_w = w_r
        go = go_r

        # ---- children: push the refracted one, or follow it alone ----------------------------
        if dr.hint(use_stack, mode="scalar"):
            w_t = weight * br.w_refr
            go_t = can_branch & (dr.max(w_t) >= opt.min_weight) & (dr.max(br.w_refr) > 0)
            o_t = offset_origin(sp, br.T, opt.eps, opt.spawn)
            push = go_r & go_t             # both children: follow R, push T
            for k in range(3):
                st_o[k].write(o_t[k], sp_top, push)
                st_d[k].write(br.T[k], sp_top, push)
                st_w[k].write(w_t[k], sp_top, push)
            st_depth.write(child_depth, sp_top, push)
            sp_top = dr.select(push, sp_top + 1, sp_top)
            only_t = go_t & ~go_r          # only the refracted child: follow T
            next_o = dr.select(only_t, o_t, next_o)
            next_d = dr.select(only_t, br.T, next_d)
            next_w = dr.select(only_t, w_t, next_w)
            go = go_r | go_t

        # ---- next ray: a child, else a pending branch, else done -----------------------------
        ray_o = dr.select(go, next_o, ray_o)
        ray_d = dr.select(go, next_d, ray_d)
        weight = dr.select(go, next_w, weight)
        depth = dr.select(go, child_depth, depth)
        if dr.hint(use_stack, mode="scalar"):
            pop = active & ~go & (sp_top > 0)
            sp_top = dr.select(pop, sp_top - 1, sp_top)
            p_o = A3(*(st_o[k].read(sp_top, pop) for k in range(3)))
            p_d = A3(*(st_d[k].read(sp_top, pop) for k in range(3)))
            p_w = A3(*(st_w[k].read(sp_top, pop) for k in range(3)))
            ray_o = dr.select(pop, p_o, ray_o)
            ray_d = dr.select(pop, p_d, ray_d)
            weight = dr.select(pop, p_w, weight)
            depth = dr.select(pop, st_depth.read(sp_top, pop), depth)
            active = go | pop
        else:
            active = go
    return radiance
