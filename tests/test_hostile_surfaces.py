"""Hostile surface files and scales: every file gets a surface or a ValueError naming it.

PLY, STL, OBJ and OFF are read by numpy code that checks each stated count before it allocates
(``defop.geometry.surface_files``); a closed STL is welded into the closed surface its OBJ describes;
``check_surface`` judges a surface on a unit bounding-box diagonal, so every scale inside
``COORDINATE_RANGE`` gets the unit box's verdict, and scales outside it a clear error. Crash-class
inputs (headers claiming 10⁹ vertices, giant sparse files) run in a child process under a 2 GiB
address-space limit, so a C++ ``bad_alloc`` or an abort could not take the test run down unseen.
"""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.geometry import surface_files as sf
from defop.geometry.mesh import Mesh, read_mesh, signed_areas
from defop.geometry.volumetric import surface as surf

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# ------------------------------------------------------------------------------------------------ a box, six ways
def _box():
    """A closed 2 × 1 × 0.5 box of 20 triangles: four sides split into 4 around a centre, two into 2."""
    V = [[x, y, z] for z in (0, 0.5) for y in (0, 1) for x in (0, 2)]  # corner i: bits (x, y, z)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]  # outward
    F = []
    for k, q in enumerate(quads):
        if k < 4:
            V.append(np.mean([V[i] for i in q], axis=0).tolist())
            c = len(V) - 1
            F += [(q[i], q[(i + 1) % 4], c) for i in range(4)]
        else:
            F += [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
    return np.array(V, float), np.array(F, np.int64)


V_BOX, F_BOX = _box()


def _rows(prefix, A):
    """One line per row of A: ``prefix`` and its numbers (repr: floats round-trip exactly)."""
    return "".join(prefix + " ".join(map(repr, row)) + "\n" for row in np.asarray(A).tolist())


def _ply_header(fmt, n_v, n_f):
    return (
        f"ply\nformat {fmt} 1.0\ncomment made by a test\nelement vertex {n_v}\nproperty double x\n"
        f"property double y\nproperty double z\nelement face {n_f}\nproperty list uchar int vertex_indices\n"
        "end_header\n"
    ).encode()


def write_ply(path, V, F, binary=False, n_v=None, endian="<"):
    fmt = "ascii" if not binary else ("binary_little_endian" if endian == "<" else "binary_big_endian")
    head = _ply_header(fmt, len(V) if n_v is None else n_v, len(F))
    if binary:
        body = V.astype(endian + "f8").tobytes() + b"".join(struct.pack(endian + "B3i", 3, *t) for t in F)
    else:
        body = (_rows("", V) + _rows("3 ", F)).encode()
    path.write_bytes(head + body)
    return path


def write_stl(path, V, F, binary=False, count=None):
    if binary:
        rec = b"".join(struct.pack("<3f", 0, 0, 0) + V[t].astype("<f4").tobytes() + b"\0\0" for t in F)
        path.write_bytes(b"binary box".ljust(80, b" ") + struct.pack("<I", len(F) if count is None else count) + rec)
    else:
        facets = "".join(
            " facet normal 0 0 0\n  outer loop\n" + _rows("   vertex ", V[t]) + "  endloop\n endfacet\n" for t in F
        )
        path.write_text(f"solid box\n{facets}endsolid box\n")
    return path


def write_obj(path, V, F):
    path.write_text("# box\n" + _rows("v ", V) + _rows("f ", F + 1))
    return path


def write_off(path, V, F):
    path.write_text(f"OFF\n{len(V)} {len(F)} 0\n" + _rows("", V) + _rows("3 ", F))
    return path


WRITERS = {
    "box.obj": write_obj,
    "box.off": write_off,
    "box.ply": write_ply,
    "binary.ply": lambda p, V, F: write_ply(p, V, F, binary=True),
    "bigendian.ply": lambda p, V, F: write_ply(p, V, F, binary=True, endian=">"),
    "box.stl": write_stl,
    "binary.stl": lambda p, V, F: write_stl(p, V, F, binary=True),
}


def _same_surface(a, b):
    """The same triangles on the same points, whatever the vertex order."""
    return sorted(map(tuple, a.V[a.F].reshape(-1, 9).tolist())) == sorted(map(tuple, b.V[b.F].reshape(-1, 9).tolist()))


# ------------------------------------------------------------------------------------------------ formats and welding
@pytest.mark.parametrize("name", sorted(WRITERS))
def test_every_format_reads_the_closed_box(tmp_path, name):
    s = surf.read_surface(WRITERS[name](tmp_path / name, V_BOX, F_BOX))
    ref = sf.SurfaceFile(V_BOX, F_BOX, 0, tmp_path, "")
    assert s.V.shape == (12, 3) and s.F.shape == (20, 3) and _same_surface(s, ref)
    assert s.welded == (48 if name.endswith(".stl") else 0)  # STL: 60 corners, 12 points
    V, F = s  # unpacks like the (V, F) tuple it was
    assert len(s) == 2 and s[0] is V and s[-1] is F
    surf.check_surface(V, F)


def test_an_stl_box_meshes_exactly_like_its_obj(tmp_path):
    """Before: 60 unwelded vertices, and 'edge (0, 1) lies in only 1 triangle'. Now the tetrahedra are equal."""
    obj = surf.read_surface(write_obj(tmp_path / "b.obj", V_BOX, F_BOX))
    ref = surf.surface_mesh(*obj, n_vertices=300)
    for name in ("box.stl", "binary.stl", "box.ply", "box.off"):
        V, F = surf.read_surface(WRITERS[name](tmp_path / name, V_BOX, F_BOX))
        assert len(F) == 20 and len(V) == 12
        mesh = surf.surface_mesh(V, F, n_vertices=300)
        np.testing.assert_array_equal(mesh.V, ref.V, err_msg=name)
        np.testing.assert_array_equal(mesh.F, ref.F, err_msg=name)
    V, F = surf.read_surface(tmp_path / "box.stl")
    shape = dop.shapes.from_surface(V, F, handles=[[0.3, 0.5, 0.25], [1.7, 0.5, 0.25], [1.0, 0.2, 0.3]], n_vertices=150)
    assert shape.mesh.dim == 3 and len(shape.handles) == 3


def test_exact_welding_merges_signed_zeros_and_nothing_nearby():
    V = np.array([[0.0, 0, 0], [-0.0, 0, 0], [1e-300, 0, 0], [1, 0, 0], [0, 1, 0]])
    F = np.array([[0, 3, 4], [1, 4, 3], [2, 3, 4]])
    W, G, n = sf.weld(V, F)
    assert n == 1 and len(W) == 4 and G.tolist() == [[0, 2, 3], [0, 3, 2], [1, 2, 3]]


def _cracked_box(jitter, seed=0):
    """The box with every triangle on its own three vertices, each moved by up to ``jitter`` (a cracked OBJ)."""
    rng = np.random.default_rng(seed)
    V = V_BOX[F_BOX].reshape(-1, 3) + rng.uniform(-jitter, jitter, (60, 3))
    return V, np.arange(60).reshape(-1, 3)


def test_tolerance_welding_is_opt_in_and_closes_a_cracked_surface(tmp_path):
    path = write_obj(tmp_path / "cracked.obj", *_cracked_box(1e-9))
    V, F = surf.read_surface(path)
    with pytest.raises(ValueError, match=r"the surface is open"):
        surf.check_surface(V, F)
    s = surf.read_surface(path, weld_tolerance=1e-6)
    assert s.welded == 48 and len(s.V) == 12
    surf.check_surface(*s)
    for bad in (-1e-3, 0.5, "1e-6", True, float("nan")):
        with pytest.raises(ValueError, match="weld_tolerance must be a number"):
            surf.read_surface(path, weld_tolerance=bad)


def test_tolerance_welding_refuses_degenerate_or_non_manifold_results(tmp_path):
    thin = V_BOX * [1, 1, 0.02]  # the box 0.01 thick: a tolerance of 0.05 × the diagonal merges top and bottom
    with pytest.raises(
        ValueError,
        match=r"t\.obj: welding within 0\.05 × the diagonal makes \d+ triangles "
        r"degenerate \(two corners merged\), first is triangle \d+",
    ):
        surf.read_surface(write_obj(tmp_path / "t.obj", thin, F_BOX), weld_tolerance=0.05)
    two = np.vstack([V_BOX, V_BOX + [2 + 1e-9, 0, 0]])  # two boxes 1e-9 apart: their touching sides would fuse
    F2 = np.vstack([F_BOX, F_BOX + 12])
    path = write_obj(tmp_path / "two.obj", two, F2)
    assert surf.read_surface(path, weld_tolerance=0).welded == 0  # 0: exact welding, in any format
    assert (
        surf.read_surface(
            write_obj(tmp_path / "dup.obj", np.vstack([V_BOX, V_BOX[:1]]), F_BOX), weld_tolerance=0
        ).welded
        == 1
    )
    with pytest.raises(
        ValueError,
        match=r"two\.obj: welding within 1e-06 × the diagonal puts edge \(\d+, \d+\) "
        r"in [34] triangles \(not a manifold\)",
    ):
        surf.read_surface(path, weld_tolerance=1e-6)


# ------------------------------------------------------------------------------------------------ hostile files
def _ply_text(n_v, n_f, body):
    return _ply_header("ascii", n_v, n_f) + body.encode()


HOSTILE = [
    ("e.ply", b"", r"holds no data \(the file is empty\)"),
    ("e.stl", b"  \n", r"holds no data \(the file is empty\)"),
    ("e.obj", b"", r"holds no data"),
    ("e.off", b"", r"holds no data"),
    ("g.ply", b"\x00\xffgarbage" * 10, r"is not a PLY file"),
    (
        "g.stl",
        b"hello world garbage" * 10,
        r"is neither binary STL \(a binary STL's header declares [\d,]+ "
        r"triangles, [\d,]+ bytes, the file has 190\) nor ASCII STL",
    ),
    ("g.obj", b"\x00\xffgarbage" * 10, r"is not a text OBJ file"),
    ("g.off", b"\x00\xffgarbage" * 10, r"is not a text OFF file"),
    ("w.obj", b"just words\nno geometry\n", r"OBJ line 1: 'just' is not an OBJ statement"),
    ("gonly.obj", b"g only\n", r"holds no triangle surface \(0 vertex lines"),
    ("huge.ply", _ply_text(10**9, 1, "0 0 0\n3 0 0 0\n"), r"declares 1,000,000,000 vertex elements, limit 10,000,000"),
    ("sq.ply", _ply_text(8, 1, "").replace(b"vertex 8", "vertex ²".encode()), r"count '²' is not a non-negative"),
    ("short.ply", _ply_text(8, 1, "0 0 0\n1 1 1\n"), r"declares 28 values .* hold at most"),
    (
        "few.ply",
        _ply_text(3, 1, "0 0 0\n1 0 0\n0 1 0\n" * 2),
        r"the header declares 3 vertex, 1 face elements, 4 data lines \(one element a line\), the file has 6 "
        r"\(the first 6 lines have the 3 values of a vertex, the header counts 3 vertex elements\)",
    ),
    (
        "nan.ply",
        _ply_text(3, 1, "0 0 zz\n1 0 0\n0 1 0\n3 0 1 2\n"),
        r"ASCII PLY line 11: vertex 0, property 'z' is not a number",
    ),
    (
        "idx.ply",
        _ply_text(3, 1, "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"),
        r"ASCII PLY face 0 indexes vertex 7, but the file has 3 vertices",
    ),
    ("inf.obj", b"v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"vertex 0 has a non-finite coordinate"),
    ("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", r"OBJ line 4: face index 0"),
    ("idx.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", r"OBJ line 4: face index 9, but the file has 3 vertices"),
    ("two.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n", r"OBJ line 3: the face has 2 vertices"),
    ("huge.off", b"OFF\n1000000000 1 0\n0 0 0\n", r"declares 1,000,000,000 vertices, limit 10,000,000"),
    (
        "short.off",
        b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n",
        r"declares 3 vertices and 1 faces, one per line, but has 3 data lines",
    ),
    (
        "s.stl",
        b"solid x\n facet normal 0 0 0\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n endloop\n endfacet\nendsolid\n",
        r"ASCII STL facet 0 \(line 6\): expected 'vertex', got 'endloop'",
    ),
    ("n.stl", b"solid x\nendsolid x\n", r"holds no triangles"),
    (
        "x.stl",
        b"solid x\n facet normal 0 0 0\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n vertex 0 1 q\n endloop\n"
        b" endfacet\nendsolid\n",
        r"ASCII STL facet 0, coordinate 8 is not a number: 'q'",
    ),
    ("x.vtk", b"# vtk DataFile", r"unknown format '\.vtk'"),
    (
        "twice.ply",
        _ply_text(3, 1, "").replace(b"end_header", b"element face 0\nend_header"),
        r"declares an element twice: vertex, face, face",
    ),
]


@pytest.mark.parametrize("name, data, match", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_hostile_surface_files_are_value_errors_naming_the_file(tmp_path, name, data, match):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(ValueError, match=rf"^surface file {re.escape(str(path))}:? .*{match}"):
        surf.read_surface(path)


def test_binary_counts_must_match_the_file_size(tmp_path):
    path = write_stl(tmp_path / "n.stl", V_BOX, F_BOX, binary=True, count=21)  # one triangle short of its count
    with pytest.raises(ValueError, match=r"declares 21 triangles, 1,134 bytes, the file has 1,084"):
        surf.read_surface(path)
    path = write_ply(tmp_path / "n.ply", V_BOX, F_BOX, binary=True, n_v=13)
    with pytest.raises(ValueError, match=r"binary PLY size [\d,]+ bytes, but its header .* make [\d,]+ bytes"):
        surf.read_surface(path)
    quad = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    quads = _ply_header("binary_little_endian", 4, 1) + quad.tobytes() + struct.pack("<B4i", 4, 0, 1, 2, 3)
    (tmp_path / "q.ply").write_bytes(quads)  # binary PLY polygons are read (they were refused)
    assert sf.parse_surface(quads, ".ply")[1].tolist() == [[0, 1, 2], [0, 2, 3]]


def test_paths_that_are_not_readable_files_say_what_they_are(tmp_path):
    with pytest.raises(ValueError, match=rf"^surface file {re.escape(str(tmp_path))} is a directory, not a file"):
        surf.read_surface(tmp_path)
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(ValueError, match=r"d\.ply is a directory, not a file"):
        surf.read_surface(tmp_path / "d.ply")
    (tmp_path / "d.npz").mkdir()
    with pytest.raises(ValueError, match=r"^mesh file .*d\.npz is a directory, not a file"):
        Mesh.load(tmp_path / "d.npz")
    os.mkfifo(tmp_path / "f.stl")  # opening a FIFO to read would block: refused from its mode
    with pytest.raises(ValueError, match=r"f\.stl is not a regular file \(a FIFO"):
        surf.read_surface(tmp_path / "f.stl")
    with pytest.raises(ValueError, match=r"^no such surface file: .*missing\.ply"):
        surf.read_surface(tmp_path / "missing.ply")


_UNREADABLE = """
import sys
from defop.geometry.mesh import Mesh
from defop.geometry.volumetric.surface import read_surface
for path, read in ((sys.argv[1], Mesh.load), (sys.argv[2], read_surface)):
    try:
        read(path)
    except ValueError as exc:
        print(exc)
"""


def test_a_file_without_read_permission_is_called_unreadable(tmp_path, npz_box):
    """Root reads any file, so as root the child drops CAP_DAC_OVERRIDE and CAP_DAC_READ_SEARCH (setpriv):
    it is then refused like any user. Before: 'is not an .npz archive'."""
    mesh_path, surf_path = npz_box(tmp_path), write_obj(tmp_path / "box.obj", V_BOX, F_BOX)
    os.chmod(mesh_path, 0)
    os.chmod(surf_path, 0)
    cmd = [sys.executable, "-c", _UNREADABLE, str(mesh_path), str(surf_path)]
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: a permission test needs a process that lacks CAP_DAC_*")
        cmd = ["setpriv", "--inh-caps=-all", "--bounding-set=-dac_override,-dac_read_search", *cmd]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        f"mesh file {mesh_path} cannot be read: permission denied",
        f"surface file {surf_path} cannot be read: permission denied",
    ]


@pytest.fixture
def npz_box():
    def make(tmp_path):
        path = tmp_path / "m.npz"
        Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]])).save(path)
        return path

    return make


# ------------------------------------------------------------------------------------------------ crash class
_CRASH = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
from defop.geometry.volumetric.surface import read_surface
for path in sys.argv[1:]:
    try:
        read_surface(path)
        print("READ", path)
    except ValueError as exc:
        print("ValueError", exc)
"""


def test_crash_class_files_are_clean_errors_under_a_2_gib_address_space(tmp_path):
    """Before: libigl allocated a 10⁹-vertex PLY, printed std::bad_alloc and aborted (double free, SIGABRT)."""
    paths = [
        tmp_path / "huge.ply",
        tmp_path / "hugeb.ply",
        tmp_path / "huge.stl",
        tmp_path / "sparse.stl",
        tmp_path / "sparse.ply",
    ]
    paths[0].write_bytes(_ply_text(10**9, 12, "0 0 0\n"))
    write_ply(paths[1], V_BOX, F_BOX, binary=True, n_v=10**9)
    write_stl(paths[2], V_BOX, F_BOX, binary=True, count=2**32 - 1)
    k = sf.MAX_FILE_ELEMENTS + 1  # a sparse file exactly as long as its count says: 500 MB that use no disk
    with open(paths[3], "wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", k))
        fh.truncate(84 + 50 * k)
    with open(paths[4], "wb") as fh:  # larger than MAX_FILE_BYTES: not read at all
        fh.write(_ply_header("binary_little_endian", 10**7, 10**7))
        fh.truncate(sf.MAX_FILE_BYTES + 1)
    out = subprocess.run(
        [sys.executable, "-c", _CRASH, *map(str, paths)], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert out.returncode == 0 and out.stderr == "", out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert len(lines) == 5 and all(line.startswith(f"ValueError surface file {p}") for line, p in zip(lines, paths))
    for line, expect in zip(
        lines,
        [
            "declares 1,000,000,000 vertex elements, limit 10,000,000",
            "declares 1,000,000,000 vertex elements, limit 10,000,000",
            "a binary STL's header declares 4,294,967,295 triangles",
            "declares 10,000,001 triangles, limit 10,000,000",
            f"has {sf.MAX_FILE_BYTES + 1:,} bytes, limit {sf.MAX_FILE_BYTES:,}",
        ],
    ):
        assert expect in line, line


def _damaged(data, good):
    how = data.draw(st.sampled_from(["random", "truncate", "mutate"]))
    if how == "random":
        return data.draw(st.binary(max_size=2000))
    if how == "truncate":
        return good[: data.draw(st.integers(0, len(good) - 1))]
    raw = bytearray(good)
    for _ in range(data.draw(st.integers(1, 8))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    return bytes(raw)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_damaged_surface_files_are_a_surface_or_a_value_error_naming_them(tmp_path_factory, data):
    """Random bytes, truncations and up to 8 changed bytes of every format: never another exception type."""
    name = data.draw(st.sampled_from(sorted(WRITERS)))
    tmp = tmp_path_factory.mktemp("damaged")
    good = WRITERS[name](tmp / name, V_BOX, F_BOX).read_bytes()
    path = tmp / name
    path.write_bytes(_damaged(data, good))
    try:
        V, F = surf.read_surface(path)
    except ValueError as exc:
        assert str(exc).startswith(f"surface file {path}")
    else:
        assert np.isfinite(V).all() and F.min() >= 0 and F.max() < len(V) and len(V) <= sf.MAX_FILE_ELEMENTS


# ------------------------------------------------------------------------------------------------ coordinate range
def _flat_box_mesh(scale):
    V, F = surf.check_surface(V_BOX * scale, F_BOX)
    return surf.surface_mesh(V, F, n_vertices=150, checked=True)


REF = _flat_box_mesh(1.0)


@settings(max_examples=15, deadline=None)
@given(exponent=st.floats(-70, 70), mantissa=st.floats(1, 10))
def test_a_box_at_any_scale_meshes_like_the_unit_box_or_gets_the_range_error(exponent, mantissa):
    scale = mantissa * 10.0**exponent
    lo, hi = surf.COORDINATE_RANGE
    diag = scale * np.linalg.norm(np.ptp(V_BOX, axis=0))
    if scale * np.abs(V_BOX).max() > hi or diag < lo:
        with pytest.raises(ValueError, match=r"COORDINATE_RANGE\): rescale it"):
            _flat_box_mesh(scale)
        return
    mesh = _flat_box_mesh(scale)
    np.testing.assert_array_equal(mesh.F, REF.F)
    # the grid spacing is rounded to 24 significant bits (mesher.round_spacing): scaled grids differ by ~1e-7 × h
    np.testing.assert_allclose(mesh.V / scale, REF.V, rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    "scale, match",
    [
        (1e160, r"has a coordinate of magnitude 2e\+160; supported coordinates are at most 1e\+50"),
        (1e-60, r"has a bounding-box diagonal of 2.29e-60; the supported diagonal is at least 1e-50"),
        (1e-320, r"has a bounding-box diagonal of"),  # subnormal coordinates
        (0.0, r"has a bounding-box diagonal of 0"),
    ],
)
def test_scales_outside_the_range_are_named(scale, match):
    with pytest.raises(ValueError, match=match):
        surf.check_surface(V_BOX * scale, F_BOX)


@pytest.mark.parametrize("scale", [1e-30, 1e-12, 1.0, 1e12, 1e30])
def test_bad_surfaces_get_the_same_verdict_at_every_scale(scale):
    """Before: 1e-30 called a valid box self-intersecting (absolute tolerances); 1e160 called it degenerate."""
    two = np.vstack([V_BOX, V_BOX + [1.0, 0.3, 0.1]])  # two overlapping boxes, not declared as parts
    with pytest.raises(ValueError, match=r"the surface intersects itself"):
        surf.check_surface(two * scale, np.vstack([F_BOX, F_BOX + 12]))
    flat = V_BOX.copy()
    flat[8] = flat[0] + 1e-15 * (flat[2] - flat[0])  # a side's centre pulled onto a corner: zero-area triangles
    with pytest.raises(ValueError, match=r"surface triangles have zero area"):
        surf.check_surface(flat * scale, F_BOX)


# ------------------------------------------------------------------------------------------------ signed_areas
@pytest.mark.parametrize(
    "F, match",
    [
        ([[0, 1, 3]], r"element 0 of F indexes vertex 3, but V has 3 vertices \(valid indices 0 to 2\)"),
        ([[0, 1, 2], [0, -1, 2]], r"element 1 of F indexes vertex -1, but V has 3 vertices"),
        ([[0.0, 1.0, 2.0]], r"F must hold integer vertex indices, got dtype float64"),
        ([0, 1, 2], r"F must have shape \(m,3\)"),
    ],
)
def test_signed_areas_names_a_bad_face_index(F, match):
    """Before: numpy's IndexError, and a negative index wrapped around silently."""
    V = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(ValueError, match=match):
        signed_areas(V, np.array(F))
    assert signed_areas(V, np.zeros((0, 3), int)).shape == (0,)


def test_read_mesh_reads_obj_and_off_without_libigl(tmp_path, capfd):
    """Planar OBJ/OFF mesh files share the numpy readers: a garbled one is a ValueError and C++ prints nothing."""
    (tmp_path / "g.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 x\n")
    with pytest.raises(
        ValueError, match=r"g\.off could not be read as \.off \(OFF line 6: face 0, index 2 is not an int"
    ):
        read_mesh(tmp_path / "g.off")
    (tmp_path / "g.obj").write_text("v 0 0 0\nv 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"g\.obj could not be read as \.obj \(OBJ line 2: a vertex needs 3"):
        read_mesh(tmp_path / "g.obj")
    assert capfd.readouterr().err == ""
    (tmp_path / "ok.obj").write_text(
        textwrap.dedent("""\
        v 0 0 0
        v 1 0 0
        v 1 1 0
        v 0 1 0
        f 1 2 3 4
    """)
    )
    assert read_mesh(tmp_path / "ok.obj").F.tolist() == [[0, 1, 2], [0, 2, 3]]  # a quad as a fan, as libigl did


@pytest.mark.parametrize("scale", [1e-45, 1e-30, 1e30, 1e45])
def test_a_surface_in_the_coordinate_range_also_solves(scale):
    """COORDINATE_RANGE promises the solver too: a box at 1e±30 passed from_surface, then libigl's 3D cotangent
    Laplacian underflowed to NaN (1e-30) or 0 (from about 1e27) and the first solve raised scipy's 'Factor is exactly
    singular'. On the unit box's mesh scaled, the solve is the unit one's, scaled."""
    H = np.array([[0.2, 0.2, 0.1], [1.8, 0.2, 0.1], [0.2, 0.8, 0.4], [1.8, 0.8, 0.4]])
    shape = dop.scene.shapes.from_surface(V_BOX * scale, F_BOX, handles=H * scale, n_vertices=150)
    assert shape.mesh.bbox_diagonal > 0.5 * scale
    unit = dop.scene.shapes.from_surface(V_BOX, F_BOX, handles=H, n_vertices=150)
    h, move = unit.handles, np.array([0.05, 0.0, 0.0])
    for mesh, idx in ((shape.mesh, shape.handles), (Mesh(unit.mesh.V * scale, unit.mesh.F), h)):
        got = dop.solve(mesh, idx, mesh.V[idx] + move * scale, energy="arap")
        assert got.converged and np.isfinite(got.X).all()
    unit = unit.mesh
    ref = dop.solve(unit, h, unit.V[h] + move, energy="arap")
    assert np.allclose(got.X / scale, ref.X, rtol=0, atol=1e-12)
    L, L1 = mesh.cotmatrix, unit.cotmatrix
    assert np.allclose((L / scale).toarray(), L1.toarray(), rtol=1e-12, atol=1e-12 * abs(L1).max())


@given(st.integers(-300, 300))
@settings(max_examples=40, deadline=None)
def test_one_overflow_free_bounding_diagonal(exponent):
    """Welding, the coordinate range and the Laplacian's rescaling read one bounding-box diagonal (three copies of the
    computation before); it neither overflows nor underflows over float64's range."""
    scale = 10.0**exponent
    d = sf.bbox_diagonal(V_BOX * scale)
    assert d == pytest.approx(np.sqrt(2**2 + 1 + 0.25) * scale, rel=1e-14)
    if 1e-50 <= d and scale <= 1e50:
        assert surf.normalised(V_BOX * scale)[1] == d


@pytest.mark.parametrize("name", ["m.obj", "m.off"])
def test_read_mesh_keeps_the_file_size_limit(tmp_path, monkeypatch, name):
    """read_mesh read any OBJ/OFF whole: a 3 GiB one raised an empty MemoryError from pathlib.
    It now has read_surface's MAX_FILE_BYTES (lowered here, so that nothing large is written or read)."""
    path = tmp_path / name
    V, F = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])
    (write_obj if name.endswith(".obj") else write_off)(path, V, F)
    read_mesh(path)  # within the limit
    monkeypatch.setattr(sf, "MAX_FILE_BYTES", path.stat().st_size - 1)
    with pytest.raises(ValueError, match=rf"^mesh file .*{re.escape(name)} has [0-9,]+ bytes, limit [0-9,]+ "):
        read_mesh(path)
