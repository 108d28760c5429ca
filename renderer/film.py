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


def srgb_encode(image) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (clamped to [0, 1]); uint8 (H, W, 3)."""
    x = np.clip(np.nan_to_num(np.asarray(image, np.float64), nan=0.0), 0.0, 1.0)
    y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(y * 255.0).astype(np.uint8)


def write_png(path, image, *, overwrite: bool = False) -> Path:
    """Write ``image`` (linear RGB (H, W, 3)) as an 8-bit sRGB PNG."""
    import imageio.v3 as iio
    img = _check_image(image, str(path))
    path = Path(path)
    with atomic_path(path, overwrite=overwrite, flag="overwrite=True") as tmp:
        iio.imwrite(tmp, srgb_encode(img), extension=".png")
    return path
