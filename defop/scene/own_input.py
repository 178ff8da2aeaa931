"""A user's own model from one file: a polygon (CSV, SVG), a picture (PNG, JPEG) or a closed surface (PLY, STL,
OBJ, OFF), its handles placed automatically unless given.

:func:`load_model` chooses the reader by the file's ending (:data:`INPUT_KINDS`): a polygon file is read by
:func:`defop.geometry.planar.polygon_files.read_polygon_file` and meshed by
:func:`~defop.scene.planar_shapes.from_polygon`, a picture by :func:`~defop.scene.planar_shapes.from_image`, a
surface by :func:`~defop.scene.shapes.from_surface`. Without handles it places :data:`DEFAULT_COUNT` of them by the
one rule of :mod:`defop.scene.auto_handles` (the shape's extremities; in 3D each a patch of
:data:`~defop.scene.auto_handles.PATCH_SIZE` vertices), and handle 0, the extremity farthest from the centroid,
is fixed. Pure: it reads the file and writes nothing.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from .. import options as opt
from ..geometry.planar.polygon_files import POLYGON_FORMATS, read_polygon_file
from ..geometry.surface_files import SURFACE_FORMATS, check_file
from .auto_handles import DEFAULT_COUNT, PATCH_SIZE
from .planar_shapes import MAX_AUTO_HANDLES, from_image, from_polygon
from .shape import Shape
from .shapes import from_surface

__all__ = ["DEFAULT_COUNT", "INPUT_KINDS", "OwnShape", "accepted_kinds", "input_kind", "load_model"]

#: the kinds of input and their file endings (any case)
INPUT_KINDS = {"polygon": POLYGON_FORMATS, "picture": (".png", ".jpg", ".jpeg"), "surface": SURFACE_FORMATS}


def accepted_kinds():
    """The accepted kinds and endings, as a sentence: ``polygon (.csv, .svg), picture (...), surface (...)``."""
    return ", ".join(f"{kind} ({', '.join(ext)})" for kind, ext in INPUT_KINDS.items())


@dataclasses.dataclass
class OwnShape:
    """A user's model as read by :func:`load_model`.

    Attributes
    ----------
    shape : Shape
    kind : str
        ``"polygon"``, ``"picture"`` or ``"surface"``.
    path : pathlib.Path
    groups : list of (g,) int numpy array
        Each handle's rows in ``shape.handles`` (one row in 2D, a patch in 3D).
    fixed : tuple of int
        The fixed handles (indices into ``groups``).
    automatic : bool
        Whether the handles were placed by :func:`defop.scene.auto_handles.extremities`.
    """

    shape: Shape
    kind: str
    path: Path
    groups: list
    fixed: tuple
    automatic: bool

    def handle_lines(self):
        """One line per handle: its number, fixed or moving, its (patch centre) position and vertex count."""
        out = []
        for i, rows in enumerate(self.groups):
            c = self.shape.P[rows].mean(axis=0)
            where = ", ".join(f"{x:.4g}" for x in c)
            patch = f", a patch of {len(rows)} vertices" if len(rows) > 1 else ""
            out.append(f"handle {i}: {'fixed' if i in self.fixed else 'moving'} at ({where}){patch}")
        return out


def input_kind(path):
    """(the path as a Path to a readable file, its kind); ValueError naming the file and the accepted kinds."""
    if isinstance(path, (str, os.PathLike)):
        ext = Path(path).suffix.lower()
        kind = next((k for k, endings in INPUT_KINDS.items() if ext in endings), None)
        if kind is None:
            raise ValueError(f"input {path}: unknown kind {ext or '(no ending)'!r}; accepted: {accepted_kinds()}")
    path = check_file(path, "input file")
    return path, kind


def _handle_spec(handles, d):
    """(count or None, (h,d) positions or None) from ``handles``: None, a count, or points."""
    if handles is None:
        return DEFAULT_COUNT[d], None
    if isinstance(handles, (int, np.integer)) and not isinstance(handles, bool):
        return opt.integer("handles", handles, minimum=1, maximum=MAX_AUTO_HANDLES), None
    H = np.atleast_2d(opt.real_array("handles", handles))
    if H.ndim != 2 or H.shape[1] != d or len(H) == 0:
        raise ValueError(f"handles: points of a {d}D model must have shape (h,{d}), got {np.shape(handles)}")
    return len(H), H


def _fixed_flags(fixed, h):
    """(fixed as a sorted tuple, the per-handle moving flags); ValueError for an index out of range or all fixed."""
    fixed = (0,) if fixed is None else fixed
    fixed = [fixed] if isinstance(fixed, (int, np.integer)) else list(fixed)
    out = []
    for f in fixed:
        out.append(opt.integer("fixed handle", f, minimum=0))
        if out[-1] >= h:
            raise ValueError(f"fixed handle {out[-1]} is out of range: the model has {h} handles, 0 to {h - 1}")
    moving = np.array([i not in out for i in range(h)])
    if not moving.any():
        raise ValueError(f"every one of the {h} handles is fixed: leave at least one moving")
    return tuple(sorted(set(out))), moving


def load_model(path, handles=None, fixed=None, n_vertices=None, name=None, weld_tolerance=None):
    """A user's model from a polygon, picture or surface file (see the module docstring).

    Parameters
    ----------
    path : str or pathlib.Path
        The file; its ending chooses the reader (:data:`INPUT_KINDS`).
    handles : int or (h,d) array_like, optional
        How many handles to place automatically (default :data:`DEFAULT_COUNT`: 4 in 2D, 3 patches in 3D), or
        handle points (2D: in the file's units, for a picture in the units of
        :func:`~defop.scene.planar_shapes.from_image`; 3D: inside the solid, each grown into a patch).
    fixed : int or sequence of int, optional
        The fixed handles, indices into the handles (default: 0, the first).
    n_vertices : int, optional
        About how many mesh vertices (default: the reader's, 1500 in 2D and 2000 in 3D).
    name : str, optional
        The shape's name (default: the file's name without its ending).
    weld_tolerance : float, optional
        For a surface file, as in :func:`~defop.scene.shapes.from_surface`.

    Returns
    -------
    own : OwnShape

    Raises
    ------
    ValueError
        Naming the file: missing or unreadable, an unknown ending (the message lists the accepted kinds), a file
        its reader refuses (no outline, a row that is not two numbers, too few points, crossing edges, an open
        surface, ...), handles of the wrong shape or outside the model, a fixed handle out of range, or every
        handle fixed.
    """
    path, kind = input_kind(path)
    d = 3 if kind == "surface" else 2
    count, H = _handle_spec(handles, d)
    fixed, moving = _fixed_flags(fixed, count)
    name = path.stem if name is None else opt.text("name", name)
    kw = {} if n_vertices is None else {"n_vertices": n_vertices}
    try:
        if kind == "polygon":
            outer, holes = read_polygon_file(path)
            shape = from_polygon(outer, holes, H, moving, name=name, n_auto_handles=count, **kw)
        elif kind == "picture":
            shape = from_image(path, H, moving, name=name, n_auto_handles=count, **kw)
        else:
            opts = dict(name=name, n_auto_handles=count, patch_size=PATCH_SIZE, weld_tolerance=weld_tolerance)
            shape = from_surface(path, None, H, moving, **opts, **kw)
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"{kind} file {path}: {exc}") from None
    size = PATCH_SIZE if d == 3 else 1
    groups = [np.arange(i * size, (i + 1) * size) for i in range(count)]
    return OwnShape(shape, kind, path, groups, fixed, H is None)
