"""Wavefront OBJ with its MTL materials, read as groups of faces that share an object name,
a material and a smoothing group (docs/scene-format.md, "OBJ + MTL").

``read_obj(path)`` returns an ``ObjFile``: positions, ``vn`` normals and one ``ObjGroup``
per (``o``/``g`` name, ``usemtl`` name, smoothing group) in the order they first appear;
``read_mtl(path)`` returns the ``Material`` of every ``newmtl`` with the ``illum`` mapping of
``ILLUM``. Statements outside what the model renders (``vt``, ``map_*`` textures, ``l``,
``p``, curves, unknown keywords) are collected as warnings naming the file and the first line
(one per keyword, with the count). Malformed lines raise ``MeshError`` with file:line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .meshio import MeshError
from .model import Material

__all__ = ["ILLUM", "ObjFile", "ObjGroup", "read_mtl", "read_obj", "mtl_material"]

#: What each MTL ``illum`` model becomes (docs/scene-format.md has the same table):
#: ("renders" | "approximates" | "refuses", how).
ILLUM = {
    0: ("approximates", "colour without lighting: rendered as illum 1 (Kd lit by the lights)"),
    1: ("renders", "diffuse: ka = Ka, kd = Kd"),
    2: ("renders", "Phong: ka = Ka, kd = Kd, ks = Ks, n = Ns"),
    3: ("renders", "Phong + ray-traced mirror: k_refl = Ks"),
    4: ("renders", "Phong + ray-traced glass: k_refl = Ks, k_refr = Tf (else 1 - d), "
                   "ior = Ni, constant weights"),
    5: ("approximates", "Fresnel mirror: a perfect mirror k_refl = Ks (the model has no "
                        "conductor Fresnel term)"),
    6: ("renders", "Phong + ray-traced refraction: as illum 4"),
    7: ("renders", "Fresnel glass: as illum 4 with combination 'fresnel'"),
    8: ("approximates", "mirror without ray tracing: rendered as illum 3 (ray traced)"),
    9: ("approximates", "glass without ray tracing: rendered as illum 4 (ray traced)"),
    10: ("refuses", "shadows cast onto invisible surfaces: not in the model"),
}

_MTL_IGNORED = ("Ke", "Pr", "Pm", "Ps", "Pc", "Pcr", "aniso", "anisor", "sharpness", "Tr",
                "norm", "bump", "disp", "decal", "refl")


@dataclass
class ObjGroup:
    """Faces sharing an object name, a material and a smoothing group.

    name: the ``o``/``g`` name in force ("" before any). material: the ``usemtl`` name or
    None. smoothing: the ``s`` group number (0 = off). material_line: the line of the
    ``usemtl``. faces: int64 (F, 3) position indices;
    normals: int64 (F, 3) ``vn`` indices, -1 where a face vertex has none."""

    name: str
    material: str | None
    smoothing: int
    material_line: int = 0
    faces: list = field(default_factory=list)
    normals: list = field(default_factory=list)


@dataclass
class ObjFile:
    """An OBJ file: float64 (V, 3) ``positions``, float64 (N, 3) ``vn`` ``normals``, the
    groups, the ``mtllib`` files named (with the line naming them) and warnings."""

    path: Path
    positions: np.ndarray
    normals: np.ndarray
    groups: list[ObjGroup]
    mtllibs: list[tuple[str, int]]
    warnings: list[str]


class _Ignored:
    """Statements that are read but not used: one warning per keyword, first line and
    count."""

    def __init__(self, path: Path):
        self.path, self.first, self.count, self.why = path, {}, {}, {}

    def add(self, key: str, lineno: int, why: str) -> None:
        self.first.setdefault(key, lineno)
        self.count[key] = self.count.get(key, 0) + 1
        self.why.setdefault(key, why)

    def lines(self) -> list[str]:
        out = []
        for key, line in self.first.items():
            n = self.count[key]
            more = f" (and {n - 1} more)" if n > 1 else ""
            out.append(f"{self.path}:{line}: '{key}' ignored{more}: {self.why[key]}")
        return out


def _floats(path, lineno, parts, n, what) -> list[float]:
    try:
        vals = [float(p) for p in parts[:n]]
    except ValueError:
        raise MeshError(f"{path}:{lineno}: '{what}' expects {n} numbers, got "
                        f"{' '.join(parts)!r}") from None
    if len(vals) < n:
        raise MeshError(f"{path}:{lineno}: '{what}' expects {n} numbers, got "
                        f"{' '.join(parts)!r}")
    if not all(math.isfinite(v) for v in vals):
        raise MeshError(f"{path}:{lineno}: '{what}' values must be finite, got "
                        f"{' '.join(parts)!r}")
    return vals


def read_obj(path) -> ObjFile:
    """Read ``path`` as an OBJ file with groups, normals and smoothing groups (module
    docstring). Polygons become fans ``(p0, p[i], p[i+1])``. Raises ``MeshError``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise MeshError(f"{path}: cannot read: {e.strerror}") from None
    ignored = _Ignored(path)
    pos: list[list[float]] = []
    nrm: list[list[float]] = []
    groups: dict[tuple, ObjGroup] = {}
    mtllibs: list[tuple[str, int]] = []
    name, material, smoothing, material_line = "", None, 0, 0
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        tag, args = parts[0], parts[1:]
        if tag == "v":
            if len(args) not in (3, 4, 6, 7):
                raise MeshError(f"{path}:{lineno}: 'v' expects 3 coordinates, got {line!r}")
            pos.append(_floats(path, lineno, args, 3, "v"))
        elif tag == "vn":
            nrm.append(_floats(path, lineno, args, 3, "vn"))
        elif tag == "f":
            if len(args) < 3:
                raise MeshError(f"{path}:{lineno}: 'f' needs at least 3 vertices, got "
                                f"{line!r}")
            vi, ni = _face(path, lineno, args, len(pos), len(nrm), ignored)
            key = (name, material, smoothing)
            g = groups.get(key)
            if g is None:
                g = groups[key] = ObjGroup(name, material, smoothing, material_line)
            for k in range(1, len(vi) - 1):
                g.faces.append((vi[0], vi[k], vi[k + 1]))
                g.normals.append((ni[0], ni[k], ni[k + 1]))
        elif tag in ("o", "g"):
            name = " ".join(args)
        elif tag == "usemtl":
            if not args:
                raise MeshError(f"{path}:{lineno}: 'usemtl' needs a material name")
            material, material_line = " ".join(args), lineno
        elif tag == "mtllib":
            if not args:
                raise MeshError(f"{path}:{lineno}: 'mtllib' needs a file name")
            mtllibs.append((" ".join(args), lineno))
        elif tag == "s":
            word = args[0].lower() if args else "off"
            if word in ("off", "0"):
                smoothing = 0
            else:
                try:
                    smoothing = int(word)
                except ValueError:
                    raise MeshError(f"{path}:{lineno}: 's' expects a group number or "
                                    f"'off', got {line!r}") from None
        elif tag == "vt":
            ignored.add(tag, lineno, "texture coordinates (textures are not supported)")
        elif tag in ("l", "p"):
            ignored.add(tag, lineno, "lines and points are not rendered")
        elif tag in ("vp", "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm",
                     "trim", "hole", "scrv", "sp", "end", "con", "mg", "bevel", "c_interp",
                     "d_interp", "lod", "usemap", "maplib", "shadow_obj", "trace_obj",
                     "ctech", "stech"):
            ignored.add(tag, lineno, "free-form and display statements are not supported")
        else:
            ignored.add(tag, lineno, "unknown OBJ statement")
    positions = np.asarray(pos, np.float64).reshape(-1, 3)
    normals = np.asarray(nrm, np.float64).reshape(-1, 3)
    out = []
    for g in groups.values():
        g.faces = np.asarray(g.faces, np.int64).reshape(-1, 3)
        g.normals = np.asarray(g.normals, np.int64).reshape(-1, 3)
        out.append(g)
    return ObjFile(path, positions, normals, out, mtllibs, ignored.lines())


def _face(path, lineno, args, n_pos, n_nrm, ignored):
    """Position and normal indices (zero-based; normal -1 when absent) of one ``f`` line."""
    vi, ni = [], []
    for tok in args:
        fields = tok.split("/")
        if len(fields) > 3 or not fields[0]:
            raise MeshError(f"{path}:{lineno}: bad face vertex {tok!r}, expected an index "
                            "like 7, 7/2, 7/2/5 or 7//5")
        idx = []
        for k, (text, count) in enumerate(((fields[0], n_pos),
                                           (fields[2] if len(fields) == 3 else "", n_nrm))):
            if not text:
                idx.append(-1)
                continue
            try:
                i = int(text)
            except ValueError:
                raise MeshError(f"{path}:{lineno}: bad face vertex {tok!r}, expected an "
                                "index like 7, 7/2, 7/2/5 or 7//5") from None
            what = "vertex" if k == 0 else "normal"
            if i == 0:
                raise MeshError(f"{path}:{lineno}: face {what} index 0 (OBJ indices start "
                                "at 1; negative ones count back)")
            j = i - 1 if i > 0 else count + i
            if not 0 <= j < count:
                raise MeshError(f"{path}:{lineno}: face {what} index {i} out of range: "
                                f"{count} {what}s defined so far")
            idx.append(j)
        vi.append(idx[0])
        ni.append(idx[1])
    return vi, ni


# ---- MTL -------------------------------------------------------------------------------------
def read_mtl(path) -> tuple[dict[str, Material], list[str]]:
    """The materials of an MTL file by name (mapped as ``mtl_material``) and the warnings
    (ignored statements, approximated ``illum`` models), each naming file and line. Raises
    ``MeshError`` (file:line) for a malformed line or a refused ``illum``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise MeshError(f"{path}: cannot read: {e.strerror}") from None
    ignored = _Ignored(path)
    warn: list[str] = []
    found: list[tuple[str, int, dict]] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        tag, args = parts[0], parts[1:]
        if tag == "newmtl":
            if not args:
                raise MeshError(f"{path}:{lineno}: 'newmtl' needs a material name")
            found.append((" ".join(args), lineno, {}))
            continue
        if not found:
            raise MeshError(f"{path}:{lineno}: {tag!r} before any 'newmtl'")
        props = found[-1][2]
        if tag in ("Ka", "Kd", "Ks", "Tf"):
            if args and args[0] in ("spectral", "xyz"):
                raise MeshError(f"{path}:{lineno}: '{tag} {args[0]}' is not supported, "
                                "expected r g b")
            vals = _floats(path, lineno, args, 1, tag)
            if len(args) >= 3:
                vals = _floats(path, lineno, args, 3, tag)
            if len(args) not in (1, 3):
                raise MeshError(f"{path}:{lineno}: '{tag}' expects 1 or 3 numbers, got "
                                f"{line!r}")
            c = np.array(vals * 3 if len(vals) == 1 else vals, np.float64)
            if np.any(c < 0):
                raise MeshError(f"{path}:{lineno}: '{tag}' expects values >= 0, got {line!r}")
            props[tag] = (c, lineno)
        elif tag in ("Ns", "Ni", "d", "illum"):
            if len(args) != 1 and not (tag == "d" and len(args) == 2 and args[0] == "-halo"):
                raise MeshError(f"{path}:{lineno}: '{tag}' expects one number, got {line!r}")
            (v,) = _floats(path, lineno, args[-1:], 1, tag)
            props[tag] = (v, lineno)
        elif tag.startswith("map_") or tag in _MTL_IGNORED:
            why = ("textures are not supported" if tag.startswith("map_") or tag in (
                "bump", "disp", "decal", "refl", "norm") else "not part of the model")
            ignored.add(tag, lineno, why)
        else:
            ignored.add(tag, lineno, "unknown MTL statement")
    materials = {}
    for name, lineno, props in found:
        if name in materials:
            raise MeshError(f"{path}:{lineno}: duplicate material {name!r}")
        materials[name] = mtl_material(path, name, lineno, props, warn)
    return materials, ignored.lines() + warn


def mtl_material(path, name: str, lineno: int, props: dict, warn: list[str]) -> Material:
    """The ``Material`` of one ``newmtl`` block (``ILLUM``; docs/scene-format.md).

    props: keyword -> (value, line) for Ka, Kd, Ks, Tf (float64 (3,)), Ns, Ni, d, illum.
    Without ``illum``: 2 when Ks > 0, else 1. Appends a warning to ``warn`` for an
    approximated model or an unused dissolve; raises ``MeshError`` for a refused one."""
    def get(key, default):
        return props[key][0] if key in props else default

    zero = np.zeros(3)
    kd, ks = get("Kd", zero), get("Ks", zero)
    ka = get("Ka", kd)
    illum_line = props.get("illum", (None, lineno))[1]
    illum = get("illum", 2.0 if np.any(ks > 0) else 1.0)
    if illum != int(illum) or int(illum) not in ILLUM:
        raise MeshError(f"{path}:{illum_line}: material {name!r}: illum {illum:g}: expected "
                        "an integer 0..10")
    illum = int(illum)
    what, how = ILLUM[illum]
    if what == "refuses":
        raise MeshError(f"{path}:{illum_line}: material {name!r}: illum {illum} ({how}); "
                        "use illum 1-9")
    if what == "approximates":
        warn.append(f"{path}:{illum_line}: material {name!r}: illum {illum} approximated "
                    f"({how})")
    model = {0: 1, 8: 3, 9: 4}.get(illum, illum)
    ns = get("Ns", 32.0)
    if ns <= 0:
        ns = 1.0
        warn.append(f"{path}:{props['Ns'][1]}: material {name!r}: Ns <= 0 read as 1")
    ior = get("Ni", 1.5)
    if ior <= 0:
        raise MeshError(f"{path}:{props['Ni'][1]}: material {name!r}: Ni must be > 0, got "
                        f"{ior:g}")
    m = Material(name=name, ka=ka, kd=kd, ks=ks if model >= 2 else zero.copy(), n=ns, ior=ior)
    glass = model in (4, 6, 7)
    if model in (3, 5) or glass:
        m = _replace(m, k_refl=ks.copy())
    if glass:
        if "Tf" in props:
            tf = get("Tf", zero)
        elif "d" in props:
            tf = np.full(3, max(0.0, 1.0 - get("d", 1.0)))
        else:
            tf = np.ones(3)
        m = _replace(m, k_refr=tf, combination="fresnel" if model == 7 else "constant")
    elif "d" in props and get("d", 1.0) < 1.0:
        warn.append(f"{path}:{props['d'][1]}: material {name!r}: dissolve d = "
                    f"{get('d', 1.0):g} ignored (transparency needs illum 4, 6 or 7)")
    return m


def _replace(m: Material, **kw) -> Material:
    from dataclasses import replace
    return replace(m, **kw)
