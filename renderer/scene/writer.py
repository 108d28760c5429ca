"""A ``Scene`` written as the project's TOML scene file (docs/scene-format.md), its geometry
as one binary PLY per object in a folder of its own: what ``whitted convert`` writes from an
OBJ + MTL, PLY or Mitsuba XML scene.

``scene_files(scene, toml_path)`` returns every file as ``{path: bytes}`` (nothing is
written here): the TOML names each mesh relative to its folder. Vertices are written in
float64 (the exact world-space positions: no transform in the file), normals as the float32
values the renderer uses, with ``normals = "file"`` for smooth objects whose normals are not
the averaged ones, and lights with their shape (sphere radius, rectangle edges), so reading
the TOML back gives the same arrays and the same image.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .loader import _vertex_normals
from .model import Scene

__all__ = ["mesh_folder", "scene_files", "ply_bytes"]


def mesh_folder(toml_path) -> Path:
    """``<stem>_meshes/`` beside the TOML file."""
    toml_path = Path(toml_path)
    return toml_path.with_name(f"{toml_path.stem}_meshes")


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None
              ) -> bytes:
    """Binary little-endian PLY: double x y z (+ float nx ny nz), uchar/int face lists."""
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}",
            "property double x", "property double y", "property double z"]
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if normals is not None:
        head += ["property float nx", "property float ny", "property float nz"]
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices",
             "end_header"]
    rec = np.empty(len(vertices), np.dtype(fields))
    for k, c in enumerate("xyz"):
        rec[c] = vertices[:, k]
        if normals is not None:
            rec["n" + c] = normals[:, k]
    frec = np.empty(len(faces), np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    frec["n"], frec["i"] = 3, faces
    return ("\n".join(head) + "\n").encode() + rec.tobytes() + frec.tobytes()


def _num(x) -> str:
    return repr(float(x))


def _vec(v) -> str:
    return "[" + ", ".join(_num(x) for x in np.asarray(v, np.float64).reshape(-1)) + "]"


def _str(s: str) -> str:
    return json.dumps(s)


def _averaged(scene: Scene, obj) -> bool:
    """Whether an object's normals are those the loader averages from its geometry."""
    vs = slice(obj.first_vertex, obj.first_vertex + obj.vertex_count)
    v = scene.positions(True)[vs]
    f = scene.faces[obj.first_face:obj.first_face + obj.face_count] - obj.first_vertex
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = _vertex_normals(v, f, cross / np.linalg.norm(cross, axis=1)[:, None])
    return bool(np.array_equal(n.astype(np.float32), scene.normals[vs]))


def scene_files(scene: Scene, toml_path, *, source: str = "") -> dict[Path, bytes]:
    """Every file of ``scene`` as a TOML scene at ``toml_path`` (module docstring), TOML
    last. source: a line for the file's description (where it came from)."""
    toml_path = Path(toml_path)
    folder = mesh_folder(toml_path)
    st = scene.settings
    out: dict[Path, bytes] = {}
    lines = [f"# Converted by whitted convert{f' from {source}' if source else ''}.",
             f"description = {_str(f'{scene.name} (converted)')}",
             f"ambient = {_vec(scene.ambient)}", "", "[render]",
             f"max_depth = {st.max_depth}", f"spp = {st.spp}",
             f"exact = {str(st.exact).lower()}", f"shading = {_str(st.shading)}",
             f"background = {_vec(st.background)}", f"min_weight = {_num(st.min_weight)}",
             f"seed = {st.seed}", f"spawn = {_str(st.spawn)}",
             f"shadow_samples = {st.shadow_samples}"]
    if st.ray_epsilon is not None:
        lines.append(f"ray_epsilon = {_num(st.ray_epsilon)}")
    for cam in scene.cameras:
        lines += ["", "[[views]]", f"name = {_str(cam.name)}", f"position = {_vec(cam.position)}",
                  f"target = {_vec(cam.target)}", f"up = {_vec(cam.up)}",
                  f"fov_y = {_num(cam.fov_y)}", f"resolution = [{cam.width}, {cam.height}]"]
    for light in scene.lights:
        lines += ["", "[[lights]]", f"name = {_str(light.name)}",
                  f"type = {_str(light.shape)}"]
        if light.shape == "rectangle":
            lines += [f"center = {_vec(light.position)}", f"edge_u = {_vec(light.edge_u)}",
                      f"edge_v = {_vec(light.edge_v)}",
                      f"two_sided = {str(light.two_sided).lower()}"]
        else:
            lines.append(f"position = {_vec(light.position)}")
        if light.shape == "sphere":
            lines.append(f"radius = {_num(light.radius)}")
        lines += [f"intensity = {_vec(light.intensity)}", f"falloff = {_str(light.falloff)}"]
    names = _unique([m.name for m in scene.materials])
    for name, m in zip(names, scene.materials):
        lines += ["", f"[materials.{_str(name)}]", f"ka = {_vec(m.ka)}", f"kd = {_vec(m.kd)}",
                  f"ks = {_vec(m.ks)}", f"n = {_num(m.n)}", f"k_refl = {_vec(m.k_refl)}",
                  f"k_refr = {_vec(m.k_refr)}", f"ior = {_num(m.ior)}",
                  f"combination = {_str(m.combination)}"]
    meshes = _unique([o.name for o in scene.objects])
    for obj, mesh in zip(scene.objects, meshes):
        vs = slice(obj.first_vertex, obj.first_vertex + obj.vertex_count)
        faces = scene.faces[obj.first_face:obj.first_face + obj.face_count] - obj.first_vertex
        mats = np.unique(scene.face_material[obj.first_face:obj.first_face + obj.face_count])
        if len(mats) != 1:
            raise ValueError(f"object {obj.name!r} has {len(mats)} materials; a scene file "
                             "gives one per object")
        file_normals = obj.smooth and not _averaged(scene, obj)
        path = folder / f"{_file_name(mesh)}.ply"
        out[path] = ply_bytes(scene.positions(True)[vs], faces,
                              scene.normals[vs] if file_normals else None)
        lines += ["", "[[objects]]", f"name = {_str(obj.name)}",
                  f"mesh = {_str(f'{folder.name}/{path.name}')}",
                  f"material = {_str(names[int(mats[0])])}",
                  f"smooth = {str(obj.smooth).lower()}"]
        if file_normals:
            lines.append('normals = "file"')
    out[toml_path] = ("\n".join(lines) + "\n").encode()
    return out


def _unique(names: list[str]) -> list[str]:
    seen, out = set(), []
    for n in names:
        name, k = n or "unnamed", 1
        while name in seen:
            k += 1
            name = f"{n}.{k}"
        seen.add(name)
        out.append(name)
    return out


def _file_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "mesh"
