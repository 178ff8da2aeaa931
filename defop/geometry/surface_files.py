"""Triangle surface files (PLY, STL, OBJ, OFF) read safely, and vertex welding.

Every count a file states is checked before anything is allocated for it: at most
:data:`MAX_FILE_ELEMENTS` vertices or triangles; a binary PLY or STL must be exactly as long as its header
plus count × record size; an ASCII count can be at most the bytes left divided by the shortest record
(every value takes at least one character and one separator); a file above :data:`MAX_FILE_BYTES` is
not read at all. The readers are numpy code (no compiled
reader: libigl's trusted a PLY header's counts, allocated 10⁹ vertices and aborted the interpreter, and
read short or garbled ASCII PLY data as uninitialised memory). Every error is a ``ValueError`` that
names the file and what is wrong.

STL stores three corners per triangle and no shared vertices: :func:`weld` merges exactly coincident
coordinates, so a closed STL reads as the same closed surface as its OBJ. Welding within a tolerance is
opt-in (``weld_tolerance``) and refuses to create degenerate or non-manifold triangles.
"""

from __future__ import annotations

import dataclasses
import os
import re
import stat
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_FILE_ELEMENTS",
    "SURFACE_FORMATS",
    "SurfaceFile",
    "bbox_diagonal",
    "check_file",
    "check_size",
    "parse_surface",
    "read_surface_file",
    "weld",
]

#: the most vertices or triangles a mesh or surface file may declare (checked before anything is allocated)
MAX_FILE_ELEMENTS = 10_000_000

#: the largest file read at all (checked before reading): a 10⁷-triangle binary STL is 500 MB
MAX_FILE_BYTES = 2**30

#: the file name endings :func:`read_surface_file` reads
SURFACE_FORMATS = (".ply", ".stl", ".obj", ".off")

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_COUNT = re.compile(r"[0-9]{1,19}")  # ASCII digits only: '²'.isdigit() is True, and int('²') fails


@dataclasses.dataclass(frozen=True, eq=False)
class SurfaceFile:
    """A triangle surface read from a file; it behaves as the tuple ``(V, F)`` (``V, F = surface``).

    Attributes
    ----------
    V : (n, 3) numpy array
        Vertex positions (float64).
    F : (k, 3) int numpy array
        Triangles, indices into V.
    welded : int
        How many vertices welding merged into others (STL: corners at exactly the same coordinates;
        with a ``weld_tolerance``, also those within it).
    path : pathlib.Path
    format : str
        ``"ply-ascii"``, ``"ply-binary_little_endian"``, ``"stl-binary"``, ``"stl-ascii"``, ``"obj"`` or ``"off"``.
    """

    V: np.ndarray
    F: np.ndarray
    welded: int
    path: Path
    format: str

    def __iter__(self):
        return iter((self.V, self.F))

    def __len__(self):
        return 2

    def __getitem__(self, i):
        return (self.V, self.F)[i]


def check_file(path, what="file"):
    """``path`` as a Path to an existing, readable regular file; ValueError naming it otherwise.

    A directory, a FIFO or device (reading one could block), a missing file and one without read
    permission each get their own message.
    """
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or pathlib.Path, got {type(path).__name__}")
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise ValueError(f"no such {what}: {path}") from None
    except OSError as exc:
        raise ValueError(f"{what} {path} cannot be read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise ValueError(f"{what} {path} is a directory, not a file")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{what} {path} is not a regular file (a FIFO, socket or device)")
    try:
        with open(path, "rb"):
            pass
    except PermissionError:
        raise ValueError(f"{what} {path} cannot be read: permission denied") from None
    except OSError as exc:
        raise ValueError(f"{what} {path} cannot be read ({exc.strerror or exc})") from None
    return path


def check_size(path, what="file"):
    """The size of the file ``path`` in bytes; ValueError naming it above :data:`MAX_FILE_BYTES` (nothing is read)."""
    size = Path(path).stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(
            f"{what} {path} has {size:,} bytes, limit {MAX_FILE_BYTES:,} (defop.geometry.surface_files.MAX_FILE_BYTES)"
        )
    return size


def read_surface_file(path, weld_tolerance=None):
    """Read a triangle surface from a PLY (ASCII or binary), STL (ASCII or binary), OBJ or OFF file.

    Parameters
    ----------
    path : str or pathlib.Path
        The format is chosen by the ending (:data:`SURFACE_FORMATS`, any case).
    weld_tolerance : float, optional
        Also merge vertices closer than ``weld_tolerance`` × the bounding-box diagonal (:func:`weld`), in
        any format; 0 merges exactly coincident ones. Without it, STL corners at exactly the same
        coordinates are merged (STL shares no vertices) and the other formats keep their vertices.

    Returns
    -------
    surface : SurfaceFile
        ``V, F = surface`` unpacks it; ``surface.welded`` counts the merged vertices.

    Raises
    ------
    ValueError
        A missing or unreadable path, a directory, an unknown ending, a count above
        :data:`MAX_FILE_ELEMENTS` or above what the file's size can hold, a malformed or empty file,
        polygons other than triangles in a binary PLY, face indices out of range, non-finite
        coordinates, or welding that creates a degenerate or non-manifold triangle. The message names the file.
    """
    path = check_file(path, "surface file")
    ext = path.suffix.lower()
    if ext not in SURFACE_FORMATS:
        raise ValueError(f"surface file {path}: unknown format {ext!r}; use {', '.join(SURFACE_FORMATS)}")
    tol = _check_tolerance(weld_tolerance)
    size = check_size(path, "surface file")
    try:
        with open(path, "rb") as fh:
            head = fh.read(84)
            if ext == ".stl" and len(head) == 84 and size == 84 + 50 * int.from_bytes(head[80:], "little"):
                _count(str(int.from_bytes(head[80:], "little")), "triangles")  # before reading a sparse giant
            data = head + fh.read()
        V, F, fmt = parse_surface(data, ext)
        welded = 0
        if ext == ".stl" or weld_tolerance is not None:
            V, F, welded = weld(V, F, tol)
    except ValueError as exc:
        raise ValueError(f"surface file {path}: {exc}") from None
    except MemoryError:
        raise MemoryError(
            f"surface file {path} ({size:,} bytes) does not fit in the memory left while it is "
            "read (ASCII files need several times their size)"
        ) from None
    return SurfaceFile(V, F, welded, path, fmt)


def parse_surface(data, ext):
    """V (n, 3), F (k, 3) and the format name from the bytes of a PLY, STL, OBJ or OFF file (no welding).

    The counts are checked as :func:`read_surface_file` describes; polygons are split into triangle fans
    (ASCII formats). ValueError (without the file name) for anything malformed.
    """
    if ext not in SURFACE_FORMATS:
        raise ValueError(f"unknown format {ext!r}; use {', '.join(SURFACE_FORMATS)}")
    if not data.strip():
        raise ValueError("holds no data (the file is empty)")
    V, F, fmt = {".ply": _read_ply, ".stl": _read_stl, ".obj": _read_obj, ".off": _read_off}[ext](data)
    return (*_checked(V, F), fmt)


def _check_tolerance(tol):
    if tol is None:
        return 0.0
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.floating, np.integer)):
        raise ValueError(f"weld_tolerance must be a number in [0, 0.1) or None, got {tol!r}")
    if not 0 <= float(tol) < 0.1:
        raise ValueError(f"weld_tolerance must be a number in [0, 0.1) (× the bounding-box diagonal), got {tol!r}")
    return float(tol)


def _checked(V, F):
    """V (n,3) finite float64 and F (k,3) int64 indexing it; ValueError naming the first bad row."""
    if len(V) == 0 or len(F) == 0:
        raise ValueError(f"holds no triangle surface ({len(V)} vertices, {len(F)} triangles)")
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ValueError(f"vertex {int(np.flatnonzero(bad)[0])} has a non-finite coordinate (NaN or inf)")
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    out = (F < 0) | (F >= len(V))
    if out.any():
        t, j = (int(x) for x in np.argwhere(out)[0])
        raise ValueError(f"triangle {t} indexes vertex {int(F[t, j])}, but the file has {len(V)} vertices")
    return np.ascontiguousarray(V), np.ascontiguousarray(F)


def _count(word, what):
    if not _COUNT.fullmatch(word):
        raise ValueError(f"the {what} count {word!r} is not a non-negative integer")
    n = int(word)
    if n > MAX_FILE_ELEMENTS:
        raise ValueError(
            f"declares {n:,} {what}, limit {MAX_FILE_ELEMENTS:,} (defop.geometry.surface_files.MAX_FILE_ELEMENTS)"
        )
    return n


def _fits(n, what, per_record, nbytes):
    """ASCII: n records of at least ``per_record`` bytes must fit in ``nbytes``."""
    if n * per_record > nbytes:
        raise ValueError(
            f"declares {n:,} {what}, but {nbytes:,} bytes of data hold at most "
            f"{nbytes // per_record:,} (each takes at least {per_record} bytes)"
        )


def _text(data, what):
    if b"\0" in data:
        raise ValueError(f"is not a text {what} file (it holds NUL bytes)")
    return data.decode("latin-1")


def _floats(tokens, where):
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for i, t in enumerate(tokens):
            try:
                float(t)
            except ValueError:
                raise ValueError(f"{where(i)} is not a number: {t[:40]!r}") from None
        raise


def _ints(tokens, where):
    for i, t in enumerate(tokens):
        if not re.fullmatch(r"[-+]?[0-9]{1,18}", t):
            raise ValueError(f"{where(i)} is not an integer: {t[:40]!r}")
    return np.array([int(t) for t in tokens], dtype=np.int64)


def _fan(polygons, where):
    """Triangles of polygons (lists of vertex indices) by fans from their first vertex."""
    tris = []
    for i, p in enumerate(polygons):
        if len(p) < 3:
            raise ValueError(f"{where(i)} has {len(p)} vertices, a face needs at least 3")
        tris += [(p[0], p[j], p[j + 1]) for j in range(1, len(p) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


# ------------------------------------------------------------------------------------------------ STL
def _read_stl(data):
    """Binary STL when the size matches its count exactly, else ASCII STL (``solid``)."""
    if len(data) >= 84:
        k = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * k:
            if k > MAX_FILE_ELEMENTS:
                _count(str(k), "triangles")
            rec = np.frombuffer(data, dtype=_STL_RECORD, count=k, offset=84)
            return rec["corners"].reshape(-1, 3).astype(np.float64), np.arange(3 * k).reshape(-1, 3), "stl-binary"
    k = int.from_bytes(data[80:84], "little")
    binary = (
        f"a binary STL's header declares {k:,} triangles, {84 + 50 * k:,} bytes, the file has {len(data):,}"
        if len(data) >= 84
        else f"{len(data)} bytes are too short for a binary STL (84-byte header)"
    )
    if not data.lstrip()[:5].lower() == b"solid":
        raise ValueError(f"is neither binary STL ({binary}) nor ASCII STL (it does not start with 'solid')")
    try:
        return (*_read_stl_ascii(_text(data, "STL")), "stl-ascii")
    except ValueError as exc:
        raise ValueError(f"is neither binary STL ({binary}) nor ASCII STL ({exc})") from None


def _read_stl_ascii(text):
    tokens = text.split()
    low = [t.lower() for t in tokens]
    starts = [i for i, t in enumerate(low) if t == "facet"]
    _fits(len(starts), "triangles", 60, len(text))  # "facet normal 0 0 0 outer loop vertex 0 0 0 ×3 endloop endfacet"
    if len(starts) > MAX_FILE_ELEMENTS:
        _count(str(len(starts)), "triangles")
    if not starts:
        raise ValueError("holds no triangles (no 'facet' in an ASCII STL)")
    keys = {
        0: "facet",
        1: "normal",
        5: "outer",
        6: "loop",
        7: "vertex",
        11: "vertex",
        15: "vertex",
        19: "endloop",
        20: "endfacet",
    }
    coords = []
    for n, s in enumerate(starts):
        for off, key in keys.items():
            if s + off >= len(low) or low[s + off] != key:
                got = tokens[s + off][:40] if s + off < len(low) else "the end of the file"
                raise ValueError(f"ASCII STL facet {n}: expected {key!r}, got {got!r}")
        coords += tokens[s + 8 : s + 11] + tokens[s + 12 : s + 15] + tokens[s + 16 : s + 19]
    V = _floats(coords, lambda i: f"ASCII STL facet {i // 9}, coordinate {i % 9}")
    return V.reshape(-1, 3), np.arange(3 * len(starts)).reshape(-1, 3)


# ------------------------------------------------------------------------------------------------ OBJ
def _read_obj(data):
    lines = _text(data, "OBJ").splitlines()
    vt, vline, faces = [], [], []
    for no, line in enumerate(lines, 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if words[0] == "v":
            if len(words) < 4:
                raise ValueError(f"OBJ line {no}: a vertex needs 3 coordinates, got {len(words) - 1}")
            vt += words[1:4]
            vline.append(no)
        elif words[0] == "f":
            faces.append((no, len(vline), [w.split("/", 1)[0] for w in words[1:]]))
    if len(vline) > MAX_FILE_ELEMENTS or len(faces) > MAX_FILE_ELEMENTS:
        _count(str(max(len(vline), len(faces))), "vertices or faces")
    if not vline or not faces:
        raise ValueError(f"holds no triangle surface ({len(vline)} vertex lines 'v', {len(faces)} face lines 'f')")
    V = _floats(vt, lambda i: f"OBJ line {vline[i // 3]}, coordinate {i % 3}")
    polys = []
    for no, seen, words in faces:
        idx = _ints(words, lambda i, no=no: f"OBJ line {no}, face index {i}")
        bad = idx == 0
        if bad.any():
            raise ValueError(f"OBJ line {no}: face index 0 (OBJ counts from 1, or from -1 backwards)")
        polys.append(np.where(idx > 0, idx - 1, seen + idx).tolist())
    return V.reshape(-1, 3), _fan(polys, lambda i: f"OBJ line {faces[i][0]}: the face"), "obj"


# ------------------------------------------------------------------------------------------------ OFF
def _read_off(data):
    lines = [ln.split("#", 1)[0].split() for ln in _text(data, "OFF").splitlines()]
    lines = [w for w in lines if w]
    if not lines or lines[0][0].upper() not in ("OFF", "COFF", "NOFF", "CNOFF"):
        raise ValueError("is not an OFF file (its first word is not OFF)")
    head = lines[0][1:] or (lines[1] if len(lines) > 1 else [])
    if len(head) < 2 or lines[0][1:2] == ["BINARY"]:
        raise ValueError("the OFF header has no vertex and face counts (binary OFF is not read)")
    nv, nf = _count(head[0], "vertices"), _count(head[1], "faces")
    body = lines[1 if lines[0][1:] else 2 :]
    _fits(nv, "vertices", 6, len(data))  # "0 0 0\n"
    _fits(nf, "faces", 8, len(data) - 6 * nv)  # "3 0 1 2\n"
    if len(body) < nv + nf:
        raise ValueError(f"declares {nv:,} vertices and {nf:,} faces, but has {len(body)} data lines")
    short = [i for i in range(nv) if len(body[i]) < 3]
    if short:
        raise ValueError(f"OFF vertex {short[0]} has {len(body[short[0]])} coordinates, needs 3")
    V = _floats([w for ln in body[:nv] for w in ln[:3]], lambda i: f"OFF vertex {i // 3}, coordinate {i % 3}")
    polys = []
    for f, ln in enumerate(body[nv : nv + nf]):
        n = _ints(ln[:1], lambda i, f=f: f"OFF face {f}: its vertex count")[0]
        if not 0 <= n <= len(ln) - 1:
            raise ValueError(f"OFF face {f} declares {n} vertices, its line has {len(ln) - 1} numbers")
        polys.append(_ints(ln[1 : 1 + n], lambda i, f=f: f"OFF face {f}, index {i}").tolist())
    return V.reshape(-1, 3), _fan(polys, lambda i: f"OFF face {i}"), "off"


# ------------------------------------------------------------------------------------------------ PLY
def _ply_header(data):
    """(format, elements, header length); elements are (name, count, [(prop, dtype or (count dtype, dtype))])."""
    m = re.match(rb"ply\r?\n(.{0,65536}?\n)end_header[ \t]*\r?\n", data, re.S)
    if not m:
        raise ValueError("is not a PLY file (no 'ply' line, or no 'end_header' in its first 64 KiB)")
    fmt, elements = None, []
    for no, line in enumerate(m.group(1).decode("utf-8", "replace").splitlines(), 2):
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format" and len(w) == 3 and w[1] in ("ascii", "binary_little_endian", "binary_big_endian"):
            fmt = w[1]
        elif w[0] == "element" and len(w) == 3:
            elements.append((w[1], _count(w[2], f"{w[1]} elements"), []))
        elif w[0] == "property" and elements and len(w) == 3 and w[1] in _PLY_TYPES:
            elements[-1][2].append((w[2], _PLY_TYPES[w[1]]))
        elif w[0] == "property" and elements and len(w) == 5 and w[1] == "list" and {w[2], w[3]} <= set(_PLY_TYPES):
            elements[-1][2].append((w[4], (_PLY_TYPES[w[2]], _PLY_TYPES[w[3]])))
        else:
            raise ValueError(f"PLY header line {no} is not understood: {line[:60]!r}")
    if fmt is None:
        raise ValueError("the PLY header has no 'format ascii|binary_little_endian|binary_big_endian 1.0' line")
    names = [e[0] for e in elements]
    if len(set(names)) < len(names):
        raise ValueError(f"the PLY header declares an element twice: {', '.join(names)}")
    for need in ("vertex", "face"):
        if need not in names:
            raise ValueError(f"the PLY header declares no {need} element")
    vprops = dict(elements[names.index("vertex")][2])
    if not all(isinstance(vprops.get(c), str) for c in "xyz"):
        raise ValueError("the PLY vertex element lacks scalar properties x, y and z")
    fprops = [p for p, t in elements[names.index("face")][2] if p in ("vertex_indices", "vertex_index")]
    if not fprops or not isinstance(dict(elements[names.index("face")][2])[fprops[0]], tuple):
        raise ValueError("the PLY face element has no list property vertex_indices")
    return fmt, elements, m.end(), fprops[0]


def _read_ply(data):
    fmt, elements, start, key = _ply_header(data)
    read = _read_ply_ascii if fmt == "ascii" else _read_ply_binary
    out = read(data, elements, start, key, ">" if fmt == "binary_big_endian" else "<")
    return (*out, f"ply-{fmt}")


def _ply_record(props, order, key):
    """The fixed-size record of a binary element (faces: triangles); ValueError for other lists."""
    fields = []
    for name, t in props:
        if isinstance(t, tuple) and name == key:
            fields += [(name + "#n", order + t[0]), (name, order + t[1], (3,))]
        elif isinstance(t, tuple):
            raise ValueError(f"binary PLY: list property {name!r} is not read (only the faces' vertex_indices)")
        else:
            fields.append((name, order + t))
    return np.dtype(fields)


def _read_ply_binary(data, elements, start, key, order):
    recs = [_ply_record(props, order, key) for _, _, props in elements]
    offsets = np.cumsum([start] + [n * r.itemsize for (_, n, _), r in zip(elements, recs)]).tolist()
    if len(data) != offsets[-1]:
        counts = ", ".join(f"{n:,} {name} × {r.itemsize} B" for (name, n, _), r in zip(elements, recs))
        i = [e[0] for e in elements].index("face")
        k = 3  # a polygon as face 0 explains the size: say so
        if elements[i][1] and len(data) >= offsets[i] + recs[i].itemsize:
            k = int(np.frombuffer(data, recs[i], 1, offsets[i])[key + "#n"][0])
        hint = f"; face 0 has {k} vertices: only triangles are read from binary PLY" if k > 3 else ""
        raise ValueError(
            f"binary PLY size {len(data):,} bytes, but its header ({start} B) and {counts} "
            f"(faces as triangles) make {offsets[-1]:,} bytes{hint}"
        )
    out = {name: np.frombuffer(data, r, n, pos) for (name, n, _), r, pos in zip(elements, recs, offsets)}
    f = out["face"]
    bad = np.flatnonzero(f[key + "#n"] != 3)
    if len(bad):
        raise ValueError(
            f"binary PLY face {int(bad[0])} has {int(f[key + '#n'][bad[0]])} vertices: "
            "only triangles are read from binary PLY"
        )
    v = out["vertex"]
    return np.column_stack([v[c].astype(np.float64) for c in "xyz"]), f[key].astype(np.int64)


def _read_ply_ascii(data, elements, start, key, order):
    tokens = _text(data[start:], "PLY").split()
    least = sum(n * (len(p) + (3 if name == "face" else 0)) for name, n, p in elements)
    if 2 * least > len(data) - start:
        _fits(least, "values (PLY counts × properties)", 2, len(data) - start)
    pos, V, F = 0, None, None
    for name, n, props in elements:
        if all(isinstance(t, str) for _, t in props):  # a fixed number of values per record
            k = len(props)
            if pos + n * k > len(tokens):
                raise ValueError(
                    f"ASCII PLY: {n:,} {name} elements need {n * k:,} values, {len(tokens) - pos:,} are left"
                )
            if name == "vertex":
                names = [p for p, _ in props]
                vals = _floats(tokens[pos : pos + n * k], lambda i, k=k: f"ASCII PLY vertex {i // k}, property {i % k}")
                cols = [names.index(c) for c in "xyz"]  # rounded to the declared type, as binary PLY holds it
                V = np.column_stack([vals[c::k].astype(props[c][1]).astype(np.float64) for c in cols])
            pos += n * k
        else:
            lists, pos = _ply_ascii_lists(tokens, pos, name, n, props, key)
            F = _fan(lists, lambda i: f"ASCII PLY face {i}") if name == "face" else F
    if pos != len(tokens):
        raise ValueError(f"ASCII PLY: {len(tokens) - pos:,} values are left after the elements its header declares")
    if V is None:
        raise ValueError("ASCII PLY: the vertex element has list properties (not read)")
    return V, F


def _ply_ascii_lists(tokens, pos, name, n, props, key):
    """Walk n records with list properties; the lists of property ``key`` and the new position."""
    out = []
    for r in range(n):
        for p, t in props:
            if pos >= len(tokens):
                raise ValueError(f"ASCII PLY: the file ends inside {name} {r} of {n:,}")
            if not isinstance(t, tuple):
                pos += 1
                continue
            m = _ints(tokens[pos : pos + 1], lambda i, r=r: f"ASCII PLY {name} {r}: its list length")[0]
            if m < 0 or pos + 1 + m > len(tokens):
                raise ValueError(f"ASCII PLY {name} {r}: a list of {m} values does not fit in the file")
            if p == key:
                out.append(_ints(tokens[pos + 1 : pos + 1 + m], lambda i, r=r: f"ASCII PLY {name} {r}, index {i}"))
            pos += 1 + m
    return out, pos


# ------------------------------------------------------------------------------------------------ welding
def bbox_diagonal(V):
    """The bounding-box diagonal of V (n, d), computed without overflow or underflow (coordinates scaled by their
    largest magnitude): the one such computation of the package (welding, the coordinate range, the Laplacian)."""
    s = float(np.abs(V).max(initial=0.0))
    return s * float(np.linalg.norm(np.ptp(V / s, axis=0))) if s > 0 else 0.0


def weld(V, F, tolerance=0.0):
    """Merge vertices at exactly the same coordinates, and optionally those within a tolerance.

    Parameters
    ----------
    V : (n, 3) numpy array
    F : (k, 3) int numpy array
    tolerance : float
        Also merge vertices closer than ``tolerance`` × the bounding-box diagonal (0: exact only). Each
        cluster of vertices linked by such distances becomes its first vertex.

    Returns
    -------
    V : (n', 3) numpy array
        The kept vertices, in the order of their first appearance.
    F : (k, 3) int numpy array
    welded : int
        n - n', how many vertices were merged into others.

    Raises
    ------
    ValueError
        Tolerance welding that makes a triangle degenerate (two corners merged) or an edge shared by
        more than two triangles; the message names the triangle or edge.
    """
    V, F = np.asarray(V, dtype=np.float64) + 0.0, np.asarray(F, dtype=np.int64)  # + 0.0: -0.0 becomes 0.0
    exact = _merge(V, F, np.unique(V, axis=0, return_inverse=True)[1].ravel())
    if not tolerance > 0:
        return exact
    # clusters of vertices linked by distances <= the tolerance (exact copies included)
    pairs = cKDTree(V).query_pairs(tolerance * bbox_diagonal(V), output_type="ndarray")
    G = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(V), len(V)))
    near = _merge(V, F, connected_components(G, directed=False)[1])
    _check_tolerance_weld(exact[1], near[1], tolerance)
    return near


def _merge(V, F, label):
    """Each group of vertices with one label becomes its first vertex (in order of first appearance)."""
    _, first = np.unique(label, return_index=True)
    keep = np.sort(first)
    rank = np.empty(len(first), dtype=np.int64)
    rank[label[keep]] = np.arange(len(keep))
    return np.ascontiguousarray(V[keep]), rank[label][F], len(V) - len(keep)


def _check_tolerance_weld(F, F2, tolerance):
    degenerate = (F2[:, 0] == F2[:, 1]) | (F2[:, 1] == F2[:, 2]) | (F2[:, 2] == F2[:, 0])
    before = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    bad = np.flatnonzero(degenerate & ~before)
    if len(bad):
        raise ValueError(
            f"welding within {tolerance:g} × the diagonal makes {len(bad)} triangles degenerate "
            f"(two corners merged), first is triangle {int(bad[0])}; use a smaller weld_tolerance"
        )
    E = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(E, axis=0, return_counts=True)
    E0 = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    if (counts > 2).any() and counts.max() > np.unique(E0, axis=0, return_counts=True)[1].max():
        k = int(np.flatnonzero(counts > 2)[0])
        raise ValueError(
            f"welding within {tolerance:g} × the diagonal puts edge ({int(uniq[k, 0])}, "
            f"{int(uniq[k, 1])}) in {int(counts[k])} triangles (not a manifold); use a smaller "
            "weld_tolerance"
        )
