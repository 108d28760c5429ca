"""Which effects a scene calls for, decided on the host before tracing.

``EffectSet.from_scene(scene)`` derives the set from the scene's materials, lights, objects
and settings alone; the integrator traces only the enabled effects (plain Python branches,
so Dr.Jit records only what runs). ``EffectSet.all()`` traces every effect (the general
kernel); ``without(name)`` drops one for debugging, with a warning, since the image then
differs from what the scene describes.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .scene import Scene

FLAGS = ("shadows", "ambient", "reflection", "refraction", "smooth_normals", "specular",
         "many_lights", "fresnel")


@dataclass(frozen=True)
class EffectSet:
    """Effects traced into the kernel.

    shadows: shadow rays (some light exists). ambient: ambient·ka is nonzero somewhere.
    reflection / refraction: some material has k_refl / k_refr > 0 and max_depth >= 1.
    smooth_normals: some object interpolates vertex normals. specular: some ks > 0 and a
    light exists. many_lights: more than one light. fresnel: some material uses Fresnel
    weights. physical: "physical" shading (else "classic").
    depth: deepest reachable bounce (0 without secondary rays).
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
        used = sorted(set(int(m) for m in np.unique(scene.face_material))) if scene.face_count else []
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
        r_refl = first(lambda m: m.reflective, used_mats, "material") if s.max_depth >= 1 else None
        r_refr = first(lambda m: m.transmissive, used_mats, "material") if s.max_depth >= 1 else None
        r_smooth = first(lambda o: o.smooth and o.face_count > 0, scene.objects, "object")
        r_spec = first(lambda m: np.any(m.ks > 0), used_mats, "material") if lights else None
        r_many = f"{len(lights)} lights" if len(lights) > 1 else None
        r_fres = first(lambda m: m.combination == "fresnel" and (m.reflective or m.transmissive),
                       used_mats, "material") if s.max_depth >= 1 else None
        for k, r in (("shadows", r_light), ("ambient", r_amb), ("reflection", r_refl),
                     ("refraction", r_refr), ("smooth_normals", r_smooth),
                     ("specular", r_spec), ("many_lights", r_many), ("fresnel", r_fres)):
            if r:
                reasons[k] = r
        secondary = bool(r_refl or r_refr)
        return cls(shadows=bool(r_light), ambient=bool(r_amb), reflection=bool(r_refl),
                   refraction=bool(r_refr), smooth_normals=bool(r_smooth),
                   specular=bool(r_spec), many_lights=bool(r_many), fresnel=bool(r_fres),
                   physical=s.shading == "physical",
                   depth=int(s.max_depth) if secondary else 0, reasons=reasons)

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

    def __str__(self) -> str:
        on = [k for k in FLAGS if getattr(self, k)]
        mode = "physical" if self.physical else "classic"
        tag = " (forced)" if self.forced else ""
        return f"effects[{mode}, depth {self.depth}{tag}]: " + (", ".join(on) or "local only")
