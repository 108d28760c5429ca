"""The in-memory scenes of the hard cases: ``mesh_scene`` (the one builder of in-memory
scenes), materials, lights, cameras and the scenes of the terminator, degenerate, robust and
Mitsuba-parity cases."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from renderer.scene import Camera, Material, ObjectInfo, PointLight, Scene, Settings, shapes


# ---- scene building ----------------------------------------------------------------------
def mesh_scene(objects, materials, *, lights=(), camera=None, settings=None, ambient=0.0,
               name="hard") -> Scene:
    """A Scene from ``objects``: (vertices float64 (V, 3), faces (F, 3), material index[,
    smooth]); float64 positions kept (``vertices64``) for float64 runs, as the loader
    does."""
    verts, norms, faces, fmat, fobj, infos = [], [], [], [], [], []
    nv = nf = 0
    for k, ob in enumerate(objects):
        V, F, m = np.asarray(ob[0], np.float64), np.asarray(ob[1], np.int64), ob[2]
        smooth = bool(ob[3]) if len(ob) > 3 else False
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        vn = np.zeros_like(V)
        for i in range(3):
            np.add.at(vn, F[:, i], fn)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        verts.append(V)
        norms.append(vn)
        faces.append(F + nv)
        fmat.append(np.full(len(F), m))
        fobj.append(np.full(len(F), k))
        infos.append(ObjectInfo(name=f"obj{k}", kind="hard", material=m, first_face=nf,
                                face_count=len(F), first_vertex=nv, vertex_count=len(V),
                                smooth=smooth))
        nv += len(V)
        nf += len(F)
    if camera is None:
        camera = Camera(position=np.array([0, 0, 5.0]), target=np.zeros(3),
                        up=np.array([0, 1.0, 0]), fov_y=40.0, width=64, height=64)
    V64, N64 = np.concatenate(verts), np.concatenate(norms)
    return Scene(cameras=[camera], settings=settings or Settings(), lights=list(lights),
                 materials=list(materials), objects=infos,
                 vertices=V64.astype(np.float32), normals=N64.astype(np.float32),
                 faces=np.concatenate(faces).astype(np.int32),
                 face_material=np.concatenate(fmat).astype(np.int32),
                 face_object=np.concatenate(fobj).astype(np.int32),
                 ambient=np.broadcast_to(np.asarray(ambient, np.float64), (3,)).copy(),
                 vertices64=V64, normals64=N64, name=name)


def material(name="m", *, ka=0.0, kd=0.0, ks=0.0, n=32.0, k_refl=0.0, k_refr=0.0, ior=1.5,
             combination="constant") -> Material:
    def v(x):
        return np.broadcast_to(np.asarray(x, np.float64), (3,)).copy()
    return Material(name=name, ka=v(ka), kd=v(kd), ks=v(ks), n=float(n), k_refl=v(k_refl),
                    k_refr=v(k_refr), ior=float(ior), combination=combination)


def point_light(pos, intensity, falloff="none") -> PointLight:
    return PointLight(position=np.asarray(pos, np.float64),
                      intensity=np.broadcast_to(np.asarray(intensity, np.float64),
                                                (3,)).copy(), falloff=falloff, name="l")


def camera(pos, target, *, fov_y=40.0, size=64, up=(0, 1, 0)) -> Camera:
    return Camera(position=np.asarray(pos, np.float64), target=np.asarray(target, np.float64),
                  up=np.asarray(up, np.float64), fov_y=fov_y, width=size, height=size)


def grid(n: int, size: float, center) -> tuple[np.ndarray, np.ndarray]:
    """A square of ``n`` x ``n`` quads (2 triangles each) of side ``size`` in the plane
    y = center.y, facing +y."""
    xs = np.linspace(-size / 2, size / 2, n + 1)
    X, Z = np.meshgrid(xs, xs, indexing="ij")
    V = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1) + np.asarray(center)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    F = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3),
                        np.stack([a, c, b], -1).reshape(-1, 3)])
    return V, F


# ---- case 7: shadow terminator --------------------------------------------------------------
def terminator_scene(subdivisions: int, angle_deg: float, size: int, fix: str = "none"
                     ) -> Scene:
    """A low-polygon icosphere (radius 1, interpolated normals, diffuse, nothing else in the
    scene) seen from +z, lit by one light (no falloff) at ``angle_deg`` from the view
    direction and a little above, so the terminator crosses the middle of the image;
    ``fix``: the ``Settings.terminator`` treatment."""
    a = math.radians(angle_deg)
    light = np.array([math.sin(a), 0.3, math.cos(a)]) * 10.0
    return mesh_scene([sphere_object((0, 0, 0), 1.0, 0, subdivisions, True)],
                      [material("white", kd=0.8)], lights=[point_light(light, 1.0)],
                      camera=camera((0, 0, 4.0), (0, 0, 0), size=size),
                      settings=Settings(terminator=fix), name="terminator")


# ---- shared test scenes --------------------------------------------------------------------
def room_scene(extra=(), extra_mats=(), *, light_pos=(0.5, 2.5, 3.0), max_depth=6,
          size=64, cam=((0, 1.0, 4.5), (0, 0.5, 0))):
    """A floor and a back wall (diffuse, no shadows cast onto them by each other) under one
    light with no falloff, plus ``extra`` objects (material indices from 2)."""
    floor = grid(1, 6.0, (0, 0, 0))
    wall = (np.array([[-3, 0, -2], [3, 0, -2], [3, 4, -2], [-3, 4, -2.0]]),
            np.array([[0, 1, 2], [0, 2, 3]]))
    mats = [material("floor", kd=[0.7, 0.6, 0.5]), material("wall", kd=[0.3, 0.5, 0.8])]
    objs = [(*floor, 0), (*wall, 1)] + list(extra)
    return mesh_scene(objs, mats + list(extra_mats),
                      lights=[point_light(light_pos, 1.0)],
                      camera=camera(*cam, size=size), settings=Settings(max_depth=max_depth))


def sphere_object(center, radius, mat, subdivisions=3, smooth=False):
    V, F = shapes.make_shape("sphere", subdivisions=subdivisions)
    return (V * radius + np.asarray(center, float), F, mat, smooth)


# ---- case 11: degenerate input -------------------------------------------------------------
def degenerate_scene() -> Scene:
    """Zero-area, collinear and duplicate-vertex triangles, and axis-aligned boxes seen
    exactly edge-on (camera in the plane of their faces)."""
    from renderer.scene import shapes as sh
    bV, bF = sh.make_shape("box")
    box1 = (bV * 0.5 + [0, 0.5, 0], bF, 2)
    box2 = (bV * 0.3 + [1.2, 1.0, 0.3], bF, 2)
    zero = (np.array([[0.3, 1.2, 0.5]] * 3), np.array([[0, 1, 2]]), 2)
    collinear = (np.array([[-1.0, 1.0, 0.5], [-0.5, 1.5, 0.5], [0.0, 2.0, 0.5]]),
                 np.array([[0, 1, 2]]), 2)
    dup = (np.array([[-1.5, 0.2, 0.5], [-1.5, 0.2, 0.5], [-1.0, 0.8, 0.5]]),
           np.array([[0, 1, 2], [0, 0, 2], [1, 2, 2]]), 2)
    mats = [material("m", kd=0.6, ks=0.3, n=20, k_refl=0.2)]
    return room_scene([box1, box2, zero, collinear, dup], mats,
                 cam=((0, 1.0, 3.0), (0, 1.0, 0)))


# ---- case 12: robust scenes --------------------------------------------------------------
def robust_scenes() -> dict:
    """The case-12 scenes by name."""
    glass = material("glass", k_refl=0.0, k_refr=1.0, ior=1.5, combination="fresnel")
    mirror = material("mirror", kd=0.05, k_refl=0.9)
    out = {}
    out["camera in glass"] = room_scene([sphere_object((0, 1.0, 4.5), 0.5, 2, 3, True),
                                    sphere_object((0, 0.6, 0), 0.5, 3)],
                                   [glass, material("red", kd=[0.8, 0.1, 0.1])])
    bV, bF = shapes.make_shape("box")
    lit_box = room_scene([(bV * 0.8 + [0, 0.8, 0], bF, 2)], [material("grey", kd=0.6)],
                    light_pos=(0, 0.8, 0))
    out["light in a closed box"] = lit_box
    q = np.array([[-1, 0.5, -1.0], [1, 0.5, -1], [1, 0.5, 1], [-1, 0.5, 1]])
    quad_faces = np.array([[0, 2, 1], [0, 3, 2]])
    # the same faces twice (red first, then green): every hit is an exact tie in t
    out["coplanar overlapping faces"] = room_scene(
        [(q, quad_faces, 2), (q, quad_faces, 3)],
        [material("red", kd=[0.9, 0, 0]), material("green", kd=[0, 0.9, 0])],
        cam=((0, 3.0, 2.0), (0, 0.5, 0)))
    # a coplanar quad inside the red one, with other vertices: t differs by rounding
    inner = np.array([[-0.6, 0.5, -0.7], [0.8, 0.5, -0.6], [0.7, 0.5, 0.9], [-0.5, 0.5, 0.6]])
    out["coplanar faces, other vertices"] = room_scene(
        [(q, quad_faces, 2), (inner, quad_faces, 3)],
        [material("red", kd=[0.9, 0, 0]), material("green", kd=[0, 0.9, 0])],
        cam=((0, 3.0, 2.0), (0, 0.5, 0)))
    m1 = (np.array([[-2, 0, -1.0], [-2, 0, 1], [-2, 3, 1], [-2, 3, -1]]),
          np.array([[0, 1, 2], [0, 2, 3]]), 2)
    m2 = (np.array([[2, 0, -1.0], [2, 0, 1], [2, 3, 1], [2, 3, -1]]),
          np.array([[0, 2, 1], [0, 3, 2]]), 2)
    out["hall of mirrors"] = room_scene([m1, m2, sphere_object((0, 1, 0), 0.4, 3)],
                                   [mirror, material("red", kd=[0.8, 0.2, 0.1])],
                                   max_depth=16, cam=((-1.9, 1.2, 0.9), (2, 1.0, -0.2)))
    return out


# ---- case 14: Mitsuba parity on hard cases ------------------------------------------------
def closed_mesh_scene(spec: dict):
    """Case 1's closed icosphere and plane (vertices, faces, centre, radius, Scene)."""
    c = np.asarray(spec["center"], np.float64)
    r = float(spec["radius"])
    V, F = shapes.make_shape("sphere", subdivisions=int(spec["subdivisions"]))
    V = V * r + c
    PV, PF = grid(int(spec["plane_grid"]), 4 * r, c + [0, -3 * r, 0])
    return V, F, c, r, mesh_scene([(V, F, 0), (PV, PF, 0)], [material(kd=0.5)])


def parity_scenes(closed_spec: dict, size: int) -> dict:
    """The render cases compared with Mitsuba: case 12's scenes, case 11's degenerate input,
    case 7's coarse sphere and case 1's closed sphere seen from its centre."""
    out = dict(robust_scenes())
    out["degenerate"] = degenerate_scene()
    out["terminator"] = terminator_scene(1, 88.0, size)
    _, _, c, _, sc = closed_mesh_scene(closed_spec)
    out["closed sphere from inside"] = replace(
        sc, lights=[point_light(c, 1.0)],
        cameras=[camera(c, c + [1.0, -0.3, 0.2], fov_y=120.0, size=size)],
        settings=replace(sc.settings, background=np.array([1.0, 0.0, 1.0])))
    return {k: v.with_size(size, size) for k, v in out.items()}
