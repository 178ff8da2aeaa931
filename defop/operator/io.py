"""Operator files: :meth:`DefOp.save` and :meth:`DefOp.load`, with the checks an untrusted file needs.

**Format** (``.npz``, a zip of ``.npy`` arrays, read without pickle): the arrays ``V`` (n, d), ``F`` (m, d+1),
``handles``, ``moving``, ``W`` (|Ψ|, d n), ``basis_P`` (n_moving, d), ``basis_centers`` (TPS), ``train_samples``
and, when compressed, ``factor_A`` and ``factor_B``; plus ``header``, a JSON object
``{"format": "defop-operator-3", "format_version": 3, "dim": d, "meta": {...}, "basis": {...}}``.

| format | written by | d | read as |
|---|---|---|---|
| ``defop-operator-1`` | before (★) | 2 | W only; old factors are recomputed |
| ``defop-operator-2`` | 7c4dc5f and before this change | 2 | as saved (d = 2 is implied) |
| ``defop-operator-3`` | this version | 2 or 3 (``dim``) | as saved |
| ``defop-branched-2`` | this version, kind ``branched`` | 2 or 3 | :func:`load_branched` (one DefOp per branch, g_b) |
| ``defop-branched-1`` | kind ``branched`` (issue 29) | 2 or 3 | :func:`load_branched`: λ²_b as the domain, no box |

A multi-valued operator (:mod:`defop.operator.branched`) is one archive: the mesh, handles and ``mode`` once, each
branch's arrays prefixed ``b<label>.`` (``W``, ``basis_centers``, ``train_samples``, the factors, ``energy`` and
``margin``), and the header's ``branches`` list; every branch is checked as a DefOp file is (steps 1-7).

**Checks before work** (:func:`load`). Every error is a ``ValueError`` that names the file and what is wrong:

1. the file's first bytes: a zip archive (a ``.npy`` array, or anything else, is "not a defop operator file");
2. the zip directory: at most :data:`MAX_MEMBERS` members, known names only, stored or deflated, unencrypted,
   and the *declared* (uncompressed) size of each member at most :data:`MAX_ARRAY_BYTES` (a zip bomb is
   rejected here, before any byte is inflated);
3. each member's ``.npy`` header (read from the first bytes of the stream): at most 3 dimensions, a plain
   numeric, bool or string dtype (never Python objects, so no pickle), and a shape whose byte count is at
   most :data:`MAX_ARRAY_BYTES` and equals what the member declares ("declares a 60000×60000 float64 matrix,
   limit ...");
4. the JSON header: at most :data:`MAX_HEADER_CHARS` characters and :data:`MAX_JSON_DEPTH` levels of nesting,
   counted before it is parsed; its integer fields (``dim``, ``format_version``, a branch's ``label`` and ``side``)
   checked to be integers before any ``int()`` (:func:`header_int`: ``side: 1.5`` is refused, not read as +1);
5. the declared shapes against each other and against :data:`MAX_CENTERS` and the polynomial degree limit
   (:data:`defop.operator.handle_bases.MAX_DEGREE`), before an array is read;
6. then the data, streamed into arrays of the declared size: decompression never produces more than the
   member declares, and a damaged stream (bad CRC, truncated) is "damaged or truncated";
7. finally every array's values (finite, indices in range, the rest pose, the handle columns).

:func:`save` writes a temporary file in the target's folder and renames it into place (atomic).
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from . import handle_bases as hb

FORMAT = "defop-operator-3"
FORMAT_VERSION = 3
#: formats this version reads, with their version numbers (1 and 2 are 2D only)
READS = {"defop-operator-1": 1, "defop-operator-2": 2, FORMAT: FORMAT_VERSION}
#: the largest array a file may declare, in bytes (uncompressed)
MAX_ARRAY_BYTES = 2 * 2**30
#: the most bytes all arrays together may declare
MAX_TOTAL_BYTES = 4 * 2**30
#: the most members (arrays) an archive may hold
MAX_MEMBERS = 16
#: the longest JSON header, in characters, and its deepest nesting of objects and lists
MAX_HEADER_CHARS = 1_000_000
MAX_JSON_DEPTH = 32
#: the most TPS centres (training samples plus the rest pose) an operator file may declare
MAX_CENTERS = 20_000
MEMBERS = (
    "header",
    "V",
    "F",
    "handles",
    "moving",
    "W",
    "basis_P",
    "basis_centers",
    "train_samples",
    "factor_A",
    "factor_B",
)
#: the multi-valued kind (:class:`defop.operator.branched.BranchedOperator`): shared arrays once, per-branch arrays
#: prefixed ``b<label>.``, the header's ``branches`` list (label, side, meta, basis of each)
#: version 2 (issue 37) adds each branch's domain function g_b (its own TPS: ``domain_w``, ``domain_centers``, the
#: header's ``domain`` entry) and the samples' ``box``; version 1 files load with λ²_b (``margin``) as g_b
BRANCHED_FORMAT = "defop-branched-2"
BRANCHED_READS = {"defop-branched-1": 1, BRANCHED_FORMAT: 2}
#: the most branches a file may hold
MAX_BRANCHES = 8
BRANCH_MEMBERS = (
    "W",
    "basis_centers",
    "train_samples",
    "factor_A",
    "factor_B",
    "energy",
    "margin",
    "domain_w",
    "domain_centers",
)
SHARED_MEMBERS = ("header", "V", "F", "handles", "moving", "basis_P", "mode", "box")
_NPY_HEADER_MAX = 65_536 + 16  # numpy's own limit on a .npy header
#: what a damaged archive can make zipfile, zlib or numpy's header parser raise while we read it
_DAMAGED = (zipfile.BadZipFile, zlib.error, EOFError, struct.error, NotImplementedError, SyntaxError, UnicodeError)


class OperatorFileError(ValueError):
    """An operator file that cannot be used; the message names the file and what is wrong with it."""


def save(op, path):
    """Write ``op`` to ``path`` as .npz: arrays plus the JSON header (exact round trip), atomically.

    The archive goes to a temporary file in the same folder, which is renamed into place only when it is
    complete: a reader sees the old file or the new one, never a partial one, and a failed save leaves no file.

    Parameters
    ----------
    op : defop.operator.defop.DefOp
    path : str or pathlib.Path
    """
    path = Path(path)
    arrays, basis = _arrays(op)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "dim": op.d, "meta": op.meta, "basis": basis}
    arrays["header"] = np.array(json.dumps(header))
    _write(path, arrays)


def _write(path, arrays):
    """np.savez of ``arrays`` to ``path``, atomically."""

    def write(tmp):
        with open(tmp, "wb") as fh:  # a handle: np.savez(name) would append ".npz" to another suffix
            np.savez(fh, **arrays)

    opt.write_atomic(path, write)


def _arrays(op):
    """The arrays of one DefOp (format 3) and its basis entry of the header."""
    params = op.handle_basis.params()
    arrays = {"V": op.mesh.V, "F": op.mesh.F, "handles": op.handles, "moving": op.moving, "W": op.W}
    arrays["basis_P"] = params["P"]
    if "centers" in params:
        arrays["basis_centers"] = params["centers"]
    if op.train_samples is not None:
        arrays["train_samples"] = op.train_samples
    if op.factors is not None:
        arrays["factor_A"], arrays["factor_B"] = op.factors
    basis = {"kind": params["kind"], "scale": params["scale"], "degree": params.get("degree")}
    if "kernel" in params:
        basis["kernel"] = params["kernel"]
    return arrays, basis


def save_branched(bop, path):
    """Write a :class:`defop.operator.branched.BranchedOperator` (kind ``branched``, module docstring), atomically.

    The mesh and handles once; per branch b its DefOp's arrays, e_b and l_b under ``b<label>.``; the mode u.
    """
    path = Path(path)
    if len(bop.branches) > MAX_BRANCHES:
        raise ValueError(f"a file holds at most {MAX_BRANCHES} branches, got {len(bop.branches)}")
    arrays, entries = {"mode": bop.mode}, []
    for b in bop.branches:
        own, basis = _arrays(b.op)
        for name in ("V", "F", "handles", "moving", "basis_P"):
            arrays[name] = own.pop(name)
        own["energy"], own["domain_w"] = b.energy_w, b.domain.w
        if b.margin_w is not None:
            own["margin"] = b.margin_w
        domain = {"own": b.domain.own}
        if b.domain.own:
            own["domain_centers"] = b.domain.basis.centers
            domain.update(scale=b.domain.basis.scale, kernel=b.domain.basis.kernel)
        arrays.update({f"b{b.label}.{name}": a for name, a in own.items()})
        entries.append({"label": b.label, "side": b.side, "meta": b.op.meta, "basis": basis, "domain": domain})
    arrays["box"] = bop.box
    header = {
        "format": BRANCHED_FORMAT,
        "format_version": 2,
        "kind": "branched",
        "dim": bop.branches[0].op.d,
        "meta": bop.meta,
        "threshold": bop.threshold.tolist(),
        "branches": entries,
    }
    arrays["header"] = np.array(json.dumps(header))
    _write(path, arrays)


def _branch_members():
    return SHARED_MEMBERS + tuple(f"b{k}.{n}" for k in range(MAX_BRANCHES) for n in BRANCH_MEMBERS)


def _branch_view(header, data, k):
    """The header and arrays of branch k as a format-3 DefOp file's."""
    entry = header["branches"][k]
    if not isinstance(entry, dict) or header_int(f"branches[{k}].label", entry.get("label")) != k:
        raise ValueError(f"branch entry {k} must be an object with label {k}")
    sub = {name: data[name] for name in ("V", "F", "handles", "moving", "basis_P") if name in data}
    sub.update({n: data[f"b{k}.{n}"] for n in BRANCH_MEMBERS if f"b{k}.{n}" in data})
    return {"meta": entry["meta"], "basis": entry["basis"], "dim": header.get("dim")}, sub


def _check_declared_branched(path, header, headers, version):
    """Each branch's declared shapes as :func:`_check_declared` checks a DefOp file's."""
    entries = header.get("branches") if isinstance(header, dict) else None
    if not isinstance(entries, list) or not 1 <= len(entries) <= MAX_BRANCHES:
        raise OperatorFileError(f"{path}: the header must list 1 to {MAX_BRANCHES} branches")
    for k, entry in enumerate(entries):
        sub_head = {"dim": header.get("dim"), "basis": entry.get("basis") if isinstance(entry, dict) else None}
        sub = {n: headers[n] for n in ("V", "F") if n in headers}
        sub.update({n: headers[f"b{k}.{n}"] for n in ("W", "basis_centers") if f"b{k}.{n}" in headers})
        _check_declared(path, sub_head, sub, FORMAT_VERSION)


def _domain(entry, data, k, op, domain_cls):
    """Branch k's domain g_b of a version-2 file (None: λ²_b on Ψ_b, from ``margin``)."""
    d = entry["domain"]
    if not isinstance(d, dict) or not isinstance(d.get("own"), bool):
        raise TypeError(f"branch entry {k}'s 'domain' must be an object with a boolean 'own'")
    if not d["own"]:
        return None
    n, dim = op.P.shape
    if d.get("kernel") != hb.KERNELS[dim]:
        raise ValueError(
            f"the {dim}D domain TPS uses the kernel {hb.KERNELS[dim]!r}, the file says {d.get('kernel')!r}"
        )
    basis = hb.TPSBasis(op.P, _array(data, f"b{k}.domain_centers", 3, "f", (None, n, dim)), float(d["scale"]))
    return domain_cls(basis, _array(data, f"b{k}.domain_w", 1, "f", (basis.size,)))


def load_branched(path, cls, branch_cls, op_cls, domain_cls=None):
    """Read a file written by :func:`save_branched`, with the checks of :func:`load`; build a ``cls``.

    Raises
    ------
    ValueError
        (:class:`OperatorFileError`) naming the file and the problem, as :func:`load`.
    """
    members = _branch_members()
    header, data, version = _read(path, BRANCHED_READS, members, len(members), _check_declared_branched)
    try:
        branches = []
        for k, entry in enumerate(header["branches"]):
            sub_head, sub = _branch_view(header, data, k)
            op = _build(op_cls, sub_head, sub, FORMAT_VERSION)
            energy = _array(data, f"b{k}.energy", 1, "f", (op.handle_basis.size,))
            domain = _domain(entry, data, k, op, domain_cls) if version >= 2 else None
            margin = None
            if domain is None or f"b{k}.margin" in data:
                margin = _array(data, f"b{k}.margin", 1, "f", (op.handle_basis.size,))
            side = header_int(f"branches[{k}].side", entry["side"], allowed=(1, -1))
            branches.append(branch_cls(k, op, energy, margin, side, domain=domain))
        mode = _array(data, "mode", 2, "f", data["V"].shape)
        meta = header["meta"]
        if not isinstance(meta, dict):
            raise TypeError("header 'meta' must be an object")
        box = _array(data, "box", 2, "f", (2, branches[0].op.P.size)) if version >= 2 else None
        return cls(branches, mode, opt.real_array("the header's threshold", header["threshold"]), meta, box=box)
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, MemoryError) as exc:
        what = f"missing {exc}" if isinstance(exc, KeyError) else str(exc) or type(exc).__name__
        raise OperatorFileError(f"{path} is not a valid multi-valued operator file: {what}") from exc


def load(path, cls):
    """Read an operator file, checking it before any work (module docstring), and build a ``cls``.

    Parameters
    ----------
    path : str or pathlib.Path
    cls : type
        :class:`defop.operator.defop.DefOp`.

    Returns
    -------
    op : cls

    Raises
    ------
    ValueError
        (:class:`OperatorFileError`) naming the file and the problem: missing, not a defop operator,
        damaged or truncated, beyond a limit, of an unknown format, or with arrays that do not fit together.
    """
    header, data, version = _read(path, READS, MEMBERS, MAX_MEMBERS, _check_declared)
    try:
        return _build(cls, header, data, version)
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, MemoryError) as exc:
        what = f"missing {exc}" if isinstance(exc, KeyError) else str(exc) or type(exc).__name__
        raise OperatorFileError(f"{path} is not a valid defop operator file: {what}") from exc


def _read(path, reads, members, max_members, check_declared):
    """(header, arrays, format version) of an operator file of one of the formats ``reads``, checked (steps 1-6)."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    path = Path(path)
    if path.is_dir():
        raise OperatorFileError(f"{path} is a directory, not an operator file")
    if path.exists() and not path.is_file():  # opening a FIFO would block
        raise OperatorFileError(f"{path} is not a regular file (a FIFO, socket or device), not an operator file")
    if not path.is_file():
        raise OperatorFileError(f"no such operator file: {path}")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
            if magic.startswith(b"\x93NUMPY"):
                raise OperatorFileError(f"{path} is a single .npy array, not a defop operator file (an .npz archive)")
            if not magic.startswith((b"PK\x03\x04", b"PK\x05\x06")):
                raise OperatorFileError(f"{path} is not a defop operator file (not a zip archive)")
            fh.seek(0)
            with zipfile.ZipFile(fh) as zf:
                headers = _member_headers(path, zf, members, max_members)
                header = _json_header(path, zf, headers)
                fmt = header.get("format") if isinstance(header, dict) else None
                if not isinstance(fmt, str) or fmt not in reads:
                    known = ", ".join(repr(f) for f in reads)
                    raise OperatorFileError(f"{path} has format {fmt!r}; this defop reads {known}")
                if "format_version" in header:
                    _field(path, "format_version", header["format_version"])
                check_declared(path, header, headers, reads[fmt])
                data = {name: _read_array(path, zf, name, h) for name, h in headers.items() if name != "header"}
    except OperatorFileError:
        raise
    except OSError as exc:
        raise OperatorFileError(f"{path} cannot be read: {exc}") from exc
    except (*_DAMAGED, ValueError, RecursionError, MemoryError) as exc:
        raise OperatorFileError(
            f"{path} is not a readable defop operator file: damaged or truncated ({type(exc).__name__}: {exc})"
        ) from exc
    return header, data, reads[fmt]


def _member_headers(path, zf, members=MEMBERS, max_members=MAX_MEMBERS):
    """{name: (shape, dtype, fortran, data_offset, info)} from the zip directory and each .npy header."""
    infos = zf.infolist()
    names = {i.filename for i in infos[: 2 * max_members]}
    if members is MEMBERS and "mode.npy" in names:
        raise OperatorFileError(f"{path} is a multi-valued operator file (kind 'branched'): use BranchedOperator.load")
    if members is MEMBERS and "joint_W.npy" in names:
        raise OperatorFileError(f"{path} is a movable-handle operator file: use defop.operator.movable.MovableOp.load")
    if members is not MEMBERS and "W.npy" in names:
        raise OperatorFileError(f"{path} is a single-valued operator file ({FORMAT} or older): use DefOp.load")
    if len(infos) > max_members:
        raise OperatorFileError(f"{path} holds {len(infos)} archive members, limit {max_members}")
    out, total = {}, 0
    for info in infos:
        name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        if name not in members or name in out:
            raise OperatorFileError(f"{path} is not a defop operator file: unexpected member {info.filename!r}")
        if info.flag_bits & 0x1 or info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise OperatorFileError(f"{path}: member {info.filename!r} is encrypted or uses an unknown compression")
        if info.file_size > MAX_ARRAY_BYTES + _NPY_HEADER_MAX:
            raise OperatorFileError(
                f"{path}: member {info.filename!r} declares {_size(info.file_size)} uncompressed, limit "
                f"{_size(MAX_ARRAY_BYTES)} per array (not inflated)"
            )
        total += info.file_size
        if total > MAX_TOTAL_BYTES:
            raise OperatorFileError(f"{path} declares more than {_size(MAX_TOTAL_BYTES)} of arrays in total")
        out[name] = _npy_header(path, zf, info, name)
    if "header" not in out:
        raise OperatorFileError(f"{path} is not a defop operator file: no 'header' member")
    return out


def _npy_header(path, zf, info, name):
    """(shape, dtype, fortran, offset, info) of one member, from its first bytes; checked against the limits."""
    with zf.open(info) as fh:
        head = fh.read(_NPY_HEADER_MAX)
    buf = io.BytesIO(head)
    try:
        version = np.lib.format.read_magic(buf)
        reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = reader(buf)
    except ValueError as exc:
        raise OperatorFileError(f"{path}: array {name!r} has a damaged .npy header ({exc})") from exc
    if dtype.hasobject or dtype.kind not in "biufU" or len(shape) > 3:
        raise OperatorFileError(
            f"{path}: array {name!r} is {dtype} with {len(shape)} dimensions; an operator file holds plain numbers "
            "(never Python objects or pickles) in at most 3 dimensions"
        )
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        raise OperatorFileError(
            f"{path}: array {name!r} declares a {'×'.join(map(str, shape))} {dtype} array ({_size(nbytes)}), "
            f"limit {_size(MAX_ARRAY_BYTES)} per array"
        )
    offset = buf.tell()
    if offset + nbytes != info.file_size:
        raise OperatorFileError(
            f"{path}: array {name!r} declares {'×'.join(map(str, shape))} {dtype} ({_size(nbytes)}), but its archive "
            f"member holds {_size(max(info.file_size - offset, 0))}: damaged or truncated"
        )
    return shape, dtype, fortran, offset, info


def _read_array(path, zf, name, head):
    """The member's data, streamed into an array of the declared (checked) size; never more is inflated."""
    shape, dtype, fortran, offset, info = head
    out = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
    view = memoryview(out.reshape(-1, order="A").view(np.uint8)) if out.size else memoryview(b"")
    with zf.open(info) as fh:
        fh.read(offset)
        got = 0
        while got < len(view):
            chunk = fh.read(min(1 << 22, len(view) - got))
            if not chunk:
                raise OperatorFileError(f"{path}: array {name!r} is truncated ({got} of {len(view)} bytes)")
            view[got : got + len(chunk)] = chunk
            got += len(chunk)
        fh.read(1)  # the end of the member: zipfile checks its CRC here (BadZipFile if damaged)
    return out


def _json_header(path, zf, headers):
    """The JSON header, its size and nesting depth checked before it is parsed."""
    shape, dtype, _, _, _ = headers["header"]
    if shape != () or dtype.kind != "U" or dtype.itemsize // 4 > MAX_HEADER_CHARS:
        raise OperatorFileError(
            f"{path}: the header must be one JSON string of at most {MAX_HEADER_CHARS} characters, got a {dtype} "
            f"array of shape {shape}"
        )
    text = str(_read_array(path, zf, "header", headers["header"]))
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise OperatorFileError(f"{path}: the JSON header is nested {depth} levels deep, limit {MAX_JSON_DEPTH}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise OperatorFileError(f"{path}: the header is not valid JSON ({exc})") from exc


def json_depth(text):
    """The deepest nesting of objects and lists in a JSON text, counted without parsing it (strings skipped)."""
    bare = re.sub(r'"(?:[^"\\]|\\.)*"', "", text)
    steps = np.frombuffer(bare.encode("utf-8", "replace"), np.uint8)
    level = np.cumsum(np.isin(steps, (ord("["), ord("{"))).astype(np.int64) - np.isin(steps, (ord("]"), ord("}"))))
    return int(level.max(initial=0))


def _check_declared(path, header, headers, version):
    """The declared shapes against each other and the limits, before any array is read."""

    def shape(name):
        return headers[name][0] if name in headers else None

    V, W, C = shape("V"), shape("W"), shape("basis_centers")
    if V is None or W is None or len(V) != 2 or len(W) != 2:
        return  # _build names what is missing or malformed (nothing large is read for it)
    d = V[1]
    if isinstance(header, dict) and ("dim" in header or version >= 3):  # (PolynomialBasis checks the degree)
        _field(path, "dim", header.get("dim"))
    if version >= 3 and isinstance(header, dict) and header.get("dim") != d:
        raise OperatorFileError(f"{path}: the header says dim = {header.get('dim')!r}, but V is {V[0]}×{V[1]}")
    if version < 3 and d != 2:
        raise OperatorFileError(f"{path}: a format-{version} operator file holds 2D meshes, but V is {V[0]}×{V[1]}")
    if C is not None and len(C) >= 1 and C[0] > MAX_CENTERS:
        raise OperatorFileError(f"{path} declares {C[0]} TPS centres, limit {MAX_CENTERS}")
    basis = header.get("basis") if isinstance(header, dict) else None
    degree = basis.get("degree") if isinstance(basis, dict) else None
    if isinstance(degree, (int, float)) and not isinstance(degree, bool) and degree > hb.MAX_DEGREE:
        raise OperatorFileError(f"{path} declares a handle basis of degree {degree}, limit {hb.MAX_DEGREE}")


def _field(path, name, value):
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


def _size(n):
    for unit, factor in (("GiB", 2**30), ("MiB", 2**20), ("kiB", 2**10)):
        if n >= factor:
            return f"{n / factor:.3g} {unit}"
    return f"{n} bytes"


def _array(data, name, ndim, dtype_kind, shape=None):
    """data[name] checked: dimension, kind (f/i/b), finite values, and ``shape`` (None = any)."""
    if name not in data:
        raise KeyError(f"array {name!r}")
    a = data[name]
    if a.ndim != ndim or a.dtype.kind not in dtype_kind:
        raise ValueError(f"array {name!r} must be {ndim}-D of kind {dtype_kind!r}, got {a.dtype} {a.shape}")
    if shape is not None and any(s is not None and s != t for s, t in zip(shape, a.shape)):
        raise ValueError(f"array {name!r} has shape {a.shape}, expected {tuple(shape)}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"array {name!r} has NaN or infinite values")
    return a


def _basis(header, data, P, version):
    """Ψ from the header's basis entry and the arrays (the kind, scale, degree and kernel checked)."""
    b = header["basis"]
    if not isinstance(b, dict):
        raise TypeError("header 'basis' must be an object")
    kind, scale = b["kind"], float(b["scale"])
    n, d = P.shape
    if kind == "tps":
        if version >= 3 and b.get("kernel", hb.KERNELS[d]) != hb.KERNELS[d]:
            raise ValueError(f"the {d}D TPS basis uses the kernel {hb.KERNELS[d]!r}, the file says {b.get('kernel')!r}")
        return hb.TPSBasis(P, _array(data, "basis_centers", 3, "f", (None, n, d)), scale)
    if kind == "linear":
        return hb.LinearBasis(P, scale)
    if kind in hb.KINDS or str(kind).startswith("degree"):
        return hb.PolynomialBasis(P, b["degree"], scale)
    raise ValueError(f"unknown handle basis {kind!r}")


def _build(cls, header, data, version):
    """The operator from a loaded header and arrays, validating both (raises KeyError/TypeError/ValueError)."""
    if not isinstance(header, dict):
        raise TypeError("the header must be a JSON object")
    meta = header["meta"]
    if not isinstance(meta, dict) or not isinstance(header["basis"], dict):
        raise TypeError("header 'meta' and 'basis' must be objects")
    V = _array(data, "V", 2, "f", (None, 2) if version < 3 else (None, None))
    d = V.shape[1]
    if d not in hb.DIMS:
        raise ValueError(f"V must have 2 or 3 columns (the dimension), got {V.shape}")
    F = _array(data, "F", 2, "iu", (None, d + 1))
    handles = _array(data, "handles", 1, "iu")
    moving = _array(data, "moving", 1, "b", handles.shape)
    mesh = Mesh(V, F)
    if handles.size and (handles.min() < 0 or handles.max() >= len(V)):
        raise ValueError(f"handle indices must lie in [0, {len(V)})")
    n = int(moving.sum())
    P = _array(data, "basis_P", 2, "f", (n, d))
    if not np.array_equal(P, V[handles[moving]]):
        raise ValueError("basis_P is not the rest position of the moving handles")
    psi = _basis(header, data, P, version)
    W = _array(data, "W", 2, "f", (psi.size, d * len(V)))
    samples = _array(data, "train_samples", 3, "f", (None, n, d)) if "train_samples" in data else None
    op = cls(mesh, handles, moving, psi, W, meta, samples)
    op.meta = meta
    if version == 1:  # format 1 factors compressed Ψ W without (★): recompute them
        if "factor_A" in data:
            op.compress(rank=header_int("meta.rank", meta.get("rank", 1)))
        return op
    if "factor_A" in data:
        A = _array(data, "factor_A", 2, "f", (psi.size - 1, None))
        B = _array(data, "factor_B", 2, "f", (A.shape[1], d * len(V)))
        if A.dtype != B.dtype or np.any(B[:, op.columns(op.handles)] != 0):
            raise ValueError("factor_B must be zero on the handle columns, in the dtype of factor_A")
        op.factors = (A, B)
    return op
