"""What the surface readers share: the element limit, the result type and checked parsing of counts and numbers."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

__all__ = [
    "MAX_FILE_ELEMENTS",
    "SurfaceFile",
    "checked",
    "count",
    "fits",
    "floats",
    "ints",
    "strip_bom",
    "text",
]

#: the most vertices or triangles a mesh or surface file may declare (checked before anything is allocated)
MAX_FILE_ELEMENTS = 10_000_000

_COUNT = re.compile(r"[0-9]{1,19}")  # ASCII digits only: '²'.isdigit() is True, and int('²') fails
_INT = re.compile(r"[-+]?[0-9]{1,18}")
_INTS = re.compile(r"(?:[-+]?[0-9]{1,18} )*[-+]?[0-9]{1,18}")
BOM = b"\xef\xbb\xbf"


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
        ``"ply-ascii"``, ``"ply-binary_little_endian"``, ``"ply-binary_big_endian"``, ``"stl-binary"``,
        ``"stl-ascii"``, ``"obj"`` or ``"off"``.
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


def strip_bom(data):
    """``data`` without a leading UTF-8 byte-order mark (text editors on Windows write one)."""
    return data[len(BOM) :] if data.startswith(BOM) else data


def count(word, what):
    """The element count ``word`` (ASCII digits) as an int, at most :data:`MAX_FILE_ELEMENTS`; ValueError otherwise."""
    if not _COUNT.fullmatch(word):
        raise ValueError(f"the {what} count {word!r} is not a non-negative integer")
    n = int(word)
    if n > MAX_FILE_ELEMENTS:
        raise ValueError(
            f"declares {n:,} {what}, limit {MAX_FILE_ELEMENTS:,} (defop.geometry.surface_files.MAX_FILE_ELEMENTS)"
        )
    return n


def fits(n, what, per_record, nbytes):
    """ASCII: ``n`` records of at least ``per_record`` bytes must fit in ``nbytes``; ValueError before allocating."""
    if n * per_record > nbytes:
        raise ValueError(
            f"declares {n:,} {what}, but {nbytes:,} bytes of data hold at most "
            f"{nbytes // per_record:,} (each takes at least {per_record} bytes)"
        )


def text(data, what):
    """The bytes of a text file as str (latin-1: every byte is a character); ValueError if it holds NUL bytes."""
    if b"\0" in data:
        raise ValueError(f"is not a text {what} file (it holds NUL bytes)")
    return data.decode("latin-1")


def floats(tokens, where):
    """float64 array of the tokens; ValueError naming ``where(i)`` of the first that is not a number.

    Python's float (numpy's too) reads ``1_0`` as 10 (PEP 515); no surface format writes a digit separator."""
    try:
        if "_" in "".join(tokens):  # one C-speed scan; the slow search below only on a hit
            raise ValueError
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for i, t in enumerate(tokens):
            try:
                if "_" in t:
                    raise ValueError
                float(t)
            except ValueError:
                raise ValueError(f"{where(i)} is not a number: {t[:40]!r}") from None
        raise


def ints(tokens, where):
    """int64 array of the tokens (decimal integers); ValueError naming ``where(i)`` of the first that is not one."""
    if _INTS.fullmatch(" ".join(tokens)):  # one regex over all: the common case, fast
        return np.array(tokens).astype(np.int64) if tokens else np.zeros(0, dtype=np.int64)
    for i, t in enumerate(tokens):
        if not _INT.fullmatch(t):
            raise ValueError(f"{where(i)} is not an integer: {t[:40]!r}")
    return np.array([int(t) for t in tokens], dtype=np.int64)


def checked(V, F):
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
