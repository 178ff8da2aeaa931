"""Planar meshes in text files: OBJ and OFF read with the checked numpy reader of :mod:`.surface_files` (the OFF
header's counts checked before the body is read) and written through libigl."""

from __future__ import annotations

import igl
import numpy as np

from .surface_files import MAX_FILE_ELEMENTS, check_size, parse_surface

__all__ = ["read_text_mesh", "check_off_header", "igl_write"]


def read_text_mesh(path, ext):
    """V and F of an OBJ/OFF (numpy reader, :mod:`.surface_files`), the OFF header's counts checked first."""
    size = check_size(path, "mesh file")  # read whole below: a 3 GiB file raised an empty MemoryError
    if ext == ".off":
        check_off_header(path, size)
    try:
        V, F, _ = parse_surface(path.read_bytes(), ext)
    except ValueError as exc:
        raise ValueError(f"mesh file {path} could not be read as {ext} ({exc})") from None
    if V.shape[1] == 3:
        if np.abs(V[:, 2]).max(initial=0) > 0:
            raise ValueError(f"{path} is not planar (z is not 0)")
        V = V[:, :2]
    return V, F


def check_off_header(path, size):
    """ValueError unless the OFF file at ``path`` (``size`` bytes) has a header whose counts it can hold."""
    with open(path, "rb") as fh:
        head = fh.read(4096).decode("ascii", "replace").split("\n")
    words = []
    for line in head:
        words += line.split("#")[0].split()
        if len(words) >= 4:
            break
    if not words or not words[0].upper().endswith("OFF"):
        raise ValueError(f"mesh file {path} is not an OFF file (no OFF header)")
    try:
        n_v, n_f = int(words[1]), int(words[2])
    except (IndexError, ValueError):
        raise ValueError(f"mesh file {path}: the OFF header has no vertex and face counts") from None
    if min(n_v, n_f) < 0 or max(n_v, n_f) > MAX_FILE_ELEMENTS or 2 * (n_v + n_f) > size:
        raise ValueError(
            f"mesh file {path} declares {n_v:,} vertices and {n_f:,} faces in {size:,} bytes "
            f"(limit {MAX_FILE_ELEMENTS:,} each, and at least 2 bytes per entry)"
        )


def igl_write(path, V3, F):
    """Write the triangles F of the vertices V3 (n,3) as ASCII OBJ/OFF through libigl (format by the ending)."""
    igl.write_triangle_mesh(str(path), V3, F, igl.FileEncoding.Ascii)
