"""Mitsuba 3 XML scenes: the subset that maps onto this project's model (docs/scene-format.md,
"Mitsuba XML").

``load_xml(path, defines=..., approximate=...)`` parses the file with ``xml.parsers.expat``
(every element keeps its line), substitutes ``$name`` parameters (``<default>`` values,
overridden by ``defines`` like Mitsuba's ``-D name=value``), resolves ``<ref id>`` (a cycle
is an error) and builds a ``Scene`` in physical shading:

- ``sensor`` ``perspective``: ``to_world`` (``lookat``, ``matrix``, ``translate``,
  ``rotate``, ``scale``), ``fov`` + ``fov_axis`` (x, y, diagonal, smaller, larger), the
  ``hdrfilm`` size; ``sampler`` and ``rfilter`` are not read: exact and
  converged sampling are the renderer's settings (a non-box filter gets a warning);
- ``emitter`` ``point`` (``position`` or ``to_world``, ``intensity``): a point light,
  inverse-square, W/sr; other emitter types are refused (``EMITTERS``);
- ``emitter`` ``area`` (``radiance``) on a ``sphere`` (``center``, ``radius``, a uniformly
  scaling ``to_world``) or ``rectangle`` (``to_world``, ``flip_normals``) shape: a sphere or
  rectangle light (docs/MODEL.md, "Lights with extent": intensity ``L_e π r²`` or
  ``L_e A``); two rectangles back to back with the same radiance are one two-sided light.
  Nested in the ``whitted`` integrator (what ``whitted export`` writes) the shape is the
  light exactly; at the top level (Mitsuba's usual place) it is read as the light with a
  warning, since our lights are not geometry (no ray sees them or is blocked by them);
- ``bsdf``: ``diffuse``, ``twosided``, ``conductor`` (``material = "none"``), ``dielectric``
  (Fresnel glass) and the project's ``whitted_phong`` / ``whitted_material`` (what ``whitted
  export`` writes); rough BSDFs and named conductors are refused, or with ``approximate``
  rendered as their smooth counterpart;
- ``shape``: ``obj``, ``ply``, ``rectangle``, ``cube`` (meshes, exact), ``sphere`` and
  ``disk`` (tessellated: an approximation, one warning), with ``to_world``,
  ``face_normals``, ``flip_normals`` and a ``bsdf`` child or ``ref``;
- ``integrator``: ``direct`` (the Whitted tree without specular children: max_depth 0;
  ``emitter_samples`` a perfect square is ``shadow_samples``), ``whitted`` (the
  project's, with ``shadow_samples`` and its nested light shapes), ``path`` refused
  (``approximate``: a Whitted tree of depth max_depth - 2, which lacks the indirect
  diffuse light).

Anything else is one ``SceneError`` line naming the file, line and element and what is done
instead. Nothing here imports Mitsuba.
"""
from __future__ import annotations

import math
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import loader, meshio, model, shapes
from . import parts as mesh_parts
from .model import Assembly, Camera, Material, PointLight, Scene, SceneError, Settings

__all__ = ["EMITTERS", "SHAPES", "BSDFS", "INTEGRATORS", "load_xml", "parse_defines"]


@dataclass
class Node:
    """One XML element: tag, attributes (after ``$name`` substitution), children, line."""

    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)


class _Ctx:
    """The file being read, its ids, parameters and options, with errors naming file and
    line."""

    def __init__(self, path: Path, approximate: bool):
        self.path, self.approximate = path, approximate
        self.ids: dict[str, Node] = {}
        self.resolving: list[str] = []
        self.sources: list[Path] = [path.resolve()]

    def error(self, node: Node | int, message: str) -> SceneError:
        line = node if isinstance(node, int) else node.line
        return SceneError(f"{self.path}:{line}: {message}")

    def warn(self, node: Node, message: str) -> None:
        warnings.warn(f"{self.path}:{node.line}: {message}", stacklevel=4)

    def approx(self, node: Node, what: str, instead: str) -> None:
        """Refuse ``what`` unless approximations are asked for; then warn."""
        if not self.approximate:
            raise self.error(node, f"{what} is outside the model's subset: refused (with "
                                   f"--approximate: {instead})")
        self.warn(node, f"{what} approximated: {instead}")


# ---- parsing ---------------------------------------------------------------------------------
def parse_defines(items) -> dict[str, str]:
    """``["name=value", ...]`` (``-D`` options) as a dict. Raises SceneError."""
    out = {}
    for item in items or ():
        name, eq, value = item.partition("=")
        if not eq or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise SceneError(f"-D {item}: expected NAME=VALUE", field="-D")
        out[name] = value
    return out


def _parse(path: Path) -> Node:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{path}: file not found") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read: {e.strerror}") from None
    parser = xml.parsers.expat.ParserCreate()
    stack: list[Node] = [Node("#document", {}, 0)]

    def start(tag, attrs):
        node = Node(tag, dict(attrs), parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(tag):
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise SceneError(f"{path}:{e.lineno}: XML syntax error: "
                         f"{xml.parsers.expat.ErrorString(e.code)}") from None
    doc = stack[0]
    if len(doc.children) != 1 or doc.children[0].tag != "scene":
        raise SceneError(f"{path}:1: expected one <scene> root element (Mitsuba 3 XML)")
    return doc.children[0]


_PARAM = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def _substitute(ctx: _Ctx, node: Node, params: dict[str, str]) -> None:
    """``$name`` in every attribute value, in document order (a ``<default>`` applies from
    where it stands, as in Mitsuba)."""
    for child in node.children:
        if child.tag == "default":
            name, value = child.attrs.get("name"), child.attrs.get("value")
            if name is None or value is None:
                raise ctx.error(child, "<default> needs 'name' and 'value'")
            params.setdefault(name, value)      # -D values come first and win
            continue

        def sub(m, child=child):
            if m.group(1) not in params:
                raise ctx.error(child, f"${m.group(1)}: parameter has no value (add "
                                       f"<default name=\"{m.group(1)}\" value=\"...\"/> or "
                                       f"pass -D {m.group(1)}=...)")
            return params[m.group(1)]

        child.attrs = {k: _PARAM.sub(sub, v) for k, v in child.attrs.items()}
        _substitute(ctx, child, params)


def _collect_ids(ctx: _Ctx, node: Node) -> None:
    for child in node.children:
        if "id" in child.attrs and child.tag not in ("ref",):
            if child.attrs["id"] in ctx.ids:
                raise ctx.error(child, f"duplicate id {child.attrs['id']!r} (first at line "
                                       f"{ctx.ids[child.attrs['id']].line})")
            ctx.ids[child.attrs["id"]] = child
        _collect_ids(ctx, child)


# ---- values ----------------------------------------------------------------------------------
def _attr(ctx: _Ctx, node: Node, key: str) -> str:
    if key not in node.attrs:
        raise ctx.error(node, f"<{node.tag}> needs a {key!r} attribute")
    return node.attrs[key]


def _num(ctx: _Ctx, node: Node, text: str, what: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise ctx.error(node, f"{what}: expected a number, got {text!r}") from None
    if not math.isfinite(x):
        raise ctx.error(node, f"{what}: expected a finite number, got {text!r}")
    return x


def _nums(ctx: _Ctx, node: Node, text: str, what: str, n: int | None = None) -> np.ndarray:
    vals = [t for t in re.split(r"[,\s]+", text.strip()) if t]
    out = np.array([_num(ctx, node, t, what) for t in vals])
    if n is not None and len(out) != n:
        raise ctx.error(node, f"{what}: expected {n} numbers, got {text!r}")
    return out


def _xyz(ctx: _Ctx, node: Node, what: str, default: float = 0.0) -> np.ndarray:
    if "value" in node.attrs:
        v = _nums(ctx, node, node.attrs["value"], what)
        if len(v) == 1:
            return np.full(3, v[0])
        if len(v) != 3:
            raise ctx.error(node, f"{what}: expected 1 or 3 numbers, got "
                                  f"{node.attrs['value']!r}")
        return v
    return np.array([_num(ctx, node, node.attrs.get(a, str(default)), f"{what}.{a}")
                     for a in "xyz"])


@dataclass
class _Props:
    """The properties of one object element, by name, each with its node."""

    nodes: dict
    objects: list          # (tag, node) of nested objects and refs, in order

    def has(self, name: str) -> bool:
        return name in self.nodes


_PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point",
                  "vector", "transform")
_OBJECT_TAGS = ("bsdf", "shape", "emitter", "sensor", "integrator", "film", "sampler",
                "rfilter", "texture", "medium", "phase", "volume", "ref")


def _props(ctx: _Ctx, node: Node) -> _Props:
    nodes, objects = {}, []
    for child in node.children:
        if child.tag in _PROPERTY_TAGS:
            name = _attr(ctx, child, "name")
            if name in nodes:
                raise ctx.error(child, f"property {name!r} given twice (first at line "
                                       f"{nodes[name].line})")
            nodes[name] = child
        elif child.tag in _OBJECT_TAGS:
            objects.append(child)
        else:
            raise ctx.error(child, f"<{child.tag}> is not a Mitsuba scene element here")
    return _Props(nodes, objects)


class _Reader:
    """Typed access to one object's properties; ``done`` records the names read so the
    rest can be reported."""

    def __init__(self, ctx: _Ctx, node: Node):
        self.ctx, self.node, self.p = ctx, node, _props(ctx, node)
        self.done: set[str] = set()

    def _get(self, name, tags):
        n = self.p.nodes.get(name)
        if n is None:
            return None
        self.done.add(name)
        if n.tag not in tags:
            raise self.ctx.error(n, f"{self.what}.{name}: expected <{'> or <'.join(tags)}>, "
                                    f"got <{n.tag}>")
        return n

    @property
    def what(self) -> str:
        return f"<{self.node.tag} type=\"{self.node.attrs.get('type', '')}\">"

    def float(self, name, default=None, *, lo=None, lo_open=False):
        n = self._get(name, ("float", "integer"))
        if n is None:
            return default
        x = _num(self.ctx, n, _attr(self.ctx, n, "value"), name)
        if lo is not None and (x < lo or (lo_open and x == lo)):
            raise self.ctx.error(n, f"{name}: expected a number {'>' if lo_open else '>='} "
                                    f"{lo}, got {x:g}")
        return x

    def integer(self, name, default=None):
        n = self._get(name, ("integer",))
        if n is None:
            return default
        text = _attr(self.ctx, n, "value")
        try:
            return int(text)
        except ValueError:
            raise self.ctx.error(n, f"{name}: expected an integer, got {text!r}") from None

    def boolean(self, name, default=None):
        n = self._get(name, ("boolean",))
        if n is None:
            return default
        text = _attr(self.ctx, n, "value").lower()
        if text not in ("true", "false"):
            raise self.ctx.error(n, f"{name}: expected true or false, got {text!r}")
        return text == "true"

    def string(self, name, default=None):
        n = self._get(name, ("string",))
        return default if n is None else _attr(self.ctx, n, "value")

    def color(self, name, default=None):
        """rgb, a one-value spectrum or a float: float64 (3,) >= 0; a texture is refused."""
        for obj in self.p.objects:
            if obj.tag == "texture" and obj.attrs.get("name") == name:
                raise self.ctx.error(obj, f"{self.what}.{name}: textures are not supported "
                                          "(refused; use an <rgb> value)")
        n = self._get(name, ("rgb", "spectrum", "float"))
        if n is None:
            return None if default is None else np.full(3, default, float) \
                if np.ndim(default) == 0 else np.asarray(default, float)
        text = _attr(self.ctx, n, "value")
        if n.tag == "spectrum" and ":" in text:
            raise self.ctx.error(n, f"{name}: a sampled spectrum is outside the model (RGB "
                                    "only): refused")
        c = _nums(self.ctx, n, text, name)
        if len(c) == 1:
            c = np.full(3, c[0])
        if len(c) != 3:
            raise self.ctx.error(n, f"{name}: expected 1 or 3 values, got {text!r}")
        if np.any(c < 0):
            raise self.ctx.error(n, f"{name}: expected values >= 0, got {text!r}")
        return c

    def point(self, name):
        n = self._get(name, ("point", "vector"))
        return None if n is None else _xyz(self.ctx, n, name)

    def transform(self, name):
        n = self._get(name, ("transform",))
        return None if n is None else _transform(self.ctx, n)

    def node_of(self, name):
        return self.p.nodes.get(name)

    def rest(self, ignore=()) -> None:
        """Report properties that were not read: one warning each (ignored)."""
        for name, n in self.p.nodes.items():
            if name not in self.done and name not in ignore:
                self.ctx.warn(n, f"{self.what}: property {name!r} ignored (not part of the "
                                 "model)")


# ---- transforms ------------------------------------------------------------------------------
def _rotate_matrix(axis: np.ndarray, deg: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    t = math.radians(deg)
    c, s = math.cos(t), math.sin(t)
    x, y, z = a
    return np.array([[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                     [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                     [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]])


def look_at(origin, target, up) -> np.ndarray:
    """Mitsuba's ``look_at``: columns (left, up', dir, origin), dir = normalize(target -
    origin), left = normalize(up × dir), up' = dir × left."""
    d = target - origin
    d = d / np.linalg.norm(d)
    left = np.cross(up / np.linalg.norm(up), d)
    left = left / np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(d, left), d, origin
    return m


def _transform(ctx: _Ctx, node: Node) -> tuple[np.ndarray, dict | None]:
    """(4x4 matrix, the lookat (origin, target, up) when it is one lookat alone)."""
    m = np.eye(4)
    single_lookat = None
    steps = node.children
    for step in steps:
        t = np.eye(4)
        if step.tag == "translate":
            t[:3, 3] = _xyz(ctx, step, "translate")
        elif step.tag == "scale":
            s = _xyz(ctx, step, "scale", default=1.0)
            t[:3, :3] = np.diag(s)
        elif step.tag == "rotate":
            angle = _num(ctx, step, _attr(ctx, step, "angle"), "rotate.angle")
            axis = _xyz(ctx, step, "rotate")
            if not np.any(axis):
                raise ctx.error(step, "rotate: the axis is zero")
            t[:3, :3] = _rotate_matrix(axis, angle)
        elif step.tag == "matrix":
            v = _nums(ctx, step, _attr(ctx, step, "value"), "matrix")
            if len(v) == 9:
                t[:3, :3] = v.reshape(3, 3)
            elif len(v) == 16:
                t = v.reshape(4, 4)
            else:
                raise ctx.error(step, f"matrix: expected 9 or 16 numbers, got {len(v)}")
            if not np.allclose(t[3], [0, 0, 0, 1]):
                raise ctx.error(step, "matrix: a projective transform (last row not "
                                      "0 0 0 1) is refused")
        elif step.tag == "lookat":
            origin = _nums(ctx, step, _attr(ctx, step, "origin"), "lookat.origin", 3)
            target = _nums(ctx, step, _attr(ctx, step, "target"), "lookat.target", 3)
            up = _nums(ctx, step, step.attrs.get("up", "0 1 0"), "lookat.up", 3)
            d = target - origin
            if not np.any(d) or np.linalg.norm(np.cross(d, up)) <= 1e-12 * \
                    np.linalg.norm(d) * max(np.linalg.norm(up), 1e-300):
                raise ctx.error(step, "lookat: target equals origin, or up is zero or "
                                      "parallel to the viewing direction")
            t = look_at(origin, target, up)
            if len(steps) == 1:
                single_lookat = {"origin": origin, "target": target, "up": up}
        else:
            raise ctx.error(step, f"<{step.tag}> is not a transform step (translate, scale, "
                                  "rotate, matrix, lookat)")
        m = t @ m
    if abs(np.linalg.det(m[:3, :3])) <= 1e-300:
        raise ctx.error(node, "to_world: singular transform")
    return m, single_lookat


# ---- objects ---------------------------------------------------------------------------------
def _deref(ctx: _Ctx, node: Node) -> Node:
    if node.tag != "ref":
        return node
    rid = _attr(ctx, node, "id")
    if rid not in ctx.ids:
        known = ", ".join(sorted(ctx.ids)) or "none"
        raise ctx.error(node, f"<ref id={rid!r}>: no object with that id (ids: {known})")
    if rid in ctx.resolving:
        chain = " -> ".join([*ctx.resolving[ctx.resolving.index(rid):], rid])
        raise ctx.error(node, f"<ref id={rid!r}>: a cycle of references ({chain})")
    return ctx.ids[rid]


def _bsdf(ctx: _Ctx, node: Node, name: str) -> Material:
    target = _deref(ctx, node)
    if target.tag != "bsdf":
        raise ctx.error(node, f"expected a <bsdf>, got <{target.tag}>")
    key = target.attrs.get("id") or name
    ctx.resolving.append(target.attrs.get("id", f"line{target.line}"))
    try:
        return _bsdf_of(ctx, target, key)
    finally:
        ctx.resolving.pop()


def _inner_bsdf(ctx: _Ctx, r: _Reader, name: str) -> Material:
    inner = [o for o in r.p.objects if o.tag in ("bsdf", "ref")]
    if len(inner) != 1:
        raise ctx.error(r.node, f"{r.what}: expected one nested <bsdf> (or <ref>), got "
                                f"{len(inner)}")
    return _bsdf(ctx, inner[0], name)


def _ior(ctx: _Ctx, r: _Reader, key: str, default: float) -> float:
    n = r.node_of(key)
    if n is None:
        return default
    if n.tag == "string":
        r.done.add(key)
        value = _attr(ctx, n, "value").lower()
        if value not in NAMED_IORS:
            raise ctx.error(n, f"{key}: unknown material {value!r} (known: "
                               f"{', '.join(sorted(NAMED_IORS))})")
        return NAMED_IORS[value]
    return r.float(key, default, lo=0.0, lo_open=True)


#: Mitsuba's named indices of refraction (``ior.h``) that its tutorials use.
NAMED_IORS = {"vacuum": 1.0, "air": 1.00028, "water": 1.3330, "bk7": 1.5046,
              "glass": 1.5046, "acrylic glass": 1.49, "polycarbonate": 1.58, "diamond": 2.419,
              "fused quartz": 1.458, "pyrex": 1.470, "ethanol": 1.361}

_ZERO = np.zeros(3)


def _bsdf_of(ctx: _Ctx, node: Node, name: str) -> Material:
    kind = node.attrs.get("type")
    r = _Reader(ctx, node)
    if kind == "twosided":
        m = _inner_bsdf(ctx, r, name)
        r.rest()
        return m
    if kind == "diffuse":
        kd = r.color("reflectance", 0.5)
        r.rest()
        return Material(name=name, ka=_ZERO.copy(), kd=kd, ks=_ZERO.copy())
    if kind in ("conductor", "roughconductor"):
        if kind == "roughconductor":
            ctx.approx(node, "<bsdf type=\"roughconductor\">", "a smooth mirror")
            r.done |= {"alpha", "alpha_u", "alpha_v", "distribution", "sample_visible"}
        material = r.string("material", "none")
        if material != "none" or r.has_any("eta", "k"):
            ctx.approx(node, f"conductor material {material!r} (Fresnel of a metal)",
                       "a perfect mirror scaled by specular_reflectance")
            r.done |= {"eta", "k"}
        k = r.color("specular_reflectance", 1.0)
        r.rest()
        return Material(name=name, ka=_ZERO.copy(), kd=_ZERO.copy(), ks=_ZERO.copy(),
                        k_refl=k)
    if kind in ("dielectric", "roughdielectric", "thindielectric"):
        if kind != "dielectric":
            ctx.approx(node, f"<bsdf type=\"{kind}\">", "a smooth dielectric")
            r.done |= {"alpha", "alpha_u", "alpha_v", "distribution", "sample_visible"}
        int_ior = _ior(ctx, r, "int_ior", 1.5046)
        ext_ior = _ior(ctx, r, "ext_ior", 1.000277)
        m = Material(name=name, ka=_ZERO.copy(), kd=_ZERO.copy(), ks=_ZERO.copy(),
                     k_refl=r.color("specular_reflectance", 1.0),
                     k_refr=r.color("specular_transmittance", 1.0), ior=int_ior / ext_ior,
                     combination="fresnel")
        r.rest()
        return m
    if kind == "whitted_phong":
        m = Material(name=name, ka=_ZERO.copy(), kd=r.color("kd", 0.5), ks=r.color("ks", 0.0),
                     n=r.float("n", 32.0, lo=0.0, lo_open=True))
        r.string("shading")
        r.rest()
        return m
    if kind == "whitted_material":
        local = [o for o in r.p.objects if o.tag in ("bsdf", "ref")]
        if not local:
            raise ctx.error(node, f"{r.what}: expected a nested local <bsdf name=\"local\">")
        base = _bsdf(ctx, local[0], name)
        m = replace(base, ka=r.color("ka", 0.0), k_refl=r.color("k_refl", 0.0),
                    k_refr=r.color("k_refr", 0.0),
                    ior=r.float("ior", 1.5, lo=0.0, lo_open=True),
                    combination=r.string("combination", "constant"))
        if m.combination not in ("constant", "fresnel"):
            raise ctx.error(r.node_of("combination"), f"combination: expected 'constant' or "
                                                      f"'fresnel', got {m.combination!r}")
        r.rest()
        return m
    if kind in ("plastic", "roughplastic", "principled", "blendbsdf", "mask", "bumpmap",
                "normalmap", "pplastic", "hair", "measured", "null", "polarizer",
                "retarder", "circular"):
        if kind in ("plastic", "roughplastic"):
            ctx.approx(node, f"<bsdf type=\"{kind}\">", "its diffuse part alone")
            kd = r.color("diffuse_reflectance", 0.5)
            return Material(name=name, ka=_ZERO.copy(), kd=kd, ks=_ZERO.copy())
        raise ctx.error(node, f"<bsdf type=\"{kind}\"> is outside the model's subset "
                              f"(supported: {', '.join(BSDFS)}): refused")
    raise ctx.error(node, f"<bsdf type=\"{kind}\">: unknown BSDF (supported: "
                          f"{', '.join(BSDFS)})")


def _has_any(self: _Reader, *names) -> bool:
    return any(n in self.p.nodes for n in names)


_Reader.has_any = _has_any

#: BSDF types read as the model's materials.
BSDFS = ("diffuse", "twosided", "conductor", "dielectric", "whitted_phong",
         "whitted_material")
#: Shape types read (meshes exact; sphere and disk tessellated).
SHAPES = ("obj", "ply", "rectangle", "cube", "sphere", "disk")
#: Emitter types read; the others are refused with one line (``_emitter``).
EMITTERS = ("point",)
#: Shapes an area emitter makes a light of (docs/MODEL.md, "Lights with extent").
LIGHT_SHAPES = ("sphere", "rectangle")
#: Integrator types read.
INTEGRATORS = ("direct", "whitted", "path")
#: Segments of a tessellated disk, geodesic frequency of a tessellated sphere.
DISK_SEGMENTS, SPHERE_FREQUENCY = 128, 16


# ---- the scene -------------------------------------------------------------------------------
@dataclass
class _Build:
    cameras: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    materials: list = field(default_factory=list)
    material_index: dict = field(default_factory=dict)
    parts: list = field(default_factory=list)
    normals: list = field(default_factory=list)
    names: set = field(default_factory=set)
    max_depth: int = 0
    min_weight: float = 0.01
    shading: str = "physical"
    ambient: np.ndarray = field(default_factory=lambda: np.zeros(3))
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    falloff_none: set = field(default_factory=set)
    shadow_samples: int = 1


def load_xml(path, *, shading: str | None = None, defines: dict | None = None,
             approximate: bool = False, cache=None) -> Scene:
    """Read a Mitsuba 3 XML scene (module docstring) as a ``Scene``. Raises SceneError
    whose message starts with ``<file>:<line>:``."""
    path = Path(path)
    ctx = _Ctx(path, approximate)
    root = _parse(path)
    _substitute(ctx, root, dict(defines or {}))
    _collect_ids(ctx, root)
    b = _Build()
    integrators = []
    for child in root.children:
        if child.tag == "default":
            continue
        if child.tag in _PROPERTY_TAGS:
            raise ctx.error(child, f"<{child.tag}> at the top level of <scene> is not a "
                                   "scene element")
        tag = child.tag
        if tag == "integrator":
            integrators.append(child)
        elif tag == "sensor":
            b.cameras.append(_sensor(ctx, child, len(b.cameras)))
        elif tag == "emitter":
            _emitter(ctx, child, b)
        elif tag == "shape":
            _shape(ctx, child, b)
        elif tag == "bsdf" or tag == "texture":
            if "id" not in child.attrs:
                ctx.warn(child, f"<{tag}> without an id at the top level is unused")
        elif tag == "include":
            raise ctx.error(child, "<include> is not supported: refused (paste the file in)")
        elif tag == "ref":
            raise ctx.error(child, "<ref> at the top level is not supported (instances)")
        else:
            raise ctx.error(child, f"<{tag}> is outside the model's subset: refused")
    if len(integrators) > 1:
        raise ctx.error(integrators[1], "a second <integrator>")
    _integrator(ctx, integrators[0] if integrators else None, b, root)
    if not b.parts:
        raise ctx.error(root, "the scene has no shapes")
    mode = shading or b.shading
    if mode not in ("classic", "physical"):
        raise SceneError(f"{path}: shading override: expected 'classic' or 'physical', got "
                         f"{mode!r}")
    lights = [replace(lt, falloff="none") if lt.name in b.falloff_none else lt
              for lt in _lights_in_order(_two_sided(b.lights))]
    if mode == "physical" and b.falloff_none:
        raise SceneError(f"{path}: physical shading needs inverse-square lights; the "
                         f"integrator's falloff_none names {sorted(b.falloff_none)}")
    settings = Settings(max_depth=b.max_depth, min_weight=b.min_weight, shading=mode,
                        background=b.background, shadow_samples=b.shadow_samples)
    scene = mesh_parts.assemble(path, b.parts, b.normals,
                                Assembly(cameras=b.cameras, settings=settings, lights=lights,
                                         materials=b.materials, ambient=b.ambient,
                                         sources=ctx.sources), cache=cache)
    return mesh_parts._frame_and_light(scene, path)


def _integrator(ctx: _Ctx, node: Node | None, b: _Build, root: Node) -> None:
    if node is None:
        ctx.approx(root, "no <integrator> (Mitsuba's default is 'path')",
                   "a Whitted tree of depth 3 (no indirect diffuse light)")
        b.max_depth = 3
        return
    kind = node.attrs.get("type")
    r = _Reader(ctx, node)
    if kind == "direct":
        n = r.integer("emitter_samples", 1)
        k = math.isqrt(max(n, 1))
        if n >= 1 and k * k == n:
            b.shadow_samples = n
        else:
            ctx.warn(r.node_of("emitter_samples"), f"emitter_samples {n}: shadow samples are "
                     f"k x k strata: {k * k} used")
            b.shadow_samples = k * k
        r.integer("bsdf_samples")
        r.boolean("hide_emitters")
        b.max_depth = 0
    elif kind == "whitted":
        b.max_depth = r.integer("max_depth", 5)
        b.min_weight = r.float("min_weight", 0.01, lo=0.0)
        b.shading = r.string("shading", "physical")
        b.background = r.color("background", 0.0)
        b.ambient = r.color("ambient", 0.0)
        names = r.string("falloff_none", "")
        b.falloff_none = {n for n in names.split(",") if n}
        b.shadow_samples = _shadow_samples(ctx, r)
        r.done |= {"spawn", "ray_offset"}
        for obj in r.p.objects:
            if obj.tag != "shape":
                raise ctx.error(obj, f"<{obj.tag}> inside <integrator type=\"whitted\">: "
                                     "only light shapes (a shape with an area emitter) go "
                                     "there")
            _area_light(ctx, obj, b, nested=True)
    elif kind == "path":
        depth = r.integer("max_depth", -1)
        whitted = 5 if depth < 0 else max(depth - 2, 0)
        ctx.approx(node, "<integrator type=\"path\">",
                   f"a Whitted tree of depth {whitted} (no indirect diffuse light)")
        r.done |= {"rr_depth", "hide_emitters"}
        b.max_depth = whitted
    else:
        raise ctx.error(node, f"<integrator type=\"{kind}\"> is outside the model's subset "
                              f"(supported: direct, whitted; path with --approximate): "
                              "refused")
    if not 0 <= b.max_depth <= 16:
        raise ctx.error(node, f"max_depth: expected 0..16, got {b.max_depth}")
    r.rest()


def _sensor(ctx: _Ctx, node: Node, i: int) -> Camera:
    kind = node.attrs.get("type")
    if kind != "perspective":
        raise ctx.error(node, f"<sensor type=\"{kind}\"> is outside the model's subset "
                              "(perspective only): refused")
    r = _Reader(ctx, node)
    if r.p.nodes.get("focal_length") is not None:
        raise ctx.error(r.p.nodes["focal_length"], "focal_length is not supported: give fov "
                                                   "(degrees) and fov_axis")
    if "fov" not in r.p.nodes:
        raise ctx.error(node, "<sensor type=\"perspective\"> needs a 'fov' (degrees)")
    fov = r.float("fov", lo=0.0, lo_open=True)
    if fov >= 180:
        raise ctx.error(r.p.nodes["fov"], f"fov: expected degrees in (0, 180), got {fov:g}")
    axis = r.string("fov_axis", "x")
    tr = r.transform("to_world")
    m, lk = tr if tr is not None else (np.eye(4), None)
    for key in ("principal_point_offset_x", "principal_point_offset_y"):
        if r.float(key, 0.0) != 0.0:
            raise ctx.error(r.p.nodes[key], f"{key}: an off-centre camera is refused")
    r.done |= {"near_clip", "far_clip", "shutter_open", "shutter_close"}
    width, height = 768, 576
    for obj in r.p.objects:
        target = _deref(ctx, obj)
        if target.tag == "film":
            fr = _Reader(ctx, target)
            if target.attrs.get("type") != "hdrfilm":
                ctx.warn(target, f"<film type=\"{target.attrs.get('type')}\">: only the size "
                                 "is read")
            width = fr.integer("width", 768)
            height = fr.integer("height", 576)
            if width < 1 or height < 1:
                raise ctx.error(target, f"film size {width} x {height}: expected >= 1")
            if fr.p.nodes.get("crop_width") or fr.p.nodes.get("crop_offset_x"):
                raise ctx.error(target, "a cropped film is refused")
            fr.done |= {"pixel_format", "component_format", "rfilter", "sample_border"}
            fr.rest()
            for sub in fr.p.objects:
                if sub.tag == "rfilter" and sub.attrs.get("type") != "box":
                    ctx.warn(sub, f"<rfilter type=\"{sub.attrs.get('type')}\"> ignored: "
                                  "converged renders use a box filter")
        elif target.tag == "sampler":
            pass        # sampling is the renderer's (exact: pixel centres; --spp: strata)
        else:
            raise ctx.error(obj, f"<{target.tag}> inside a sensor is not supported")
    aspect = width / height
    t = math.tan(math.radians(fov) / 2)
    if axis == "smaller":
        axis = "x" if aspect < 1 else "y"
    elif axis == "larger":
        axis = "x" if aspect > 1 else "y"
    if axis == "x":
        ty = t / aspect
    elif axis == "y":
        ty = t
    elif axis == "diagonal":
        ty = t / math.sqrt(1 + aspect * aspect)
    else:
        raise ctx.error(r.p.nodes["fov_axis"], f"fov_axis: expected x, y, diagonal, smaller "
                                                f"or larger, got {axis!r}")
    fov_y = math.degrees(2 * math.atan(ty))
    r.rest()
    if lk is not None:
        pos, target, up = lk["origin"], lk["target"], lk["up"]
    else:
        a = m[:3, :3]
        left, up, d = a[:, 0], a[:, 1], a[:, 2]
        if np.dot(np.cross(up, d), left) <= 0 or np.linalg.norm(d) == 0:
            raise ctx.error(node, "to_world: a mirrored camera frame is refused")
        pos, target = m[:3, 3].copy(), m[:3, 3] + d / np.linalg.norm(d)
    name = node.attrs.get("id", f"view{i}")
    return Camera(position=np.asarray(pos, float), target=np.asarray(target, float),
                  up=np.asarray(up, float), fov_y=fov_y, width=width, height=height,
                  name=name)


def _emitter(ctx: _Ctx, node: Node, b: _Build) -> None:
    kind = node.attrs.get("type")
    if kind not in EMITTERS:
        what = {"area": "an area emitter belongs inside a <shape> (sphere or rectangle)",
                "constant": "an environment light has no Whitted equivalent",
                "envmap": "an environment map has no Whitted equivalent"}.get(
                    kind, "outside the model's point lights")
        raise ctx.error(node, f"<emitter type=\"{kind}\">: {what}: refused (point emitters "
                              "only)")
    r = _Reader(ctx, node)
    pos = r.point("position")
    tr = r.transform("to_world")
    if pos is None:
        pos = np.zeros(3) if tr is None else tr[0][:3, 3].copy()
    elif tr is not None:
        raise ctx.error(node, "point emitter: give either position or to_world")
    intensity = r.color("intensity", 1.0)
    r.rest()
    name = node.attrs.get("id", f"light{len(b.lights)}")
    b.lights.append(PointLight(position=pos, intensity=intensity, falloff="inverse_square",
                               name=name))


def _shadow_samples(ctx: _Ctx, r: _Reader) -> int:
    n = r.integer("shadow_samples", 1)
    try:
        model.validate_settings(shadow_samples=n, where="integrator")
    except SceneError as e:
        raise ctx.error(r.node_of("shadow_samples"), str(e)) from None
    return n


def _area_light(ctx: _Ctx, node: Node, b: _Build, *, nested: bool) -> None:
    """A ``sphere`` or ``rectangle`` shape carrying an ``area`` emitter as our light of that
    shape (module docstring); its BSDF, if any, is not read (lights are not geometry)."""
    kind = node.attrs.get("type")
    if kind not in LIGHT_SHAPES:
        raise ctx.error(node, f"<shape type=\"{kind}\"> as a light: lights with extent are "
                              f"{' and '.join(LIGHT_SHAPES)} shapes: refused")
    r = _Reader(ctx, node)
    emitters = [o for o in r.p.objects if o.tag == "emitter"]
    for o in r.p.objects:
        if o.tag not in ("emitter", "bsdf", "ref"):
            raise ctx.error(o, f"<{o.tag}> inside a light's shape is not supported: refused")
    if len(emitters) != 1:
        raise ctx.error(node, f"<shape type=\"{kind}\"> as a light needs one <emitter "
                              f"type=\"area\">, got {len(emitters)}")
    em = emitters[0]
    if em.attrs.get("type") != "area":
        raise ctx.error(em, f"<emitter type=\"{em.attrs.get('type')}\"> on a shape: only "
                            "an area emitter makes a light of it: refused")
    er = _Reader(ctx, em)
    radiance = er.color("radiance", 1.0)
    er.rest()
    tr = r.transform("to_world")
    m = np.eye(4) if tr is None else tr[0]
    flip = bool(r.boolean("flip_normals", False))
    name = node.attrs.get("id") or f"light{len(b.lights)}"
    if kind == "sphere":
        centre = r.point("center")
        radius = r.float("radius", 1.0, lo=0.0, lo_open=True)
        a = m[:3, :3] * radius
        scale = np.linalg.norm(a, axis=0)
        if not np.allclose(a.T @ a, scale[0] ** 2 * np.eye(3), rtol=0,
                           atol=1e-9 * scale.max() ** 2):
            raise ctx.error(node, "to_world: a sphere light scales uniformly (an ellipsoid "
                                  "is outside the model): refused")
        if flip:
            raise ctx.error(r.node_of("flip_normals"), "flip_normals: a sphere light "
                            "emitting inwards lights nothing outside it: refused")
        c = m[:3, :3] @ (np.zeros(3) if centre is None else centre) + m[:3, 3]
        radius = float(scale[0])
        light = PointLight(position=c, intensity=radiance * (math.pi * radius * radius),
                           shape="sphere", radius=radius, name=name)
    else:
        eu, ev = 2.0 * m[:3, 0], 2.0 * m[:3, 1]
        normal = np.linalg.inv(m[:3, :3]).T @ np.array([0.0, 0.0, 1.0])
        if flip:
            normal = -normal
        if np.dot(normal, np.cross(eu, ev)) < 0:       # the side Mitsuba's normal faces
            eu, ev = ev, eu
        area = float(np.linalg.norm(np.cross(eu, ev)))
        light = PointLight(position=m[:3, 3].copy(), intensity=radiance * area,
                           shape="rectangle", edge_u=eu, edge_v=ev, name=name)
    r.rest()
    if name in {lt.name for lt in b.lights}:
        raise ctx.error(node, f"duplicate light id {name!r}")
    b.lights.append(light)


def _two_sided(lights: list) -> list:
    """Two rectangle lights back to back (same centre and radiance, edges swapped: what
    ``whitted export`` writes for a two-sided light, ``<id>`` and ``<id>_back``) as one
    two-sided light named after the first of them without ``_back``."""
    out, used = [], set()
    for i, a in enumerate(lights):
        if i in used:
            continue
        if a.shape == "rectangle" and not a.two_sided:
            for j in range(i + 1, len(lights)):
                c = lights[j]
                if j not in used and c.shape == "rectangle" and not c.two_sided and \
                        np.array_equal(a.position, c.position) and \
                        np.array_equal(a.edge_u, c.edge_v) and \
                        np.array_equal(a.edge_v, c.edge_u) and \
                        np.array_equal(a.intensity, c.intensity):
                    used.add(j)
                    front = a if not a.name.endswith("_back") else c
                    a = replace(front, name=front.name.removesuffix("_back"),
                                two_sided=True)
                    if front is c:          # keep the front's orientation
                        a = replace(a, edge_u=c.edge_u, edge_v=c.edge_v)
                    break
        out.append(a)
    return out


def _lights_in_order(lights: list) -> list:
    """Lights named ``light<i>`` (every one: ``whitted export``'s ids) in the order of
    ``i``, the scene's own order; otherwise in the file's order."""
    idx = [re.fullmatch(r"light(\d+)", lt.name) for lt in lights]
    if all(idx):
        return [lt for _, lt in sorted(zip((int(m.group(1)) for m in idx), lights),
                                       key=lambda p: p[0])]
    return lights


def _material_index(ctx: _Ctx, b: _Build, shape: Node, r: _Reader) -> int:
    refs = [o for o in r.p.objects if o.tag in ("bsdf", "ref")]
    for o in r.p.objects:
        if o.tag == "emitter":
            raise ctx.error(o, f"<emitter type=\"{o.attrs.get('type')}\"> on a "
                               f"<shape type=\"{shape.attrs.get('type')}\">: lights with "
                               f"extent are {' and '.join(LIGHT_SHAPES)} shapes with an "
                               "area emitter: refused")
        if o.tag not in ("bsdf", "ref"):
            raise ctx.error(o, f"<{o.tag}> inside a shape is not supported: refused")
    if len(refs) > 1:
        raise ctx.error(refs[1], "a shape takes one <bsdf>")
    if not refs:
        key = "#default"
        if key not in b.material_index:
            b.material_index[key] = len(b.materials)
            b.materials.append(Material(name="default", ka=np.zeros(3), kd=np.full(3, 0.5),
                                        ks=np.zeros(3)))
        return b.material_index[key]
    node = refs[0]
    target = _deref(ctx, node)
    key = target.attrs.get("id") or f"#line{target.line}"
    if key not in b.material_index:
        name = target.attrs.get("id") or f"bsdf{len(b.materials)}"
        b.material_index[key] = len(b.materials)
        b.materials.append(_bsdf(ctx, node, name))
    return b.material_index[key]


def _shape(ctx: _Ctx, node: Node, b: _Build) -> None:
    kind = node.attrs.get("type")
    if kind not in SHAPES:
        raise ctx.error(node, f"<shape type=\"{kind}\"> is outside the model's subset "
                              f"(supported: {', '.join(SHAPES)}): refused")
    if kind in LIGHT_SHAPES and any(c.tag == "emitter" for c in node.children):
        ctx.warn(node, f"<shape type=\"{kind}\"> with an emitter read as a {kind} light: "
                       "lights are not geometry here (no ray sees the shape or is blocked "
                       "by it), unlike Mitsuba's emitting shape")
        _area_light(ctx, node, b, nested=False)
        return
    r = _Reader(ctx, node)
    material = _material_index(ctx, b, node, r)
    tr = r.transform("to_world")
    m = np.eye(4) if tr is None else tr[0]
    flat = bool(r.boolean("face_normals", False))
    flip = bool(r.boolean("flip_normals", False))
    name = node.attrs.get("id") or f"{kind}{len(b.parts)}"
    if kind in ("obj", "ply"):
        fname = r.string("filename")
        if fname is None:
            raise ctx.error(node, f"<shape type=\"{kind}\"> needs a 'filename'")
        mesh = ctx.path.parent / fname
        if not mesh.is_file():
            raise ctx.error(r.p.nodes["filename"], f"filename: file not found: {mesh}")
        r.done |= {"flip_tex_coords"}
        try:
            if kind == "obj":
                parts, normals = _obj_shape(ctx, node, mesh, m, material, flat, name, b)
            else:
                part, fn, _ = mesh_parts.ply_part(mesh, m, material=material, name=name,
                                                  flat=flat)
                if fn is None and not flat:
                    ctx.warn(node, f"{fname}: no vertex normals: averaged normals (Mitsuba "
                                   "weights them by angle: an approximation)")
                parts, normals = [part], [fn]
        except meshio.MeshError as e:
            raise ctx.error(node, str(e)) from None
        ctx.sources.append(mesh.resolve())
    else:
        verts, faces, smooth = _builtin(ctx, node, kind, r)
        world = verts @ m[:3, :3].T + m[:3, 3]
        if np.linalg.det(m[:3, :3]) < 0:
            faces = faces[:, [0, 2, 1]]
        parts = [loader._Part(name, kind, material, smooth and not flat, world, faces)]
        normals = [None]
    r.rest()
    for part, fn in zip(parts, normals):
        if part.name in b.names:
            raise ctx.error(node, f"duplicate shape id {part.name!r}")
        b.names.add(part.name)
        if flip:
            part.faces = part.faces[:, [0, 2, 1]]
            fn = None if fn is None else -fn
        b.parts.append(part)
        b.normals.append(fn)


def _obj_shape(ctx, node, mesh, m, material, flat, name, b):
    """An ``obj`` shape: one mesh with the shape's BSDF (Mitsuba ignores MTL files)."""
    mats: list[Material] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # usemtl / mtllib: Mitsuba ignores them
        parts, normals, _ = mesh_parts.obj_parts(mesh, mats, m, flat=flat, taken=set())
    if any(fn is None for fn in normals) and not flat:
        ctx.warn(node, f"{mesh.name}: faces without vertex normals: averaged normals "
                       "(Mitsuba weights them by angle: an approximation)")
    world = np.concatenate([p.world for p in parts])
    offsets = np.cumsum([0] + [len(p.world) for p in parts])
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets)])
    fn = None
    if all(n is not None for n in normals):
        fn = np.concatenate(normals)
    smooth = not flat and (fn is not None or any(p.smooth for p in parts))
    if fn is None and not flat:
        smooth = True            # Mitsuba computes vertex normals for a mesh without them
    return [loader._Part(name, "obj", material, smooth, world, faces)], [fn]


def _builtin(ctx: _Ctx, node: Node, kind: str, r: _Reader):
    """Object-space (vertices, faces, smooth) of Mitsuba's built-in shapes: ``rectangle``
    [-1, 1]² at z = 0 facing +z, ``cube`` [-1, 1]³, ``sphere`` (``center``, ``radius``),
    ``disk`` (unit, z = 0, facing +z)."""
    if kind == "rectangle":
        v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
        return v, np.array([[0, 1, 2], [2, 3, 0]]), False
    if kind == "cube":
        v, f = shapes.box()
        return v * 2.0, f, False
    if kind == "sphere":
        centre = r.point("center")
        radius = r.float("radius", 1.0, lo=0.0, lo_open=True)
        ctx.warn(node, f"<shape type=\"sphere\"> tessellated ({20 * SPHERE_FREQUENCY ** 2} "
                       "triangles, smooth normals): an approximation of Mitsuba's exact "
                       "sphere")
        v, f = shapes.sphere(frequency=SPHERE_FREQUENCY)
        v = v * radius + (np.zeros(3) if centre is None else centre)
        return v, f, True
    ctx.warn(node, f"<shape type=\"disk\"> tessellated ({DISK_SEGMENTS} segments): an "
                   "approximation of Mitsuba's exact disk")
    a = np.linspace(0, 2 * math.pi, DISK_SEGMENTS, endpoint=False)
    v = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([np.cos(a), np.sin(a), 0 * a], 1)])
    k = np.arange(DISK_SEGMENTS)
    f = np.stack([np.zeros_like(k), 1 + k, 1 + (k + 1) % DISK_SEGMENTS], 1)
    return v, f, False
