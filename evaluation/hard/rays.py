"""The rays of the hard cases and their queries: ``spawn_origin`` (the one offset rule every
spawned ray goes through, so a new rule drops in without touching the cases), random
directions and points, closest-hit and any-hit answers, device batches and their timing."""

from __future__ import annotations

import math
import time

import drjit as dr
import numpy as np

from renderer.accel import Ray
from renderer.device import array3
from renderer.shade import SurfacePoint, offset_origin

from .cases import Config


# ---- ray spawning: the one function a new offset rule replaces ----------------------------
def spawn_origin(p, ng, direction, eps):
    """Origin of a ray leaving the surface point ``p`` (Array3f) with unit geometric normal
    ``ng`` along ``direction`` with the explicit offset ``eps`` (a float or a Float per ray):
    ``renderer.shade.offset_origin``'s override, ``p + ε N'``."""
    sp = SurfacePoint(p=p, ng=ng, ns=ng)
    return offset_origin(sp, direction, eps)


def unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def mesh_edges(F):
    """The distinct edges (int (E, 2), sorted vertex pairs) of the triangles ``F``."""
    return np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]),
                             axis=1), axis=0)


def ball_points(rng, n):
    return unit_vectors(rng, n) * rng.uniform(0, 1, size=(n, 1)) ** (1 / 3)


def closest_hit(acc, t, o, d, t_max=None):
    """Closest hits of the host rays (float64 (N, 3) each): (found bool (N,), prim (N,)
    original face index, t (N,))."""
    n = len(o)
    tm = t.Float(np.full(n, np.inf) if t_max is None else t_max)
    hit = acc.intersect(Ray(o=array3(t, o), d=array3(t, d), t_max=tm),
                        dr.full(t.Bool, True, n))
    order = dr.gather(t.UInt32, acc.tris.order, hit.prim, hit.found)
    dr.eval(hit.found, order, hit.t)
    return hit.found.numpy(), order.numpy(), hit.t.numpy()


def device_rays(t, cfg: Config, k: int, batch: int, c, r):
    """``k`` rays from uniform random points of the ball of radius ``r/2`` about ``c`` in
    uniform random directions, drawn on the device (PCG32 stream ``batch`` of seed
    ``cfg.seed``; float64 arithmetic, then the precision in use), so 10^8 rays cost no
    host traffic."""
    import importlib
    m = importlib.import_module(f"drjit.{t.backend}")
    F64 = m.Float64
    rng = m.PCG32(size=k, initstate=cfg.seed * 1000003 + batch,
                  initseq=dr.arange(m.UInt64, k))

    def sphere():
        z = 1.0 - 2.0 * rng.next_float64()
        phi = (2.0 * math.pi) * rng.next_float64()
        s = dr.safe_sqrt(1.0 - z * z)
        return s * dr.cos(phi), s * dr.sin(phi), z

    dx, dy, dz = sphere()
    ux, uy, uz = sphere()
    rad = (0.5 * r) * dr.cbrt(rng.next_float64())
    o = t.Array3f(t.Float(F64(c[0]) + rad * ux), t.Float(F64(c[1]) + rad * uy),
                  t.Float(F64(c[2]) + rad * uz))
    d = t.Array3f(t.Float(dx), t.Float(dy), t.Float(dz))
    return o, d


def device_interior_misses(acc, t, cfg: Config, k: int, batch: int, c, r) -> int:
    """Misses of ``device_rays(k, batch)``, counted on the device."""
    o, d = device_rays(t, cfg, k, batch, c, r)
    hit = acc.intersect(Ray(o=o, d=d, t_max=dr.full(t.Float, dr.inf, k)),
                        dr.full(t.Bool, True, k))
    miss = dr.count(~hit.found)
    return int(miss[0] if hasattr(miss, "__len__") else miss)


def time_rays(acc, t, cfg: Config, c, r, n: int, reps: int = 3) -> float:
    """Closest-hit cost per ray (ns) of ``n`` random interior rays already on the device:
    the best of ``reps`` timed runs after a warm-up (JIT compilation excluded)."""
    o, d = device_rays(t, cfg, n, 1 << 30, c, r)
    dr.eval(o, d)
    ray = Ray(o=o, d=d, t_max=t.Float(np.full(n, np.inf)))
    times = []
    for _ in range(reps + 1):             # the first run compiles the kernel: dropped
        dr.sync_thread()
        t0 = time.perf_counter()
        hit = acc.intersect(ray, dr.full(t.Bool, True, n))
        dr.eval(hit.found, hit.t, hit.prim)
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    best = min(times[1:])
    return 1e9 * best / n


def ray_answers(acc, t, o, d):
    """``(found, face, t, any_hit)`` numpy arrays of the host rays ``o``, ``d``."""
    found, face, th = closest_hit(acc, t, o, d)
    n = len(o)
    p = acc.intersect_p(Ray(o=array3(t, o), d=array3(t, d), t_max=t.Float(np.full(n, np.inf))),
                        dr.full(t.Bool, True, n))
    return found, face, th, p.numpy()
