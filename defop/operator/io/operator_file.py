"""The single-valued operator file (kind ``operator``): :meth:`DefOp.save` and :meth:`DefOp.load`."""

from __future__ import annotations

import json

import numpy as np

from .. import handle_bases as hb
from . import files
from .files import OperatorFileError, array, header_int

FORMAT = "defop-operator-3"
FORMAT_VERSION = 3
#: formats this version reads, with their version numbers (1 and 2 are 2D only)
READS = {"defop-operator-1": 1, "defop-operator-2": 2, FORMAT: FORMAT_VERSION}
MEMBERS = files.MESH_MEMBERS + (
    "W",
    "basis_P",
    "basis_centers",
    "train_samples",
    "factor_A",
    "factor_B",
)
KIND = files.register(files.FileKind("operator", READS, MEMBERS, "a single-valued operator file", "DefOp.load", "W"))


def save(op, path):
    """Write ``op`` to ``path`` as .npz: arrays plus the JSON header (exact round trip), atomically.

    The archive goes to a temporary file in the same folder, which is renamed into place only when it is
    complete: a reader sees the old file or the new one, never a partial one, and a failed save leaves no file.

    Parameters
    ----------
    op : defop.operator.defop.DefOp
    path : str or pathlib.Path
    """
    arrays, basis = operator_arrays(op)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "dim": op.d, "meta": op.meta, "basis": basis}
    arrays["header"] = np.array(json.dumps(header))
    files.write(path, arrays)


def operator_arrays(op):
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


def load(path, cls):
    """Read an operator file, checking it before any work (:mod:`defop.operator.io`), and build a ``cls``.

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
        of another kind (naming it and its loader), damaged or truncated, beyond a limit, of an unknown format,
        or with arrays that do not fit together.
    """
    header, data, version = files.read_file(path, KIND, check_declared)
    with files.load_errors(path, "defop operator file"):
        return build(cls, header, data, version)


def check_declared(path, header, shapes, version):
    """The declared shapes against each other and the limits, before any array is read."""
    V, W, C = shapes.get("V"), shapes.get("W"), shapes.get("basis_centers")
    if V is None or W is None or len(V) != 2 or len(W) != 2:
        return  # build names what is missing or malformed (nothing large is read for it)
    d = V[1]
    if isinstance(header, dict) and ("dim" in header or version >= 3):  # (PolynomialBasis checks the degree)
        files.field(path, "dim", header.get("dim"))
    if version >= 3 and isinstance(header, dict) and header.get("dim") != d:
        raise OperatorFileError(f"{path}: the header says dim = {header.get('dim')!r}, but V is {V[0]}×{V[1]}")
    if version < 3 and d != 2:
        raise OperatorFileError(f"{path}: a format-{version} operator file holds 2D meshes, but V is {V[0]}×{V[1]}")
    if C is not None and len(C) >= 1 and C[0] > files.MAX_CENTERS:
        raise OperatorFileError(f"{path} declares {C[0]} TPS centres, limit {files.MAX_CENTERS}")
    basis = header.get("basis") if isinstance(header, dict) else None
    degree = basis.get("degree") if isinstance(basis, dict) else None
    if isinstance(degree, (int, float)) and not isinstance(degree, bool) and degree > hb.MAX_DEGREE:
        raise OperatorFileError(f"{path} declares a handle basis of degree {degree}, limit {hb.MAX_DEGREE}")


def basis_of(header, data, P, version):
    """Ψ from the header's basis entry and the arrays (the kind, scale, degree and kernel checked)."""
    b = files.header_object(header, "basis")
    kind, scale = b["kind"], float(b["scale"])
    n, d = P.shape
    if kind == "tps":
        if version >= 3 and b.get("kernel", hb.KERNELS[d]) != hb.KERNELS[d]:
            raise ValueError(f"the {d}D TPS basis uses the kernel {hb.KERNELS[d]!r}, the file says {b.get('kernel')!r}")
        return hb.TPSBasis(P, array(data, "basis_centers", 3, "f", (None, n, d)), scale)
    if kind == "linear":
        return hb.LinearBasis(P, scale)
    if kind in hb.KINDS or str(kind).startswith("degree"):
        return hb.PolynomialBasis(P, b["degree"], scale)
    raise ValueError(f"unknown handle basis {kind!r}")


def build(cls, header, data, version):
    """The operator from a loaded header and arrays, validating both (raises KeyError/TypeError/ValueError)."""
    meta = files.header_object(files.header_object(header, None), "meta")
    files.header_object(header, "basis")
    if version < 3:
        array(data, "V", 2, "f", (None, 2))
    mesh, handles, moving = files.mesh_and_handles(data)
    V = mesh.V
    d = V.shape[1]
    n = int(moving.sum())
    P = array(data, "basis_P", 2, "f", (n, d))
    if not np.array_equal(P, V[handles[moving]]):
        raise ValueError("basis_P is not the rest position of the moving handles")
    psi = basis_of(header, data, P, version)
    W = array(data, "W", 2, "f", (psi.size, d * len(V)))
    samples = array(data, "train_samples", 3, "f", (None, n, d)) if "train_samples" in data else None
    op = cls(mesh, handles, moving, psi, W, meta, samples)
    op.meta = meta
    if version == 1:  # format 1 factors compressed Ψ W without (★): recompute them
        if "factor_A" in data:
            op.compress(rank=header_int("meta.rank", meta.get("rank", 1)))
        return op
    if "factor_A" in data:
        A = array(data, "factor_A", 2, "f", (psi.size - 1, None))
        B = array(data, "factor_B", 2, "f", (A.shape[1], d * len(V)))
        if A.dtype != B.dtype or np.any(B[:, op.columns(op.handles)] != 0):
            raise ValueError("factor_B must be zero on the handle columns, in the dtype of factor_A")
        op.factors = (A, B)
    return op
