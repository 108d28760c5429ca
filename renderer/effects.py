"""Which effects a scene calls for, decided on the host before tracing.

``EffectSet.from_scene(scene)`` derives the set from the scene's materials, lights, objects
and settings alone (with the reason for each effect and the deepest bounce a ray can reach);
the integrator traces only the enabled effects (the set is passed down as it is, and every
term is behind ``if dr.hint(fx.<flag>, mode="scalar")``, so Dr.Jit records only what runs;
``renderer.stats.kernel_operations`` measures the kernels). ``EffectSet.all()`` traces every
effect (the general kernel); ``without(name)`` drops one for debugging, with a warning, since
the image then differs from what the scene describes.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .scene import Scene
from .scene.model import used_materials

FLAGS = ("shadows", "ambient", "reflection", "refraction", "smooth_normals", "specular",
         "many_lights", "fresnel", "soft_shadows")


@dataclass(frozen=True)
class EffectSet:
    """Effects traced into the kernel.

    shadows: shadow rays (some light exists). ambient: ambient·ka is nonzero somewhere.
    reflection / refraction: some material has k_refl / k_refr > 0 and max_depth >= 1
    (refraction implies reflection: total internal reflection and Fresnel reflect).
    smooth_normals: some object interpolates vertex normals. specular: some ks > 0 and a
    light exists. many_lights: more than one light. fresnel: some material uses Fresnel
    weights. soft_shadows: some light has extent (a sphere or rectangle light: several
    jittered shadow rays per light, docs/MODEL.md "Lights with extent"); a scene of point
    lights traces without it, exactly today's kernel. physical: "physical" shading (else
    "classic").
    depth: deepest reachable bounce (0 without secondary rays; see ``reachable_depth``).
    reasons: flag -> why it is on (the material, light or object asking for it).
    forced: True when the set does not follow from the scene (``all()`` / ``without()``).
    """

    shadows: bool = False
    ambient: bool = False
    reflection: bool = False
    refraction: bool = False
    smooth_normals: bool = False
    specular: bool = False
    many_lights: bool = False
    fresnel: bool = False
    soft_shadows: bool = False
    physical: bool = False
    depth: int = 0
    reasons: dict = field(default_factory=dict, compare=False)
    forced: bool = False

    @property
    def secondary(self) -> bool:
        """Secondary (reflected or refracted) rays are traced."""
        return (self.reflection or self.refraction) and self.depth > 0

    @classmethod
    def from_scene(cls, scene: Scene) -> "EffectSet":
        s = scene.settings
        mats, lights = scene.materials, scene.lights
        used = used_materials(scene)
        used_mats = [mats[i] for i in used if i < len(mats)]
        reasons = {}

        def first(pred, items, what):
            for it in items:
                if pred(it):
                    return f"{what} {getattr(it, 'name', '') or '?'!r}"
            return None

        amb = np.asarray(scene.ambient, np.float64)
        r_amb = first(lambda m: np.any(amb * m.ka > 0), used_mats, "material")
        r_light = f"light {lights[0].name or '0'!r}" if lights else None
        deep = s.max_depth >= 1
        r_refl = first(lambda m: m.reflective, used_mats, "material") if deep else None
        r_refr = first(lambda m: m.transmissive, used_mats, "material") if deep else None
        if r_refr and not r_refl:
            r_refl = f"{r_refr} (total internal reflection)"
        r_smooth = first(lambda o: o.smooth and o.face_count > 0, scene.objects, "object")
        r_spec = first(lambda m: np.any(m.ks > 0), used_mats, "material") if lights else None
        r_many = f"{len(lights)} lights" if len(lights) > 1 else None
        r_fres = first(lambda m: m.combination == "fresnel" and (m.reflective or m.transmissive),
                       used_mats, "material") if deep else None
        r_soft = first(lambda li: li.extent, lights, "light")
        if r_soft:
            big = next(li for li in lights if li.extent)
            r_soft += f" is a {big.shape} ({s.shadow_samples} shadow samples)"
        for k, r in (("shadows", r_light), ("ambient", r_amb), ("reflection", r_refl),
                     ("refraction", r_refr), ("smooth_normals", r_smooth),
                     ("specular", r_spec), ("many_lights", r_many), ("fresnel", r_fres),
                     ("soft_shadows", r_soft)):
            if r:
                reasons[k] = r
        secondary = bool(r_refl or r_refr)
        depth, why = reachable_depth(scene) if secondary else (0, "")
        if secondary:
            reasons["depth"] = why
        return cls(shadows=bool(r_light), ambient=bool(r_amb), reflection=bool(r_refl),
                   refraction=bool(r_refr), smooth_normals=bool(r_smooth),
                   specular=bool(r_spec), many_lights=bool(r_many), fresnel=bool(r_fres),
                   soft_shadows=bool(r_soft),
                   physical=s.shading == "physical",
                   depth=depth, reasons=reasons)

    @classmethod
    def all(cls, scene: Scene) -> "EffectSet":
        """Every effect traced (the general kernel); shading mode and depth from ``scene``."""
        return cls(**{k: True for k in FLAGS}, physical=scene.settings.shading == "physical",
                   depth=int(scene.settings.max_depth), reasons={k: "forced" for k in FLAGS},
                   forced=True)

    def without(self, name: str) -> "EffectSet":
        """The same set with effect ``name`` off (debugging: the image is then not the
        scene's truth, and a warning says so)."""
        if name not in FLAGS:
            raise ValueError(f"effects.without: expected one of {FLAGS}, got {name!r}")
        warnings.warn(f"effect {name!r} forced off: the image differs from the scene's truth",
                      stacklevel=2)
        reasons = dict(self.reasons)
        reasons.pop(name, None)
        return replace(self, **{name: False}, reasons=reasons, forced=True)

    def lines(self) -> list[str]:
        """One line per enabled effect, ``"name — reason"``, then the traced depth."""
        out = [f"{k} — {self.reasons.get(k, 'forced')}" for k in FLAGS if getattr(self, k)]
        if self.secondary:
            why = self.reasons.get("depth", "forced")
            out.append(f"secondary rays — depth {self.depth}: {why}")
        else:
            out.append("secondary rays — off (nothing reflects or transmits, or max_depth 0)")
        return out

    def __str__(self) -> str:
        on = [k for k in FLAGS if getattr(self, k)]
        mode = "physical" if self.physical else "classic"
        tag = " (forced)" if self.forced else ""
        return f"effects[{mode}, depth {self.depth}{tag}]: " + (", ".join(on) or "local only")


def _welded_edges_closed(V: np.ndarray, F: np.ndarray) -> bool:
    """Every edge (vertices welded by exact position) is shared by exactly two faces."""
    _, idx = np.unique(V, axis=0, return_inverse=True)
    G = idx.reshape(-1)[F]
    e = np.sort(np.concatenate([G[:, [0, 1]], G[:, [1, 2]], G[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def convex_mirror(scene: Scene, obj: int) -> str | None:
    """Why object ``obj`` cannot see itself in its own reflection, or None if it might.

    True (a reason string) when the object has flat normals (so a reflected ray leaves on
    the side of the face plane the ray came from), its vertices lie on one closed side of
    every face plane (convex, checked in float64 with a tolerance of 1e-6 of the object's
    bounding-box diagonal), and either all its faces are coplanar, or it is closed (every
    edge shared by two faces, vertices welded by position) and every camera of the scene is
    strictly outside it. Then a camera ray hits it from outside and the reflected ray moves
    away from every face plane, so it can never hit the object again.
    """
    o = scene.objects[obj]
    if o.smooth:
        return None
    mask = np.asarray(scene.face_object) == obj
    F = np.asarray(scene.faces)[mask]
    if len(F) == 0:
        return None
    V = np.asarray(scene.vertices, np.float64)
    P = V[np.unique(F)]
    tol = 1e-6 * max(float(np.linalg.norm(P.max(0) - P.min(0))), 1e-30)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    keep = ln > 0
    n, a = n[keep] / ln[keep, None], a[keep]
    if len(n) == 0 or len(n) * len(P) > 20_000_000:
        return None                                           # degenerate, or too big to check
    dist = np.einsum("fk,fvk->fv", n, P[None, :, :] - a[:, None, :])   # (faces, vertices)
    above, below = dist.max(1) > tol, dist.min(1) < -tol
    if np.any(above & below):
        return None                                           # not convex
    if not np.any(above | below):
        return f"object {o.name!r} is a flat planar mirror"
    if not _welded_edges_closed(V, F):
        return None
    side = np.where(above, 1.0, -1.0)                        # where the solid lies
    for cam in scene.cameras:
        dc = np.einsum("fk,fk->f", n, np.asarray(cam.position, np.float64)[None, :] - a)
        if not np.any(side * dc < -tol):
            return None                                       # a camera inside the mirror
    return f"object {o.name!r} is a closed convex mirror with flat faces, every camera outside"


def reachable_depth(scene: Scene) -> tuple[int, str]:
    """The deepest bounce a ray can reach, and why (for a scene with secondary rays).

    ``max_depth`` in general. Capped at 1 when every face whose material reflects belongs to
    one object, no used material transmits, and that object cannot see itself
    (``convex_mirror``): only camera rays can hit a mirror then, and a reflected ray ends at
    its first (non-reflective) hit. The cap holds for the scene's own cameras.
    """
    md = int(scene.settings.max_depth)
    mats = scene.materials
    fm = np.asarray(scene.face_material)
    spec_mat = np.array([m.reflective or m.transmissive for m in mats], bool)
    if md <= 1 or any(m.transmissive for i, m in enumerate(mats) if np.any(fm == i)):
        return md, f"max_depth {md}"
    spec_faces = spec_mat[fm]
    objs = np.unique(np.asarray(scene.face_object)[spec_faces])
    if len(objs) != 1:
        return md, f"max_depth {md}"
    why = convex_mirror(scene, int(objs[0]))
    if why is None:
        return md, f"max_depth {md}"
    return 1, f"capped at 1 (max_depth {md}): {why} and nothing else reflects or transmits"
