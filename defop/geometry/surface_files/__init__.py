"""Triangle surface files (PLY, STL, OBJ, OFF) read safely, and vertex welding.

One module per format reads the bytes as its specification writes them (:mod:`.ply`, :mod:`.stl`,
:mod:`.obj`, :mod:`.off`); a UTF-8 byte-order mark at the start of a text file is skipped. Every count a file
states is checked before anything is allocated for it: at most :data:`MAX_FILE_ELEMENTS` vertices or
triangles; a binary PLY or STL must be exactly as long as its header and elements; an ASCII count can be at
most the bytes left divided by the shortest record, and the data lines must be as many as the counts say; a
file above :data:`MAX_FILE_BYTES` is not read at all. Polygons are triangulated by :func:`triangulate`
(convex ones as fans, other simple planar ones by ear clipping; non-planar or self-crossing ones refused,
named). The readers are numpy code (no compiled reader: libigl's trusted a PLY header's counts, allocated
10⁹ vertices and aborted the interpreter, and read short or garbled ASCII PLY data as uninitialised memory).
Every error is a ``ValueError`` that names the file and what is wrong (the line, element or field).

STL stores three corners per triangle and no shared vertices: :func:`weld` merges exactly coincident
coordinates, so a closed STL reads as the same closed surface as its OBJ. Welding within a tolerance is
opt-in (``weld_tolerance``) and refuses to create degenerate or non-manifold triangles.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from .common import MAX_FILE_ELEMENTS, SurfaceFile, checked, count, strip_bom
from .obj import read_obj
from .off import read_off
from .ply import read_ply
from .polygons import PLANARITY_TOLERANCE, triangulate
from .stl import read_stl
from .weld import bbox_diagonal, weld

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_FILE_ELEMENTS",
    "PLANARITY_TOLERANCE",
    "SURFACE_FORMATS",
    "SurfaceFile",
    "bbox_diagonal",
    "check_file",
    "check_size",
    "parse_surface",
    "read_surface_file",
    "triangulate",
    "weld",
]

#: the largest file read at all (checked before reading): a 10⁷-triangle binary STL is 500 MB
MAX_FILE_BYTES = 2**30

#: the file name endings :func:`read_surface_file` reads
SURFACE_FORMATS = (".ply", ".stl", ".obj", ".off")


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
                count(str(int.from_bytes(head[80:], "little")), "triangles")  # before reading a sparse giant
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

    The counts are checked as :func:`read_surface_file` describes; polygons are triangulated
    (:func:`triangulate`). ValueError (without the file name) for anything malformed.
    """
    if ext not in SURFACE_FORMATS:
        raise ValueError(f"unknown format {ext!r}; use {', '.join(SURFACE_FORMATS)}")
    if ext != ".stl":  # a binary STL's 80-byte header may start with any bytes (read_stl skips it if ASCII)
        data = strip_bom(data)
    if not strip_bom(data).strip():
        raise ValueError("holds no data (the file is empty)")
    V, F, fmt = {".ply": read_ply, ".stl": read_stl, ".obj": read_obj, ".off": read_off}[ext](data)
    return (*checked(V, F), fmt)


def _check_tolerance(tol):
    if tol is None:
        return 0.0
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.floating, np.integer)):
        raise ValueError(f"weld_tolerance must be a number in [0, 0.1) or None, got {tol!r}")
    if not 0 <= float(tol) < 0.1:
        raise ValueError(f"weld_tolerance must be a number in [0, 0.1) (× the bounding-box diagonal), got {tol!r}")
    return float(tol)
