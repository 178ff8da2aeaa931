"""PLY surfaces (ascii, binary_little_endian, binary_big_endian 1.0), every property read as its declared type.

The header names the elements in file order, each with a count and typed properties; a list property has an
integer count type and an item type. Every element is read, in order, so that the faces are found after any
element the reader does not use. Coordinates (``x``, ``y``, ``z`` of ``vertex``) may have any numeric type; in
an ASCII file a value of an integer type must be written as an integer within that type's range (``0.5`` in an
``int`` property is refused, naming it: reading it as 0 would collapse the mesh). Face indices
(``vertex_indices`` or ``vertex_index`` of ``face``) are lists of any length (polygons are triangulated by
:func:`.polygons.triangulate`); an index of a floating-point type must be a whole number. An ASCII file holds
one element a line, and its data lines must be exactly as many as the header's counts; a binary file must end
where its last element does.
"""

from __future__ import annotations

import collections
import re
import struct

import numpy as np

from .common import count, fits, floats, ints, strip_bom, text
from .polygons import triangulate

__all__ = ["PLY_TYPES", "read_ply"]

#: the PLY scalar types and their numpy codes
PLY_TYPES = {
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
_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}
_FACE_KEYS = ("vertex_indices", "vertex_index")

#: one property: its name, its numpy code (scalar) or item code (list), its list count code or None, its PLY type
Prop = collections.namedtuple("Prop", "name code count_code typename")


def read_ply(data):
    """V (n, 3), F (k, 3) and ``"ply-<format>"`` from the bytes of a PLY file; ValueError naming element and line."""
    data = strip_bom(data)
    fmt, elements, start = _header(data)
    key = next(p.name for p in elements["face"][1] if p.name in _FACE_KEYS)
    if fmt == "ascii":
        values = _read_ascii(data, elements, start)
        return (*_surface(values, key, "ASCII PLY"), "ply-ascii")
    try:
        values = _read_binary(data, elements, start, ">" if fmt == "binary_big_endian" else "<")
        return (*_surface(values, key, "binary PLY"), f"ply-{fmt}")
    except ValueError as exc:
        hint = _size_hint(data, elements, start)
        raise ValueError(f"{hint}; read as declared: {exc}" if hint else str(exc)) from None


def _surface(values, key, kind):
    V = np.column_stack([np.asarray(values["vertex"][c], dtype=np.float64) for c in "xyz"]).reshape(-1, 3)
    return V, triangulate(V, _whole(values["face"][key], kind), lambda i: f"{kind} face {i}")


def _size_hint(data, elements, start):
    """For an error in a binary PLY: the size its counts give with triangle faces, when the file's differs."""
    size = start
    for n, props in elements.values():
        size += n * sum(
            np.dtype(p.code).itemsize * (3 if p.count_code else 1)
            + (np.dtype(p.count_code).itemsize if p.count_code else 0)
            for p in props
        )
    if size == len(data):
        return ""
    return (
        f"binary PLY size {len(data):,} bytes, but its header ({start} B) and counts make {size:,} bytes "
        "with triangle faces (are the counts right?)"
    )


def _whole(lists, kind):
    """Face index lists as int64 (an (n, k) array or a list of arrays); a fractional index is refused."""
    if isinstance(lists, np.ndarray):
        _check_whole(lists, lambda r, j: f"{kind} face {r}, index {j}")
        return lists.astype(np.int64)
    for r, a in enumerate(lists):
        _check_whole(a[None, :], lambda _, j, r=r: f"{kind} face {r}, index {j}")
    return [a.astype(np.int64) for a in lists]


def _check_whole(A, where):
    if A.dtype.kind == "f":
        bad = ~(np.isfinite(A) & (A == np.floor(A)) & (np.abs(A) < 2**62))
        if bad.any():
            r, j = (int(x) for x in np.argwhere(bad)[0])
            raise ValueError(f"{where(r, j)} is {float(A[r, j])!r}: a vertex index must be a whole number")


def _header(data):
    """(format, {element: (count, [Prop])} in file order, header length)."""
    m = re.match(rb"ply\r?\n(.{0,65536}?\n)end_header[ \t]*\r?\n", data, re.S)
    if not m:
        raise ValueError("is not a PLY file (no 'ply' line, or no 'end_header' in its first 64 KiB)")
    fmt, elements, current = None, {}, None
    for no, line in enumerate(m.group(1).decode("utf-8", "replace").splitlines(), 2):
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format" and len(w) == 3 and w[1] in ("ascii", "binary_little_endian", "binary_big_endian"):
            if w[2] not in ("1.0", "1"):
                raise ValueError(f"PLY header line {no}: format version {w[2][:20]!r}, only 1.0 is read")
            fmt = w[1]
        elif w[0] == "element" and len(w) == 3:
            if w[1] in elements:
                raise ValueError(f"the PLY header declares an element twice: {', '.join([*elements, w[1]])}")
            current = w[1]
            elements[current] = (count(w[2], f"{w[1]} elements"), [])
        elif w[0] == "property" and current and len(w) in (3, 5) and w[-1] in {p.name for p in elements[current][1]}:
            raise ValueError(f"PLY header line {no}: element {current} declares property {w[-1][:40]!r} twice")
        elif w[0] == "property" and current and len(w) == 3 and w[1] in PLY_TYPES:
            elements[current][1].append(Prop(w[2], PLY_TYPES[w[1]], None, w[1]))
        elif w[0] == "property" and current and len(w) == 5 and w[1] == "list" and {w[2], w[3]} <= set(PLY_TYPES):
            if PLY_TYPES[w[2]][0] == "f":
                raise ValueError(f"PLY header line {no}: the list count type {w[2]!r} is not an integer type")
            elements[current][1].append(Prop(w[4], PLY_TYPES[w[3]], PLY_TYPES[w[2]], w[3]))
        else:
            raise ValueError(f"PLY header line {no} is not understood: {line[:60]!r}")
    if fmt is None:
        raise ValueError("the PLY header has no 'format ascii|binary_little_endian|binary_big_endian 1.0' line")
    for need in ("vertex", "face"):
        if need not in elements:
            raise ValueError(f"the PLY header declares no {need} element")
    vprops = {p.name: p for p in elements["vertex"][1]}
    if not all(c in vprops and vprops[c].count_code is None for c in "xyz"):
        raise ValueError("the PLY vertex element lacks scalar properties x, y and z")
    if not any(p.name in _FACE_KEYS and p.count_code for p in elements["face"][1]):
        raise ValueError("the PLY face element has no list property vertex_indices")
    return fmt, elements, m.end()


# ------------------------------------------------------------------------------------------------ ASCII
def _read_ascii(data, elements, start):
    """{element: {property: array, or list of arrays for a list property}} from one element a line."""
    least = sum(n * (len(p) + (3 if name == "face" else 0)) for name, (n, p) in elements.items())
    if 2 * least > len(data) - start:
        fits(least, "values (PLY counts × properties)", 2, len(data) - start)
    first = data[:start].count(b"\n") + 1
    rows = [(no, ln.split()) for no, ln in enumerate(text(data[start:], "PLY").splitlines(), first)]
    rows = [(no, w) for no, w in rows if w]
    total = sum(n for n, _ in elements.values())
    if len(rows) != total:
        counts = ", ".join(f"{n:,} {name}" for name, (n, _) in elements.items())
        raise ValueError(
            f"ASCII PLY: the header declares {counts} elements, {total:,} data lines (one element a line), "
            f"the file has {len(rows):,}{_hint(rows, elements)}"
        )
    out, pos = {}, 0
    for name, (n, props) in elements.items():
        part = rows[pos : pos + n]
        pos += n
        if any(p.count_code for p in props):
            out[name] = _ascii_uniform(part, name, props) or _ascii_lists(part, name, props, _first_values(elements))
            continue
        bad = [i for i, (_, w) in enumerate(part) if len(w) != len(props)]
        if bad:
            no, w = part[bad[0]]
            raise ValueError(
                f"ASCII PLY line {no}: {name} {bad[0]} has {len(w)} values, its properties are {len(props)}"
            )
        out[name] = {
            p.name: _typed(
                [w[c] for _, w in part],
                p,
                lambda i, p=p, part=part, name=name: f"ASCII PLY line {part[i][0]}: {name} {i}, property {p.name!r}",
            )
            for c, p in enumerate(props)
        }
    return out


def _hint(rows, elements):
    """Where the first element's lines seem to end, when that differs from its count (a vertex count too small)."""
    n0 = next(iter(elements.values()))[0]
    k = len(rows[0][1]) if rows else 0
    same = next((i for i, (_, w) in enumerate(rows) if len(w) != k), len(rows))
    name = next(iter(elements))
    return (
        f" (the first {same:,} lines have the {k} values of a {name}, the header counts {n0:,} {name} elements)"
        if same != n0
        else ""
    )


def _typed(tokens, p, where):
    """The tokens as values of property p's type; a fractional or out-of-range value of an integer type is refused."""
    if p.code[0] == "f":
        return floats(tokens, where).astype(p.code)  # rounded to the declared type, as a binary PLY holds it
    what = lambda i: f"{where(i)} ({p.typename})"  # noqa: E731
    values = ints(tokens, what)
    lo, hi = np.iinfo(p.code).min, np.iinfo(p.code).max
    out = np.flatnonzero((values < lo) | (values > hi))
    if len(out):
        raise ValueError(
            f"{what(int(out[0]))} is {int(values[out[0]])}, outside the range of {p.typename} [{lo}, {hi}]"
        )
    return values


def _ascii_uniform(part, name, props):
    """Columns of an element with one list property whose lines all hold the same number of values (a mesh of
    triangles): read column by column; None when the lines differ (they are walked one by one)."""
    widths = {len(w) for _, w in part}
    lists = [p for p in props if p.count_code]
    m = len(part[0][1]) - len(props) if part else -1
    if len(widths) != 1 or len(lists) != 1 or m < 0:
        return None
    out, c = {}, 0
    for p in props:

        def where(i, p=p):
            return f"ASCII PLY line {part[i][0]}: {name} {i}, property {p.name!r}"

        if p.count_code is None:
            out[p.name] = _typed([w[c] for _, w in part], p, where)
            c += 1
            continue
        counts = _typed([w[c] for _, w in part], Prop(p.name, p.count_code, None, "list count"), where)
        if (counts != m).any():
            return None
        items = _typed([t for _, w in part for t in w[c + 1 : c + 1 + m]], p, lambda i, where=where: where(i // m))
        out[p.name] = items.reshape(len(part), m)
        c += 1 + m
    return out


def _first_values(elements):
    """(name, values a line) of the first element when it has no list properties, else None."""
    name, (_, props) = next(iter(elements.items()))
    return None if any(p.count_code for p in props) else (name, len(props))


def _ascii_lists(part, name, props, first):
    """Walk the lines of an element with list properties; {property: values per record}. An error says when its
    line looks like one of the first element (``first``: name and values a line), which a count too small gives."""
    out = {p.name: [] for p in props}
    for r, (no, w) in enumerate(part):
        try:
            _ascii_record(out, no, w, r, name, props)
        except ValueError as exc:
            hint = ""
            if first and first[0] != name and len(w) == first[1]:
                hint = f" (the line looks like a {first[0]}: is the {first[0]} count right?)"
            raise ValueError(f"{exc}{hint}") from None
    return out


def _ascii_record(out, no, w, r, name, props):
    """Append the values of one line to ``out``."""
    pos = 0
    for p in props:
        where = lambda i, p=p: f"ASCII PLY line {no}: {name} {r}, property {p.name!r}"  # noqa: E731
        if pos >= len(w):
            raise ValueError(f"{where(0)}: the line ends before it")
        if p.count_code is None:
            out[p.name].append(_typed(w[pos : pos + 1], p, where)[0])
            pos += 1
            continue
        m = int(_typed(w[pos : pos + 1], Prop(p.name, p.count_code, None, "list count"), where)[0])
        if pos + 1 + m > len(w):
            raise ValueError(f"{where(0)}: a list of {m} values, the line has {len(w) - pos - 1} after its count")
        out[p.name].append(_typed(w[pos + 1 : pos + 1 + m], p, lambda i, where=where: f"{where(0)}, item {i}"))
        pos += 1 + m
    if pos != len(w):
        raise ValueError(f"ASCII PLY line {no}: {name} {r} has {len(w) - pos} values after its properties")


# ------------------------------------------------------------------------------------------------ binary
def _read_binary(data, elements, start, order):
    """{element: {property: array, or (n, k) array / list of arrays for a list property}}; the size must match."""
    out, pos = {}, start
    for name, (n, props) in elements.items():
        if any(p.count_code for p in props):
            out[name], pos = _binary_lists(data, pos, name, n, props, order)
            continue
        rec = np.dtype([(p.name, order + p.code) for p in props])
        _need(data, pos, n * rec.itemsize, f"{n:,} {name} elements × {rec.itemsize} B")
        a = np.frombuffer(data, rec, n, pos)
        out[name] = {p.name: a[p.name] for p in props}
        pos += n * rec.itemsize
    if pos != len(data):
        raise ValueError(f"binary PLY: {len(data) - pos:,} bytes are left after the elements its header declares")
    return out


def _need(data, pos, nbytes, what):
    if pos + nbytes > len(data):
        raise ValueError(
            f"binary PLY size {len(data):,} bytes ends inside its data: {what} from byte {pos:,} need "
            f"{nbytes:,} bytes, {len(data) - pos:,} are left"
        )


def _binary_lists(data, pos, name, n, props, order):
    """An element with list properties: one fixed record when every list has the first record's length, else walked."""
    if n == 0:
        return {p.name: np.zeros((0, 3)) for p in props}, pos
    lengths = _walk(data, pos, name, 1, props, order)[2]
    rec = np.dtype(
        [
            f
            for p, k in zip(props, lengths)
            for f in (
                [(p.name + "#n", order + p.count_code), (p.name, order + p.code, (k,))]
                if p.count_code
                else [(p.name, order + p.code)]
            )
        ]
    )
    if pos + n * rec.itemsize <= len(data):
        a = np.frombuffer(data, rec, n, pos)
        if all((a[p.name + "#n"] == k).all() for p, k in zip(props, lengths) if p.count_code):
            return {
                p.name: a[p.name].reshape(n, -1) if p.count_code else a[p.name] for p in props
            }, pos + n * rec.itemsize
    values, pos, _ = _walk(data, pos, name, n, props, order)
    return values, pos


def _walk(data, pos, name, n, props, order):
    """Read n records one by one: ({property: list of values}, new position, list lengths of the first record)."""
    out = {p.name: [] for p in props}
    first = []
    for r in range(n):
        for p in props:
            if p.count_code is None:
                size = struct.calcsize(order + _STRUCT[p.code])
                _need(data, pos, size, f"{name} {r}, property {p.name!r}")
                out[p.name].append(struct.unpack_from(order + _STRUCT[p.code], data, pos)[0])
                pos += size
                continue
            csize = struct.calcsize(order + _STRUCT[p.count_code])
            _need(data, pos, csize, f"{name} {r}, the count of list {p.name!r}")
            k = struct.unpack_from(order + _STRUCT[p.count_code], data, pos)[0]
            if k < 0:
                raise ValueError(f"binary PLY {name} {r}: list {p.name!r} has a negative length {k}")
            isize = np.dtype(p.code).itemsize
            _need(data, pos + csize, k * isize, f"{name} {r}, list {p.name!r} of {k} values")
            out[p.name].append(np.frombuffer(data, order + p.code, k, pos + csize))
            pos += csize + k * isize
            if r == 0:
                first.append(k)
        if r == 0:
            first = [first.pop(0) if p.count_code else 0 for p in props]
    return out, pos, first
