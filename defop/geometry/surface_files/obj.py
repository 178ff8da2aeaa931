"""Wavefront OBJ surfaces: ``v`` vertices and ``f`` polygons; every error names its line.

Read as the OBJ specification writes them: a face index counts from 1, or from -1 backwards (-1 is the last
vertex defined so far); ``v/vt/vn``, ``v//vn`` and ``v/vt`` forms keep their vertex index; a line ending in a
backslash continues on the next; ``#`` starts a comment. Texture coordinates, normals, groups, materials, lines,
points and the other statements of the specification are skipped; a word that is no statement is refused.
Polygons are triangulated by :func:`.polygons.triangulate`.
"""

from __future__ import annotations

import re

from .common import MAX_FILE_ELEMENTS, count, floats, text
from .polygons import triangulate

__all__ = ["read_obj"]

#: the statements of the OBJ specification (Wavefront, version 3.0) besides ``v`` and ``f``, skipped
_STATEMENTS = frozenset(
    "vt vn vp l p g o s mg usemtl mtllib cstype deg bmat step curv curv2 surf parm trim hole scrv sp end con "
    "call csh bevel c_interp d_interp lod maplib usemap shadow_obj trace_obj ctech stech".split()
)
_CORNER = re.compile(r"([-+]?[0-9]{1,18})(?:/(?:[-+]?[0-9]{1,18})?(?:/[-+]?[0-9]{1,18})?)?")


def read_obj(data):
    """V (n, 3), F (k, 3) and ``"obj"`` from the bytes of an OBJ file; ValueError naming the line."""
    vt, vline, faces = [], [], []
    for no, line in _lines(text(data, "OBJ")):
        words = line.split()
        if not words:
            continue
        if words[0] == "v":
            if len(words) < 4:
                raise ValueError(f"OBJ line {no}: a vertex needs 3 coordinates, got {len(words) - 1}")
            vt += words[1:4]
            vline.append(no)
        elif words[0] == "f":
            faces.append((no, len(vline), words[1:]))
        elif words[0] not in _STATEMENTS:
            raise ValueError(f"OBJ line {no}: {words[0][:40]!r} is not an OBJ statement")
    if len(vline) > MAX_FILE_ELEMENTS or len(faces) > MAX_FILE_ELEMENTS:
        count(str(max(len(vline), len(faces))), "vertices or faces")
    if not vline or not faces:
        raise ValueError(f"holds no triangle surface ({len(vline)} vertex lines 'v', {len(faces)} face lines 'f')")
    V = floats(vt, lambda i: f"OBJ line {vline[i // 3]}, coordinate {i % 3}").reshape(-1, 3)
    polys = [_face(no, seen, words, len(V)) for no, seen, words in faces]
    return V, triangulate(V, polys, lambda i: f"OBJ line {faces[i][0]}: the face"), "obj"


def _lines(src):
    """(line number, text without comment) of each logical line; a trailing backslash joins the next line."""
    out, held, first = [], "", 0
    for no, line in enumerate(src.splitlines(), 1):
        line = line.split("#", 1)[0]
        if not held:
            first = no
        if line.rstrip().endswith("\\"):
            held += line.rstrip()[:-1] + " "
            continue
        out.append((first, held + line))
        held = ""
    if held:
        out.append((first, held))
    return out


def _face(no, seen, words, n):
    """0-based vertex indices of the face on line ``no``, written after ``seen`` vertices of the file's ``n``."""
    idx = []
    for i, w in enumerate(words):
        m = _CORNER.fullmatch(w)
        if not m:
            raise ValueError(f"OBJ line {no}: face corner {i + 1} {w[:40]!r} is not v, v/vt, v//vn or v/vt/vn")
        v = m.group(1)
        k = int(v)
        if k == 0:
            raise ValueError(f"OBJ line {no}: face index 0 (OBJ counts from 1, or from -1 backwards)")
        if k < 0 and -k > seen:
            raise ValueError(
                f"OBJ line {no}: face index {k} counts back from the {seen} vertices defined before this line"
            )
        if k > n:
            raise ValueError(f"OBJ line {no}: face index {k}, but the file has {n} vertices")
        idx.append(k - 1 if k > 0 else seen + k)
    return idx
