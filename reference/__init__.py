"""The Mitsuba 3 side of the check: scene translation and XML export (``mitsuba_scene``), our
plugins (``plugins``) and golden images (``golden``): only what talks to Mitsuba.

``reference`` may import ``renderer``; ``renderer`` never imports ``reference``. Mitsuba is
imported lazily through ``mitsuba_variant()`` so that ``import reference`` stays cheap, and
nothing here picks a variant or registers a plugin on import.
"""
from __future__ import annotations

#: Variants the harness renders with, best first (the GPU machine has only cuda_ad_rgb).
VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb")
#: Comparison modes: "exact" (one ray through each pixel centre in both renderers) and
#: "converged" (k x k stratified samples per pixel, box filter).
MODES = ("exact", "converged")


def mitsuba_variant(variant: str | None = None) -> str:
    """Select and return the Mitsuba variant: ``variant`` if given, else the one already
    set if it is one of ``VARIANTS``, else cuda_ad_rgb when CUDA is present, else
    llvm_ad_rgb. Registers the project's plugins for it."""
    import drjit as dr
    import mitsuba as mi

    if variant is None:
        current = mi.variant()
        if current in VARIANTS:
            variant = current
        elif dr.has_backend(dr.JitBackend.CUDA) and "cuda_ad_rgb" in mi.variants():
            variant = "cuda_ad_rgb"
        else:
            variant = "llvm_ad_rgb"
    if variant not in mi.variants():
        raise RuntimeError(f"Mitsuba variant {variant!r} is not available "
                           f"(have {mi.variants()})")
    if mi.variant() != variant:
        mi.set_variant(variant)
    from . import plugins
    plugins.register()
    return variant
