"""The multi-valued operator file (kind ``branched``): :meth:`BranchedOperator.save` and ``load``.

One archive: the mesh, handles and ``mode`` once, each branch's arrays prefixed ``b<label>.`` (``W``,
``basis_centers``, ``train_samples``, the factors, ``energy``, ``domain_w``, ``domain_centers`` and, in version-1
files, ``margin``), and the header's ``branches`` list (label, side, meta, basis and domain of each); every branch
is checked as a single-valued file is. Version 2 adds each branch's domain function g_b (its own TPS) and the
samples' ``box``; a version-1 file's domain is λ²_b = Ψ_b(Q) · l_b (``margin``), read as a domain on Ψ_b.
"""

from __future__ import annotations

import json

import numpy as np

from ... import options as opt
from .. import handle_bases as hb
from . import files, operator_file
from .files import OperatorFileError, array, header_int

BRANCHED_FORMAT = "defop-branched-2"
BRANCHED_READS = {"defop-branched-1": 1, BRANCHED_FORMAT: 2}
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
SHARED_MEMBERS = files.MESH_MEMBERS + ("basis_P", "mode", "box")
KIND = files.register(
    files.FileKind(
        "branched",
        BRANCHED_READS,
        SHARED_MEMBERS + tuple(f"b{k}.{n}" for k in range(files.MAX_BRANCHES) for n in BRANCH_MEMBERS),
        "a multi-valued operator file (kind 'branched')",
        "BranchedOperator.load",
        "mode",
    )
)


def save_branched(bop, path):
    """Write a :class:`defop.operator.branched.BranchedOperator` (module docstring), atomically.

    The mesh and handles once; per branch b its DefOp's arrays, e_b and g_b under ``b<label>.``; the mode u.
    """
    if len(bop.branches) > files.MAX_BRANCHES:
        raise ValueError(f"a file holds at most {files.MAX_BRANCHES} branches, got {len(bop.branches)}")
    arrays, entries = {"mode": bop.mode}, []
    for b in bop.branches:
        own, basis = operator_file.operator_arrays(b.op)
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
    files.write(path, arrays)


def branch_view(header, data, k):
    """The header and arrays of branch k as a format-3 single-valued file's."""
    entry = header["branches"][k]
    if not isinstance(entry, dict) or header_int(f"branches[{k}].label", entry.get("label")) != k:
        raise ValueError(f"branch entry {k} must be an object with label {k}")
    sub = {name: data[name] for name in ("V", "F", "handles", "moving", "basis_P") if name in data}
    sub.update({n: data[f"b{k}.{n}"] for n in BRANCH_MEMBERS if f"b{k}.{n}" in data})
    return {"meta": entry.get("meta"), "basis": entry.get("basis"), "dim": header.get("dim")}, sub


def check_declared(path, header, shapes, version):
    """Each branch's declared shapes as a single-valued file's (:func:`operator_file.check_declared`)."""
    entries = header.get("branches") if isinstance(header, dict) else None
    if not isinstance(entries, list) or not 1 <= len(entries) <= files.MAX_BRANCHES:
        raise OperatorFileError(f"{path}: the header must list 1 to {files.MAX_BRANCHES} branches")
    for k, entry in enumerate(entries):
        sub_head = {"dim": header.get("dim"), "basis": entry.get("basis") if isinstance(entry, dict) else None}
        sub = {n: shapes[n] for n in ("V", "F") if n in shapes}
        sub.update({n: shapes[f"b{k}.{n}"] for n in ("W", "basis_centers") if f"b{k}.{n}" in shapes})
        operator_file.check_declared(path, sub_head, sub, operator_file.FORMAT_VERSION)


def domain_of(entry, data, k, op, domain_cls):
    """Branch k's domain g_b of a version-2 file (None: λ²_b on Ψ_b, from ``margin``)."""
    d = entry.get("domain")
    if not isinstance(d, dict) or not isinstance(d.get("own"), bool):
        raise TypeError(f"branch entry {k}'s 'domain' must be an object with a boolean 'own'")
    if not d["own"]:
        return None
    n, dim = op.P.shape
    if d.get("kernel") != hb.KERNELS[dim]:
        raise ValueError(
            f"the {dim}D domain TPS uses the kernel {hb.KERNELS[dim]!r}, the file says {d.get('kernel')!r}"
        )
    basis = hb.TPSBasis(op.P, array(data, f"b{k}.domain_centers", 3, "f", (None, n, dim)), float(d["scale"]))
    return domain_cls(basis, array(data, f"b{k}.domain_w", 1, "f", (basis.size,)))


def load_branched(path, cls, branch_cls, op_cls, domain_cls=None):
    """Read a file written by :func:`save_branched`, with the checks of a single-valued file; build a ``cls``.

    Raises
    ------
    ValueError
        (:class:`OperatorFileError`) naming the file and the problem (another kind's file: its kind and loader).
    """
    header, data, version = files.read_file(path, KIND, check_declared)
    with files.load_errors(path, "multi-valued operator file"):
        files.header_object(header, None)
        branches = []
        for k, entry in enumerate(header["branches"]):
            sub_head, sub = branch_view(header, data, k)
            op = operator_file.build(op_cls, sub_head, sub, operator_file.FORMAT_VERSION)
            energy = array(data, f"b{k}.energy", 1, "f", (op.handle_basis.size,))
            domain = domain_of(entry, data, k, op, domain_cls) if version >= 2 else None
            margin = None
            if domain is None or f"b{k}.margin" in data:
                margin = array(data, f"b{k}.margin", 1, "f", (op.handle_basis.size,))
            side = header_int(f"branches[{k}].side", entry.get("side"), allowed=(1, -1))
            branches.append(branch_cls(k, op, energy, margin, side, domain=domain))
        mode = array(data, "mode", 2, "f", data["V"].shape)
        meta = files.header_object(header, "meta")
        box = array(data, "box", 2, "f", (2, branches[0].op.P.size)) if version >= 2 else None
        return cls(branches, mode, opt.real_array("the header's threshold", header["threshold"]), meta, box=box)
