"""Film: averaging samples into pixels, and image files.

Images are numpy float32 arrays of shape (H, W, 3), linear RGB, row 0 at the top.
EXR files hold linear float32 R, G, B channels, plus optional layers such as a per-pixel
variance (``var.R``, ``var.G``, ``var.B``) (OpenEXR 3.x Python API), and optional metadata as
string attributes of the header, each named ``whitted:<field>`` (``write_exr(metadata=)``,
``read_exr_metadata``; other tools show them as they show any attribute); PNGs are 8-bit sRGB
(clamped), for looking at; ``srgb_encode`` is the one linear -> sRGB conversion. Writers
go through ``renderer.outputs.atomic_path`` (temporary file in the same folder, fsync,
rename), so an interrupted or failed write leaves no partial file, and never replace an
existing file unless the caller passes ``overwrite=True`` (``OutputExistsError``).
"""
from __future__ import annotations

import os
from pathlib import Path

import drjit as dr
import numpy as np

from .camera import block_pixel
from .outputs import atomic_path


def develop(radiance, width: int, height: int, spp: int, t,
            block: tuple[int, int] | None = None):
    """Box-filter ``radiance`` (Array3f, width ``W·H·spp``, samples of a pixel contiguous)
    into a TensorXf of shape (H, W, 3). ``block``: the pixels come in that block order
    (``camera.primary_rays(..., block=...)``); each is scattered to its row-major place, in
    the kernel that computes it (exact mode: the frame stays one kernel)."""
    if spp > 1:
        radiance = dr.block_reduce(dr.ReduceOp.Add, radiance, spp) * (1.0 / spp)
    if block is None:
        flat = dr.ravel(radiance, order="F")
    else:
        x, y = block_pixel(dr.arange(t.UInt32, width * height), width, height, block)
        flat = dr.zeros(t.Float, 3 * width * height)
        dr.scatter(flat, radiance, y * width + x)        # flat[3 p + c] = radiance[c]
    return t.TensorXf(flat, shape=(height, width, 3))


def _check_image(image, what: str) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{what}: expected an image of shape (H, W, 3), got {img.shape}")
    return img


#: Prefix of the header attributes that hold ``write_exr``'s metadata.
META_PREFIX = "whitted:"


def write_exr(path, image, *, layers: dict | None = None, overwrite: bool = False,
              metadata: dict | None = None) -> Path:
    """Write ``image`` (float (H, W, 3) linear RGB) as a float32 OpenEXR file (ZIP, scanline).

    layers: further (H, W, 3) images stored beside it as channels ``<name>.R``, ``<name>.G``,
        ``<name>.B`` (e.g. ``{"var": variance}``; float32, so values far below half's range
        survive).
    metadata: field -> value, each stored as the string attribute ``whitted:<field>`` of the
        header (values are written as ``str(value)``; ``read_exr_metadata`` reads them back).
    """
    import OpenEXR
    if OpenEXR.global_thread_count() == 0:   # the library compresses its blocks on threads
        OpenEXR.set_global_thread_count(os.cpu_count() or 1)     # (the same bytes)
    img = np.ascontiguousarray(_check_image(image, str(path)), dtype=np.float32)
    extra = {name: np.ascontiguousarray(_check_image(v, f"{path}: layer {name!r}"), np.float32)
             for name, v in (layers or {}).items()}
    for name, v in extra.items():
        if v.shape != img.shape:
            raise ValueError(f"{path}: layer {name!r} has shape {v.shape}, the image {img.shape}")
    path = Path(path)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({f"{META_PREFIX}{k}": str(v) for k, v in (metadata or {}).items()})
    channels = {c: np.ascontiguousarray(img[:, :, i]) for i, c in enumerate("RGB")}
    for name, v in extra.items():
        channels.update({f"{name}.{c}": np.ascontiguousarray(v[:, :, i])
                         for i, c in enumerate("RGB")})
    with atomic_path(path, overwrite=overwrite, flag="overwrite=True") as tmp:
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))
    return path


#: The first four bytes of every OpenEXR file.
EXR_MAGIC = bytes((0x76, 0x2F, 0x31, 0x01))


def read_exr_layers(path) -> dict[str, np.ndarray]:
    """Read an OpenEXR file written by ``write_exr``: ``{"": RGB image, name: layer, ...}``,
    each float32 (H, W, 3) (a layer is the channels ``<name>.R/G/B``). A file that is not
    OpenEXR, or is truncated or damaged, is a ``ValueError`` naming it; one that cannot be
    opened the ``OSError`` of opening it."""
    import OpenEXR
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such EXR file")
    with open(path, "rb") as f:          # an unreadable file is the OSError it is
        magic = f.read(4)
    if magic != EXR_MAGIC:
        raise ValueError(f"{path}: not an OpenEXR file (starts with {magic!r})")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            ch = {k: np.asarray(v.pixels, np.float32) for k, v in f.channels().items()}
    except Exception as e:               # OpenEXR's RuntimeError for a damaged file
        raise ValueError(f"{path}: truncated or damaged OpenEXR file "
                         f"({' '.join(str(e).split())[:120]})") from None
    missing = [c for c in "RGB" if c not in ch]
    if missing:
        raise ValueError(f"{path}: missing channels {missing} (has {sorted(ch)})")
    names = sorted({k.rsplit(".", 1)[0] for k in ch if k.endswith((".R", ".G", ".B"))})
    out = {"": np.stack([ch[c] for c in "RGB"], axis=-1)}
    for name in names:
        if all(f"{name}.{c}" in ch for c in "RGB"):
            out[name] = np.stack([ch[f"{name}.{c}"] for c in "RGB"], axis=-1)
    return out


def read_exr_metadata(path) -> dict[str, str]:
    """The metadata ``write_exr`` stored in an OpenEXR file's header: field -> string (empty
    for a file written without any). Errors as ``read_exr_layers``."""
    import OpenEXR
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such EXR file")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != EXR_MAGIC:
        raise ValueError(f"{path}: not an OpenEXR file (starts with {magic!r})")
    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            # copied while the file is open (closing it empties the header it returned)
            header = {k: v for k, v in f.header().items()
                      if isinstance(k, str) and k.startswith(META_PREFIX)}
    except Exception as e:               # OpenEXR's RuntimeError for a damaged file
        raise ValueError(f"{path}: truncated or damaged OpenEXR file "
                         f"({' '.join(str(e).split())[:120]})") from None
    return {k[len(META_PREFIX):]: str(v) for k, v in header.items()}


def read_exr(path) -> np.ndarray:
    """Read an RGB OpenEXR file as float32 (H, W, 3) (other layers are ignored)."""
    return read_exr_layers(path)[""]


#: The first eight bytes of every PNG file.
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def srgb_decode(values) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear RGB (the inverse of ``srgb_encode``'s curve),
    float32."""
    x = np.asarray(values, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def read_png(path) -> np.ndarray:
    """Read a PNG (8- or 16-bit; grey, grey + alpha, RGB or RGBA; alpha is dropped) as
    linear RGB float32 (H, W, 3) through ``srgb_decode``. A file that is not a PNG, or is
    damaged, is a ``ValueError`` naming it; one that cannot be opened its ``OSError``."""
    import imageio.v3 as iio
    path = Path(path)
    with open(path, "rb") as f:
        magic = f.read(8)
    if magic != PNG_MAGIC:
        raise ValueError(f"{path}: not a PNG file (starts with {magic[:4]!r})")
    try:
        data = np.asarray(iio.imread(path, extension=".png"))
    except Exception as e:               # Pillow's errors for a truncated or damaged file
        raise ValueError(f"{path}: truncated or damaged PNG file "
                         f"({' '.join(str(e).split())[:120]})") from None
    top = 65535.0 if data.dtype == np.uint16 or data.max(initial=0) > 255 else 255.0
    if data.ndim == 2:
        data = data[:, :, None]
    if data.shape[2] in (2, 4):
        data = data[:, :, :-1]           # drop alpha
    if data.shape[2] == 1:
        data = np.repeat(data, 3, axis=2)
    return srgb_decode(data.astype(np.float64) / top)


def srgb_curve(image) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (NaN as 0, clamped to [0, 1]) by the curve itself, in
    float64: the definition ``srgb_encode`` answers (uint8, the input's shape)."""
    x = np.clip(np.nan_to_num(np.asarray(image, np.float64), nan=0.0), 0.0, 1.0)
    y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(y * 255.0).astype(np.uint8)


_TABLES: dict = {}
#: ``srgb_encode``'s key: the top bits of a value's bit pattern (sign, exponent and the
#: first 7 / 8 mantissa bits), a bucket of values within 2^-7 / 2^-8 of each other, over
#: which the curve's byte rises by less than one: at most one step per bucket.
_KEY_BITS = {np.float32: 16, np.float64: 20}


def _srgb_steps(dtype) -> np.ndarray:
    """The 255 values of ``dtype`` (float32 or float64) where ``srgb_curve``'s byte steps
    up: entry k - 1 is the least value whose byte is at least k, found by bisection over the
    values' bit patterns in [0, 1] (ordered as the values are: no sign bit)."""
    uint = np.uint32 if dtype == np.float32 else np.uint64
    k = np.arange(1, 256)
    lo = np.zeros(255, uint)
    hi = np.full(255, np.array(1.0, dtype).view(uint))       # the byte of 1.0 is 255
    while np.any(lo < hi):
        mid = lo + (hi - lo) // 2
        up = srgb_curve(mid.view(dtype)) >= k
        hi = np.where(up, mid, hi)
        lo = np.where(up, lo, mid + 1)
    return hi.view(dtype)


def _srgb_tables(dtype) -> tuple:
    """Per key (``_KEY_BITS``): the byte of the bucket's least value (``srgb_curve``'s) and
    the one step inside the bucket (the least value with the next byte; +inf where the byte
    does not change in the bucket; NaN, which no value reaches, from 1.0's key on). Keys
    of negative values (sign bit) give 0, keys from 1.0's on (infinities and NaN included;
    NaN is set to 0 after) give 255."""
    if dtype not in _TABLES:
        uint = np.uint32 if dtype == np.float32 else np.uint64
        bits = 8 * np.dtype(dtype).itemsize
        shift = bits - _KEY_BITS[dtype]
        n = 1 << _KEY_BITS[dtype]
        top = int(np.array(1.0, dtype).view(uint)) >> shift        # the key of 1.0
        base = np.zeros(n, np.uint8)
        step = np.full(n, np.inf, dtype)
        keys = np.arange(top + 1, dtype=uint)
        first = (keys << uint(shift)).view(dtype)                   # each bucket's least
        nxt = ((keys + uint(1)) << uint(shift)).view(dtype)
        byte = srgb_curve(first)
        base[:top + 1] = byte
        base[top:n // 2] = 255                                     # 1.0 and above
        steps = np.append(_srgb_steps(dtype), np.inf).astype(dtype)
        s = steps[byte]                                            # next byte's least value
        inside = s < nxt
        step[:top + 1] = np.where(inside, s, np.inf)
        step[top:] = np.nan                                        # never reached

        _TABLES[dtype] = (base, step, shift, uint)
    return _TABLES[dtype]


def srgb_encode(image) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (clamped to [0, 1], NaN as 0); uint8, the input's shape.
    The bytes are ``srgb_curve``'s; a float32 or float64 image gets them from
    ``_srgb_tables`` (a bucket's byte, plus one where the value reaches the bucket's step:
    no float64 copy and power per value), any other dtype or byte order from the curve."""
    img = np.asarray(image)
    if img.dtype.type not in _KEY_BITS or not img.dtype.isnative:
        return srgb_curve(img)
    base, step, shift, uint = _srgb_tables(img.dtype.type)
    key = img.view(uint) >> uint(shift)
    out = base[key]
    out += img >= step[key]
    out[np.isnan(img)] = 0           # (their keys lie above 1.0's)
    return out


#: zlib level of the PNGs (``write_png``): 1, the fastest; the PNG is lossless at any level.
PNG_COMPRESS_LEVEL = 1


def write_png(path, image, *, overwrite: bool = False) -> Path:
    """Write ``image`` (linear RGB (H, W, 3)) as an 8-bit sRGB PNG (through Pillow itself:
    imageio's import and plugin layer cost a render's start-up more than the write), its
    pixels compressed at zlib level ``PNG_COMPRESS_LEVEL``."""
    from PIL import Image
    img = _check_image(image, str(path))
    path = Path(path)
    with atomic_path(path, overwrite=overwrite, flag="overwrite=True") as tmp:
        Image.fromarray(np.ascontiguousarray(srgb_encode(img))).save(
            tmp, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return path
