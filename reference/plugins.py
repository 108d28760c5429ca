"""The few Mitsuba 3 plugins the reference needs, kept small on purpose.

The independent part of the check is Mitsuba's own code: geometry and ray intersection,
the ``perspective`` sensor, the ``point`` emitter, and the ``conductor`` / ``dielectric``
BSDFs (Fresnel term, refracted direction, radiance compression). What is ours:

``whitted_phong`` (BSDF)
    The Phong-like local lobe of docs/MODEL.md, one-sided (the translator wraps it in
    ``twosided``). Parameters (defaults): ``shading`` ("classic") "classic" | "physical";
    ``kd``, ``ks`` (rgb, 0); ``n`` (float, 32). ``eval`` returns, for light direction
    ``wo`` and viewer ``wi`` in the shading frame with ``cosθ = wo.z > 0``,
    classic ``kd cosθ + ks max(0, R·wi)^n``, physical ``cosθ (kd/π + ks (n+2)/(2π)
    max(0, R·wi)^n)`` (Mitsuba 0.6 ``phong``), with ``R`` the mirror of ``wo``.

``whitted_material`` (BSDF)
    A container that the Whitted integrator reads on the host: ``ka``, ``k_refl``,
    ``k_refr`` (rgb, 0), ``ior`` (1.5), ``combination`` ("constant") "constant" |
    "fresnel", a nested ``local`` BSDF (twosided whitted_phong) and an optional nested
    ``specular`` BSDF (twosided conductor, or a dielectric for transmissive materials).
    Its own ``eval`` is that of ``local``, so other integrators see the Phong lobe.

``whitted`` (integrator)
    The deterministic Whitted tree of docs/MODEL.md, evaluated as host-level recursion over
    ray batches with masks (eagerly evaluated, so empty branches are pruned). Parameters:
    ``max_depth`` (5), ``min_weight`` (0.01), ``shading`` ("classic"), ``spawn``
    ("mitsuba") "mitsuba" | "fixed", ``ray_offset`` (absolute ε, 1e-4, read only with
    ``spawn = "fixed"``), ``background`` and ``ambient`` (rgb, 0), ``falloff_none``
    (comma-separated ids of point emitters without 1/dist² falloff, ""), ``shadow_samples``
    (1) and the shapes of the lights with extent nested in it (``sphere`` / ``rectangle``
    shapes carrying an ``area`` emitter, ``mitsuba_scene.area_light_dicts``): they are not
    part of the scene, so no ray hits them; at each hit every one is sampled
    ``shadow_samples`` times by its own ``sample_direction`` (cone sampling for a sphere,
    area sampling for a rectangle) with the sampler's ``next_2d``, each sample with its
    own shadow ray and weight ``1 / shadow_samples``; physical shading takes Mitsuba's
    ``L_e / pdf``, classic the point-light intensity ``I`` of docs/MODEL.md (``L_e`` times
    the projected area ``π r²``, or times the area and the emission cosine). It works under
    ``mi.render`` (converged mode) and through ``render_exact`` (one ray per given film
    position, exact mode).

    Secondary and shadow rays are spawned by Mitsuba itself (``spawn = "mitsuba"``):
    ``si.spawn_ray(d)`` and ``si.spawn_ray_to(p_light)``, Mitsuba's own offset along the
    geometric normal, ``(1 + max|p|) · RayEpsilon``, and shadow rays ending
    ``ShadowEpsilon`` short of the light. So the goldens check our ray spawning too, not
    only shading. ``spawn = "fixed"`` (the old rule, ``p ± ε N_g`` with an absolute ε,
    shadow rays ``ε`` short) exists only to study the reference itself
    (``evaluation/speckles.py``).

Importing this module registers nothing: ``register()`` defines the classes for the Mitsuba
variant in use (``mi.BSDF`` and ``mi.SamplingIntegrator`` are the variant's own classes) and
registers them, once per variant. ``reference.mitsuba_variant()`` selects a variant and
calls it.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

#: Plugin classes by variant, then by plugin name (filled by ``register``).
_PLUGINS: dict[str, dict[str, type]] = {}


def _color(props, name, default=0.0) -> np.ndarray:
    """An rgb property as float64 (3,), accepting a float, an rgb or a 3-list."""
    if name not in props:
        return np.full(3, float(default))
    v = props[name]
    arr = np.array(v, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        arr = np.full(3, arr[0])
    if arr.size != 3 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{props.plugin_name()}: property {name!r} must be an rgb triple, "
                         f"got {v!r}")
    return arr


def _const(c: np.ndarray):
    return mi.Color3f(float(c[0]), float(c[1]), float(c[2]))


def _hmax(c):
    return dr.maximum(dr.maximum(c[0], c[1]), c[2])


def _define_plugins() -> dict[str, type]:
    """The plugin classes for the current Mitsuba variant, by plugin name."""

    class PhongBSDF(mi.BSDF):
        """One-sided Phong-like lobe (see the module docstring)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.shading = props.get("shading", "classic")
            if self.shading not in ("classic", "physical"):
                raise ValueError(f"whitted_phong: property 'shading' must be 'classic' or "
                                 f"'physical', got {self.shading!r}")
            self.kd = _color(props, "kd")
            self.ks = _color(props, "ks")
            self.n = float(props.get("n", 32.0))
            if not self.n > 0:
                raise ValueError(f"whitted_phong: property 'n' must be > 0, got {self.n}")
            flags = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection
                     | mi.BSDFFlags.FrontSide)
            self.m_flags = flags
            self.m_components = [flags]

        def eval(self, ctx, si, wo, active=True):
            cos_o = mi.Frame3f.cos_theta(wo)
            active = active & (cos_o > 0)
            r = mi.Vector3f(-wo.x, -wo.y, wo.z)            # mirror of the light direction
            rv = dr.maximum(dr.dot(r, si.wi), 0.0)
            spec = dr.power(rv, self.n)
            kd, ks = _const(self.kd), _const(self.ks)
            if self.shading == "classic":
                value = kd * cos_o + ks * spec
            else:
                value = cos_o * (kd * dr.inv_pi + ks * ((self.n + 2) * dr.inv_two_pi) * spec)
            return dr.select(active, value, 0.0)

        def pdf(self, ctx, si, wo, active=True):
            return dr.select(mi.Frame3f.cos_theta(wo) > 0,
                             mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = mi.BSDFSample3f()
            bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = 0
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (bs.pdf > 0)
            value = self.eval(ctx, si, bs.wo, ok) / dr.maximum(bs.pdf, 1e-20)
            return bs, dr.select(ok, value, 0.0)

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"PhongBSDF[shading={self.shading}, kd={self.kd}, ks={self.ks}, n={self.n}]"


    class WhittedMaterial(mi.BSDF):
        """Material container read by the ``whitted`` integrator (see the module docstring)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.ka = _color(props, "ka")
            self.k_refl = _color(props, "k_refl")
            self.k_refr = _color(props, "k_refr")
            self.ior = float(props.get("ior", 1.5))
            self.combination = props.get("combination", "constant")
            if self.combination not in ("constant", "fresnel"):
                raise ValueError(f"whitted_material: property 'combination' must be 'constant' "
                                 f"or 'fresnel', got {self.combination!r}")
            self.local = props.get("local", None)
            self.specular = props.get("specular", None)
            if self.local is None:
                raise ValueError("whitted_material: nested BSDF 'local' is required")
            self.transmissive = bool(np.any(self.k_refr > 0))
            if self.transmissive and self.specular is None:
                raise ValueError("whitted_material: k_refr > 0 needs a nested 'specular' "
                                 "dielectric")
            self.m_flags = self.local.flags() | (self.specular.flags() if self.specular else 0)
            self.m_components = [self.local.flags()]

        def eval(self, ctx, si, wo, active=True):
            return self.local.eval(ctx, si, wo, active)

        def pdf(self, ctx, si, wo, active=True):
            return self.local.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.local.eval_pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            return self.local.sample(ctx, si, sample1, sample2, active)

        def traverse(self, callback):
            pass

        def to_string(self):
            return (f"WhittedMaterial[ka={self.ka}, k_refl={self.k_refl}, k_refr={self.k_refr}, "
                    f"ior={self.ior}, combination={self.combination}]")


    class WhittedIntegrator(mi.SamplingIntegrator):
        """Deterministic Whitted integrator (see the module docstring)."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.max_depth = int(props.get("max_depth", 5))
            self.min_weight = float(props.get("min_weight", 0.01))
            self.shading = props.get("shading", "classic")
            if self.shading not in ("classic", "physical"):
                raise ValueError(f"whitted: property 'shading' must be 'classic' or 'physical', "
                                 f"got {self.shading!r}")
            self.spawn = props.get("spawn", "mitsuba")
            if self.spawn not in ("mitsuba", "fixed"):
                raise ValueError(f"whitted: property 'spawn' must be 'mitsuba' or 'fixed', "
                                 f"got {self.spawn!r}")
            self.ray_offset = float(props.get("ray_offset", 1e-4))
            self.background = _color(props, "background")
            self.ambient = _color(props, "ambient")
            ids = props.get("falloff_none", "")
            self.falloff_none = {s for s in ids.split(",") if s}
            self.shadow_samples = int(props.get("shadow_samples", 1))
            self.area_lights = []       # (shape, id) of the nested lights with extent
            for key in props.keys():
                v = props[key]
                if isinstance(v, mi.Shape):
                    if v.emitter() is None:
                        raise ValueError(f"whitted: nested shape {key!r} has no emitter")
                    self.area_lights.append((v, v.id() or key))
            self._tables = None

        # ---- host-side tables -------------------------------------------------------------
        def _prepare(self, scene):
            """Material list and shape-id → material-index table (cached per scene)."""
            if self._tables is not None and self._tables[0] is scene:
                return self._tables
            materials, index = [], {}
            shape_ids, mat_of_shape = [], []
            for shape in scene.shapes():
                bsdf = shape.bsdf()
                if not isinstance(bsdf, WhittedMaterial):
                    raise ValueError(f"whitted: shape {shape.id()!r} needs a 'whitted_material' "
                                     f"BSDF, got {type(bsdf).__name__}")
                if id(bsdf) not in index:
                    index[id(bsdf)] = len(materials)
                    materials.append(bsdf)
                shape_ids.append(int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0]))
                mat_of_shape.append(index[id(bsdf)])
            table = np.zeros(max(shape_ids, default=0) + 1, np.uint32)
            table[shape_ids] = mat_of_shape
            lights = []
            for em in scene.emitters():
                if not em.is_environment() and em.flags() & mi.EmitterFlags.DeltaPosition:
                    lights.append((em, em.id() in self.falloff_none))
                else:
                    raise ValueError(f"whitted: emitter {em.id()!r} is not a point emitter")
            self._tables = (scene, materials, mi.UInt32(table), lights)
            return self._tables

        # ---- Mitsuba entry point (converged mode, via mi.render) --------------------------
        def sample(self, scene, sampler, ray, medium=None, active=True):
            ray = mi.Ray3f(ray.o, ray.d)
            L = self.radiance(scene, ray, mi.Bool(active), sampler=sampler)
            return L, mi.Bool(True), []

        # ---- exact mode -------------------------------------------------------------------
        def render_exact(self, scene, film_xy: np.ndarray) -> np.ndarray:
            """Radiance of one ray per film position. film_xy: float (N, 2) in [0, 1]^2
            (pixel position / resolution, y = 0 the top row). Returns float32 (N, 3)."""
            sensor = scene.sensors()[0]
            pos = mi.Point2f(mi.Float(film_xy[:, 0].astype(np.float32)),
                             mi.Float(film_xy[:, 1].astype(np.float32)))
            n = film_xy.shape[0]
            ray, _ = sensor.sample_ray(0.0, dr.full(mi.Float, 0.5, n), pos,
                                       dr.full(mi.Point2f, 0.5, n))
            sampler = None
            if self.area_lights:            # shadow samples of lights with extent
                sampler = mi.load_dict({"type": "independent"})
                sampler.seed(0, n)
            L = self.radiance(scene, mi.Ray3f(ray.o, ray.d), dr.full(mi.Bool, True, n),
                              sampler=sampler)
            return np.ascontiguousarray(np.array(L, dtype=np.float32).reshape(3, n).T)

        # ---- the Whitted tree -------------------------------------------------------------
        def radiance(self, scene, ray, active, depth=0, acc=None, sampler=None):
            """Radiance along ``ray`` (Ray3f, unit d) for lanes ``active``; ``acc`` is the
            accumulated weight of the path (Color3f), ``depth`` the tree depth of ``ray``;
            ``sampler`` draws the shadow samples of the lights with extent."""
            _, materials, mat_table, lights = self._prepare(scene)
            acc = mi.Color3f(1.0) if acc is None else acc
            eps = self.ray_offset
            mode = (mi.TransportMode.Radiance if self.shading == "physical"
                    else mi.TransportMode.Importance)    # Importance: no η² factor (classic)

            # ---- closest hit --------------------------------------------------------------
            si = scene.ray_intersect(ray, active)
            hit = active & si.is_valid()
            result = dr.select(active & ~hit, _const(self.background), mi.Color3f(0.0))
            dr.eval(result, si, hit)
            if not dr.any(hit):
                return result
            sid = dr.reinterpret_array(mi.UInt32, si.shape)
            mat = dr.gather(mi.UInt32, mat_table, sid, hit)
            x, ng = si.p, si.n

            def offset(direction):
                # spawn = "fixed": leave on the side of the geometric normal the ray goes into.
                side = dr.select(dr.dot(direction, ng) >= 0, 1.0, -1.0)
                return x + (eps * side) * ng

            def spawn_ray(direction):
                """A secondary ray leaving the hit along ``direction`` (unit)."""
                if self.spawn == "mitsuba":
                    return si.spawn_ray(direction)
                return mi.Ray3f(offset(direction), direction)

            def spawn_shadow_ray(p_light, direction):
                """A shadow ray from the hit to ``p_light`` (``direction``: unit, to it)."""
                if self.spawn == "mitsuba":
                    return si.spawn_ray_to(p_light)
                o = offset(direction)
                to_light = p_light - o
                dist = dr.norm(to_light)
                shadow = mi.Ray3f(o, to_light / dist)
                shadow.maxt = dist - eps
                return shadow

            # ---- ambient ------------------------------------------------------------------
            for k, m in enumerate(materials):
                result += dr.select(hit & (mat == k), _const(self.ambient * m.ka), 0.0)

            # ---- local light: every point light, with a shadow ray ------------------------
            ctx = mi.BSDFContext(mode)
            for em, no_falloff in lights:
                ds, intensity = em.sample_direction(si, mi.Point2f(0.5), hit)   # I / dist²
                if no_falloff:
                    intensity = intensity * dr.square(ds.dist)
                shadow = spawn_shadow_ray(ds.p, ds.d)
                lit = hit & ~scene.ray_test(shadow, hit)
                wo = si.to_local(ds.d)
                for k, m in enumerate(materials):
                    mk = lit & (mat == k)
                    f = m.local.eval(ctx, si, wo, mk)
                    result += dr.select(mk, f * intensity, 0.0)
            result += self._area_light_terms(scene, si, hit, mat, materials, ctx, sampler,
                                             spawn_shadow_ray)

            if depth + 1 > self.max_depth:
                return result

            # ---- specular children: directions from Mitsuba's BSDFs, weights per MODEL.md ----
            refl_d, refl_w = mi.Vector3f(0.0), mi.Color3f(0.0)
            refr_d, refr_w = mi.Vector3f(0.0), mi.Color3f(0.0)
            any_refl = any_refr = False
            for k, m in enumerate(materials):
                if m.specular is None:
                    continue
                mk = hit & (mat == k)
                if not m.transmissive:
                    bs, w = m.specular.sample(ctx, si, 0.5, mi.Point2f(0.5), mk)
                    refl_d = dr.select(mk, si.to_world(bs.wo), refl_d)
                    refl_w = dr.select(mk, w, refl_w)
                    any_refl = True
                    continue
                c_r = mi.BSDFContext(mode, mi.BSDFFlags.All, 0)      # reflection lobe
                c_t = mi.BSDFContext(mode, mi.BSDFFlags.All, 1)      # transmission lobe
                bs_r, w_r = m.specular.sample(c_r, si, 0.5, mi.Point2f(0.5), mk)
                bs_t, w_t = m.specular.sample(c_t, si, 0.5, mi.Point2f(0.5), mk)
                if m.combination == "constant":
                    f, _, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(si.wi), m.ior)
                    tir = f >= 1.0
                    w_r = dr.select(tir, _const(m.k_refl + m.k_refr), _const(m.k_refl))
                    scale = dr.square(eta_ti) if self.shading == "physical" else 1.0
                    w_t = dr.select(tir, 0.0, _const(m.k_refr) * scale)
                refl_d = dr.select(mk, si.to_world(bs_r.wo), refl_d)
                refl_w = dr.select(mk, w_r, refl_w)
                refr_d = dr.select(mk, si.to_world(bs_t.wo), refr_d)
                refr_w = dr.select(mk, w_t, refr_w)
                any_refl = any_refr = True

            for present, d, w in ((any_refl, refl_d, refl_w), (any_refr, refr_d, refr_w)):
                if not present:
                    continue
                child_acc = acc * w
                go = hit & (_hmax(child_acc) >= self.min_weight) & (_hmax(w) > 0)
                dr.eval(go)
                if not dr.any(go):
                    continue
                child = spawn_ray(dr.normalize(d))
                Lc = self.radiance(scene, child, go, depth + 1, child_acc, sampler)
                result += dr.select(go, w * Lc, 0.0)
            dr.eval(result)
            return result

        def _area_light_terms(self, scene, si, hit, mat, materials, ctx, sampler,
                              spawn_shadow_ray):
            """The lights with extent at the hits: ``shadow_samples`` samples of each."""
            total = mi.Color3f(0.0)
            if not self.area_lights:
                return total
            if sampler is None:
                raise ValueError("whitted: lights with extent need a sampler")
            inv_n = 1.0 / self.shadow_samples
            for shape, key in self.area_lights:
                em = shape.emitter()
                sphere = shape.shape_type() == mi.ShapeType.Sphere
                box = shape.bbox()
                centre = mi.Point3f(box.center())
                radius = float(box.extents()[0]) * 0.5
                area = float(shape.surface_area()[0])
                # classic: the point-light intensity I of MODEL.md (L_e × π r², or L_e × A)
                proj = (np.pi * radius * radius) if sphere else area
                no_falloff = key.removesuffix("_back") in self.falloff_none
                outside = dr.squared_norm(si.p - centre) > radius * radius if sphere \
                    else mi.Bool(True)
                for _ in range(self.shadow_samples):
                    ds, spec = em.sample_direction(si, sampler.next_2d(hit), hit)
                    ok = hit & outside & (ds.pdf > 0) & (_hmax(spec) > 0)
                    if self.shading == "physical":
                        Li = spec
                    else:
                        L_e = spec * ds.pdf              # spec is L_e / pdf
                        Li = L_e * proj
                        if not sphere:
                            Li = Li * dr.maximum(-dr.dot(ds.d, ds.n), 0.0)
                        if not no_falloff:
                            Li = Li / dr.square(ds.dist)
                    shadow = spawn_shadow_ray(ds.p, ds.d)
                    lit = ok & ~scene.ray_test(shadow, ok)
                    wo = si.to_local(ds.d)
                    for k, m in enumerate(materials):
                        mk = lit & (mat == k)
                        f = m.local.eval(ctx, si, wo, mk)
                        total += dr.select(mk, f * Li * inv_n, 0.0)
                    dr.eval(total)
            return total

        def aov_names(self):
            return []

        def to_string(self):
            return (f"WhittedIntegrator[max_depth={self.max_depth}, min_weight={self.min_weight}, "
                    f"shading={self.shading}, spawn={self.spawn}, ray_offset={self.ray_offset}]")

    return {"whitted_phong": PhongBSDF, "whitted_material": WhittedMaterial,
            "whitted": WhittedIntegrator}


def register() -> dict[str, type]:
    """Register ``whitted_phong``, ``whitted_material`` and ``whitted`` for the current Mitsuba
    variant (idempotent: the second call for a variant does nothing). Returns the plugin
    classes by name. A variant must be set first (``reference.mitsuba_variant()``)."""
    variant = mi.variant()
    if variant is None:
        raise RuntimeError("reference.plugins.register(): no Mitsuba variant is set; "
                           "select one first (reference.mitsuba_variant())")
    if variant not in _PLUGINS:
        classes = _define_plugins()
        mi.register_bsdf("whitted_phong", lambda props: classes["whitted_phong"](props))
        mi.register_bsdf("whitted_material", lambda props: classes["whitted_material"](props))
        mi.register_integrator("whitted", lambda props: classes["whitted"](props))
        _PLUGINS[variant] = classes
    return _PLUGINS[variant]
