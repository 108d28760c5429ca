"""PLY vertex attributes beside the positions and faces ``meshio.load_ply`` reads: vertex
normals (``nx, ny, nz``) and colours (``red, green, blue``), for imported scenes
(``importers``) and Mitsuba XML ``ply`` shapes."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .meshio import MeshError, _parse_ply_header, load_ply

__all__ = ["PlyMesh", "read_ply"]


@dataclass
class PlyMesh:
    """float64 (V, 3) ``vertices``, int64 (F, 3) ``faces``; float64 (V, 3) ``normals`` and
    ``colors`` (in [0, 1]: integer types divided by their maximum), None when absent."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None


def read_ply(path) -> PlyMesh:
    """Positions and faces (``meshio.load_ply``) with the vertex element's normals and
    colours when it has them. Raises ``MeshError`` (file, and line for ascii) for a
    malformed file or a non-finite normal."""
    path = Path(path)
    vertices, faces = load_ply(path)
    data = path.read_bytes()
    fmt, elements, start, first_line = _parse_ply_header(path, data)
    names = [e.name for e in elements]
    vertex = elements[names.index("vertex")]
    cols = [p[0] for p in vertex.props]
    wanted = [c for c in ("nx", "ny", "nz", "red", "green", "blue") if c in cols]
    if not wanted:
        return PlyMesh(vertices, faces)
    if names.index("vertex") != 0 or not vertex.fixed:
        raise MeshError(f"{path}: vertex attributes are read only from a first element "
                        "'vertex' without list properties")
    if fmt == "ascii":
        lines = data[start:].decode("ascii", errors="replace").splitlines()[:vertex.count]
        arr = np.array(" ".join(lines).split(), np.float64).reshape(vertex.count, -1)
        columns = {c: arr[:, k].astype(vertex.props[k][1]) for k, c in enumerate(cols)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dt = np.dtype([(p[0], order + p[1]) for p in vertex.props])
        rec = np.frombuffer(data, dt, vertex.count, start)
        columns = {c: rec[c] for c in cols}
    normals = colors = None
    if all(c in columns for c in ("nx", "ny", "nz")):
        normals = np.stack([columns[c].astype(np.float64) for c in ("nx", "ny", "nz")], 1)
        if not np.all(np.isfinite(normals)):
            bad = int(np.argwhere(~np.isfinite(normals))[0, 0])
            where = f"{path}:{first_line + bad}" if fmt == "ascii" else f"{path}"
            raise MeshError(f"{where}: vertex {bad} has a non-finite normal "
                            f"{normals[bad].tolist()}")
    if all(c in columns for c in ("red", "green", "blue")):
        raw = [columns[c] for c in ("red", "green", "blue")]
        scale = (float(np.iinfo(raw[0].dtype).max)
                 if np.issubdtype(raw[0].dtype, np.integer) else 1.0)
        colors = np.stack([r.astype(np.float64) / scale for r in raw], 1)
    return PlyMesh(vertices, faces, normals, colors)
