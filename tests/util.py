"""Small scene builders for tests: quads, boxes and slabs from numpy arrays, two shared
test scenes, and ``pixel_ray``, the test oracle of the camera model (written independently of
``renderer.camera`` on purpose)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from renderer.scene import Camera, Material, PointLight, Scene, Settings


def material(name="m", *, ka=0.0, kd=0.0, ks=0.0, n=32.0, k_refl=0.0, k_refr=0.0, ior=1.5,
             combination="constant") -> Material:
    v = lambda x: np.broadcast_to(np.asarray(x, np.float64), (3,)).copy()
    return Material(name=name, ka=v(ka), kd=v(kd), ks=v(ks), n=float(n), k_refl=v(k_refl),
                    k_refr=v(k_refr), ior=float(ior), combination=combination)


def quad(p0, p1, p2, p3):
    """Two triangles (p0 p1 p2), (p0 p2 p3); normal along (p1-p0)×(p2-p0)."""
    V = np.array([p0, p1, p2, p3], np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return V, F


def box(lo, hi):
    """Closed axis-aligned box with outward winding."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1])
                  for x in (lo[0], hi[0])])
    # vertex index bits: x=1, y=2, z=4
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    F = []
    for a, b, cc, d in faces:
        F += [[a, b, cc], [a, cc, d]]
    F = np.array(F)
    # check outward winding
    ctr = (lo + hi) / 2
    for f in F:
        n = np.cross(c[f[1]] - c[f[0]], c[f[2]] - c[f[0]])
        assert np.dot(n, c[f].mean(0) - ctr) > 0
    return c, F


def make_scene(objects, *, materials, lights=(), camera=None, settings=None, ambient=0.0,
               name="test") -> Scene:
    """objects: list of (vertices (V,3), faces (F,3), material index[, smooth]).

    ``evaluation.hard.scenes.mesh_scene`` (the one builder of in-memory scenes), with this
    module's defaults: a 16x16 camera, objects of kind "test", and no float64 vertices (a
    float64 render sees the float32 positions widened, as for a scene built in code)."""
    from evaluation.hard.scenes import mesh_scene

    if camera is None:
        camera = Camera(position=np.array([0, 0, 5.0]), target=np.zeros(3),
                        up=np.array([0, 1.0, 0]), fov_y=40.0, width=16, height=16)
    sc = mesh_scene(objects, list(materials), lights=lights, camera=camera, settings=settings,
                    ambient=ambient, name=name)
    return replace(sc, objects=[replace(o, kind="test") for o in sc.objects],
                   vertices64=None, normals64=None)


def light(pos, intensity, falloff="inverse_square", name="l"):
    return PointLight(position=np.asarray(pos, np.float64),
                      intensity=np.broadcast_to(np.asarray(intensity, np.float64), (3,)).copy(),
                      falloff=falloff, name=name)


def camera(pos, target, *, fov_y=40.0, width=16, height=16, up=(0, 1, 0)):
    return Camera(position=np.asarray(pos, np.float64), target=np.asarray(target, np.float64),
                  up=np.asarray(up, np.float64), fov_y=fov_y, width=width, height=height)


def pixel_ray(cam: Camera, px: float, py: float) -> np.ndarray:
    """The unit camera direction through film position (px, py) (docs/MODEL.md), float64."""
    f = cam.target - cam.position
    f = f / np.linalg.norm(f)
    r = np.cross(f, cam.up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(cam.fov_y) / 2)
    tx = ty * cam.width / cam.height
    d = f + (2 * px / cam.width - 1) * tx * r + (1 - 2 * py / cam.height) * ty * u
    return d / np.linalg.norm(d)


def diffuse_scene(**settings) -> Scene:
    """A diffuse floor and a specular cube under two lights with ambient light, 32x32."""
    floor = quad([-2, -1, -2], [-2, -1, 2], [2, -1, 2], [2, -1, -2])
    cube = box([-0.5, -1, -0.5], [0.5, 0, 0.5])
    return make_scene([(*floor, 0), (*cube, 1)],
                      materials=[material("floor", kd=0.7, ka=0.2),
                                 material("cube", kd=[0.2, 0.4, 0.8], ks=0.5, n=20, ka=0.1)],
                      lights=[light([1, 2, 1.5], 6.0), light([-1.5, 1, 1], [1, 0.5, 0.2])],
                      camera=camera([0, 1, 4], [0, -0.5, 0], width=32, height=32),
                      ambient=0.3, settings=Settings(**settings))


def glass_scene(**settings) -> Scene:
    """``diffuse_scene`` with the cube made of Fresnel glass (reflection and refraction)."""
    sc = diffuse_scene(**settings)
    sc.materials.append(material("glass", k_refl=0.2, k_refr=0.8, ks=0.5, n=50,
                                 combination="fresnel"))
    sc.face_material[sc.face_object == 1] = 2
    return sc
