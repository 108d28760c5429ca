"""Primary rays of the pinhole camera (docs/MODEL.md, "Camera and pixels").

The camera's frame lives in ``CameraArrays`` (device arrays of width 1, made opaque), so a
frame function wrapped in ``dr.freeze`` takes the camera as an input and can be re-run with
a moved camera without re-tracing. Ray ``k`` of a batch belongs to pixel ``k // spp`` (row
major, ``y = 0`` the top row) and is its sample ``k % spp``, so the samples of one pixel are
contiguous and the film averages them with a block reduction.

Converged-mode jitter: one ``PCG32(size=W·H·spp, initstate=seed)`` generator (Dr.Jit adds
``arange(size)`` to the state and the stream, so every ray has its own sequence); ray ``k``
draws ``ξ1`` then ``ξ2``. The same seed gives the same image on every backend.

Tiles: ``primary_rays(..., first_row=y0, rows=n)`` makes only the rays of rows
``y0 .. y0+n-1``, numbered by their index ``k`` in the whole image (the generator is seeded
with ``initstate = seed + k0``, ``initseq = default + k0`` for the tile's first ray ``k0``,
which is what the whole-image generator gives ray ``k0``), so a tiled render has the same
rays, bit for bit, as one batch. ``first_row`` is an opaque ``UInt32`` so that every tile
reuses one compiled kernel.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .device import Types
from .scene import Camera, SceneError, validate_settings

#: Dr.Jit's (and the original PCG32's) default stream, ``PCG32(initseq=...)``.
PCG32_DEFAULT_STREAM = 0xDA3E39CB94B95BDB


@dataclass
class CameraArrays:
    """The camera frame on the device (each entry width 1).

    position: Array3f eye point; right, up, forward: Array3f orthonormal basis
    (``r``, ``u``, ``f`` of MODEL.md); tan_x, tan_y: Float half-extents of the film plane
    at distance 1.
    """

    position: object = None
    right: object = None
    up: object = None
    forward: object = None
    tan_x: object = None
    tan_y: object = None


def camera_frame(cam: Camera) -> dict:
    """The camera basis on the host (float64): position, right, up, forward, tan_x, tan_y."""
    pos = np.asarray(cam.position, np.float64)
    f = np.asarray(cam.target, np.float64) - pos
    if np.linalg.norm(f) == 0:
        raise SceneError(f"camera {cam.name!r}: target equals position")
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(cam.up, np.float64))
    if np.linalg.norm(r) < 1e-12:
        raise SceneError(f"camera {cam.name!r}: up is parallel to the view direction")
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    tan_y = float(np.tan(np.radians(cam.fov_y) / 2))
    tan_x = tan_y * cam.width / cam.height
    return dict(position=pos, right=r, up=u, forward=f, tan_x=tan_x, tan_y=tan_y)


def camera_arrays(cam: Camera, t: Types) -> CameraArrays:
    """Upload ``cam``'s frame as opaque width-1 arrays of types ``t``."""
    fr = camera_frame(cam)
    # Scalars made opaque, not ``device.array3`` rows: with arrays built from numpy a
    # frozen frame function records again for a moved camera (seen on the orbit).
    def a3(v):
        return t.Array3f(*(float(x) for x in v))

    ca = CameraArrays(position=a3(fr["position"]), right=a3(fr["right"]), up=a3(fr["up"]),
                      forward=a3(fr["forward"]), tan_x=t.Float(fr["tan_x"]),
                      tan_y=t.Float(fr["tan_y"]))
    dr.make_opaque(ca)
    return ca


def primary_rays(cam: CameraArrays, width: int, height: int, t: Types, *,
                 spp: int = 1, exact: bool = True, seed: int = 0, first_row=None,
                 rows: int | None = None):
    """Camera rays for every pixel sample.

    Returns ``(o, d)``: Array3f of width ``width·height·spp`` (``d`` unit length), ray ``k``
    in pixel ``k // spp``. Exact mode (``spp`` must be 1): pixel centres. Converged mode:
    ``spp = k²`` stratified jittered samples per pixel. Raises SceneError
    (``validate_settings``) for any other ``spp``.

    first_row, rows: only the ``rows`` image rows from ``first_row`` (a ``t.UInt32`` of
    width 1, made opaque by the caller) on: width ``width·rows·spp``, the same rays as
    those rows of the whole image (see the module's "Tiles").
    """
    validate_settings(spp=spp, exact=exact)
    n = width * (height if rows is None else rows) * spp
    idx = dr.arange(t.UInt32, n)
    if first_row is not None:
        idx = idx + first_row * (width * spp)
    if exact:
        pix = idx
        px = t.Float(pix % width) + 0.5
        py = t.Float(pix // width) + 0.5
    else:
        k = int(round(np.sqrt(spp)))
        pix = idx // spp
        s = idx - pix * spp
        if first_row is None:
            rng = t.PCG32(n, initstate=seed)
        else:
            UInt64 = dr.uint64_array_t(t.UInt32)
            k0 = UInt64(first_row) * (width * spp)
            rng = t.PCG32(n, initstate=UInt64(seed) + k0,
                          initseq=UInt64(PCG32_DEFAULT_STREAM) + k0)
        xi1 = rng.next_float(t.Float)
        xi2 = rng.next_float(t.Float)
        inv_k = 1.0 / k
        px = t.Float(pix % width) + (t.Float(s % k) + xi1) * inv_k
        py = t.Float(pix // width) + (t.Float(s // k) + xi2) * inv_k
    sx = dr.fma(px, 2.0 / width, -1.0) * cam.tan_x
    sy = dr.fma(py, -2.0 / height, 1.0) * cam.tan_y
    d = dr.normalize(cam.forward + sx * cam.right + sy * cam.up)
    o = t.Array3f(cam.position)
    return o, d
