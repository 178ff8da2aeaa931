"""STL surfaces, binary and ASCII: three corners per triangle, welded later (STL shares no vertices).

A file is binary STL when its size is exactly the 84-byte header plus 50 bytes per triangle its count
declares (an ASCII file that happens to match would be unusual: its 81st to 84th characters read as that count);
otherwise it must be ASCII STL, starting with ``solid`` (after an optional UTF-8 byte-order mark), each facet
``facet normal nx ny nz / outer loop / vertex x y z ×3 / endloop / endfacet``, and ending with ``endsolid``
(a truncated file has no end); anything else between facets is refused. Normals are not read.
"""

from __future__ import annotations

import numpy as np

from .common import MAX_FILE_ELEMENTS, count, fits, floats, strip_bom, text

__all__ = ["read_stl"]

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_KEYS = {
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


def read_stl(data):
    """V (3k, 3), F (k, 3) and ``"stl-binary"`` or ``"stl-ascii"`` from the bytes of an STL file (not welded)."""
    if len(data) >= 84:
        k = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * k:
            if k > MAX_FILE_ELEMENTS:
                count(str(k), "triangles")
            rec = np.frombuffer(data, dtype=_STL_RECORD, count=k, offset=84)
            return rec["corners"].reshape(-1, 3).astype(np.float64), np.arange(3 * k).reshape(-1, 3), "stl-binary"
    k = int.from_bytes(data[80:84], "little")
    binary = (
        f"a binary STL's header declares {k:,} triangles, {84 + 50 * k:,} bytes, the file has {len(data):,}"
        if len(data) >= 84
        else f"{len(data)} bytes are too short for a binary STL (84-byte header)"
    )
    data = strip_bom(data)
    if not data.lstrip()[:5].lower() == b"solid":
        raise ValueError(f"is neither binary STL ({binary}) nor ASCII STL (it does not start with 'solid')")
    try:
        return (*_read_ascii(text(data, "STL")), "stl-ascii")
    except ValueError as exc:
        raise ValueError(f"is neither binary STL ({binary}) nor ASCII STL ({exc})") from None


def _read_ascii(src):
    tokens = src.split()
    low = [t.lower() for t in tokens]
    starts = [i for i, t in enumerate(low) if t == "facet"]
    fits(len(starts), "triangles", 60, len(src))  # "facet normal 0 0 0 outer loop vertex 0 0 0 ×3 endloop endfacet"
    if len(starts) > MAX_FILE_ELEMENTS:
        count(str(len(starts)), "triangles")
    if not starts:
        raise ValueError("holds no triangles (no 'facet' in an ASCII STL)")
    named = len(src.lstrip().split("\n", 1)[0].split())  # 'solid' and its name, on the first line
    if starts[0] != named:
        raise ValueError(f"ASCII STL line {_line(src, tokens, named)}: expected 'facet', got {tokens[named][:40]!r}")
    coords = []
    for n, s in enumerate(starts):
        for off, key in _KEYS.items():
            if s + off >= len(low) or low[s + off] != key:
                got = tokens[s + off][:40] if s + off < len(low) else "the end of the file"
                raise ValueError(
                    f"ASCII STL facet {n} (line {_line(src, tokens, s + off)}): expected {key!r}, got {got!r}"
                )
        coords += tokens[s + 8 : s + 11] + tokens[s + 12 : s + 15] + tokens[s + 16 : s + 19]
        end = starts[n + 1] if n + 1 < len(starts) else len(low)
        if end > s + 21 and low[s + 21] != "endsolid" or end == s + 21 and n + 1 == len(starts):
            got = tokens[s + 21][:40] if s + 21 < len(low) else "the end of the file"
            raise ValueError(
                f"ASCII STL after facet {n} (line {_line(src, tokens, s + 21)}): expected 'facet' or 'endsolid', "
                f"got {got!r}" + (" (truncated?)" if end == s + 21 else "")
            )
    V = floats(coords, lambda i: f"ASCII STL facet {i // 9}, coordinate {i % 9}")
    return V.reshape(-1, 3), np.arange(3 * len(starts)).reshape(-1, 3)


def _line(src, tokens, i):
    """The line number of token i, or of the last token past the end (computed only for a message)."""
    pos = 0
    for t in tokens[: i + 1]:
        pos = src.index(t, pos) + len(t)
    return src.count("\n", 0, pos) + 1
