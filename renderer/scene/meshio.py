"""Triangle-mesh readers: Wavefront OBJ and PLY (ascii, binary little/big endian).

Both return ``(vertices, faces)``: float64 (V, 3) positions and int64 (F, 3) zero-based
vertex indices. Polygons are split into fans ``(p0, p[i], p[i+1])``. Only positions and
faces are read; normals, texture coordinates, groups, materials and extra PLY properties are
ignored. Malformed input raises ``MeshError`` naming the file (and the line, for OBJ and
ascii PLY). Indices out of range and non-finite coordinates are errors; degenerate triangles
are kept (the scene loader drops them).

The readers are vectorised with numpy where the data allows: an all-triangle binary PLY is
read with one structured ``frombuffer``; ascii PLY is tokenised in one pass.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["MeshError", "load_mesh", "load_obj", "load_ply", "MESH_FORMATS"]


class MeshError(ValueError):
    """A mesh file is malformed; the message names the file (and line where known)."""


def _finish(path, vertices: np.ndarray, faces: np.ndarray):
    """Shared checks: finite coordinates, indices in range."""
    if vertices.size and not np.all(np.isfinite(vertices)):
        bad = int(np.argwhere(~np.isfinite(vertices))[0, 0])
        raise MeshError(f"{path}: vertex {bad} has a non-finite coordinate "
                        f"{vertices[bad].tolist()}")
    if faces.size:
        lo, hi = int(faces.min()), int(faces.max())
        if lo < 0 or hi >= len(vertices):
            f = int(np.argwhere((faces < 0) | (faces >= len(vertices)))[0, 0])
            raise MeshError(f"{path}: face {f} has vertex indices {faces[f].tolist()} out of "
                            f"range, expected 0 <= index < {len(vertices)} (vertex count)")
    return vertices.astype(np.float64, copy=False), faces.astype(np.int64, copy=False)


def _fan(polygons: list[list[int]]) -> np.ndarray:
    tris = [(p[0], p[i], p[i + 1]) for p in polygons for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


# ---- OBJ -------------------------------------------------------------------------------------
def load_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a Wavefront OBJ: ``v x y z [w]`` and ``f`` lines (``i``, ``i/t``, ``i/t/n``,
    ``i//n``; negative indices count back from the last vertex read). Other statements
    (vt, vn, g, o, s, usemtl, mtllib, l, p, ...) are ignored.

    Returns float64 (V, 3) vertices and int64 (F, 3) triangles (polygons as fans).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise MeshError(f"{path}: cannot read: {e.strerror}") from None
    coords: list[str] = []
    polys: list[list[int]] = []
    n_vert = 0
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line or line[0] not in "vf":
            continue
        parts = line.split()
        if not parts:
            continue
        tag = parts[0]
        if tag == "v":
            if len(parts) not in (4, 5, 7):     # x y z [w] or x y z r g b
                raise MeshError(f"{path}:{lineno}: 'v' expects 3 coordinates, "
                                f"got {line.strip()!r}")
            coords.append(" ".join(parts[1:4]))
            try:
                for p in parts[1:4]:
                    float(p)
            except ValueError:
                raise MeshError(f"{path}:{lineno}: 'v' coordinates must be numbers, "
                                f"got {line.strip()!r}") from None
            n_vert += 1
        elif tag == "f":
            if len(parts) < 4:
                raise MeshError(f"{path}:{lineno}: 'f' needs at least 3 vertices, "
                                f"got {line.strip()!r}")
            poly = []
            for tok in parts[1:]:
                head = tok.split("/", 1)[0]
                try:
                    i = int(head)
                except ValueError:
                    raise MeshError(f"{path}:{lineno}: bad face vertex {tok!r}, expected "
                                    "an index like 7, 7/2, 7/2/5 or 7//5") from None
                if i == 0:
                    raise MeshError(f"{path}:{lineno}: face index 0 (OBJ indices start "
                                    "at 1; negative ones count back)")
                j = i - 1 if i > 0 else n_vert + i
                if j < 0 or j >= n_vert:
                    raise MeshError(f"{path}:{lineno}: face index {i} out of range: "
                                    f"{n_vert} vertices defined so far")
                poly.append(j)
            polys.append(poly)
    vertices = (np.array(" ".join(coords).split(), dtype=np.float64).reshape(-1, 3)
                if coords else np.zeros((0, 3)))
    if polys and all(len(p) == 3 for p in polys):    # fast path: all triangles
        faces = np.asarray(polys, dtype=np.int64)
    else:
        faces = _fan(polys)
    return _finish(path, vertices, faces)


# ---- PLY -------------------------------------------------------------------------------------
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class _Element:
    def __init__(self, name: str, count: int):
        self.name, self.count = name, count
        self.props: list[tuple] = []     # (name, type) or (name, count_type, item_type)

    @property
    def fixed(self) -> bool:
        return all(len(p) == 2 for p in self.props)


def _parse_ply_header(path, data: bytes):
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError(f"{path}: not a PLY file (expected 'ply' ... 'end_header')")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    lines = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[_Element] = []
    for lineno, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0] in ("ply", "comment", "obj_info"):
            continue
        if parts[0] == "format":
            if len(parts) != 3 or parts[1] not in ("ascii", "binary_little_endian",
                                                     "binary_big_endian"):
                raise MeshError(f"{path}:{lineno}: unsupported PLY format {line!r}, "
                                "expected ascii, binary_little_endian or binary_big_endian")
            fmt = parts[1]
        elif parts[0] == "element":
            if len(parts) != 3 or not parts[2].isdigit():
                raise MeshError(f"{path}:{lineno}: bad element line {line!r}")
            elements.append(_Element(parts[1], int(parts[2])))
        elif parts[0] == "property":
            if not elements:
                raise MeshError(f"{path}:{lineno}: property before any element")
            if len(parts) == 5 and parts[1] == "list":
                if parts[2] not in _PLY_TYPES or parts[3] not in _PLY_TYPES:
                    raise MeshError(f"{path}:{lineno}: unknown PLY type in {line!r}")
                elements[-1].props.append((parts[4], _PLY_TYPES[parts[2]],
                                           _PLY_TYPES[parts[3]]))
            elif len(parts) == 3 and parts[1] in _PLY_TYPES:
                elements[-1].props.append((parts[2], _PLY_TYPES[parts[1]]))
            else:
                raise MeshError(f"{path}:{lineno}: bad property line {line!r}")
        else:
            raise MeshError(f"{path}:{lineno}: unknown PLY header line {line!r}")
    if fmt is None:
        raise MeshError(f"{path}: PLY header has no 'format' line")
    return fmt, elements, body_start, len(lines) + 1


def _face_list_prop(path, el: _Element):
    lists = [p for p in el.props if len(p) == 3]
    names = [p for p in lists if p[0] in ("vertex_indices", "vertex_index")]
    if len(names) != 1:
        raise MeshError(f"{path}: element 'face' needs one list property "
                        "'vertex_indices' (or 'vertex_index')")
    return names[0]


def load_ply(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY file (ascii, binary_little_endian or binary_big_endian).

    Vertex positions are the ``x, y, z`` properties of element ``vertex`` (any numeric type;
    other properties ignored). Faces are the ``list`` property ``vertex_indices`` of element
    ``face`` with any count/index types and polygon sizes (fanned). Other elements are skipped.
    Returns float64 (V, 3) vertices and int64 (F, 3) triangles.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise MeshError(f"{path}: cannot read: {e.strerror}") from None
    fmt, elements, start, body_line = _parse_ply_header(path, data)
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise MeshError(f"{path}: PLY has no 'vertex' element")
    vprops = [p[0] for p in elements[names.index("vertex")].props]
    for axis in "xyz":
        if axis not in vprops:
            raise MeshError(f"{path}: element 'vertex' has no property '{axis}'")
    if fmt == "ascii":
        vertices, polys = _ply_ascii(path, data[start:], elements, body_line)
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        vertices, polys = _ply_binary(path, data, start, elements, order)
    return _finish(path, vertices, polys)


def _ply_ascii(path, body: bytes, elements, first_line):
    text = body.decode("ascii", errors="replace")
    lines = text.splitlines()
    pos = 0                     # current line index into ``lines``
    vertices = np.zeros((0, 3))
    faces = np.zeros((0, 3), np.int64)

    def bad(i, what):
        return MeshError(f"{path}:{first_line + i}: {what}")

    for el in elements:
        chunk = lines[pos:pos + el.count]
        if len(chunk) < el.count:
            raise MeshError(f"{path}: file ends after {len(chunk)} of {el.count} "
                            f"'{el.name}' lines")
        if el.name == "vertex":
            if not el.fixed:
                raise MeshError(f"{path}: list properties in 'vertex' are not supported")
            n = len(el.props)
            try:
                arr = np.array(" ".join(chunk).split(), dtype=np.float64)
            except ValueError:
                for i, ln in enumerate(chunk):
                    try:
                        [float(x) for x in ln.split()]
                    except ValueError:
                        raise bad(pos + i, f"vertex {i}: expected numbers, got {ln!r}") \
                            from None
                raise
            if arr.size != n * el.count:
                for i, ln in enumerate(chunk):
                    if len(ln.split()) != n:
                        raise bad(pos + i, f"vertex {i}: expected {n} values, got {ln!r}")
            arr = arr.reshape(el.count, n)
            cols = [p[0] for p in el.props]
            vertices = arr[:, [cols.index("x"), cols.index("y"), cols.index("z")]]
        elif el.name == "face":
            prop = _face_list_prop(path, el)
            if len(el.props) == 1:
                try:
                    arr = np.array(" ".join(chunk).split(), dtype=np.int64)
                except ValueError:
                    arr = None
                if arr is not None and arr.size == 4 * el.count and el.count and \
                        np.all(arr[::4] == 3):                 # fast path: triangles
                    faces = arr.reshape(-1, 4)[:, 1:]
                    pos += el.count
                    continue
            k = [p[0] for p in el.props].index(prop[0])
            polys = []
            for i, ln in enumerate(chunk):
                toks = ln.split()
                # Scalar properties before the list take one token each.
                try:
                    vals = [int(float(x)) for x in toks]
                except ValueError:
                    raise bad(pos + i, f"face {i}: expected integers, got {ln!r}") from None
                off = 0
                for p in el.props[:k]:
                    off += 1 if len(p) == 2 else 1 + vals[off]
                if off >= len(vals) or len(vals) < off + 1 + vals[off]:
                    raise bad(pos + i, f"face {i}: truncated line {ln!r}")
                cnt = vals[off]
                if cnt < 3:
                    raise bad(pos + i, f"face {i}: polygon with {cnt} vertices, expected >= 3")
                polys.append(vals[off + 1: off + 1 + cnt])
            faces = _fan(polys)
        pos += el.count
    return vertices, faces


def _ply_binary(path, data: bytes, start: int, elements, order: str):
    off = start
    vertices = np.zeros((0, 3))
    faces = np.zeros((0, 3), np.int64)
    for el in elements:
        if el.fixed:
            dt = np.dtype([(p[0], order + p[1]) for p in el.props])
            size = dt.itemsize * el.count
            if off + size > len(data):
                raise MeshError(f"{path}: file ends inside element '{el.name}' "
                                f"({el.count} records of {dt.itemsize} bytes expected)")
            arr = np.frombuffer(data, dt, el.count, off)
            off += size
            if el.name == "vertex":
                vertices = np.stack([arr[a].astype(np.float64) for a in "xyz"], axis=1)
            continue
        if el.name == "vertex":
            raise MeshError(f"{path}: list properties in 'vertex' are not supported")
        # Fast path: every list has 3 entries -> fixed-size records.
        tri_dt = np.dtype([(p[0], order + p[1]) if len(p) == 2 else
                           (p[0], [("n", order + p[1]), ("i", order + p[2], (3,))])
                           for p in el.props])
        arr = None
        if off + tri_dt.itemsize * el.count <= len(data):
            arr = np.frombuffer(data, tri_dt, el.count, off)
            ok = all(np.all(arr[p[0]]["n"] == 3) for p in el.props if len(p) == 3)
            if not ok:
                arr = None
        if arr is not None:
            off += tri_dt.itemsize * el.count
            if el.name == "face":
                prop = _face_list_prop(path, el)
                faces = arr[prop[0]]["i"].astype(np.int64)
            continue
        # General path: walk the records.
        polys = []
        for i in range(el.count):
            for p in el.props:
                if len(p) == 2:
                    off += np.dtype(p[1]).itemsize
                    continue
                cdt, idt = np.dtype(order + p[1]), np.dtype(order + p[2])
                if off + cdt.itemsize > len(data):
                    raise MeshError(f"{path}: file ends inside '{el.name}' {i}")
                cnt = int(np.frombuffer(data, cdt, 1, off)[0])
                off += cdt.itemsize
                if off + cnt * idt.itemsize > len(data):
                    raise MeshError(f"{path}: file ends inside '{el.name}' {i}")
                if el.name == "face" and p[0] in ("vertex_indices", "vertex_index"):
                    if cnt < 3:
                        raise MeshError(f"{path}: face {i}: polygon with {cnt} vertices, "
                                        "expected >= 3")
                    polys.append(np.frombuffer(data, idt, cnt, off).astype(np.int64).tolist())
                off += cnt * idt.itemsize
        if el.name == "face":
            _face_list_prop(path, el)
            faces = _fan(polys)
    return vertices, faces


# ---- dispatch --------------------------------------------------------------------------------
MESH_FORMATS = {".obj": load_obj, ".ply": load_ply}


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read ``path`` by its extension (``MESH_FORMATS``)."""
    path = Path(path)
    reader = MESH_FORMATS.get(path.suffix.lower())
    if reader is None:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r}, expected one of "
                        f"{sorted(MESH_FORMATS)}")
    return reader(path)
