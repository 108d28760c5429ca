"""OBJ and PLY readers against hand-written files and the bundled meshes' known counts."""
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from renderer.scene.meshio import MeshError, load_mesh, load_obj, load_ply

# the shared meshes lie beside the repository, as tests/data/imports/*.xml name them
MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)


def test_obj_polygons_become_fans_with_all_index_styles(tmp_path):
    p = tmp_path / "m.obj"
    p.write_text("# square and a triangle\nmtllib x.mtl\no thing\ng grp\n"
                 "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nusemtl red\n"
                 "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
                 "f -4//1 -3//1 -1//1\n"      # negative: relative to the 4 vertices read
                 "f 1/1 3/1 4/1\n")
    v, f = load_obj(p)
    assert v.dtype == np.float64 and f.dtype == np.int64
    np.testing.assert_array_equal(v, SQUARE)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [0, 1, 3], [0, 2, 3]])


@pytest.mark.parametrize("body, where", [
    ("v 0 0\n", ":1:"),
    ("v 0 0 0\nv 1 0 0\nv 0 x 0\n", ":3:"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", ":4:"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", ":4:"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", ":4:"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", ":4:"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a\n", ":4:"),
    ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 0"),
    ("v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 0"),
])
def test_obj_malformed_lines_name_file_and_line(tmp_path, body, where):
    p = tmp_path / "bad.obj"
    p.write_text(body)
    with pytest.raises(MeshError) as e:
        load_obj(p)
    assert str(p) in str(e.value) and where in str(e.value)


def _ply_header(fmt, nv, nf, vtype="float", extra="",
                face="property list uchar int vertex_indices"):
    return (f"ply\nformat {fmt} 1.0\ncomment test\nelement vertex {nv}\n"
            f"property {vtype} x\nproperty {vtype} y\nproperty {vtype} z\n{extra}"
            f"element face {nf}\n{face}\nend_header\n").encode()


def test_ply_ascii_with_extra_properties_and_polygons(tmp_path):
    p = tmp_path / "a.ply"
    body = "0 0 0 7\n1 0 0 7\n1 1 0 7\n0 1 0 7\n4 0 1 2 3\n3 0 2 3\n"
    p.write_bytes(_ply_header("ascii", 4, 2, extra="property uchar confidence\n") + body.encode())
    v, f = load_ply(p)
    np.testing.assert_array_equal(v, SQUARE)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [0, 2, 3]])


@pytest.mark.parametrize("order, fmt", [("<", "binary_little_endian"), (">", "binary_big_endian")])
@pytest.mark.parametrize("vtype, code", [("double", "d"), ("float", "f"), ("short", "h")])
def test_ply_binary_both_endians_and_types(tmp_path, order, fmt, vtype, code):
    verts = b"".join(struct.pack(order + 3 * code, *p) for p in SQUARE.astype(int).tolist())
    tris = struct.pack(order + "BiiiBiii", 3, 0, 1, 2, 3, 0, 2, 3)
    p = tmp_path / "b.ply"
    p.write_bytes(_ply_header(fmt, 4, 2, vtype=vtype) + verts + tris)
    v, f = load_ply(p)
    np.testing.assert_array_equal(v, SQUARE)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])
    # Same vertices, one quad with ushort count and uint indices: the general path.
    quad = struct.pack(order + "HIIII", 4, 0, 1, 2, 3)
    p.write_bytes(_ply_header(fmt, 4, 1, vtype=vtype,
                              face="property list ushort uint vertex_indices") + verts + quad)
    v, f = load_ply(p)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("make, message", [
    (lambda: b"plx\n", "not a PLY"),
    (lambda: _ply_header("binary_middle_endian", 3, 1), "unsupported PLY format"),
    (lambda: _ply_header("binary_little_endian", 3, 1) + b"\0" * 10, "file ends"),
    (lambda: _ply_header("ascii", 3, 1) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n", "out of range"),
    (lambda: _ply_header("ascii", 3, 1) + b"0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n", "non-finite"),
    (lambda: _ply_header("ascii", 3, 1) + b"0 0 0\n1 0 0\n", "file ends"),
])
def test_ply_malformed_files_raise(tmp_path, make, message):
    p = tmp_path / "bad.ply"
    p.write_bytes(make())
    with pytest.raises(MeshError) as e:
        load_ply(p)
    assert str(p) in str(e.value) and message in str(e.value)


def test_unsupported_extension(tmp_path):
    with pytest.raises(MeshError, match="unsupported mesh format"):
        load_mesh(tmp_path / "x.stl")


# Counts from /work/shared/data/meshes/SOURCES.md (checked there with plyfile / another reader).
@pytest.mark.parametrize("rel, nv, nf", [
    ("stanford_bunny/bun_zipper.ply", 35947, 69451),
    ("conference/conference.ply", 194399, 331179),
    ("cornell_box/cornell_box.obj", 76, 36),
    ("utah_teapot/teapot.obj", 3644, 6320),
])
def test_real_meshes_have_known_counts_and_load_fast(rel, nv, nf):
    path = MESHES / rel
    if not path.exists():
        pytest.skip(f"{path} not present")
    t0 = time.perf_counter()
    v, f = load_mesh(path)
    elapsed = time.perf_counter() - t0
    assert v.shape == (nv, 3) and f.shape == (nf, 3)
    assert f.min() >= 0 and f.max() < nv
    assert elapsed < 2.0, f"{rel} took {elapsed:.2f} s"


def test_bunny_bounding_box_matches_sources():
    path = MESHES / "stanford_bunny/bun_zipper.ply"
    if not path.exists():
        pytest.skip("bunny not present")
    v, _ = load_mesh(path)
    np.testing.assert_allclose(v.min(0), [-0.0947, 0.0330, -0.0619], atol=1e-4)
    np.testing.assert_allclose(v.max(0), [0.0610, 0.1873, 0.0588], atol=1e-4)
