"""Surface files written in every format and encoding read back to the same mesh; corrupted ones are refused.

Random closed meshes (convex hulls of random points, at random scales and offsets) are written as PLY (ASCII,
binary little and big endian, with random property types and extra properties), STL (ASCII and binary), OBJ
(random positive or negative indices and ``v/vt/vn`` forms) and OFF (comments, counts on the keyword's line or
the next). Read back, they hold the same triangles (faces compared as sets of vertex triples, each turned to
start at its smallest corner: orientation kept; float32 coordinates for STL and ``float`` PLY). Random
corruptions (truncation, changed counts, garbage characters, fractional indices, a byte-order mark) give either a
``ValueError`` naming the file, or, where the corruption changes nothing (a byte-order mark, a character in a
comment), the same mesh: never another exception and never a different mesh.
"""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from defop.geometry import surface_files as sf
from defop.geometry.volumetric import surface as surf

FORMATS = ["ply-ascii", "ply-le", "ply-be", "stl-ascii", "stl-binary", "obj", "off"]
EXT = {"ply-ascii": ".ply", "ply-le": ".ply", "ply-be": ".ply", "stl-ascii": ".stl", "stl-binary": ".stl"}
SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


# ------------------------------------------------------------------------------------------------ meshes
def hull_mesh(seed, n, scale, offset):
    """A closed convex surface: the hull of n random points, outward, with only the hull's vertices."""
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 3)) * scale + offset
    hull = ConvexHull(P)
    F = hull.simplices.copy()
    normal = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    flip = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    F[flip] = F[flip][:, [0, 2, 1]]
    used, F = np.unique(F, return_inverse=True)
    return P[used], F.reshape(-1, 3)


def triples(V, F):
    """The triangles as a set of vertex-coordinate triples, each turned to start at its smallest corner."""
    out = set()
    for t in np.asarray(V, dtype=np.float64)[F].tolist():
        t = [tuple(c) for c in t]
        k = t.index(min(t))
        out.add(tuple(t[k:] + t[:k]))
    return out


@st.composite
def meshes(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    n = draw(st.integers(4, 24))
    scale = draw(st.sampled_from([1e-6, 1.0, 3e4]))
    offset = draw(st.sampled_from([0.0, 10.0, -1e3])) * scale
    return hull_mesh(seed, n, scale, offset)


# ------------------------------------------------------------------------------------------------ writers
def _rows(prefix, A):
    return "".join(prefix + " ".join(map(repr, row)) + "\n" for row in np.asarray(A).tolist())


def write(fmt, V, F, draw=None, opt=None):
    """The bytes of V, F in ``fmt``; ``opt`` (a dict of choices, drawn when ``draw`` is given) varies the encoding."""
    opt = {} if opt is None else opt
    pick = (
        (lambda key, values: opt.setdefault(key, draw(st.sampled_from(values))))
        if draw
        else (lambda k, v: opt.get(k, v[0]))
    )
    if fmt.startswith("ply"):
        return _ply(fmt, V, F, pick)
    if fmt == "stl-ascii":
        facets = "".join(
            f"facet normal 0 0 0\n outer loop\n{_rows('  vertex ', V[t].astype(np.float32).astype(float))}"
            " endloop\nendfacet\n"
            for t in F
        )
        return f"solid {pick('name', ['s', 'two words'])}\n{facets}endsolid\n".encode()
    if fmt == "stl-binary":
        rec = b"".join(struct.pack("<3f", 0, 0, 0) + V[t].astype("<f4").tobytes() + b"\0\0" for t in F)
        return b"header".ljust(80, b" ") + struct.pack("<I", len(F)) + rec
    if fmt == "obj":
        form = pick("form", ["{}", "{}/1", "{}//1", "{}/1/1"])
        negative = pick("negative", [False, True])
        body = "# written by a test\n" + _rows("v ", V) + "vt 0 0\nvn 0 0 1\ng part\n"
        rel = [[i - len(V) if negative else i + 1 for i in t] for t in F.tolist()]
        return (body + "".join("f " + " ".join(form.format(i) for i in t) + "\n" for t in rel)).encode()
    same_line = pick("same_line", [False, True])
    head = f"OFF {len(V)} {len(F)} 0\n" if same_line else f"OFF\n# a comment\n{len(V)} {len(F)}\n"
    return (head + _rows("", V) + "# faces\n" + _rows("3 ", F)).encode()


def _ply(fmt, V, F, pick):
    coord = pick("coord", ["double", "float"])
    index = pick("index", ["int", "uint"])
    extra = pick("extra", [False, True])  # an extra vertex and face property, and an element after the faces
    encoding = {"ply-ascii": "ascii", "ply-le": "binary_little_endian", "ply-be": "binary_big_endian"}[fmt]
    head = f"ply\nformat {encoding} 1.0\n"
    head += f"comment a test\nelement vertex {len(V)}\n" + "".join(f"property {coord} {c}\n" for c in "xyz")
    head += "property uchar red\n" * extra + f"element face {len(F)}\nproperty list uchar {index} vertex_indices\n"
    head += "property short flags\nelement tag 1\nproperty int id\n" * extra + "end_header\n"
    Vt = V.astype(np.float32).astype(float) if coord == "float" else V
    if fmt == "ply-ascii":
        vrows = "".join(" ".join(map(repr, v)) + " 7" * extra + "\n" for v in Vt.tolist())
        frows = "".join("3 " + " ".join(map(str, t)) + " -2" * extra + "\n" for t in F.tolist())
        return (head + vrows + frows + "5\n" * extra).encode()
    o = "<" if fmt == "ply-le" else ">"
    c, i = {"double": "d", "float": "f"}[coord], {"int": "i", "uint": "I"}[index]
    body = b"".join(struct.pack(o + "3" + c + "B" * extra, *v, *[7] * extra) for v in Vt.tolist())
    body += b"".join(struct.pack(o + "B3" + i + "h" * extra, 3, *t, *[-2] * extra) for t in F.tolist())
    return head.encode() + body + struct.pack(o + "i", 5) * extra


def expected(fmt, V, F, opt=None):
    f32 = fmt.startswith("stl") or (opt or {}).get("coord") == "float"
    return triples(V.astype(np.float32).astype(float) if f32 else V, F)


# ------------------------------------------------------------------------------------------------ round trips
def written(tmp_path_factory, fmt, V, F, draw, corrupted=False):
    """(path, encoding choices, corruption kind or None) of V, F written in ``fmt``, corrupted if asked."""
    opt = {}
    raw, kind = write(fmt, V, F, draw, opt), None
    if corrupted:
        raw, kind = corrupt(fmt, raw, draw)
    path = tmp_path_factory.mktemp("m") / f"m{EXT.get(fmt, '.' + fmt)}"
    path.write_bytes(raw)
    return path, opt, kind


@settings(max_examples=60, **SETTINGS)
@given(mesh=meshes(), fmt=st.sampled_from(FORMATS), data=st.data())
def test_every_format_and_encoding_reads_back_the_same_mesh(tmp_path_factory, mesh, fmt, data):
    V, F = mesh
    path, opt, _ = written(tmp_path_factory, fmt, V, F, data.draw)
    s = sf.read_surface_file(path)
    assert len(s.F) == len(F) and triples(s.V, s.F) == expected(fmt, V, F, opt)
    assert len(s.V) == len(V)  # STL welded exactly back to the shared vertices
    surf.check_surface(*s)


# ------------------------------------------------------------------------------------------------ corruptions
def _last_line_start(raw):
    return raw.rstrip(b"\n").rfind(b"\n") + 1


def corrupt(fmt, raw, draw):
    """(bytes, kind) of a corruption of ``raw`` that a reader can detect, or that changes nothing."""
    kinds = ["bom", "fraction"] + ["count"] * (fmt not in ("obj", "stl-ascii")) + ["truncate"] * (fmt != "obj")
    kinds += ["garbage"] * (fmt in ("ply-ascii", "stl-ascii", "obj", "off"))
    kind = draw(st.sampled_from(kinds))
    if kind == "bom":
        return b"\xef\xbb\xbf" + raw, kind
    if kind == "truncate":  # text: at least the last line goes (a cut last number looks like another number)
        end = _last_line_start(raw) if fmt in ("ply-ascii", "off") else len(raw)
        if fmt == "stl-ascii":
            end = raw.rfind(b"endsolid")
        return raw[: draw(st.integers(0, end - 1))], kind
    if kind == "count":
        return _recount(fmt, raw, draw), kind
    if kind == "fraction":
        return _fraction(fmt, raw, draw), kind
    at = draw(st.integers(0, len(raw)))
    return raw[:at] + draw(st.sampled_from([b"@", b"q", b"Z", b"!", b"$"])) + raw[at:], kind


def _recount(fmt, raw, draw):
    d = draw(st.sampled_from([-3, -1, 1, 2]))
    if fmt == "stl-binary":
        return raw[:80] + struct.pack("<I", max(0, struct.unpack("<I", raw[80:84])[0] + d)) + raw[84:]
    if fmt == "off":
        m = re.search(rb"(\d+) (\d+)", raw)
        g = draw(st.sampled_from([1, 2]))
        new = str(max(0, int(m.group(g)) + d)).encode()
        return raw[: m.start(g)] + new + raw[m.end(g) :]
    which = draw(st.sampled_from([b"vertex", b"face"]))
    m = re.search(rb"element " + which + rb" (\d+)", raw)
    return raw[: m.start(1)] + str(max(0, int(m.group(1)) + d)).encode() + raw[m.end(1) :]


def _fraction(fmt, raw, draw):
    """An index written with a fraction (binary PLY: a float-typed index list holding 0.5)."""
    if fmt in ("ply-le", "ply-be", "stl-binary"):
        o = ">" if fmt == "ply-be" else "<"
        V, F = hull_mesh(1, 8, 1.0, 0.0)
        F = F.astype(float)
        F[draw(st.integers(0, len(F) - 1)), draw(st.integers(0, 2))] += 0.5
        head = raw[: raw.index(b"end_header\n") + 11] if fmt != "stl-binary" else None
        if head is None:
            return raw[:83]  # an STL has no indices: a short file instead
        head = re.sub(rb"element vertex \d+", b"element vertex 8", head)
        head = re.sub(rb"element face \d+", f"element face {len(F)}".encode(), head)
        head = re.sub(rb"list uchar u?int vertex_indices", b"list uchar float vertex_indices", head)
        head = head.replace(b"property uchar red\n", b"").replace(b"property short flags\n", b"")
        head = head.replace(b"element tag 1\nproperty int id\n", b"")
        head = re.sub(rb"property float ([xyz])", rb"property double \1", head)
        return head + V.astype(o + "f8").tobytes() + b"".join(struct.pack(o + "B3f", 3, *t) for t in F)
    text = raw.decode("latin-1")
    spots = {
        "ply-ascii": r"(?m)^3 (\d+)",
        "off": r"(?m)^3 (\d+)",
        "obj": r"(?m)^f (-?\d+)",
        "stl-ascii": r"vertex (\S+)",
    }[fmt]
    found = list(re.finditer(spots, text))
    m = found[draw(st.integers(0, len(found) - 1))]  # ASCII STL has no indices: a coordinate with two points
    return (text[: m.end(1)] + ".5" + text[m.end(1) :]).encode("latin-1")


@settings(max_examples=150, **SETTINGS)
@given(mesh=meshes(), fmt=st.sampled_from(FORMATS), data=st.data())
def test_corrupted_files_are_refused_by_name_or_read_unchanged(tmp_path_factory, mesh, fmt, data):
    V, F = mesh
    path, opt, kind = written(tmp_path_factory, fmt, V, F, data.draw, corrupted=True)
    try:
        s = sf.read_surface_file(path)
    except ValueError as exc:
        msg = str(exc)
        assert msg.startswith(f"surface file {path}") and len(msg) > len(str(path)) + 20, msg
        if kind == "fraction" and fmt != "stl-ascii" and fmt != "stl-binary":
            assert re.search(r"(line \d+|face \d+)", msg), msg
        return
    assert kind in ("bom", "garbage", "truncate", "count"), f"{kind} read as a surface"
    assert triples(s.V, s.F) == expected(fmt, V, F, opt), f"{kind}: a different mesh was read silently"


# ------------------------------------------------------------------------------------------------ polygons
def star_prism(seed, k, h=0.7):
    """A prism over a random star-shaped (often concave) k-gon: its caps are two k-gons, its sides quads."""
    rng = np.random.default_rng(seed)
    gaps = rng.uniform(1, 2, k)  # every angular gap below pi (at most 4 pi / 5): the origin sees every edge
    angle = np.cumsum(gaps * 2 * np.pi / gaps.sum())
    radius = rng.uniform(0.2, 1.0, k)
    P = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    area = 0.5 * float(np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1]))
    V = np.vstack([np.column_stack([P, np.zeros(k)]), np.column_stack([P, np.full(k, h)])])
    polys = [list(range(k - 1, -1, -1)), list(range(k, 2 * k))]
    polys += [[i, (i + 1) % k, (i + 1) % k + k, i + k] for i in range(k)]
    return V, polys, area * h


def write_polygons(fmt, V, polys):
    if fmt == "obj":
        body = "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
        return (body + "".join("f " + " ".join(str(i - len(V)) for i in p) + "\n" for p in polys)).encode()
    if fmt == "off":
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
        return (
            f"OFF\n{len(V)} {len(polys)} 0\n" + body + "".join(f"{len(p)} {' '.join(map(str, p))}\n" for p in polys)
        ).encode()
    head = _ply_head_polygons("ascii" if fmt == "ply-ascii" else "binary_big_endian", len(V), len(polys))
    if fmt == "ply-ascii":
        rows = "".join(" ".join(map(repr, v)) + "\n" for v in V.tolist())
        return head + (rows + "".join(f"{len(p)} {' '.join(map(str, p))}\n" for p in polys)).encode()
    return head + V.astype(">f8").tobytes() + b"".join(struct.pack(f">B{len(p)}i", len(p), *p) for p in polys)


def _ply_head_polygons(encoding, nv, nf):
    return (
        f"ply\nformat {encoding} 1.0\nelement vertex {nv}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()


@settings(max_examples=40, **SETTINGS)
@given(
    seed=st.integers(0, 2**32 - 1),
    k=st.integers(4, 14),
    fmt=st.sampled_from(["obj", "off", "ply-ascii", "ply-be"]),
)
def test_concave_polygons_are_triangulated_inside_themselves(tmp_path_factory, seed, k, fmt):
    """Each cap becomes k-2 triangles inside it: the surface is closed, does not cross itself, and encloses the
    prism's volume (a fan of a concave cap overlaps itself and fails here)."""
    V, polys, volume = star_prism(seed, k)
    path = tmp_path_factory.mktemp("poly") / f"p{EXT.get(fmt, '.' + fmt)}"
    path.write_bytes(write_polygons(fmt, V, polys))
    s = sf.read_surface_file(path)
    assert len(s.F) == 2 * (k - 2) + 2 * k
    W, F = surf.check_surface(*s)
    assert surf.enclosed_volume(W, F) == pytest.approx(volume, rel=1e-9)
