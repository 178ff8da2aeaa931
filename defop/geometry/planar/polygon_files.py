"""Polygon files: an outline (and its holes) read from CSV rows of x,y or from an SVG drawing.

CSV: one vertex ``x,y`` a row (commas, semicolons, tabs or spaces between the two numbers); an optional header
row of two names (``x,y``); a blank row ends a loop, and the loops after the first are holes. Lines starting
with ``#`` are comments.

SVG: every ``<polygon>``, ``<polyline>`` and ``<path>`` (also ``<rect>``, ``<circle>`` and ``<ellipse>``), parsed by
``svgelements`` with its transforms applied. A path's straight segments keep their end points; each curved
segment (Bézier or arc) is sampled at :data:`CURVE_POINTS` points. Every closed subpath is a loop; SVG's y axis
points down, so y is negated (the drawing stays upright). The loop of largest area is the outline, the others
are holes (:func:`defop.geometry.planar.polygon.validate_polygon` checks they lie inside it).

The loops are returned as read; :func:`defop.geometry.planar.polygon.validate_polygon` checks them (too few
points, crossings, holes outside the outline) when they are meshed.
"""

from __future__ import annotations

import re

import numpy as np

from ..surface_files import check_file, check_size
from .polygon import polygon_area

__all__ = ["CURVE_POINTS", "POLYGON_FORMATS", "read_polygon_file", "parse_csv", "svg_loops"]

#: the file name endings :func:`read_polygon_file` reads
POLYGON_FORMATS = (".csv", ".svg")

#: points sampled on each curved segment of an SVG path (its start included, its end the next segment's start)
CURVE_POINTS = 16

_SEPARATOR = re.compile(r"[,;\t ]+")


def read_polygon_file(path):
    """The outline and holes of a polygon file (see the module docstring for the formats).

    Parameters
    ----------
    path : str or pathlib.Path
        Ending in ``.csv`` or ``.svg`` (:data:`POLYGON_FORMATS`, any case).

    Returns
    -------
    outer : (k,2) float numpy array
    holes : list of (l,2) float numpy array

    Raises
    ------
    ValueError
        Naming the file: missing or unreadable, another ending, a row that is not two numbers (the line),
        non-finite coordinates, no loop at all, or an SVG that cannot be parsed.
    """
    path = check_file(path, "polygon file")
    ext = path.suffix.lower()
    if ext not in POLYGON_FORMATS:
        raise ValueError(f"polygon file {path}: unknown format {ext!r}; use {', '.join(POLYGON_FORMATS)}")
    check_size(path, "polygon file")
    try:
        text = path.read_bytes().decode("utf-8-sig")
        loops = parse_csv(text) if ext == ".csv" else svg_loops(text)
        if not loops:
            raise ValueError("no outline in it" + ("" if ext == ".csv" else " (no polygon, polyline or path)"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"polygon file {path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except ValueError as exc:
        raise ValueError(f"polygon file {path}: {exc}") from None
    loops.sort(key=lambda L: -abs(polygon_area(L)) if len(L) >= 3 else 0.0)
    return loops[0], loops[1:]


def parse_csv(text):
    """The loops of a CSV polygon's text: a list of (k,2) float arrays (a blank row ends a loop)."""
    loops, rows, first = [], [], True
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if line.startswith("#"):
            continue
        header, first = first and bool(line), first and not line
        if not line:
            if rows:
                loops.append(_closed(np.array(rows)))
            rows = []
            continue
        fields = [f for f in _SEPARATOR.split(line) if f]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if header and len(fields) == 2:  # a header row of two names
                continue
            raise ValueError(f"line {number}: {line[:60]!r} is not two numbers x,y") from None
        if len(values) != 2:
            raise ValueError(f"line {number}: {line[:60]!r} has {len(values)} values, not two (x,y)")
        if not np.isfinite(values).all():
            raise ValueError(f"line {number}: {line[:60]!r} is not finite")
        rows.append(values)
    if rows:
        loops.append(_closed(np.array(rows)))
    return loops


def _closed(P):
    """A loop without its closing repetition of the first point."""
    return P[:-1] if len(P) > 1 and np.array_equal(P[0], P[-1]) else P


def svg_loops(text):
    """The closed loops of an SVG document's text: a list of (k,2) float arrays, y pointing up."""
    import io

    import svgelements as se

    try:
        svg = se.SVG.parse(io.StringIO(text), reify=True)
    except Exception as exc:  # svgelements raises ParseError, ValueError, ElementTree errors ...
        raise ValueError(f"not an SVG document ({type(exc).__name__}: {exc})") from None
    loops = []
    for element in svg.elements():
        if isinstance(element, se.Polyline) and not isinstance(element, se.Polygon):
            points = [(p.x, p.y) for p in element.points]
            if points:
                loops.append(_closed(np.array(points, float)))
        elif isinstance(element, se.Shape) and not isinstance(element, se.Group):
            loops.extend(_path_loops(se, se.Path(element)))
    loops = [L for L in loops if len(L)]
    for L in loops:
        if not np.isfinite(L).all():
            raise ValueError("a coordinate is not finite")
        L[:, 1] = 0.0 - L[:, 1]  # -0.0 would print as such
    return loops


def _path_loops(se, path):
    """The loops of one svgelements Path: one per subpath, straight segments by their ends, curves sampled."""
    loops = []
    for sub in path.as_subpaths():
        points = []
        for seg in sub:
            if isinstance(seg, se.Move):
                continue
            if isinstance(seg, (se.Line, se.Close)):
                points.append((seg.start.x, seg.start.y))
            else:
                t = np.linspace(0.0, 1.0, CURVE_POINTS, endpoint=False)
                points.extend((p[0], p[1]) for p in seg.npoint(t))
        if points:
            loops.append(_dedupe(np.array(points, float)))
    return loops


def _dedupe(P):
    """A loop without consecutive repeated points (a zero-length segment), nor its closing repetition."""
    keep = np.ones(len(P), bool)
    keep[1:] = np.any(P[1:] != P[:-1], axis=1)
    return _closed(P[keep])
