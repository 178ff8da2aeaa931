"""The movable-handle operator file (kind ``movable``, format ``defop-movable-1``): :meth:`MovableOp.save` and
``load``: the nominal mesh and handles, the joint TPS (``joint_W``, ``joint_centers``), the training reach, the
placement regions and, when compressed, the factors; the header holds the dimension, the scales and ``meta``."""

from __future__ import annotations

import json

import numpy as np

from ...scene.placement import PlacementRegions
from .. import handle_bases as hb
from . import files
from .files import OperatorFileError, array

FORMAT = "defop-movable-1"
MEMBERS = files.MESH_MEMBERS + (
    "joint_W",
    "joint_centers",
    "reach",
    "placement_movable",
    "placement_vertices",
    "placement_sizes",
    "placement_reach",
    "placement_members",
    "placement_member_sizes",
    "factor_A",
    "factor_B",
)
KIND = files.register(
    files.FileKind(
        "movable", {FORMAT: 1}, MEMBERS, "a movable-handle operator file", "defop.operator.MovableOp.load", "joint_W"
    )
)


def save_movable(op, path):
    """Write ``op`` (:class:`defop.operator.movable.MovableOp`) to ``path`` atomically: arrays, placement regions,
    JSON header."""
    arrays = {
        "V": op.mesh.V,
        "F": op.mesh.F,
        "handles": op.handles,
        "moving": op.moving,
        "joint_W": op.W,
        "joint_centers": op.basis.centers,
        **op.placement.to_arrays(),
    }
    if op.reach is not None:
        arrays["reach"] = op.reach
    if op.factors is not None:
        arrays["factor_A"], arrays["factor_B"] = op.factors
    header = {
        "format": FORMAT,
        "format_version": 1,
        "kind": "movable",
        "dim": op.d,
        "meta": op.meta,
        "scales": list(op.scales),
    }
    arrays["header"] = np.array(json.dumps(header))
    files.write(path, arrays)


def check_declared(path, header, shapes, version):
    """The header's dimension against V, and the declared TPS centres against the limit."""
    if not isinstance(header, dict):
        raise OperatorFileError(f"{path}: the header must be a JSON object, got {type(header).__name__}")
    d = files.field(path, "dim", header.get("dim"))
    V = shapes.get("V")
    if V is not None and (len(V) != 2 or V[1] != d):
        raise OperatorFileError(f"{path}: the header says dim = {d}, but V is {'×'.join(map(str, V))}")
    C = shapes.get("joint_centers")
    if C is not None and len(C) >= 1 and C[0] > files.MAX_CENTERS:
        raise OperatorFileError(f"{path} declares {C[0]} TPS centres, limit {files.MAX_CENTERS}")


def load_movable(path, cls):
    """Read a file of :func:`save_movable`, checked before any work (:func:`defop.operator.io.files.read_file`),
    then every array against the others, and build a ``cls`` (:class:`defop.operator.movable.MovableOp`); a
    ValueError (``OperatorFileError``) names the file and the problem."""
    header, data, _ = files.read_file(path, KIND, check_declared)
    with files.load_errors(path, "movable-handle operator file"):
        meta = files.header_object(header, "meta")
        mesh, handles, moving = files.mesh_and_handles(data)
        d, nv = mesh.dim, mesh.n_vertices
        regions = {k: array(data, k, 1, "iu") for k in ("placement_movable", "placement_vertices", "placement_sizes")}
        regions["placement_reach"] = array(data, "placement_reach", 1, "f")
        for k in ("placement_members", "placement_member_sizes"):
            if k in data:
                regions[k] = array(data, k, 1, "iu")
        pr = PlacementRegions.from_arrays(mesh, handles, moving, regions)
        C = array(data, "joint_centers", 3, "f", (None, pr.n_movable + int(moving.sum()), d))
        basis = hb.TPSBasis(np.zeros(C.shape[1:]), C, 1.0)
        W = array(data, "joint_W", 2, "f", (basis.size, d * nv))
        reach = array(data, "reach", 1, "f", (int(moving.sum()),)) if "reach" in data else None
        if reach is not None and np.any(reach < 0):
            raise ValueError(f"array 'reach' must be {len(reach)} non-negative finite lengths, got {reach}")
        s = header.get("scales")
        if (
            not isinstance(s, list)
            or len(s) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in s)
        ):
            raise ValueError(f"header 'scales' must be two positive numbers, got {s!r}")
        s = [float(x) for x in s]
        if not all(np.isfinite(s)) or min(s) <= 0:
            raise ValueError(f"header 'scales' must be two positive numbers, got {s}")
        op = cls(mesh, handles, moving, pr, basis, W, s, meta, reach)
        op.meta = meta
        if "factor_A" in data:
            fa = array(data, "factor_A", 2, "f", (basis.size - 1, None))
            fb = array(data, "factor_B", 2, "f", (fa.shape[1], d * nv))
            if fa.dtype != fb.dtype or np.any(fb[:, op.columns(op.still)] != 0):
                raise ValueError(
                    "factor_B must be zero on the columns of the handles that are not movable, in the dtype of factor_A"
                )
            op.factors = (fa, fb)
        return op
