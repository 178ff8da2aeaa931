"""Object File Format (OFF) surfaces, as Geomview and the Princeton shape benchmark write them.

The first word is ``OFF`` with the optional prefixes ``ST``, ``C`` and ``N`` (texture coordinates, colours
and normals after the three coordinates of a vertex; skipped); the counts ``vertices faces [edges]`` follow on
the same line or the next. One vertex per line, then one face per line (``k i1 … ik``, colour values after the
indices skipped); ``#`` starts a comment. The data lines must be exactly as many as the counts say (more or fewer
is refused, naming the counts), and every vertex line holds as many values as the first.
Four-dimensional (``4OFF``), n-dimensional (``nOFF``) and binary OFF are refused.
"""

from __future__ import annotations

import re

import numpy as np

from .common import count, fits, floats, ints, text
from .polygons import triangulate

__all__ = ["read_off"]

_KEYWORD = re.compile(r"(ST)?C?N?(4)?(n)?OFF")
_INTS = re.compile(r"(?:[0-9]{1,18} )*[0-9]{1,18}")


def read_off(data):
    """V (n, 3), F (k, 3) and ``"off"`` from the bytes of an OFF file; ValueError naming the line."""
    lines = [(no, ln.split("#", 1)[0].split()) for no, ln in enumerate(text(data, "OFF").splitlines(), 1)]
    lines = [(no, w) for no, w in lines if w]
    m = _KEYWORD.fullmatch(lines[0][1][0]) if lines else None
    if not m:
        raise ValueError("is not an OFF file (its first word is not OFF)")
    if m.group(2) or m.group(3):
        raise ValueError(f"is a {lines[0][1][0]} file (4- or n-dimensional vertices): only 3D OFF is read")
    head = lines[0][1][1:] or (lines[1][1] if len(lines) > 1 else [])
    if len(head) < 2 or lines[0][1][1:2] == ["BINARY"]:
        raise ValueError("the OFF header has no vertex and face counts (binary OFF is not read)")
    nv, nf = count(head[0], "vertices"), count(head[1], "faces")
    body = lines[1 if lines[0][1][1:] else 2 :]
    fits(nv, "vertices", 6, len(data))  # "0 0 0\n"
    fits(nf, "faces", 8, len(data) - 6 * nv)  # "3 0 1 2\n"
    if len(body) != nv + nf:
        raise ValueError(
            f"declares {nv:,} vertices and {nf:,} faces, one per line, but has {len(body)} data lines" + _hint(body, nv)
        )
    short = [i for i in range(nv) if len(body[i][1]) < 3]
    if short:
        no, w = body[short[0]]
        raise ValueError(f"OFF line {no}: vertex {short[0]} has {len(w)} coordinates, needs 3")
    odd = [i for i in range(nv) if len(body[i][1]) != len(body[0][1])]
    if odd:
        no, w = body[odd[0]]
        raise ValueError(
            f"OFF line {no}: vertex {odd[0]} has {len(w)} values, vertex 0 has {len(body[0][1])} "
            f"(is the vertex count {nv:,} right?)"
        )
    V = floats(
        [w for _, ln in body[:nv] for w in ln[:3]],
        lambda i: f"OFF line {body[i // 3][0]}: vertex {i // 3}, coordinate {i % 3}",
    ).reshape(-1, 3)
    polys = _uniform_faces(body[nv:])
    if polys is None:
        polys = [_face(f, no, ln, nv, len(body[0][1])) for f, (no, ln) in enumerate(body[nv:])]
    return V, triangulate(V, polys, lambda i: f"OFF line {body[nv + i][0]}: face {i}"), "off"


def _uniform_faces(lines):
    """(nf, k) indices when every face line is ``k i1 … ik`` with one k (no colours), else None (read line by line)."""
    width = {len(w) for _, w in lines}
    if len(width) != 1:
        return None
    words = [t for _, w in lines for t in w]
    if not _INTS.fullmatch(" ".join(words)):
        return None
    M = np.array(words).astype(np.int64).reshape(len(lines), -1)
    return M[:, 1:] if (M[:, 0] == M.shape[1] - 1).all() and M.shape[1] > 3 else None


def _face(f, no, ln, nv, vk):
    """The vertex indices of face f on line ``no``; an error says when the line looks like a vertex (vk values)."""
    try:
        n = ints(ln[:1], lambda i: f"OFF line {no}: face {f}: its vertex count")[0]
        if not 3 <= n <= len(ln) - 1:
            raise ValueError(
                f"OFF line {no}: face {f} has {n} vertices, a face needs at least 3"
                if n < 3
                else f"OFF line {no}: face {f} declares {n} vertices, its line has {len(ln) - 1} numbers"
            )
        return ints(ln[1 : 1 + n], lambda i: f"OFF line {no}: face {f}, index {i}").tolist()
    except ValueError as exc:
        hint = f" (the line looks like a vertex: is the vertex count {nv:,} right?)" if len(ln) == vk else ""
        raise ValueError(f"{exc}{hint}") from None


def _hint(body, nv):
    """Where the vertex lines seem to end, when that differs from the header's count."""
    looks_vertex = [len(w) == 3 or not _is_int(w[0]) for _, w in body]
    k = next((i for i, v in enumerate(looks_vertex) if not v), len(body))
    return f" ({k} lines look like vertices, the header says {nv:,})" if k != nv else ""


def _is_int(word):
    """Whether ``word`` is a decimal integer (a face line starts with one)."""
    return re.fullmatch(r"[0-9]{1,18}", word) is not None
