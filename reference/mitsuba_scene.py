"""Translate a ``Scene`` into a Mitsuba 3 scene, render it, export it as Mitsuba XML.

Built-ins wherever they mean the same thing as docs/MODEL.md: ``perspective`` sensor
(``fov_axis = "y"``, the same look-at), ``point`` emitters (W/sr), one ``mi.Mesh`` per object
(vertex normals only for smooth objects), ``conductor`` (``material = "none"``) and
``dielectric`` for the specular parts, an ``hdrfilm`` with a **box** filter. Two-sidedness is
explicit: the Phong lobe and the mirror are wrapped in ``twosided``, the dielectric is not.
Only the Phong lobe and the Whitted integrator are ours (``reference.plugins``).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from renderer.outputs import (
    OutputError,
    OutputExistsError,
    check_output_file,
    write_bytes,
    write_text,
)
from renderer.scene import Scene

from . import MODES


def _mi():
    from . import mitsuba_variant
    mitsuba_variant()
    import mitsuba as mi
    return mi


def _rgb(c) -> dict:
    return {"type": "rgb", "value": [float(x) for x in np.asarray(c, np.float64).reshape(3)]}


def _camera(scene: Scene, view: int):
    if not 0 <= view < len(scene.cameras):
        raise ValueError(f"{scene.path or scene.name}: view {view} out of range "
                         f"(scene has {len(scene.cameras)} cameras)")
    return scene.cameras[view]


def material_dict(mat, shading: str) -> dict:
    """The ``whitted_material`` dict of a ``renderer.scene.Material``."""
    local = {"type": "twosided",
             "bsdf": {"type": "whitted_phong", "shading": shading,
                      "kd": _rgb(mat.kd), "ks": _rgb(mat.ks), "n": float(mat.n)}}
    d = {"type": "whitted_material", "ka": _rgb(mat.ka), "k_refl": _rgb(mat.k_refl),
         "k_refr": _rgb(mat.k_refr), "ior": float(mat.ior),
         "combination": mat.combination, "local": local}
    if mat.transmissive:
        d["specular"] = {"type": "dielectric", "int_ior": float(mat.ior), "ext_ior": 1.0,
                         "specular_reflectance": _rgb(mat.k_refl),
                         "specular_transmittance": _rgb(mat.k_refr)}
    elif mat.reflective:
        d["specular"] = {"type": "twosided",
                         "bsdf": {"type": "conductor", "material": "none",
                                  "specular_reflectance": _rgb(mat.k_refl)}}
    return d


def _builtin_material_dict(scene: Scene, mat) -> dict:
    if mat.reflective or mat.transmissive or np.any(mat.ks > 0):
        raise ValueError(f"{scene.path or scene.name}: material {mat.name!r} is not "
                         f"diffuse-only (ks, k_refl, k_refr must be 0 for builtins=True)")
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(mat.kd)}}


def portable_problems(scene: Scene) -> list[str]:
    """The parts of ``scene`` that stock Mitsuba plugins cannot express with the same
    meaning, one line each naming the part, why, and the project's plugin it needs; empty
    when ``to_mitsuba_dict(..., portable=True)`` can write it (``portable_material_dict``)."""
    st = scene.settings
    out = []
    if st.shading != "physical":
        out.append(f"settings.shading {st.shading!r}: the classic lobe (no 1/pi, light "
                   "without falloff) has no stock BSDF → whitted_phong and the 'whitted' "
                   "integrator (try --shading physical)")
    if np.any(scene.ambient > 0):
        out.append("ambient: Whitted's constant ambient term has no stock equivalent → the "
                   "'whitted' integrator")
    if np.any(st.background > 0):
        out.append("settings.background: a colour seen by escaping rays that lights nothing "
                   "(a stock 'constant' emitter would light the scene) → the 'whitted' "
                   "integrator")
    for i, light in enumerate(scene.lights):
        if light.falloff != "inverse_square":
            out.append(f"lights[{i}] ({light.name!r}): falloff 'none' (stock 'point' "
                       "emitters fall off as 1/dist²) → the 'whitted' integrator")
        if light.extent:
            out.append(f"lights[{i}] ({light.name!r}): a {light.shape} light is invisible "
                       "and blocks nothing (a stock area emitter's shape is hit by every "
                       "ray) → the 'whitted' integrator")
    for m in scene.materials:
        diffuse = bool(np.any(m.kd > 0))
        if np.any(m.ks > 0):
            out.append(f"material {m.name!r}: Phong lobe (ks > 0) → whitted_phong")
        elif diffuse and (m.reflective or m.transmissive):
            out.append(f"material {m.name!r}: diffuse and specular parts in one material "
                       "→ whitted_material")
        elif m.transmissive and m.combination != "fresnel":
            out.append(f"material {m.name!r}: glass with constant weights (combination "
                       "'constant'; a stock dielectric always applies Fresnel) → "
                       "whitted_material")
    return out


def portable_material_dict(mat) -> dict:
    """The stock BSDF that means the same as ``mat`` in physical mode (``portable_problems``
    must be empty): twosided ``diffuse`` (kd), twosided ``conductor`` with ``material =
    "none"`` (a mirror: k_refl), ``dielectric`` (Fresnel glass: k_refl and k_refr scale the
    reflected and refracted lobes, as MODEL.md's ``fresnel`` weights do)."""
    if mat.transmissive:
        return {"type": "dielectric", "int_ior": float(mat.ior), "ext_ior": 1.0,
                "specular_reflectance": _rgb(mat.k_refl),
                "specular_transmittance": _rgb(mat.k_refr)}
    if mat.reflective:
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": _rgb(mat.k_refl)}}
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(mat.kd)}}


def portable_integrator(scene: Scene) -> tuple[dict, str | None]:
    """The stock integrator of a portable export and, when it does not mean the same as the
    Whitted tree, a one-line note saying how it differs: ``direct`` for a scene without
    mirrors or glass (the same image); ``path`` otherwise (Mitsuba has no stock Whitted
    integrator: ``path`` adds the indirect diffuse light a Whitted image lacks and has no
    ``min_weight`` pruning)."""
    st = scene.settings
    if not any(m.reflective or m.transmissive for m in scene.materials):
        return {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1}, None
    depth = int(st.max_depth) + 2      # camera segment + max_depth bounces + the light
    note = (f"integrator: stock 'path' (max_depth {depth}) for the mirror/glass rays; it "
            "adds indirect diffuse light and has no min_weight pruning, so it converges to "
            "a brighter image than the Whitted tree; the exact Whitted image needs the "
            "project's 'whitted' integrator (export without --portable)")
    return {"type": "path", "max_depth": depth, "rr_depth": depth}, note


def area_light_dicts(light, key: str) -> dict:
    """The Mitsuba shapes of a light with extent (docs/MODEL.md, "Lights with extent"),
    ``{id: shape dict}``, each carrying an ``area`` emitter of radiance ``L_e``: a ``sphere``
    (centre, radius), or a ``rectangle`` mapped onto the parallelogram (its ``[-1, 1]²``
    to ``c + x e_u/2 + y e_v/2``, normal along ``e_u × e_v``); a two-sided rectangle adds a
    second one with flipped normals (``<id>_back``). They are nested in the ``whitted``
    integrator, not in the scene: no ray hits them (lights are not geometry), and the
    integrator samples them with their own ``sample_direction``."""
    mi = _mi()
    emitter = {"type": "area", "radiance": _rgb(light.radiance)}
    if light.shape == "sphere":
        return {key: {"type": "sphere", "center": [float(v) for v in light.position],
                      "radius": float(light.radius), "emitter": emitter}}
    eu, ev = (np.asarray(e, np.float64) for e in (light.edge_u, light.edge_v))
    n = np.cross(eu, ev)
    n = n / np.linalg.norm(n)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = eu / 2, ev / 2, n, light.position
    rect = {"type": "rectangle", "to_world": mi.ScalarTransform4f(m.tolist()),
            "emitter": emitter}
    out = {key: rect}
    if light.two_sided:
        out[f"{key}_back"] = dict(rect, flip_normals=True, emitter=dict(emitter))
    return out


def mesh_parts(scene: Scene):
    """Per object and material: (key, object, material index, vertices float32 (V, 3),
    normals float32 (V, 3) or None, faces uint32 (F, 3) local indices)."""
    parts = []
    for i, obj in enumerate(scene.objects):
        fs = slice(obj.first_face, obj.first_face + obj.face_count)
        faces = scene.faces[fs].astype(np.int64)
        mats = scene.face_material[fs]
        for m in np.unique(mats):
            sel = faces[mats == m]
            used, local = np.unique(sel.reshape(-1), return_inverse=True)
            verts = scene.vertices[used].astype(np.float32)
            normals = scene.normals[used].astype(np.float32) if obj.smooth else None
            key = f"obj{i}" if len(np.unique(mats)) == 1 else f"obj{i}_m{int(m)}"
            parts.append((key, obj, int(m), verts, normals,
                          local.reshape(-1, 3).astype(np.uint32)))
    return parts


def sensor_dict(scene: Scene, *, view: int = 0, spp: int = 1, mode: str = "exact",
                seed: int = 0) -> dict:
    mi = _mi()
    cam = _camera(scene, view)
    diag = max(scene.diagonal, float(np.linalg.norm(cam.position - cam.target)), 1e-6)
    if mode == "converged":
        k = int(round(np.sqrt(spp)))
        if k * k != spp:
            raise ValueError(f"spp must be a perfect square (k x k strata), got {spp}")
        sampler = {"type": "stratified", "sample_count": int(spp), "seed": int(seed),
                   "jitter": True}
    else:
        sampler = {"type": "independent", "sample_count": 1, "seed": int(seed)}
    return {
        "type": "perspective", "fov": float(cam.fov_y), "fov_axis": "y",
        "near_clip": 1e-6 * diag, "far_clip": 1e6 * diag,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=[float(v) for v in cam.position], target=[float(v) for v in cam.target],
            up=[float(v) for v in cam.up]),
        "sampler": sampler,
        "film": {"type": "hdrfilm", "width": int(cam.width), "height": int(cam.height),
                 "pixel_format": "rgb", "component_format": "float32",
                 "rfilter": {"type": "box"}},
    }


#: The offset rule the reference used before it spawned rays natively (fraction of the
#: scene diagonal); ``spawn="fixed"`` only.
FIXED_RAY_EPSILON = 1e-4


def fixed_ray_offset(scene: Scene) -> float:
    """Absolute offset of ``spawn="fixed"``: the scene's ``ray_epsilon`` override, else
    ``FIXED_RAY_EPSILON``, times the scene diagonal."""
    eps = scene.settings.ray_epsilon
    return float((FIXED_RAY_EPSILON if eps is None else eps) * max(scene.diagonal, 1e-30))


def to_mitsuba_dict(scene: Scene, *, view: int = 0, spp: int = 1, mode: str = "exact",
                    seed: int = 0, builtins: bool = False, meshes: str = "objects",
                    portable: bool = False, overwrite: bool = False,
                    spawn: str = "mitsuba") -> dict:
    """A dict for ``mi.load_dict`` describing ``scene`` seen from ``cameras[view]``.

    mode: "exact" (one ray per pixel centre, driven by ``render_mitsuba``) or "converged"
    (``spp`` = k² stratified samples, box filter, ``mi.render``).
    builtins: no plugin of ours at all: twosided ``diffuse`` BSDFs and the ``direct``
    integrator (diffuse-only physical scenes with zero ambient and background only).
    meshes: "objects" (``mi.Mesh`` objects) or a folder path string to write .ply files into
    (atomically; an existing one is replaced only when ``overwrite``), referenced as
    ``<folder name>/<key>.ply``, relative to the folder's parent (``export_xml`` puts the
    XML there).
    portable: stock plugins only (``portable_material_dict``, ``portable_integrator``);
    ValueError listing ``portable_problems`` when some part needs our plugins.
    spawn: how the ``whitted`` integrator spawns secondary and shadow rays: "mitsuba"
    (Mitsuba's own ``spawn_ray`` / ``spawn_ray_to``: the goldens) or "fixed" (an absolute
    offset of ``FIXED_RAY_EPSILON`` × scene diagonal, or the scene's own ``ray_epsilon``
    override: only to study the reference, ``evaluation/speckles.py``).
    """
    mi = _mi()
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    st = scene.settings
    where = scene.path or scene.name
    d: dict = {"type": "scene"}
    if portable:
        problems = portable_problems(scene)
        if problems:
            raise ValueError(f"{where}: not portable to stock Mitsuba plugins: "
                             + "; ".join(problems))
        d["integrator"] = portable_integrator(scene)[0]
    elif builtins:
        if st.shading != "physical":
            raise ValueError(f"{where}: settings.shading must be 'physical' for builtins=True")
        if np.any(scene.ambient > 0) or np.any(st.background > 0):
            raise ValueError(f"{where}: ambient and background must be 0 for builtins=True")
        d["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1}
    else:
        d["integrator"] = {
            "type": "whitted", "max_depth": int(st.max_depth),
            "min_weight": float(st.min_weight), "shading": st.shading,
            "spawn": spawn, "ray_offset": fixed_ray_offset(scene),
            "background": _rgb(st.background),
            "ambient": _rgb(scene.ambient),
            "falloff_none": ",".join(f"light{i}" for i, light in enumerate(scene.lights)
                                     if light.falloff == "none"),
            "shadow_samples": int(st.shadow_samples)}
        for i, light in enumerate(scene.lights):
            if light.extent:
                d["integrator"].update(area_light_dicts(light, f"light{i}"))
    d["sensor"] = sensor_dict(scene, view=view, spp=spp, mode=mode, seed=seed)
    for i, light in enumerate(scene.lights):
        if builtins and light.falloff != "inverse_square":
            raise ValueError(f"{where}: lights[{i}].falloff must be 'inverse_square' for "
                             f"builtins=True")
        if light.extent:
            if builtins:
                raise ValueError(f"{where}: lights[{i}] is a {light.shape} light; "
                                 "builtins=True takes point lights only")
            continue
        d[f"light{i}"] = {"type": "point", "position": [float(v) for v in light.position],
                          "intensity": _rgb(light.intensity)}
    mats: dict[int, object] = {}
    for key, _, m, verts, normals, faces in mesh_parts(scene):
        if m not in mats:
            if portable:
                md = portable_material_dict(scene.materials[m])
            elif builtins:
                md = _builtin_material_dict(scene, scene.materials[m])
            else:
                md = material_dict(scene.materials[m], st.shading)
            mats[m] = md if meshes != "objects" else mi.load_dict(md)
        if meshes == "objects":
            props = mi.Properties()
            props["bsdf"] = mats[m]
            mesh = mi.Mesh(key, verts.shape[0], faces.shape[0], props,
                           has_vertex_normals=normals is not None)
            params = mi.traverse(mesh)
            params["vertex_positions"] = mi.Float(verts.reshape(-1))
            params["faces"] = mi.UInt32(faces.reshape(-1))
            if normals is not None:
                params["vertex_normals"] = mi.Float(normals.reshape(-1))
            params.update()
            d[key] = mesh
        else:
            fname = f"{Path(meshes).name}/{key}.ply"
            write_ply(Path(meshes) / f"{key}.ply", verts, faces, normals, overwrite=overwrite)
            d[key] = {"type": "ply", "filename": fname, "face_normals": normals is None,
                      "bsdf": {"type": "ref", "id": f"mat{m}"}}
            d.setdefault("_materials", {})[f"mat{m}"] = mats[m]
    return d


def load(scene: Scene, **kw):
    """``mi.load_dict(to_mitsuba_dict(scene, **kw))``."""
    mi = _mi()
    return mi.load_dict(to_mitsuba_dict(scene, **kw))


def film_positions(width: int, height: int) -> np.ndarray:
    """Pixel centres (x + 0.5, y + 0.5) / (width, height), row-major from the top row:
    float64 (height·width, 2), the film positions of exact mode (docs/MODEL.md)."""
    y, x = np.mgrid[0:height, 0:width]
    return np.stack([(x.reshape(-1) + 0.5) / width, (y.reshape(-1) + 0.5) / height], 1)


def render_exact(mi_scene) -> np.ndarray:
    """One ray through each pixel centre of a loaded Mitsuba scene whose integrator is
    ``whitted``. Returns float32 (H, W, 3) linear RGB."""
    sensor = mi_scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().size())
    rgb = mi_scene.integrator().render_exact(mi_scene, film_positions(w, h))
    return rgb.reshape(h, w, 3)


def render_mitsuba(scene: Scene, *, view: int = 0, mode: str = "exact", spp: int = 1,
                   seed: int = 0, builtins: bool = False, spawn: str = "mitsuba") -> np.ndarray:
    """Render ``scene`` with Mitsuba (``spawn``: see ``to_mitsuba_dict``). Returns float32
    (H, W, 3) linear RGB."""
    mi = _mi()
    sc = load(scene, view=view, mode=mode, spp=spp, seed=seed, builtins=builtins, spawn=spawn)
    if mode == "exact" and not builtins:
        return render_exact(sc)
    return np.array(mi.render(sc, spp=spp, seed=seed), dtype=np.float32)[..., :3]


def render_converged_with_variance(scene: Scene, *, view: int = 0, spp: int = 256,
                                   batches: int = 16, seed: int = 0,
                                   builtins: bool = False, progress=None):
    """Converged render as the mean of ``batches`` independent stratified renders of
    ``spp // batches`` samples each. Returns (mean float32 (H, W, 3), var float32 (H, W, 3),
    batch_spp): ``var`` is the per-pixel variance of ONE batch estimate (a ``batch_spp``
    render), so an independent render at ``batch_spp`` has that variance and the mean has
    ``var / batches``."""
    if spp % batches:
        raise ValueError(f"spp ({spp}) must be a multiple of batches ({batches})")
    b_spp = spp // batches
    imgs = []
    for b in range(batches):
        imgs.append(render_mitsuba(scene, view=view, mode="converged", spp=b_spp,
                                   seed=seed * 1000003 + b + 1, builtins=builtins))
        if progress:
            progress()
    stack = np.stack(imgs).astype(np.float64)
    return (stack.mean(0).astype(np.float32), stack.var(0, ddof=1).astype(np.float32),
            b_spp)


# ---- bare geometry and rays (the benchmark's peer) ----------------------------------------
def load_triangles(vertices: np.ndarray, faces: np.ndarray):
    """A loaded Mitsuba scene of one mesh holding every triangle, no material or light, so
    ``prim_index`` of a hit is the row of ``faces``. vertices: float (V, 3); faces: int
    (F, 3). Returns (the scene, seconds ``mi.load_dict`` took to build its accelerator)."""
    import time
    mi = _mi()
    mesh = mi.Mesh("all", vertices.shape[0], faces.shape[0])
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(faces, np.uint32).ravel())
    params.update()
    t0 = time.perf_counter()
    scene = mi.load_dict({"type": "scene", "mesh": mesh})
    return scene, time.perf_counter() - t0


def rays(o: np.ndarray, d: np.ndarray, t_max: np.ndarray | None = None):
    """A ``mi.Ray3f`` batch from host rows: origins and directions float (N, 3), and
    ``t_max`` float (N,) (None: unbounded)."""
    mi = _mi()

    def column(x, k):
        return mi.Float(np.ascontiguousarray(np.asarray(x)[:, k], np.float32))

    o3 = mi.Point3f(*(column(o, k) for k in range(3)))
    d3 = mi.Vector3f(*(column(d, k) for k in range(3)))
    if t_max is None:
        return mi.Ray3f(o3, d3)
    return mi.Ray3f(o3, d3, mi.Float(np.asarray(t_max, np.float32)), mi.Float(0.0),
                    mi.Color0f())


# ---- export -------------------------------------------------------------------------------
def write_ply(path: Path, verts: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None, *, overwrite: bool = False) -> None:
    """Binary little-endian PLY: float x y z (+ nx ny nz), faces as uchar/int lists; written
    atomically, an existing file replaced only when ``overwrite``."""
    path = Path(path)
    cols = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(verts)}"]
    head += [f"property float {c}" for c in cols]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices",
             "end_header"]
    vdata = verts if normals is None else np.concatenate([verts, normals], 1)
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    frec = np.empty(len(faces), fdt)
    frec["n"] = 3
    frec["i"] = faces
    data = (("\n".join(head) + "\n").encode() + np.ascontiguousarray(vdata, "<f4").tobytes()
            + frec.tobytes())
    write_bytes(path, data, overwrite=overwrite, flag="--force")


def _xml_value(parent, name, value):
    import mitsuba as mi
    if isinstance(value, dict):
        t = value["type"]
        if t == "rgb":
            ET.SubElement(parent, "rgb", name=name,
                          value=", ".join(repr(float(v)) for v in value["value"]))
        elif t == "ref":
            ET.SubElement(parent, "ref", name=name, id=value["id"])
        else:
            tag = {"twosided": "bsdf", "whitted_phong": "bsdf", "whitted_material": "bsdf",
                   "dielectric": "bsdf", "conductor": "bsdf", "diffuse": "bsdf",
                   "perspective": "sensor", "stratified": "sampler",
                   "independent": "sampler", "hdrfilm": "film", "box": "rfilter",
                   "point": "emitter", "ply": "shape", "whitted": "integrator",
                   "area": "emitter", "sphere": "shape", "rectangle": "shape",
                   "direct": "integrator", "path": "integrator"}[t]
            _xml_object(parent, tag, value, name=name)
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=name, value=str(value).lower())
    elif isinstance(value, int):
        ET.SubElement(parent, "integer", name=name, value=str(value))
    elif isinstance(value, float):
        ET.SubElement(parent, "float", name=name, value=repr(value))
    elif isinstance(value, str):
        ET.SubElement(parent, "string", name=name, value=value)
    elif isinstance(value, list) and len(value) == 3:
        ET.SubElement(parent, "point", name=name, x=repr(value[0]), y=repr(value[1]),
                      z=repr(value[2]))
    elif isinstance(value, mi.ScalarTransform4f):
        tr = ET.SubElement(parent, "transform", name=name)
        m = np.array(value.matrix, dtype=np.float64).reshape(4, 4)
        ET.SubElement(tr, "matrix", value=" ".join(repr(float(v)) for v in m.reshape(-1)))
    else:
        raise TypeError(f"export: cannot write property {name!r} of type {type(value)}")


def _xml_object(parent, tag, d, name=None, id=None):
    attrs = {"type": d["type"]}
    if name and tag not in ("shape", "emitter", "sensor", "integrator"):
        attrs["name"] = name
    if name and tag == "shape":            # a light's shape nested in the integrator
        attrs["id"] = name
    if id:
        attrs["id"] = id
    el = ET.SubElement(parent, tag, **attrs)
    for k, v in d.items():
        if k == "type":
            continue
        if isinstance(v, dict) and v.get("type") == "ref":
            ET.SubElement(el, "ref", id=v["id"])
            continue
        _xml_value(el, k, v)
    return el


def export_paths(path) -> tuple[Path, Path]:
    """Where ``export_xml(scene, path)`` writes: the XML file and its own mesh folder
    ``<xml stem>_meshes/`` beside it, so two exports into one folder never share a mesh."""
    path = Path(path)
    return path, path.with_name(f"{path.stem}_meshes")


def check_export(path, *, overwrite: bool = False) -> tuple[Path, Path]:
    """Before any work: the XML and its mesh folder can be written, and neither exists
    unless ``overwrite`` (``OutputExistsError`` naming ``--force``)."""
    xml, mesh_dir = export_paths(path)
    check_output_file(xml, overwrite=overwrite, flag="--force")
    if mesh_dir.exists() and not mesh_dir.is_dir():
        raise OutputError(f"{mesh_dir}: is a file; the export's mesh folder goes there")
    if mesh_dir.is_dir() and any(mesh_dir.iterdir()) and not overwrite:
        raise OutputExistsError(f"{mesh_dir}: exists (pass --force to replace the export)")
    return xml, mesh_dir


def export_xml(scene: Scene, path, *, view: int = 0, spp: int = 1,
               mode: str = "exact", portable: bool = False, overwrite: bool = False) -> Path:
    """Write ``scene`` as a Mitsuba 3 XML file at ``path``, its meshes as .ply files in a
    folder of its own, ``<xml stem>_meshes/`` (``export_paths``). Nothing is replaced
    unless ``overwrite`` (checked before anything is written: ``check_export``); every file
    is written atomically, the XML last.

    By default it loads with ``mi.load_file`` once our plugins are registered for the
    variant in use (``reference.mitsuba_variant()`` or ``reference.plugins.register()``).
    ``portable``: stock plugins only, so plain Mitsuba loads it (see ``to_mitsuba_dict``;
    ValueError listing the parts that need our plugins).
    """
    xml, mesh_dir = check_export(path, overwrite=overwrite)
    if portable:                                   # refuse before writing any mesh
        problems = portable_problems(scene)
        if problems:
            raise ValueError(f"{scene.path or scene.name}: not portable to stock Mitsuba "
                             "plugins: " + "; ".join(problems))
    d = to_mitsuba_dict(scene, view=view, spp=spp, mode=mode, meshes=str(mesh_dir),
                        portable=portable, overwrite=overwrite)
    root = ET.Element("scene", version="3.0.0")
    for key, md in d.pop("_materials", {}).items():
        _xml_object(root, "bsdf", md, id=key)
    for key, v in d.items():
        if key == "type":
            continue
        tag = {"integrator": "integrator", "sensor": "sensor"}.get(key)
        if tag is None:
            tag = "emitter" if v["type"] == "point" else "shape"
        _xml_object(root, tag, v, id=key if tag in ("emitter", "shape") else None)
    ET.indent(root)
    write_text(xml, ET.tostring(root, encoding="unicode") + "\n", overwrite=overwrite,
               flag="--force")
    return xml
