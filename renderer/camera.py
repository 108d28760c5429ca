"""Primary rays of the pinhole camera (docs/MODEL.md, "Camera and pixels").

The camera's frame lives in ``CameraArrays`` (device arrays of width 1, made opaque), so a
frame function wrapped in ``dr.freeze`` takes the camera as an input and can be re-run with
a moved camera without re-tracing. Ray ``k`` of a batch belongs to pixel ``k // spp`` (row
major, ``y = 0`` the top row) and is its sample ``k % spp``, so the samples of one pixel are
contiguous and the film averages them with a block reduction.

Converged-mode jitter: ray ``k`` (its row-major number in the whole image) has its own
PCG32 sequence, seeded with ``initstate = seed + k``, ``initseq = default stream + k``
(what one ``PCG32(size=W·H·spp, initstate=seed)`` generator gives ray ``k``: Dr.Jit adds
``arange(size)`` to both), and draws ``ξ1`` then ``ξ2``. The same seed gives the same
image on every backend.

Tiles: ``primary_rays(..., tile=RayTile(first_row=y0, rows=n))`` makes only the rays of rows
``y0 .. y0+n-1``, seeded by their numbers in the whole image, so a tiled render has the
same rays, bit for bit, as one batch. ``first_row`` is an opaque ``UInt32`` so that every
tile reuses one compiled kernel.

Pixel blocks: with ``block=(bw, bh)`` the rays come in block order instead of row major:
the image (or tile) is cut into blocks of ``bw × bh`` pixels (narrower or shorter at the
right and bottom edges), numbered row by row, each block's pixels row major, so that a
SIMD packet (LLVM) or warp (CUDA) of ``bw·bh`` lanes holds a compact patch of the image
and its secondary and shadow rays stay alike (fewer traversal steps where a lane waits for
the slowest of its packet). Each ray keeps its row-major number ``k`` for its random
numbers (``PCG32.seed`` with ``seed + k``, ``stream + k``), so the rays are the same, bit
for bit, in either order; ``film.develop(..., block=...)`` puts the pixels back in row-major
order. ``BLOCKS`` holds the renderer's block per backend.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .device import Types, normalize
from .scene import Camera, SceneError, validate_settings

#: Dr.Jit's (and the original PCG32's) default stream, ``PCG32(initseq=...)``.
PCG32_DEFAULT_STREAM = 0xDA3E39CB94B95BDB
#: The renderer's pixel block per backend (``Renderer`` frames): 4 × 8 pixels, a warp of 32
#: lanes on CUDA, two packets of 16 (AVX-512) on LLVM. Whitted frames in these blocks take
#: less kernel time than in row-major order on both backends, and more than in blocks of
#: 8 × 4 or 16 × 2 (``lab/notes/accel-decisions.md``).
BLOCKS = {"cuda": (4, 8), "llvm": (4, 8)}


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


def block_pixel(q, width: int, rows: int, block: tuple[int, int]):
    """Pixel ``(x, y)`` (UInt32 arrays) of slot ``q`` (UInt32, ``0 <= q < width·rows``) in
    the block order of a ``width × rows`` image (the module's "Pixel blocks"). Every divisor
    is a host constant (the four kinds of block: full, or cut at the right, the bottom or
    both, are computed and selected), so the divisions compile to multiplications."""
    bw, bh = block
    w_last, h_last = width % bw, rows % bh       # the cut blocks' width and height (0: none)
    by = q // (width * bh)                       # block row; the rows above are full
    r = q - by * (width * bh)

    def in_row(h):
        """(x, y in the block) of slot ``r`` of a block row ``h`` pixels high."""
        bx = r // (h * bw)                       # blocks to the left are full width
        c = r - bx * (h * bw)
        yy = c // bw
        xx = c - yy * bw
        if w_last:
            cut = bx == width // bw
            yc = c // w_last
            xx = dr.select(cut, c - yc * w_last, xx)
            yy = dr.select(cut, yc, yy)
        return bx * bw + xx, yy

    x, yy = in_row(bh)
    if h_last:
        xc, yc = in_row(h_last)
        cut = by == rows // bh
        x, yy = dr.select(cut, xc, x), dr.select(cut, yc, yy)
    return x, by * bh + yy


@dataclass
class RayTile:
    """Which of an image's camera rays ``primary_rays`` makes, and in which order.

    first_row, rows: only the ``rows`` image rows from ``first_row`` (a ``t.UInt32`` of
    width 1, made opaque by the caller) on (the module's "Tiles"); None: every row.
    block: ``(bw, bh)``: the rays in block order (the module's "Pixel blocks"); None:
    row-major order.
    """

    first_row: object = None
    rows: int | None = None
    block: tuple[int, int] | None = None


def _ray_pixels(width: int, height: int, t: Types, spp: int, tile: RayTile):
    """``(x, y, s, n)`` of each ray in ``primary_rays``'s order: its pixel column and row in
    the whole image, its sample in that pixel, and the number of rays."""
    n_rows = height if tile.rows is None else tile.rows
    n = width * n_rows * spp
    idx = dr.arange(t.UInt32, n)
    slot = idx // spp if spp > 1 else idx       # pixel slot, and the sample in it
    s = idx - slot * spp if spp > 1 else dr.zeros(t.UInt32, n)
    if tile.block is None:
        x, y = slot % width, slot // width
    else:
        x, y = block_pixel(slot, width, n_rows, tile.block)
    if tile.first_row is not None:
        y = y + tile.first_row
    return x, y, s, n


def ray_keys(width: int, height: int, t: Types, *, spp: int = 1, seed: int = 0,
             tile: RayTile | None = None):
    """UInt32 random key of each ray of ``primary_rays`` (same arguments, same order): the
    low 32 bits of ``seed + k`` xor its high 32 bits, ``k`` the ray's row-major number in
    the whole image, so a ray keeps its key in any batching, tile or block order and
    batches seeded ``n`` rays apart (``evaluation.rules.render_batches``) share no key."""
    x, y, s, _ = _ray_pixels(width, height, t, spp, RayTile() if tile is None else tile)
    UInt64 = dr.uint64_array_t(t.UInt32)
    v = UInt64(seed) + UInt64(y * width + x) * spp + UInt64(s)
    return t.UInt32(v & 0xFFFFFFFF) ^ t.UInt32(v >> 32)


def primary_rays(cam: CameraArrays, width: int, height: int, t: Types, *,
                 spp: int = 1, exact: bool = True, seed: int = 0,
                 tile: RayTile | None = None):
    """Camera rays for every pixel sample.

    Returns ``(o, d)``: Array3f of width ``width·height·spp`` (``d`` unit length), ray ``k``
    in pixel ``k // spp``. Exact mode (``spp`` must be 1): pixel centres. Converged mode:
    ``spp = k²`` stratified jittered samples per pixel. Raises SceneError
    (``validate_settings``) for any other ``spp``.

    tile (``RayTile``): with ``first_row`` and ``rows``, only those rows: width
    ``width·rows·spp``, the same rays as those rows of the whole image (see the module's
    "Tiles"); with ``block``, the rays in block order (the module's "Pixel blocks"): ray
    ``k`` is sample ``k % spp`` of the pixel in slot ``k // spp``; the same rays as
    without.
    """
    validate_settings(spp=spp, exact=exact)
    x, y, s, n = _ray_pixels(width, height, t, spp, RayTile() if tile is None else tile)
    if exact:
        px = t.Float(x) + 0.5
        py = t.Float(y) + 0.5
    else:
        k = int(round(np.sqrt(spp)))
        UInt64 = dr.uint64_array_t(t.UInt32)
        ray = UInt64(y * width + x) * spp + UInt64(s)    # row-major number of the ray
        rng = t.PCG32(n)
        rng.seed(UInt64(seed) + ray, UInt64(PCG32_DEFAULT_STREAM) + ray)
        xi1 = rng.next_float(t.Float)
        xi2 = rng.next_float(t.Float)
        inv_k = 1.0 / k
        px = t.Float(x) + (t.Float(s % k) + xi1) * inv_k
        py = t.Float(y) + (t.Float(s // k) + xi2) * inv_k
    sx = dr.fma(px, 2.0 / width, -1.0) * cam.tan_x
    sy = dr.fma(py, -2.0 / height, 1.0) * cam.tan_y
    d = normalize(cam.forward + sx * cam.right + sy * cam.up)
    o = t.Array3f(cam.position)
    return o, d
