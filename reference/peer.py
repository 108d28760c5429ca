"""A fair Mitsuba 3 peer for the Whitted frame: one kernel, frozen, written Mitsuba's way.

The harness's ``whitted`` integrator (``reference.plugins.WhittedIntegrator``) walks the tree
as host recursion over ray batches (``dr.eval`` and ``dr.any`` at every level), which is right
for a reference and wrong as a speed peer. This module is what a competent Mitsuba user would
write for speed: the same model (docs/MODEL.md) over the same translated ``mi.Scene``
(``reference.mitsuba_scene``), with

- ``scene.ray_intersect`` for closest hits and ``scene.ray_test`` for shadow rays;
- the shape's BSDF through ``si.bsdf(ray).eval(...)`` (a virtual call on ``BSDFPtr``: the
  project's ``whitted_material`` -> ``twosided`` -> ``whitted_phong``) for local light;
- the specular children sampled from Mitsuba's own ``conductor`` / ``dielectric`` by a
  virtual call on a per-shape ``BSDFPtr`` table (component 0 = reflection, 1 = transmission),
  with the weights of docs/MODEL.md (the ``constant`` combination overrides them);
- the tree unrolled by Python recursion at trace time, every branch under a mask (no
  ``dr.eval``, no ``dr.any``, no host sync), so a frame is ONE kernel;
- the shadow samples of a light with extent as one symbolic ``dr.while_loop`` (a PCG32
  in its state, stratified as ours), so the kernel does not grow with their number;
- ``dr.freeze`` around the frame function, so a repeated frame skips tracing and compiling.

Ray offsets are those of docs/MODEL.md (absolute ``ray_offset`` along ``±N_g``), written out
with ``mi.Ray3f`` instead of ``si.spawn_ray`` (whose relative epsilon is another model).

Branches are pruned on the host only where no lane can take them: a reflected child needs
some reflective or transmissive shape, a refracted child some transmissive shape, and the
largest weight product a path can reach (from the material table) must be ``>= min_weight``.
The unrolled tree has up to ``2^(depth+1) - 1`` nodes with refraction (``depth + 1``
without), which is why deep trees stop compiling in reasonable time.

Entry points: ``Peer(mi_scene)`` (tables from a scene loaded in exact mode by
``reference.mitsuba_scene.load``), ``Peer.frame(pos)`` (traced), ``Peer.frozen()``,
``render_peer(scene, ...)`` (float32 (H, W, 3)).
"""
from __future__ import annotations

import math

import numpy as np

# ---- project imports (one block; renamed at merge) ---------------------------------------
from reference import mitsuba_variant
from reference.mitsuba_scene import film_positions
from reference.mitsuba_scene import load as load_mitsuba

# --------------------------------------------------------------------------------------------


def _mi():
    import mitsuba as mi
    return mi


def _ptr_id(mi, obj) -> int:
    """Registry id of a Mitsuba object (what a ``*Ptr`` array stores; 0 = null)."""
    import drjit as dr
    if obj is None:
        return 0
    ptr = mi.ShapePtr(obj) if isinstance(obj, mi.Shape) else mi.BSDFPtr(obj)
    return int(dr.reinterpret_array(mi.UInt32, ptr)[0])


class Peer:
    """The one-kernel Whitted integrator over a loaded ``mi.Scene``.

    Settings (max_depth, min_weight, shading, ray_offset, background, ambient, falloff-free
    lights) are read from the scene's ``whitted`` integrator, i.e. from the translation of
    the project's scene; ``max_depth`` may be overridden. Host constants (lights, which
    branches exist) are baked into the trace; per-shape material data live in device tables
    passed to the frame function as arguments.
    """

    def __init__(self, mi_scene, *, max_depth: int | None = None):
        mi = _mi()
        import drjit as dr
        integ = mi_scene.integrator()
        self.scene = mi_scene
        self.max_depth = int(integ.max_depth if max_depth is None else max_depth)
        self.min_weight = float(integ.min_weight)
        self.physical = integ.shading == "physical"
        self.eps = float(integ.ray_offset)
        self.background = [float(x) for x in integ.background]
        ambient = np.asarray(integ.ambient, np.float64)

        # per-shape tables, indexed by the shape's registry id
        shapes = list(mi_scene.shapes())
        ids = [_ptr_id(mi, s) for s in shapes]
        size = max(ids, default=0) + 1
        ka = np.zeros((size, 3))
        k_refl = np.zeros((size, 3))
        k_refr = np.zeros((size, 3))
        ior = np.ones(size)
        const_glass = np.zeros(size, bool)
        transmissive = np.zeros(size, bool)
        spec_id = np.zeros(size, np.uint32)
        w_refl_max, w_refr_max = 0.0, 0.0        # largest child weight (max over RGB)
        for sid, shape in zip(ids, shapes):
            m = shape.bsdf()
            if not all(hasattr(m, a) for a in ("ka", "k_refl", "k_refr", "specular")):
                raise ValueError(f"peer: shape {shape.id()!r} needs a 'whitted_material' BSDF, "
                                 f"got {type(m).__name__}")
            ka[sid] = ambient * m.ka
            k_refl[sid], k_refr[sid], ior[sid] = m.k_refl, m.k_refr, m.ior
            transmissive[sid] = m.transmissive
            const_glass[sid] = m.transmissive and m.combination == "constant"
            spec_id[sid] = _ptr_id(mi, m.specular)
            if m.specular is not None:
                k = m.k_refl + (m.k_refr if m.transmissive else 0)
                w_refl_max = max(w_refl_max, float(np.max(k)))
            if m.transmissive:
                scale = max(m.ior, 1 / m.ior) ** 2 if self.physical else 1.0
                w_refr_max = max(w_refr_max, float(np.max(m.k_refr)) * scale)
        self.w_refl_max, self.w_refr_max = w_refl_max, w_refr_max
        self.any_refl = bool(np.any(spec_id > 0))
        self.any_refr = bool(np.any(transmissive))

        lights = []
        for em in mi_scene.emitters():
            if em.is_environment() or not em.flags() & mi.EmitterFlags.DeltaPosition:
                raise ValueError(f"peer: emitter {em.id()!r} is not a point emitter")
            lights.append((em, em.id() in integ.falloff_none))
        self.lights = lights
        # lights with extent: the area emitters nested in the integrator (not in the scene)
        self.area_lights = list(getattr(integ, "area_lights", []))
        self.shadow_samples = int(getattr(integ, "shadow_samples", 1))
        self._rng = None               # the frame's PCG32 while a frame is traced

        def c3(a):
            return mi.Color3f(*(mi.Float(a[:, k].astype(np.float32)) for k in range(3)))

        self.tables = {"ka": c3(ka), "k_refl": c3(k_refl), "k_refr": c3(k_refr),
                       "ior": mi.Float(ior.astype(np.float32)),
                       "const_glass": mi.Bool(const_glass),
                       "transmissive": mi.Bool(transmissive),
                       "spec": mi.UInt32(spec_id)}
        dr.eval(self.tables)
        sensor = mi_scene.sensors()[0]
        self.width, self.height = (int(v) for v in sensor.film().size())

    # ---- the Whitted tree, unrolled ------------------------------------------------------
    def radiance(self, scene, tables, ray, active, depth: int = 0, acc=None,
                 bound: float = 1.0):
        """Radiance along ``ray`` for lanes ``active`` (traced, no evaluation). ``acc`` is
        the accumulated weight of the path (Color3f), ``depth`` the tree depth of ``ray`` and
        ``bound`` the largest accumulated weight (max over RGB) any lane can have on this
        branch (host constants)."""
        mi = _mi()
        import drjit as dr
        eps = self.eps
        acc = mi.Color3f(1.0) if acc is None else acc
        mode = mi.TransportMode.Radiance if self.physical else mi.TransportMode.Importance
        ctx = mi.BSDFContext(mode)

        si = scene.ray_intersect(ray, active)
        hit = active & si.is_valid()
        result = dr.select(active & ~hit, mi.Color3f(*self.background), mi.Color3f(0.0))
        sid = dr.reinterpret_array(mi.UInt32, si.shape)
        x, ng = si.p, si.n

        def offset(direction):
            side = dr.select(dr.dot(direction, ng) >= 0, 1.0, -1.0)
            return x + (eps * side) * ng

        result += dr.gather(mi.Color3f, tables["ka"], sid, hit)

        bsdf = si.bsdf(ray)
        for em, no_falloff in self.lights:
            ds, intensity = em.sample_direction(si, mi.Point2f(0.5), hit)
            if no_falloff:
                intensity = intensity * dr.square(ds.dist)
            o = offset(ds.d)
            to_light = ds.p - o
            dist = dr.norm(to_light)
            shadow = mi.Ray3f(o, to_light / dist)
            shadow.maxt = dist - eps
            lit = hit & ~scene.ray_test(shadow, hit)
            f = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
            result += dr.select(lit, f * intensity, 0.0)
        result += self._area_terms(scene, si, hit, bsdf, ctx, offset)

        if depth + 1 > self.max_depth:
            return result
        go_refl = self.any_refl and bound * self.w_refl_max >= self.min_weight
        go_refr = self.any_refr and bound * self.w_refr_max >= self.min_weight
        if not (go_refl or go_refr):
            return result

        spec_id = dr.gather(mi.UInt32, tables["spec"], sid, hit)
        has_spec = hit & (spec_id > 0)
        spec = dr.reinterpret_array(mi.BSDFPtr, spec_id)
        transmissive = dr.gather(mi.Bool, tables["transmissive"], sid, hit) & has_spec
        const_glass = dr.gather(mi.Bool, tables["const_glass"], sid, hit) & has_spec
        c_r = mi.BSDFContext(mode, mi.BSDFFlags.All, 0)       # reflection lobe
        c_t = mi.BSDFContext(mode, mi.BSDFFlags.All, 1)       # transmission lobe
        k_refl = dr.gather(mi.Color3f, tables["k_refl"], sid, const_glass)
        k_refr = dr.gather(mi.Color3f, tables["k_refr"], sid, const_glass)
        ior = dr.gather(mi.Float, tables["ior"], sid, const_glass)
        f, _, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(si.wi), ior)
        tir = f >= 1.0

        if go_refl:
            bs_r, w_r = spec.sample(c_r, si, 0.5, mi.Point2f(0.5), has_spec)
            w_r = dr.select(const_glass, dr.select(tir, k_refl + k_refr, k_refl), w_r)
            w_r = dr.select(has_spec, w_r, 0.0)
            child_acc = acc * w_r
            go = has_spec & (_hmax(child_acc) >= self.min_weight) & (_hmax(w_r) > 0)
            d = si.to_world(bs_r.wo)
            child = mi.Ray3f(offset(d), dr.normalize(d))
            Lc = self.radiance(scene, tables, child, go, depth + 1, child_acc,
                               bound * self.w_refl_max)
            result += dr.select(go, w_r * Lc, 0.0)
        if go_refr:
            bs_t, w_t = spec.sample(c_t, si, 0.5, mi.Point2f(0.5), transmissive)
            scale = dr.square(eta_ti) if self.physical else 1.0
            w_t = dr.select(const_glass, dr.select(tir, 0.0, k_refr * scale), w_t)
            w_t = dr.select(transmissive, w_t, 0.0)
            child_acc = acc * w_t
            go = transmissive & (_hmax(child_acc) >= self.min_weight) & (_hmax(w_t) > 0)
            d = si.to_world(bs_t.wo)
            child = mi.Ray3f(offset(d), dr.normalize(d))
            Lc = self.radiance(scene, tables, child, go, depth + 1, child_acc,
                               bound * self.w_refr_max)
            result += dr.select(go, w_t * Lc, 0.0)
        return result

    def _area_terms(self, scene, si, hit, bsdf, ctx, offset):
        """Lights with extent (docs/MODEL.md): ``shadow_samples = k²`` samples of each by its
        own ``sample_direction``, stratified as ours (sample ``s = j k + i`` at
        ``((i + ξ1)/k, (j + ξ2)/k)``, ``ξ`` from the ray's PCG32), each with a shadow ray and
        weight ``1 / k²``; physical ``L_e / pdf``, classic the point-light intensity (as
        ``reference.plugins``). The samples are one symbolic loop per light (the PCG32 in
        its state), so the kernel's size does not grow with ``k²``."""
        mi = _mi()
        total = mi.Color3f(0.0)
        integ = self.scene.integrator()
        for shape, key in self.area_lights:
            total = self._area_light(scene, si, hit, bsdf, ctx, offset, shape,
                                     key.removesuffix("_back") in integ.falloff_none, total)
        return total

    def _area_light(self, scene, si, hit, bsdf, ctx, offset, shape, no_falloff, total):
        """``total`` plus one light's ``shadow_samples`` terms (a ``dr.while_loop``)."""
        mi = _mi()
        import drjit as dr
        n = self.shadow_samples
        k = math.isqrt(n)
        inv_n, inv_k = 1.0 / n, 1.0 / k
        em = shape.emitter()
        sphere = shape.shape_type() == mi.ShapeType.Sphere
        box = shape.bbox()
        radius = float(box.extents()[0]) * 0.5
        proj = np.pi * radius * radius if sphere else float(shape.surface_area()[0])
        outside = (dr.squared_norm(si.p - mi.Point3f(box.center())) > radius * radius
                   if sphere else mi.Bool(True))
        physical, eps = self.physical, self.eps

        def body(s, total, rng):
            row = s // k
            u = mi.Point2f((mi.Float(s - row * k) + rng.next_float32()) * inv_k,
                           (mi.Float(row) + rng.next_float32()) * inv_k)
            ds, spec = em.sample_direction(si, u, hit)
            ok = hit & outside & (ds.pdf > 0) & (_hmax(spec) > 0)
            if physical:
                Li = spec
            else:
                Li = spec * ds.pdf * proj
                if not sphere:
                    Li = Li * dr.maximum(-dr.dot(ds.d, ds.n), 0.0)
                if not no_falloff:
                    Li = Li / dr.square(ds.dist)
            o = offset(ds.d)
            to_light = ds.p - o
            dist = dr.norm(to_light)
            shadow = mi.Ray3f(o, to_light / dist)
            shadow.maxt = dist - eps
            lit = ok & ~scene.ray_test(shadow, ok)
            f = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
            total = total + dr.select(lit, f * Li * inv_n, 0.0)
            return s + 1, total, rng

        s0 = dr.zeros(mi.UInt32, dr.width(hit))
        total = dr.zeros(mi.Color3f, dr.width(hit)) + total
        _, total, self._rng = dr.while_loop(
            (s0, total, self._rng), lambda s, total, rng: s < n, body,
            labels=("s", "total", "rng"), label="peer shadow samples")
        return total

    # ---- frames ------------------------------------------------------------------------------
    def frame_fn(self):
        """``frame(scene, tables, pos) -> TensorXf (H, W, 3)``: one ray through each film
        position ``pos`` (Point2f in [0, 1]², row-major from the top row)."""
        mi = _mi()
        import drjit as dr
        w, h = self.width, self.height

        def frame(scene, tables, pos):
            sensor = scene.sensors()[0]
            ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
            self._rng = None
            if self.area_lights:           # the shadow samples' numbers, one stream a ray
                n = dr.width(pos)
                self._rng = mi.PCG32(n, dr.arange(mi.UInt64, n))
            L = self.radiance(scene, tables, mi.Ray3f(ray.o, ray.d), mi.Bool(True))
            return mi.TensorXf(dr.ravel(L), shape=(h, w, 3))
        return frame

    def positions(self):
        """Film positions of exact mode (``reference.mitsuba_scene.film_positions``)."""
        mi = _mi()
        import drjit as dr
        xy = film_positions(self.width, self.height)
        pos = mi.Point2f(mi.Float(xy[:, 0].astype(np.float32)),
                         mi.Float(xy[:, 1].astype(np.float32)))
        dr.eval(pos)
        return pos

    def frame(self, pos=None):
        """One traced frame, evaluated: TensorXf (H, W, 3)."""
        import drjit as dr
        img = self.frame_fn()(self.scene, self.tables, self.positions() if pos is None else pos)
        dr.eval(img)
        return img

    def frozen(self):
        """``run(pos) -> TensorXf``: the frame function under ``dr.freeze`` (evaluated).
        Python's cycle collector is held off during each call: freeing device memory while
        a frame is being recorded makes Dr.Jit abort ("this function cannot be recorded")."""
        import gc

        import drjit as dr
        fn = dr.freeze(self.frame_fn())
        scene, tables = self.scene, self.tables

        def run(pos):
            was = gc.isenabled()
            gc.disable()
            try:
                img = fn(scene, tables, pos)
                dr.eval(img)
            finally:
                if was:
                    gc.enable()
            return img
        return run


def _hmax(c):
    import drjit as dr
    return dr.maximum(dr.maximum(c[0], c[1]), c[2])


def load_peer(scene, *, backend: str = "llvm", view: int = 0) -> Peer:
    """Translate ``scene`` (a ``renderer`` Scene; its ``settings.max_depth`` is used) and
    build the peer on the Mitsuba variant of ``backend`` ("llvm" | "cuda")."""
    mitsuba_variant("cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb")
    return Peer(load_mitsuba(scene, view=view, mode="exact", spp=1, spawn="fixed"))


def render_peer(scene, *, backend: str = "llvm", view: int = 0,
                freeze: bool = False) -> np.ndarray:
    """``scene`` rendered by the peer in exact mode: float32 (H, W, 3) linear RGB."""
    peer = load_peer(scene, backend=backend, view=view)
    img = peer.frozen()(peer.positions()) if freeze else peer.frame()
    return np.asarray(img.numpy(), np.float32)
