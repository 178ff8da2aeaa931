"""What every operator file shares: the kinds and their formats, the limits, and the checked read of one file.

Each kind declares its formats, its archive members and the loader that reads it (:data:`KINDS`). A loader given
another kind's file (or a cache entry, or a mesh file) names what the file is and which loader reads it, before
any limit of its own kind is applied. The archive itself is read by :class:`defop.geometry.archive.NpzReader`
(the member count, no pickle, declared sizes, damaged archives); here come the JSON header (its size and depth
counted before it is parsed, its integer fields checked before any ``int()``), the format, the declared shapes
(each kind's ``check_declared``) and the arrays' kinds and values (:func:`array`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from pathlib import Path

import numpy as np

from ... import options as opt
from ...geometry.archive import ArchiveError, Limits, NpzReader, Reraise
from ...geometry.mesh import Mesh
from .. import handle_bases as hb

#: the largest array a file may declare, in bytes (uncompressed)
MAX_ARRAY_BYTES = 2 * 2**30
#: the most bytes all arrays together may declare
MAX_TOTAL_BYTES = 4 * 2**30
#: the most members (arrays) a single-valued operator file may hold
MAX_MEMBERS = 16
#: the longest JSON header, in characters, and its deepest nesting of objects and lists
MAX_HEADER_CHARS = 1_000_000
MAX_JSON_DEPTH = 32
#: the most TPS centres (training samples plus the rest pose) an operator file may declare
MAX_CENTERS = 20_000
#: the most branches a multi-valued file may hold
MAX_BRANCHES = 8
#: the members every operator file begins with: its JSON header, the mesh and the handles
MESH_MEMBERS = ("header", "V", "F", "handles", "moving")
#: the float dtypes an operator file may store (the compiled kernels take these; float16 is refused by name)
FLOATS = (np.dtype(np.float32), np.dtype(np.float64))


class OperatorFileError(ValueError):
    """An operator file that cannot be used; the message names the file and what is wrong with it."""


@dataclasses.dataclass(frozen=True)
class FileKind:
    """One kind of operator file: its formats (name -> version), members, what it is and which loader reads it.

    ``signature``: a member only this kind's files hold (how a file of another kind is recognised).
    """

    name: str
    formats: dict
    members: tuple
    description: str
    loader: str
    signature: str

    @property
    def max_members(self):
        return MAX_MEMBERS if self.name == "operator" else len(self.members)


#: the kinds of operator file, filled by the format modules (:mod:`.operator_file`, :mod:`.branched_file`,
#: :mod:`.movable_file`)
KINDS = {}
#: archives of defop that are not operator files: (signature members, what the file is, the reader that reads it)
OTHER_ARCHIVES = (
    (("__meta__.npy",), "a defop cache entry", "defop.training.cache.Cache.load"),
    (("V.npy", "F.npy"), "a mesh file", "defop.geometry.mesh.read_mesh"),
)


def register(kind):
    """Add a :class:`FileKind` to :data:`KINDS`; returns it."""
    KINDS[kind.name] = kind
    return kind


def kind_of(names, header=None):
    """(what the file is, its loader) from its member names (and the header's format, if read), or None."""
    fmt = header.get("format") if isinstance(header, dict) else None
    for kind in KINDS.values():
        if isinstance(fmt, str) and fmt in kind.formats:
            return kind.name, f"{kind.description} ({fmt})", kind.loader
    for kind in KINDS.values():
        if f"{kind.signature}.npy" in names:
            return kind.name, kind.description, kind.loader
    for members, what, loader in OTHER_ARCHIVES:  # a mesh file holds V and F only
        if set(members) <= set(names) and (len(members) == 1 or len(names) == len(members)):
            return None, what, loader
    return None


def wrong_kind(path, kind, names, header=None):
    """The OperatorFileError of a file of another kind than ``kind``, or None when it may be ``kind``'s."""
    got = kind_of(names, header)
    if got is None or got[0] == kind.name:
        return None
    return OperatorFileError(f"{path} is {got[1]}, not {kind.description}: use {got[2]}")


def check_path(path):
    """``path`` as a pathlib.Path to an existing regular file (an OperatorFileError naming it otherwise)."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    path = Path(path)
    if path.is_dir():
        raise OperatorFileError(f"{path} is a directory, not an operator file")
    if path.exists() and not path.is_file():  # opening a FIFO would block
        raise OperatorFileError(f"{path} is not a regular file (a FIFO, socket or device), not an operator file")
    if not path.is_file():
        raise OperatorFileError(f"no such operator file: {path}")
    return path


def read_file(path, kind, check_declared):
    """(header, arrays, format version) of a file of ``kind`` (a :class:`FileKind`), checked before any work.

    ``check_declared(path, header, shapes, version)`` checks the declared shapes ({name: shape}) before an array
    is read. Every error is an :class:`OperatorFileError` naming the file.
    """
    path = check_path(path)
    limits = Limits(kind.max_members, MAX_ARRAY_BYTES, MAX_TOTAL_BYTES)
    try:
        with NpzReader(path, str(path), "a defop operator file", limits) as z:
            names = z.names()
            other = wrong_kind(path, kind, names)
            if other is not None:
                raise other
            members = z.members(kind.members)
            if "header" not in members:
                raise OperatorFileError(f"{path} is not a defop operator file: no 'header' member")
            header = json_header(path, z, members["header"])
            if not isinstance(header, dict):
                raise OperatorFileError(f"{path}: the header must be a JSON object, got {type(header).__name__}")
            fmt = header.get("format")
            other = wrong_kind(path, kind, names, header)
            if other is not None:
                raise other
            if not isinstance(fmt, str) or fmt not in kind.formats:
                known = ", ".join(repr(f) for f in kind.formats)
                raise OperatorFileError(f"{path} has format {fmt!r}; this defop reads {known}")
            if "format_version" in header:
                field(path, "format_version", header["format_version"])
            check_declared(path, header, {n: m.shape for n, m in members.items()}, kind.formats[fmt])
            with z.translated():
                data = {name: z.read(m) for name, m in members.items() if name != "header"}
    except ArchiveError as exc:
        raise OperatorFileError(str(exc)) from exc.__cause__
    return header, data, kind.formats[fmt]


def json_header(path, reader, member):
    """The JSON header, its size and nesting depth checked before it is parsed."""
    if member.shape != () or member.dtype.kind != "U" or member.dtype.itemsize // 4 > MAX_HEADER_CHARS:
        raise OperatorFileError(
            f"{path}: the header must be one JSON string of at most {MAX_HEADER_CHARS} characters, got a "
            f"{member.dtype} array of shape {member.shape}"
        )
    text = str(reader.read(member))
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise OperatorFileError(f"{path}: the JSON header is nested {depth} levels deep, limit {MAX_JSON_DEPTH}")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise OperatorFileError(f"{path}: the header is not valid JSON ({exc})") from exc


def json_depth(text):
    """The deepest nesting of objects and lists in a JSON text, counted without parsing it (strings skipped)."""
    bare = re.sub(r'"(?:[^"\\]|\\.)*"', "", text)
    steps = np.frombuffer(bare.encode("utf-8", "replace"), np.uint8)
    level = np.cumsum(np.isin(steps, (ord("["), ord("{"))).astype(np.int64) - np.isin(steps, (ord("]"), ord("}"))))
    return int(level.max(initial=0))


def field(path, name, value):
    """:func:`header_int` with the file named in the error (an :class:`OperatorFileError`)."""
    try:
        return header_int(name, value)
    except ValueError as exc:
        raise OperatorFileError(f"{path}: {exc}") from None


def header_int(name, value, allowed=None):
    """An integer field of a file's header, checked before any ``int()``: a JSON integer (an integral float is
    accepted), never a bool, a fraction (``side: 1.5`` is not +1), a string (``'²'``) or null; in ``allowed`` if given.

    Raises
    ------
    ValueError
        ``"the header's {name} must be an integer, got {value!r}"`` (the callers add the file's name).
    """
    n = opt.integer(f"the header's {name}", value)
    if allowed is not None and n not in allowed:
        raise ValueError(f"the header's {name} must be one of {', '.join(map(str, allowed))}, got {value!r}")
    return n


def header_object(header, name):
    """``header[name]`` (``name`` None: the header itself), checked to be a JSON object (TypeError naming it)."""
    if name is not None and isinstance(header, dict) and name not in header:
        raise KeyError(name)
    value = header if name is None else header.get(name) if isinstance(header, dict) else None
    if not isinstance(value, dict):
        what = "the header" if name is None else f"header {name!r}"
        raise TypeError(f"{what} must be a JSON object, got {type(value).__name__}")
    return value


def array(data, name, ndim, dtype_kind, shape=None):
    """data[name] checked: dimension, kind (f/i/u/b), float32 or float64, finite values, and ``shape`` (None = any)."""
    if name not in data:
        raise KeyError(f"array {name!r}")
    a = data[name]
    if a.ndim != ndim or a.dtype.kind not in dtype_kind:
        raise ValueError(f"array {name!r} must be {ndim}-D of kind {dtype_kind!r}, got {a.dtype} {a.shape}")
    if a.dtype.kind == "f" and a.dtype not in FLOATS:
        raise ValueError(f"array {name!r} is {a.dtype}; an operator file stores float32 or float64 numbers")
    if shape is not None and any(s is not None and s != t for s, t in zip(shape, a.shape)):
        raise ValueError(f"array {name!r} has shape {a.shape}, expected {tuple(shape)}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"array {name!r} has NaN or infinite values")
    return a


def mesh_and_handles(data, dims=hb.DIMS):
    """(mesh, handles, moving) of a file's ``V``, ``F``, ``handles`` and ``moving``, each checked by name."""
    V = array(data, "V", 2, "f")
    d = V.shape[1]
    if d not in dims:
        raise ValueError(f"V must have {' or '.join(map(str, dims))} columns (the dimension), got {V.shape}")
    F = array(data, "F", 2, "iu", (None, d + 1))
    handles = array(data, "handles", 1, "iu")
    moving = array(data, "moving", 1, "b", handles.shape)
    if handles.size and (handles.min() < 0 or handles.max() >= len(V)):
        bad = handles[(handles < 0) | (handles >= len(V))]
        raise ValueError(f"array 'handles': handle indices must lie in [0, {len(V)}), got {bad[:5].tolist()}")
    return Mesh(V, F), handles, moving


def write(path, arrays):
    """np.savez of ``arrays`` to ``path``, atomically (a reader sees the old file or the new one)."""

    def save(tmp):
        with open(tmp, "wb") as fh:  # a handle: np.savez(name) would append ".npz" to another suffix
            np.savez(fh, **arrays)

    opt.write_atomic(Path(path), save)


def load_errors(path, what):
    """A context turning a build's KeyError/TypeError/ValueError/... into an OperatorFileError naming the file."""

    def invalid(exc):
        reason = f"missing {exc}" if isinstance(exc, KeyError) else str(exc) or type(exc).__name__
        return OperatorFileError(f"{path} is not a valid {what}: {reason}")

    errors = (KeyError, TypeError, ValueError, IndexError, OverflowError, MemoryError)
    return Reraise(errors, invalid, keep=(OperatorFileError,))
